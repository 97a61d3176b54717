"""Campaign perturbations: sampling is reproducible and within its ranges, and the `replay`
command printed for a run builds the very ReplayConfig the campaign flew."""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.app.cli import build_parser
from companion.app.replay_options import replay_config_kwargs
from companion.campaign.perturb import PerturbationRanges, sample
from companion.campaign.runner import base_config, make_tasks, replay_command
from companion.replay.runner import ReplayConfig

ROOT = Path(__file__).resolve().parents[3]
MISSION = str(ROOT / "tests" / "data" / "missions" / "px4_short.plan")


def _config_from_command(command: str) -> ReplayConfig:
    argv = shlex.split(command)
    assert argv[:4] == ["python", "-m", "companion", "replay"]
    args = build_parser().parse_args(argv[3:])
    return ReplayConfig(**replay_config_kwargs(args))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32), index=st.integers(0, 10_000),
       mode=st.sampled_from(["position", "attitude", "rates", "onboard"]))
def test_replay_command_recreates_the_campaign_config(seed: int, index: int, mode: str) -> None:
    p = sample(PerturbationRanges(), seed, index)
    flown = p.replay_config(base_config(mode, 100.0))
    assert _config_from_command(replay_command(MISSION, mode, 100.0, p)) == flown


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32), index=st.integers(0, 10_000))
def test_samples_are_reproducible_and_within_their_ranges(seed: int, index: int) -> None:
    r = PerturbationRanges()
    p = sample(r, seed, index)
    assert sample(r, seed, index) == p
    assert 0.0 <= p.wind_m_s <= r.wind_max_m_s
    assert 0.0 <= p.wind_from_deg <= 360.0
    assert 0.0 <= p.gust_m_s <= r.gust_max_m_s
    for name in ("inertia_error_x", "inertia_error_y", "inertia_error_z"):
        assert abs(getattr(p, name)) <= r.inertia_error
    assert abs(p.mass_error) <= r.mass_error
    assert abs(p.hover_thrust_error) <= r.hover_thrust_error
    assert abs(p.drag_error) <= r.drag_error
    assert 0.0 <= p.latency_s <= r.latency_max_s and 0.0 <= p.jitter_s <= r.jitter_max_s
    assert 0.0 <= p.loss_pct <= r.loss_max_pct
    assert 0.0 <= p.pos_noise_m <= r.pos_noise_max_m
    assert (p.start_offset_n_m**2 + p.start_offset_e_m**2) ** 0.5 <= r.start_offset_max_m + 1e-3
    # the mock gets the errors as true vehicle parameters
    mp = dict(p.mock_params())
    assert mp.get("SIH_MASS", 1.0) == pytest.approx(1.0 + p.mass_error, abs=1e-4)
    assert mp.get("MPC_THR_HOVER", 0.5) == p.hover_thrust


def test_zero_ranges_fly_the_plain_replay_with_the_runs_seed() -> None:
    zero = PerturbationRanges(**{f.name: 0.0 for f in dataclasses.fields(PerturbationRanges)})
    p = sample(zero, 3, 1)
    assert p.replay_args() == ["--seed", str(p.seed)]
    assert p.replay_config(ReplayConfig()) == ReplayConfig(seed=p.seed)


def test_turning_one_perturbation_off_leaves_the_others_unchanged() -> None:
    full = sample(PerturbationRanges(), 11, 4)
    no_wind = sample(PerturbationRanges(wind_max_m_s=0.0), 11, 4)
    assert no_wind.wind_m_s == 0.0
    assert dataclasses.replace(no_wind, wind_m_s=full.wind_m_s,
                               wind_from_deg=full.wind_from_deg) == full


def test_more_runs_keep_the_earlier_runs_and_modes_share_the_draws() -> None:
    few = make_tasks([MISSION], ["attitude", "rates"], 3, 5, PerturbationRanges())
    more = make_tasks([MISSION], ["attitude", "rates"], 5, 5, PerturbationRanges())
    few_cmds = {t.command for t in few}
    assert few_cmds <= {t.command for t in more}
    by_mode = {m: [t.perturbation for t in few if t.mode == m] for m in ("attitude", "rates")}
    assert by_mode["attitude"] == by_mode["rates"]
    assert len({t.perturbation.seed for t in more}) == 5


def test_bad_ranges_are_refused_with_the_field_name() -> None:
    with pytest.raises(ValueError, match="mass_error"):
        PerturbationRanges(mass_error=-0.1)
    with pytest.raises(ValueError, match="drag_error"):
        PerturbationRanges(drag_error=1.5)


def test_keep_decides_which_tlogs_come_back_and_never_changes_the_result(
        tmp_path: Path) -> None:
    """--keep failed flies without a tlog and flies a failed run again with one: the row is
    the same as without any tlog, and the tlog is a readable flight log."""
    from pymavlink import mavutil

    from companion.campaign.runner import WALL_CLOCK_COLUMNS, execute_run

    def flight(row: dict[str, object]) -> dict[str, object]:
        return {k: v for k, v in row.items() if k not in WALL_CLOCK_COLUMNS}

    t = make_tasks([MISSION], ["position"], 1, 2, PerturbationRanges())[0]
    storm = dataclasses.replace(t.perturbation, wind_m_s=11.0, wind_from_deg=90.0)
    t = dataclasses.replace(t, perturbation=storm)
    out = {k: execute_run(dataclasses.replace(t, keep=k))
           for k in ("none", "failed", "all")}
    assert out["none"].row["ok"] is False, "an 11 m/s wind should make this run fail"
    assert flight(out["none"].row) == flight(out["failed"].row) == flight(out["all"].row)
    assert out["none"].tlog is None
    assert out["failed"].tlog is not None and out["failed"].tlog == out["all"].tlog
    path = tmp_path / "run.tlog"
    path.write_bytes(out["failed"].tlog)
    mlog = mavutil.mavlink_connection(str(path))
    try:
        assert mlog.recv_match(type="HEARTBEAT") is not None
    finally:
        mlog.close()
