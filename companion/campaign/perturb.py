"""Perturbations of a Monte-Carlo replay campaign: ranges, per-run sampling, replay arguments.

Pure (numpy only, no clock, no I/O). Run `i` of a campaign with seed `s` draws its values from
`numpy.random.default_rng([s, i])`, in a fixed order, so the same run of every mission and every
setpoint mode sees the same wind, mass error, ... (paired comparisons) and adding runs never
changes earlier ones. Values are rounded (4 decimals) and written as `replay` options with
`repr`, so the printed command re-creates the run bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # (kept out of `python -m companion` start-up: the replay stack is heavy)
    from companion.replay.runner import ReplayConfig

#: Quantisation of sampled values (decimals), so commands stay readable and exact.
DECIMALS = 4
#: The mock's defaults the relative errors apply to (PX4 SIH quadrotor, sitl_mock/params.py).
SIH_MASS_KG = 1.0
SIH_INERTIA_KG_M2 = (0.025, 0.025, 0.030)
SIH_KDV_N_PER_M_S = 1.0
#: Hover thrust the companion and MPC_THR_HOVER assume by default (the true value is 0.49).
HOVER_THRUST = 0.5


@dataclass(frozen=True)
class PerturbationRanges:
    """Ranges runs are drawn from (uniform; errors are relative, +-value; 0 turns one off).

    wind_max_m_s: steady wind speed 0..max, direction uniform over the compass.
    gust_max_m_s: gust std 0..max (sitl_mock SIM_WIND_GUST, correlation SIM_WIND_GUST_T 2 s).
    mass_error, inertia_error, drag_error: the mock's SIH_MASS, SIH_I{XX,YY,ZZ} (each axis on
    its own), SIH_KDV = default * (1 + e) while the companion keeps the defaults.
    hover_thrust_error: the hover thrust the companion and PX4 (MPC_THR_HOVER) are told,
    0.5 * (1 + e), against the true one (0.49 times the mass ratio).
    latency_max_s, jitter_max_s: telemetry delay 0..max plus uniform jitter 0..max.
    loss_max_pct: datagram loss 0..max in both directions.
    pos_noise_max_m: SIM_POS_NOISE 0..max [m]; SIM_VEL_NOISE is half of it [m/s]. The mock
    adds it to each sample, white; PX4 sends the EKF2 output predictor's estimate, which IMU
    propagation and EKF2_TAU_POS smooth: on real PX4 v1.16 SIH the position steps that the
    velocity does not explain are 4-11 mm std (p99 18-29 mm). The default 0.02 gives up to
    28 mm std (2.5-7x that); the former 0.1 gave 127 mm (10-25x), and its sample-to-sample
    jumps, times the position gain, were what failed the session-19 campaign's thrust-chatter
    runs (BENCHMARKS.md, session 20).
    start_offset_max_m: vehicle placed 0..max metres from the planned home, any direction.
    """

    wind_max_m_s: float = 6.0
    gust_max_m_s: float = 1.5
    mass_error: float = 0.2
    inertia_error: float = 0.3
    hover_thrust_error: float = 0.1
    drag_error: float = 0.3
    latency_max_s: float = 0.05
    jitter_max_s: float = 0.02
    loss_max_pct: float = 5.0
    pos_noise_max_m: float = 0.02
    start_offset_max_m: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{f.name} must be a finite value >= 0, got {v!r}")
        for name in ("mass_error", "inertia_error", "hover_thrust_error", "drag_error"):
            if getattr(self, name) >= 0.9:
                raise ValueError(f"{name} must be < 0.9 (a relative error), got "
                                 f"{getattr(self, name)}")
        if self.loss_max_pct > 100.0:
            raise ValueError(f"loss_max_pct must be <= 100, got {self.loss_max_pct}")


@dataclass(frozen=True)
class Perturbation:
    """The values one run flies with (units in the names; errors relative)."""

    seed: int
    wind_m_s: float
    wind_from_deg: float
    gust_m_s: float
    mass_error: float
    inertia_error_x: float
    inertia_error_y: float
    inertia_error_z: float
    hover_thrust_error: float
    drag_error: float
    latency_s: float
    jitter_s: float
    loss_pct: float
    pos_noise_m: float
    start_offset_n_m: float
    start_offset_e_m: float

    @property
    def hover_thrust(self) -> float:
        """Hover thrust the companion and MPC_THR_HOVER are given [0..1]."""
        return _q(HOVER_THRUST * (1.0 + self.hover_thrust_error))

    def mock_params(self) -> list[tuple[str, float]]:
        """The mock's true vehicle and sensor parameters for this run (only non-defaults)."""
        ix, iy, iz = SIH_INERTIA_KG_M2
        out = [
            ("SIH_MASS", _q(SIH_MASS_KG * (1.0 + self.mass_error))),
            ("SIH_IXX", _q6(ix * (1.0 + self.inertia_error_x))),
            ("SIH_IYY", _q6(iy * (1.0 + self.inertia_error_y))),
            ("SIH_IZZ", _q6(iz * (1.0 + self.inertia_error_z))),
            ("SIH_KDV", _q(SIH_KDV_N_PER_M_S * (1.0 + self.drag_error))),
            ("MPC_THR_HOVER", self.hover_thrust),
            ("SIM_WIND_GUST", self.gust_m_s),
            ("SIM_POS_NOISE", self.pos_noise_m),
            ("SIM_VEL_NOISE", _q(0.5 * self.pos_noise_m)),
        ]
        defaults = {"SIH_MASS": SIH_MASS_KG, "SIH_IXX": ix, "SIH_IYY": iy, "SIH_IZZ": iz,
                    "SIH_KDV": SIH_KDV_N_PER_M_S, "MPC_THR_HOVER": HOVER_THRUST}
        return [(k, v) for k, v in out if v != defaults.get(k, 0.0)]

    def replay_args(self) -> list[str]:
        """`python -m companion replay` options that fly exactly this run."""
        args = ["--seed", str(self.seed)]
        if self.wind_m_s:
            args += ["--wind", repr(self.wind_m_s), "--wind-from", repr(self.wind_from_deg)]
        if self.hover_thrust != HOVER_THRUST:
            args += ["--hover-thrust", repr(self.hover_thrust)]
        if self.latency_s:
            args += ["--latency", repr(self.latency_s)]
        if self.jitter_s:
            args += ["--jitter", repr(self.jitter_s)]
        if self.loss_pct:
            args += ["--loss", repr(self.loss_pct)]
        if self.start_offset_n_m or self.start_offset_e_m:
            # '=' form: a negative north value would otherwise look like an option
            args += [f"--start-offset={self.start_offset_n_m!r},{self.start_offset_e_m!r}"]
        for name, value in self.mock_params():
            args += ["--mock-param", f"{name}={value!r}"]
        return args

    def replay_config(self, base: ReplayConfig) -> ReplayConfig:
        """`base` (vehicle, mode, rate) with this run's values; what `replay` builds from
        `replay_args()` (a test checks both agree)."""
        return dataclasses.replace(
            base,
            seed=self.seed,
            wind_m_s=self.wind_m_s,
            wind_from_deg=self.wind_from_deg if self.wind_m_s else base.wind_from_deg,
            params=dataclasses.replace(base.params, hover_thrust=self.hover_thrust),
            mock_params=tuple(self.mock_params()),
            latency_s=self.latency_s,
            jitter_s=self.jitter_s,
            loss_pct=self.loss_pct,
            start_offset_ne_m=(self.start_offset_n_m, self.start_offset_e_m),
        )

    def as_row(self) -> dict[str, float | int]:
        """Flat column -> value mapping (for the results table)."""
        row: dict[str, float | int] = asdict(self)
        row["hover_thrust"] = self.hover_thrust
        row["start_offset_m"] = _q(math.hypot(self.start_offset_n_m, self.start_offset_e_m))
        return row


def _q(x: float) -> float:
    return float(round(float(x), DECIMALS)) + 0.0  # + 0.0: no negative zero in commands


def _q6(x: float) -> float:
    return float(round(float(x), 6)) + 0.0


def sample(ranges: PerturbationRanges, campaign_seed: int, run_index: int) -> Perturbation:
    """Values of run `run_index` of the campaign seeded `campaign_seed` (see module docstring).

    Every draw is made whether or not its range is zero, so turning one perturbation off does
    not change the others."""
    import numpy as np

    if campaign_seed < 0 or run_index < 0:
        raise ValueError("campaign seed and run index must be >= 0")
    rng = np.random.default_rng([campaign_seed, run_index])
    u = rng.random(16)
    r = ranges

    def sym(x: float, e: float) -> float:
        return _q((2.0 * x - 1.0) * e)

    off_r = r.start_offset_max_m * math.sqrt(u[14])  # uniform over the disc
    off_a = 2.0 * math.pi * u[15]
    return Perturbation(
        seed=int(rng.integers(0, 2**31 - 1)),
        wind_m_s=_q(u[0] * r.wind_max_m_s),
        wind_from_deg=_q(u[1] * 360.0) if r.wind_max_m_s else 0.0,
        gust_m_s=_q(u[2] * r.gust_max_m_s),
        mass_error=sym(u[3], r.mass_error),
        inertia_error_x=sym(u[4], r.inertia_error),
        inertia_error_y=sym(u[5], r.inertia_error),
        inertia_error_z=sym(u[6], r.inertia_error),
        hover_thrust_error=sym(u[7], r.hover_thrust_error),
        drag_error=sym(u[8], r.drag_error),
        latency_s=_q(u[9] * r.latency_max_s),
        jitter_s=_q(u[10] * r.jitter_max_s),
        loss_pct=_q(u[11] * r.loss_max_pct),
        pos_noise_m=_q(u[12] * r.pos_noise_max_m),
        # u[13] is reserved (kept so future perturbations do not shift the offset draws)
        start_offset_n_m=_q(off_r * math.cos(off_a)),
        start_offset_e_m=_q(off_r * math.sin(off_a)),
    )


__all__ = ["Perturbation", "PerturbationRanges", "sample"]
