"""Build the checked-in C setpoint library with the system C compiler and call it via ctypes.

This module imports nothing from ``companion`` (so ``companion`` may import it without a
cycle). The shared library is compiled on first use into a cache directory keyed by a hash of
the sources, the compiler and the flags (``$ECCA_GEN_C_CACHE``, else
``$XDG_CACHE_HOME/ecca-offboard/gen_c``, else ``~/.cache/ecca-offboard/gen_c``); later loads
reuse it. :func:`load_setpoint_library` returns ``None`` when no compiler is available or the
build fails, so callers can fall back to the pure-Python path::

    native = load_setpoint_library()
    if native is not None:
        sp = native.multirotor(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, params)
        # from a PiecewiseBezier: state, sp = native.trajectory_setpoint(traj, t, params)
        # rover (car-like with a wheel base): native.rover(vel_xy, acc_xy, jerk_xy, 0.3)
    else:
        sp = multirotor_setpoint(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, params)

Units, frames and field names are those of ``companion.flatness`` (NED, FRD, SI, q_wxyz).
Call :func:`load_setpoint_library` once at start-up, not in the control loop: the first call
in a fresh cache compiles the library (a few seconds). Results agree with the Python path to
1e-12 relative (double), tested in ``tests/gen_c/test_gen_c_native.py``.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

__all__ = [
    "LIB_DIR",
    "NativeBuildError",
    "NativeFlatState",
    "NativeMultirotorSetpoint",
    "NativeRoverSetpoint",
    "NativeSetpoint",
    "PiecewiseLike",
    "build_library",
    "cache_dir",
    "find_compiler",
    "load_setpoint_library",
]

log = logging.getLogger(__name__)

LIB_DIR = Path(__file__).resolve().parent / "ecca_setpoint"
SOURCES = ("ecca_setpoint.c", "ecca_gen_d.c", "ecca_gen_f.c")
HEADERS = ("ecca_setpoint.h", "ecca_setpoint_gen.h", "ecca_gen_d.h", "ecca_gen_f.h",
           "ecca_setpoint_impl.inc")
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared")
NUM_CTRL_PTS = 8

Precision = Literal["double", "float"]
FloatArray = npt.NDArray[np.float64]


class NativeBuildError(RuntimeError):
    """The C library could not be compiled or loaded."""


class MultirotorParamsLike(Protocol):
    """Anything with the fields of ``companion.flatness.MultirotorParams``."""

    @property
    def mass(self) -> float: ...
    @property
    def inertia(self) -> Any: ...
    @property
    def g(self) -> float: ...
    @property
    def hover_thrust(self) -> float: ...
    @property
    def drag(self) -> float: ...


def cache_dir() -> Path:
    """Folder of compiled libraries (created on demand)."""
    env = os.environ.get("ECCA_GEN_C_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "ecca-offboard" / "gen_c"


def find_compiler() -> str | None:
    """``$CC`` if set, else the first of cc, gcc, clang on PATH; None if there is none."""
    env = os.environ.get("CC")
    if env:
        return shutil.which(env) or env
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _source_hash(lib_dir: Path, compiler: str, flags: tuple[str, ...],
                 files: tuple[str, ...] = SOURCES + HEADERS) -> str:
    h = hashlib.sha256()
    try:
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True,
                                 timeout=30, check=False).stdout
    except (OSError, subprocess.SubprocessError):
        version = ""
    h.update(compiler.encode() + b"\0" + version.encode() + b"\0" + " ".join(flags).encode())
    for name in files:
        h.update(b"\0" + name.encode() + b"\0" + (lib_dir / name).read_bytes())
    return h.hexdigest()[:20]


def build_library(lib_dir: Path = LIB_DIR, *, cache: Path | None = None,
                  compiler: str | None = None, extra_flags: tuple[str, ...] = (),
                  sources: tuple[str, ...] = SOURCES, headers: tuple[str, ...] = HEADERS,
                  name: str = "ecca_setpoint") -> Path:
    """Compile ``sources`` of ``lib_dir`` into a shared library ``lib<name>-<hash>.so`` in the
    cache (if not there yet); its path. The defaults build the setpoint library.

    Raises :class:`NativeBuildError` with the compiler output if compilation fails.
    """
    cc = compiler or find_compiler()
    if cc is None:
        raise NativeBuildError("no C compiler found (set $CC or install cc/gcc/clang)")
    flags = CFLAGS + tuple(extra_flags)
    out_dir = cache or cache_dir()
    key = _source_hash(lib_dir, cc, flags, sources + headers)
    target = out_dir / f"lib{name}-{key}.so"
    if target.exists():
        return target
    out_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=".build-", suffix=".so", dir=out_dir)
    os.close(fd)
    cmd = [cc, *flags, f"-I{lib_dir}", *(str(lib_dir / s) for s in sources), "-o", tmp_name,
           "-lm"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
        if proc.returncode != 0:
            raise NativeBuildError(
                f"compiling the C library {name} failed ({' '.join(cmd)}):\n{proc.stderr}")
        os.replace(tmp_name, target)  # atomic: concurrent builders race harmlessly
    finally:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
    return target


# ---------------------------------------------------------------------- ctypes mirrors


def _structs(real: type[Any]) -> dict[str, type[ctypes.Structure]]:
    class Segment(ctypes.Structure):
        _fields_ = [("ctrl_pts_ned_m", real * 3 * NUM_CTRL_PTS),
                    ("yaw_ctrl_pts_rad", real * NUM_CTRL_PTS), ("duration_s", real)]

    class FlatState(ctypes.Structure):
        _fields_ = [("pos_ned_m", real * 3), ("vel_ned_m_s", real * 3),
                    ("acc_ned_m_s2", real * 3), ("jerk_ned_m_s3", real * 3),
                    ("snap_ned_m_s4", real * 3), ("yaw_rad", real), ("yaw_rate_rad_s", real),
                    ("yaw_acc_rad_s2", real)]

    class Params(ctypes.Structure):
        _fields_ = [("mass_kg", real), ("inertia_frd_kg_m2", real * 3 * 3),
                    ("gravity_m_s2", real), ("hover_thrust", real), ("drag_n_s_m", real)]

    class Attitude(ctypes.Structure):
        _fields_ = [("thrust_n", real), ("thrust_dot_n_s", real), ("thrust_ddot_n_s2", real),
                    ("thrust_norm", real), ("q_wxyz", real * 4), ("omega_frd_rad_s", real * 3),
                    ("omega_dot_frd_rad_s2", real * 3), ("moment_frd_n_m", real * 3),
                    ("flags", ctypes.c_uint), ("singular", ctypes.c_int)]

    class Heading(ctypes.Structure):
        _fields_ = [("yaw_rad", real), ("speed_m_s", real), ("speed_dot_m_s2", real),
                    ("yaw_rate_rad_s", real), ("yaw_acc_rad_s2", real),
                    ("singular", ctypes.c_int)]

    class Steering(ctypes.Structure):
        _fields_ = [("heading", Heading), ("curvature_1_m", real),
                    ("curvature_rate_1_m_s", real), ("steer_angle_rad", real),
                    ("steer_rate_rad_s", real)]

    return {"segment": Segment, "state": FlatState, "params": Params, "attitude": Attitude,
            "heading": Heading, "steering": Steering}


_ERRORS = {
    -1: "internal error: NULL pointer passed to the C setpoint library",
    -2: "refusing to compute a setpoint from a non-finite or out-of-range input "
        "(NaN/inf, |value| > 1e12, duration <= 0, mass <= 0, g <= 0, hover_thrust outside "
        "(0, 1], drag < 0, wheel base outside (0, 1e12] m)",
    -3: "the setpoint would be non-finite: inputs are far outside any flyable range",
}


@dataclass(frozen=True)
class NativeFlatState:
    """Evaluated Bezier segment: NED position..snap (m, m/s, ...), yaw (rad) and derivatives."""

    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    jerk: FloatArray
    snap: FloatArray
    yaw: float
    yaw_rate: float
    yaw_acc: float


@dataclass(frozen=True)
class NativeMultirotorSetpoint:
    """Same fields, units and frames as ``companion.flatness.MultirotorSetpoint``."""

    thrust: float
    thrust_dot: float
    thrust_ddot: float
    thrust_norm: float
    q_wxyz: FloatArray
    omega_frd: FloatArray
    omega_dot_frd: FloatArray
    moment_frd: FloatArray
    singular: bool
    flags: int

    @property
    def C_eb(self) -> FloatArray:
        """Attitude as a DCM (body FRD -> world NED), from ``q_wxyz``."""
        return _quat_to_dcm(self.q_wxyz)


@dataclass(frozen=True)
class NativeRoverSetpoint:
    """Same fields as ``companion.flatness.RoverSetpoint`` (the Ackermann fields curvature
    [1/m], curvature_rate [1/(m s)], steer_angle [rad], steer_rate [rad/s] are None without a
    wheel base; the rates also without jerk)."""

    yaw: float
    speed: float
    speed_dot: float
    yaw_rate: float
    yaw_acc: float | None
    singular: bool
    curvature: float | None = None
    curvature_rate: float | None = None
    steer_angle: float | None = None
    steer_rate: float | None = None


def _quat_to_dcm(q: FloatArray) -> FloatArray:
    """C_eb (body FRD -> world NED) of a unit Hamilton quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _view(struct: Any, prec: str) -> npt.NDArray[Any]:
    """The reals of a ctypes struct as a writable numpy view (float64 or float32)."""
    dt = np.float64 if prec == "double" else np.float32
    return np.frombuffer(struct, dtype=dt)


def _vec(x: npt.ArrayLike, n: int, name: str) -> FloatArray:
    if type(x) is np.ndarray and x.shape == (n,) and x.dtype == np.float64:
        return x  # fast path of the per-cycle call
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) (one sample), got {a.shape}")
    return a


class NativeSetpoint:
    """The compiled library (double and float variants) behind a small Python API.

    Methods take one sample (plain floats / length-n sequences), like the single-sample path of
    ``companion.flatness``, and raise ``ValueError`` where it would (non-finite input).
    Thread-safe: the C functions are re-entrant and every call uses its own structs.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lib = ctypes.CDLL(str(path))
        self._s = {"double": _structs(ctypes.c_double), "float": _structs(ctypes.c_float)}
        self._fn: dict[tuple[str, str], Any] = {}
        self._param_cache: dict[tuple[Any, ...], Any] = {}
        self._tls = threading.local()
        for prec, sfx, real in (("double", "", ctypes.c_double), ("float", "_f", ctypes.c_float)):
            s = self._s[prec]
            P = ctypes.POINTER
            sig = {
                "bezier": ("ecca_bezier_eval", [P(s["segment"]), real, P(s["state"])]),
                "multirotor": ("ecca_multirotor_setpoint",
                               [P(s["state"]), P(s["params"]), P(s["attitude"])]),
                "rover": ("ecca_rover_setpoint", [P(s["state"]), P(s["heading"])]),
                "full": ("ecca_full_setpoint", [P(s["segment"]), real, P(s["params"]),
                                                P(s["state"]), P(s["attitude"])]),
                "full_rover": ("ecca_full_rover_setpoint",
                               [P(s["segment"]), real, P(s["state"]), P(s["heading"])]),
                "ackermann": ("ecca_ackermann_setpoint",
                              [P(s["state"]), real, P(s["steering"])]),
                "full_ackermann": ("ecca_full_ackermann_setpoint",
                                   [P(s["segment"]), real, real, P(s["state"]),
                                    P(s["steering"])]),
                "tracking_core": ("ecca_tracking_core", [P(real), P(real)]),
                "disturbance_step": ("ecca_disturbance_step", [P(real), P(real)]),
                "velocity_correction_step": ("ecca_velocity_correction_step",
                                             [P(real), P(real)]),
            }
            for key, (cname, argtypes) in sig.items():
                fn = getattr(self._lib, cname + sfx)
                fn.argtypes = argtypes
                fn.restype = ctypes.c_int
                self._fn[(prec, key)] = fn
        ver = self._lib.ecca_setpoint_casadi_version
        ver.restype = ctypes.c_char_p
        ver.argtypes = []
        self.casadi_version: str = ver().decode()

    # -- helpers ----------------------------------------------------------------------------
    def _call(self, prec: str, key: str, *args: Any) -> None:
        rc = self._fn[(prec, key)](*args)
        if rc != 0:
            raise ValueError(_ERRORS.get(rc, f"C setpoint library error {rc}"))

    def _params(self, prec: str, params: MultirotorParamsLike) -> Any:
        inertia = params.inertia
        if not isinstance(inertia, tuple):
            inertia = tuple(np.asarray(inertia, dtype=np.float64).ravel().tolist())
        key = (prec, params.mass, inertia, params.g, params.hover_thrust, params.drag)
        cached = self._param_cache.get(key)
        if cached is None:
            if len(self._param_cache) >= 16:
                self._param_cache.clear()
            cached = self._param_cache[key] = self._make_params(prec, params)
        return cached

    def _make_params(self, prec: str, params: MultirotorParamsLike) -> Any:
        p = self._s[prec]["params"]()
        p.mass_kg = float(params.mass)
        J = np.asarray(params.inertia, dtype=np.float64)
        if J.shape == (3,):
            J = np.diag(J)
        if J.shape != (3, 3):
            raise ValueError(f"inertia must be 3x3 (kg m^2), got {J.shape}")
        for i in range(3):
            for k in range(3):
                p.inertia_frd_kg_m2[i][k] = float(J[i, k])
        p.gravity_m_s2 = float(params.g)
        p.hover_thrust = float(params.hover_thrust)
        p.drag_n_s_m = float(params.drag)
        return p

    def _segment(self, prec: str, ctrl_pts: npt.ArrayLike, yaw_ctrl_pts: npt.ArrayLike | None,
                 duration: float) -> Any:
        seg = self._s[prec]["segment"]()
        cp = np.asarray(ctrl_pts, dtype=np.float64)
        if cp.shape != (NUM_CTRL_PTS, 3):
            raise ValueError(f"ctrl_pts must have shape ({NUM_CTRL_PTS}, 3) (degree 7, NED m); "
                             f"elevate lower-degree segments first, got {cp.shape}")
        ycp = (np.zeros(NUM_CTRL_PTS) if yaw_ctrl_pts is None
               else np.asarray(yaw_ctrl_pts, dtype=np.float64).reshape(-1))
        if ycp.shape != (NUM_CTRL_PTS,):
            raise ValueError(f"yaw_ctrl_pts must have {NUM_CTRL_PTS} values, got {ycp.shape}")
        x = _view(seg, prec)
        x[: 3 * NUM_CTRL_PTS] = cp.ravel()  # layout: ctrl_pts[8][3], yaw_ctrl_pts[8], duration
        x[3 * NUM_CTRL_PTS : 4 * NUM_CTRL_PTS] = ycp
        x[4 * NUM_CTRL_PTS] = duration
        return seg

    @staticmethod
    def _flat(st: Any, prec: str) -> NativeFlatState:
        y = _view(st, prec)[:18].astype(np.float64)
        return NativeFlatState(pos=y[0:3], vel=y[3:6], acc=y[6:9], jerk=y[9:12], snap=y[12:15],
                               yaw=float(y[15]), yaw_rate=float(y[16]), yaw_acc=float(y[17]))

    @staticmethod
    def _attitude(a: Any, prec: str) -> NativeMultirotorSetpoint:
        # The struct starts with 17 reals: thrust x4, q_wxyz[4], omega[3], omega_dot[3], moment[3]
        y = _view(a, prec)[:17].astype(np.float64)
        return NativeMultirotorSetpoint(
            thrust=float(y[0]), thrust_dot=float(y[1]), thrust_ddot=float(y[2]),
            thrust_norm=float(y[3]), q_wxyz=y[4:8], omega_frd=y[8:11], omega_dot_frd=y[11:14],
            moment_frd=y[14:17], singular=bool(a.singular), flags=int(a.flags))

    # -- public API -------------------------------------------------------------------------
    def bezier(self, ctrl_pts: npt.ArrayLike, yaw_ctrl_pts: npt.ArrayLike | None,
               duration: float, t: float, *, precision: Precision = "double") -> NativeFlatState:
        """Evaluate a degree-7 segment (ctrl_pts (8, 3) NED m, yaw_ctrl_pts (8,) rad or None,
        duration s) at local time t (s, clamped to [0, duration])."""
        seg = self._segment(precision, ctrl_pts, yaw_ctrl_pts, duration)
        st = self._s[precision]["state"]()
        self._call(precision, "bezier", ctypes.byref(seg), float(t), ctypes.byref(st))
        return self._flat(st, precision)

    def multirotor(self, vel: npt.ArrayLike, acc: npt.ArrayLike, jerk: npt.ArrayLike,
                   snap: npt.ArrayLike, yaw: float, yaw_rate: float, yaw_acc: float,
                   params: MultirotorParamsLike, *,
                   precision: Precision = "double") -> NativeMultirotorSetpoint:
        """Same arguments as ``companion.flatness.multirotor_setpoint`` (one sample)."""
        _st, x, att, att_ref, st_ref = self._scratch(precision)
        x[3:6] = _vec(vel, 3, "vel")  # layout: pos, vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc
        x[6:9] = _vec(acc, 3, "acc")
        x[9:12] = _vec(jerk, 3, "jerk")
        x[12:15] = _vec(snap, 3, "snap")
        x[15], x[16], x[17] = yaw, yaw_rate, yaw_acc
        self._call(precision, "multirotor", st_ref,
                   ctypes.byref(self._params(precision, params)), att_ref)
        return self._attitude(att, precision)

    def _scratch(self, prec: str) -> tuple[Any, npt.NDArray[Any], Any, Any, Any]:
        """Per-thread reusable input state / output attitude structs (with a numpy view and
        byref handles): the hot path allocates no ctypes objects."""
        cache = getattr(self._tls, prec, None)
        if cache is None:
            st = self._s[prec]["state"]()
            att = self._s[prec]["attitude"]()
            cache = (st, _view(st, prec), att, ctypes.byref(att), ctypes.byref(st))
            setattr(self._tls, prec, cache)
        return cache

    @staticmethod
    def _heading(hs: Any, jerk: bool, steering: Any = None) -> NativeRoverSetpoint:
        """NativeRoverSetpoint of a heading struct (and the steering struct around it)."""
        rates = None if steering is None or not jerk else steering
        return NativeRoverSetpoint(
            yaw=float(hs.yaw_rad), speed=float(hs.speed_m_s), speed_dot=float(hs.speed_dot_m_s2),
            yaw_rate=float(hs.yaw_rate_rad_s),
            yaw_acc=float(hs.yaw_acc_rad_s2) if jerk else None, singular=bool(hs.singular),
            curvature=None if steering is None else float(steering.curvature_1_m),
            curvature_rate=None if rates is None else float(rates.curvature_rate_1_m_s),
            steer_angle=None if steering is None else float(steering.steer_angle_rad),
            steer_rate=None if rates is None else float(rates.steer_rate_rad_s))

    def rover(self, vel_xy: npt.ArrayLike, acc_xy: npt.ArrayLike,
              jerk_xy: npt.ArrayLike | None = None, wheel_base_m: float | None = None, *,
              precision: Precision = "double") -> NativeRoverSetpoint:
        """Same arguments as ``companion.flatness.rover_setpoint`` (one sample):
        ``ecca_rover_setpoint``, or ``ecca_ackermann_setpoint`` with a wheel base (m)."""
        st = self._s[precision]["state"]()
        x = _view(st, precision)
        x[3:5] = _vec(vel_xy, 2, "vel_xy")
        x[6:8] = _vec(acc_xy, 2, "acc_xy")
        x[9:11] = 0.0 if jerk_xy is None else _vec(jerk_xy, 2, "jerk_xy")
        if wheel_base_m is None:
            hs = self._s[precision]["heading"]()
            self._call(precision, "rover", ctypes.byref(st), ctypes.byref(hs))
            return self._heading(hs, jerk_xy is not None)
        sp = self._s[precision]["steering"]()
        self._call(precision, "ackermann", ctypes.byref(st), float(wheel_base_m),
                   ctypes.byref(sp))
        return self._heading(sp.heading, jerk_xy is not None, sp)

    def tracking_core(self, x: npt.ArrayLike, *,
                      precision: Precision = "double") -> FloatArray:
        """``ecca_tracking_core``: the tracking law's core on one input vector `x` (the 60
        values of ``companion.control.core.CORE_INPUTS``); the 16 outputs (``CORE_OUTPUTS``).
        ValueError on a refused input or a non-finite result."""
        return self._vector_call("tracking_core", x, 60, 16, precision)

    def _vector_call(self, key: str, x: npt.ArrayLike, n_in: int, n_out: int,
                     precision: Precision) -> FloatArray:
        """A generated function of one input vector (`n_in` values) and one output vector."""
        real = ctypes.c_double if precision == "double" else ctypes.c_float
        xin = (real * n_in)(*_vec(x, n_in, "x").tolist())
        out = (real * n_out)()
        self._call(precision, key, xin, out)
        return np.array(out[:], dtype=np.float64)

    def disturbance_step(self, x: npt.ArrayLike, *,
                         precision: Precision = "double") -> FloatArray:
        """``ecca_disturbance_step``: the disturbance observer's update on one input vector `x`
        (the 12 values of ``companion.control.observer.DIST_INPUTS``); the 4 outputs
        (``DIST_OUTPUTS``: v_hat, d_hat). ValueError on a refused input or a non-finite
        result."""
        return self._vector_call("disturbance_step", x, 12, 4, precision)

    def velocity_correction_step(self, x: npt.ArrayLike, *,
                                 precision: Precision = "double") -> FloatArray:
        """``ecca_velocity_correction_step``: the velocity correction's update on one input
        vector `x` (the 15 values of ``companion.mavlink.velocity_correction.VCORR_INPUTS``);
        the 4 outputs (``VCORR_OUTPUTS``: p_hat, corr). ValueError on a refused input or a
        non-finite result."""
        return self._vector_call("velocity_correction_step", x, 15, 4, precision)

    def full_rover(self, ctrl_pts: npt.ArrayLike, duration: float, t: float,
                   wheel_base_m: float | None = None, *, precision: Precision = "double",
                   ) -> tuple[NativeFlatState, NativeRoverSetpoint]:
        """Evaluate a segment (ctrl_pts (8, 3) NED m, duration s) at local time t (s) and compute
        the rover setpoint of its x, y derivatives in one C call: ``ecca_full_rover_setpoint``,
        or ``ecca_full_ackermann_setpoint`` with a wheel base (m)."""
        seg = self._segment(precision, ctrl_pts, None, duration)
        st = self._s[precision]["state"]()
        if wheel_base_m is None:
            hs = self._s[precision]["heading"]()
            self._call(precision, "full_rover", ctypes.byref(seg), float(t), ctypes.byref(st),
                       ctypes.byref(hs))
            return self._flat(st, precision), self._heading(hs, True)
        sp = self._s[precision]["steering"]()
        self._call(precision, "full_ackermann", ctypes.byref(seg), float(t),
                   float(wheel_base_m), ctypes.byref(st), ctypes.byref(sp))
        return self._flat(st, precision), self._heading(sp.heading, True, sp)

    def full(self, ctrl_pts: npt.ArrayLike, yaw_ctrl_pts: npt.ArrayLike | None, duration: float,
             t: float, params: MultirotorParamsLike, *, precision: Precision = "double",
             ) -> tuple[NativeFlatState, NativeMultirotorSetpoint]:
        """Evaluate a segment at t and compute the multirotor setpoint, in one C call."""
        seg = self._segment(precision, ctrl_pts, yaw_ctrl_pts, duration)
        st = self._s[precision]["state"]()
        att = self._s[precision]["attitude"]()
        self._call(precision, "full", ctypes.byref(seg), float(t),
                   ctypes.byref(self._params(precision, params)), ctypes.byref(st),
                   ctypes.byref(att))
        return self._flat(st, precision), self._attitude(att, precision)

    def trajectory_setpoint(self, traj: PiecewiseLike, t: float, params: MultirotorParamsLike,
                            *, precision: Precision = "double",
                            ) -> tuple[NativeFlatState, NativeMultirotorSetpoint]:
        """Full setpoint of a piecewise trajectory (e.g. ``companion.trajectory.PiecewiseBezier``
        with a 3-D position and an optional yaw channel) at global time ``t`` (s).

        Like ``PiecewiseBezier.evaluate``: t is clamped to [0, duration] and at a joint the later
        segment is used. Segments of degree < 7 are degree-elevated (exact) before the C call.
        """
        breaks = np.asarray(traj.breaks, dtype=np.float64)
        m = len(breaks) - 1
        tc = min(max(float(t), float(breaks[0])), float(breaks[-1]))
        i = int(np.clip(np.searchsorted(breaks, tc, side="right") - 1, 0, m - 1))
        cp = _elevate_to(np.asarray(traj.control_points[i], dtype=np.float64), NUM_CTRL_PTS)
        yaw = traj.yaw
        ycp = (None if yaw is None else
               _elevate_to(np.asarray(yaw.control_points[i], dtype=np.float64), NUM_CTRL_PTS))
        return self.full(cp, ycp, float(breaks[i + 1] - breaks[i]), tc - float(breaks[i]),
                         params, precision=precision)


class PiecewiseLike(Protocol):
    """What :meth:`NativeSetpoint.trajectory_setpoint` needs of a piecewise Bezier trajectory."""

    @property
    def breaks(self) -> Any: ...
    @property
    def control_points(self) -> Any: ...
    @property
    def yaw(self) -> Any: ...


def _elevate_to(points: FloatArray, count: int) -> FloatArray:
    """Degree-elevate Bezier control points (n+1, d) to ``count`` points (same curve)."""
    pts = points.reshape(points.shape[0], -1)
    if pts.shape[0] > count:
        raise ValueError(f"segment degree {pts.shape[0] - 1} exceeds the C library's degree "
                         f"{count - 1}")
    while pts.shape[0] < count:
        n = pts.shape[0] - 1  # degree n -> n+1: Q_i = i/(n+1) P_{i-1} + (1 - i/(n+1)) P_i
        a = (np.arange(n + 2) / (n + 1))[:, None]
        padded = np.vstack([pts, pts[-1:]])
        shifted = np.vstack([pts[:1], pts])
        pts = a * shifted + (1 - a) * padded
    return pts if points.ndim > 1 and points.shape[1] > 1 else pts[:, 0]


_lock = threading.Lock()
_loaded: dict[str, NativeSetpoint | None] = {}


def load_setpoint_library(*, lib_dir: Path = LIB_DIR) -> NativeSetpoint | None:
    """The compiled library, built on first use; ``None`` (with one warning logged) when no C
    compiler is available or the build fails. Cached per process."""
    key = str(lib_dir)
    with _lock:
        if key not in _loaded:
            try:
                _loaded[key] = NativeSetpoint(build_library(lib_dir))
            except (NativeBuildError, OSError) as exc:
                log.warning("native setpoint library unavailable, using the Python path: %s", exc)
                _loaded[key] = None
        return _loaded[key]
