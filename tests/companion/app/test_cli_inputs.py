"""Bad command-line input is a clean message and exit 2, checked before anything starts; what
the CLI prints is shown as written (square brackets too), once, with file names in full."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

import pytest

import companion.app.fly
import companion.replay.runner
from companion.app.cli import EXIT_BAD_INPUT, EXIT_FAILURE, build_parser, main
from companion.flight.report import FlightReport, WaypointResult
from companion.mission import MissionError, load_mission, mission_to_flight_plan

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples" / "missions"


def _no_mock(*_a: Any, **_k: Any) -> Any:
    raise AssertionError("the embedded mock must not start for bad input")


@pytest.fixture
def never_start_mock(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(companion.app.fly, "embedded_mock", _no_mock)


def _run(capsys: pytest.CaptureFixture[str], args: list[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(text: str) -> str:
    return re.sub(r"\s+", " ", text)


@pytest.mark.parametrize(
    ("args", "part"),
    [
        (["status", "--connect", "udpin://0.0.0.0:99999"], "port 99999 out of range"),
        (["fly", "square", "--connect", "udpout://127.0.0.1:0"], "out of range 1..65535"),
        (["replay", "x.plan", "--jobs", "0"], "--jobs: expected a whole number >= 1"),
        (["fly", "square", "--size", "0"], "--size: expected a number > 0"),
        (["fly", "square", "--speed", "nan"], "--speed: expected a number > 0"),
        (["fly", "square", "--laps", "0"], "--laps: expected a whole number >= 1"),
        (["fly", "square", "--alt", "0.2"], "above 0.5 m"),
    ],
)
def test_bad_options_exit_2_before_anything_starts(
    capsys: pytest.CaptureFixture[str], never_start_mock: None, args: list[str], part: str
) -> None:
    code, _out, err = _run(capsys, args)
    assert code == EXIT_BAD_INPUT
    assert part in _one_line(err)
    assert "Traceback" not in err


def test_unknown_fly_target_lists_the_patterns(
    capsys: pytest.CaptureFixture[str], never_start_mock: None
) -> None:
    code, _out, err = _run(capsys, ["fly", "hexagon"])
    assert code == EXIT_BAD_INPUT
    assert "hexagon: no such mission file, and not a pattern" in err
    assert all(p in err for p in ("figure8", "circle", "square"))


def test_square_brackets_in_messages_are_printed_as_written(
    capsys: pytest.CaptureFixture[str], never_start_mock: None, tmp_path: Path
) -> None:
    bad = tmp_path / "v[1].toml"
    bad.write_text("[vehicle]\nmass_kg = 1.0\n[limit]\n")
    code, _out, err = _run(capsys, ["fly", "square", "--vehicle-file", str(bad)])
    assert code == EXIT_BAD_INPUT
    assert "use [vehicle] and [limits]" in err
    assert "v[1].toml" in err


def test_vehicle_file_named_once_per_message(
    capsys: pytest.CaptureFixture[str], never_start_mock: None, tmp_path: Path
) -> None:
    bad = tmp_path / "veh.toml"
    bad.write_text('[vehicle]\nmass_kg = "x"\n')
    code, _out, err = _run(capsys, ["fly", "square", "--vehicle", str(bad)])  # former spelling
    assert code == EXIT_BAD_INPUT
    assert err.count("veh.toml") == 1 and "mass_kg must be a finite number" in err


def test_replay_summary_names_files_in_full_and_each_error_once(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    long_name = tmp_path / "qgroundcontrol_exported_survey_mission_north_field.plan"
    long_name.write_text('{"fileType": "Plan", "version": 1, "mission": {"version": 2, '
                         '"items": []}}')
    bracket = tmp_path / "mission [draft].waypoints"
    bracket.write_text("QGC WPL 110\n")
    code, out, err = _run(capsys, ["replay", str(long_name), str(bracket), "--out",
                                   str(tmp_path / "out")])
    assert code == EXIT_BAD_INPUT
    table = out[out.index("Replay summary"):]
    first_column = "".join(ln.split("│")[1].strip() for ln in table.splitlines()
                           if ln.startswith("│"))
    assert long_name.name in first_column  # folded over lines, never cut
    assert "mission[draft].waypoints" in first_column.replace(" ", "")
    both = out + err
    assert both.count("no plannedHomePosition") == 1
    assert both.count("no home line") == 1


def test_replay_prints_each_warning_once(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The replay itself is stubbed (it loads and plans, then stops): the progress bar sizing
    pass over the same file must not repeat the loader's and planner's warnings."""

    def stub(path: str, *_a: Any, **_k: Any) -> Any:
        mission_to_flight_plan(load_mission(path))
        raise MissionError(path, "stub: stop after planning")

    monkeypatch.setattr(companion.replay.runner, "replay_file", stub)
    src = ROOT / "tests" / "data" / "missions" / "all_commands.plan"
    main(["replay", str(src), "--out", str(tmp_path)])
    ignored = [r for r in caplog.records if "ignored (no position)" in r.getMessage()]
    assert len(ignored) == 2  # items 12 and 13, once each


def test_px4_compare_row_is_not_ok_with_missed_waypoints(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    wps = tuple(WaypointResult(float(i), 0.0, -5.0, 1.0, 0.5, True, i) for i in range(11))
    px4 = FlightReport(kind="px4_mission", result="ok", waypoints=wps, waypoints_reached=9,
                       duration_s=12.0, planned_duration_s=10.0, max_tilt_deg=11.0)
    report = FlightReport(kind="replay", result="ok", waypoints=wps, waypoints_reached=11,
                          duration_s=10.0, planned_duration_s=10.0, rms_error_m=0.1,
                          max_error_m=0.2, max_tilt_deg=10.0, real_time_factor=20.0,
                          px4_mission=px4)

    def stub(path: str, out: str, *_a: Any, **_k: Any) -> Any:
        return companion.replay.runner.ReplayResult(Path(path).stem, Path(out), report, True)

    monkeypatch.setattr(companion.replay.runner, "replay_file", stub)
    code, out, _err = _run(capsys, ["replay", str(EXAMPLES / "square.plan"), "--out",
                                    str(tmp_path), "--compare-px4-mission"])
    row = next(ln for ln in out.splitlines() if "PX4 AUTO.MISSION" in ln)
    assert "9/11" in row and "missed 2 waypoint(s)" in row
    assert " ok " not in row
    assert code == EXIT_FAILURE  # a waypoint AUTO.MISSION missed fails the comparison


def test_rover_plan_as_quad_points_to_vehicle_rover() -> None:
    with pytest.raises(MissionError, match="--vehicle rover"):
        mission_to_flight_plan(load_mission(EXAMPLES / "rover_square.plan"))


@pytest.mark.parametrize(("vtype", "flown_as"), [(1, "quad"), (20, "quad"), (2, "rover")])
def test_plan_for_another_vehicle_kind_is_flown_with_a_warning(
    tmp_path: Path, vtype: int, flown_as: str
) -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    doc["mission"]["vehicleType"] = vtype
    p = tmp_path / "other.plan"
    p.write_text(json.dumps(doc))
    plan = mission_to_flight_plan(load_mission(p), vehicle=flown_as)  # type: ignore[arg-type]
    assert any(f"vehicleType {vtype}" in w for w in plan.warnings)


def test_quad_plan_flown_as_quad_has_no_vehicle_warning() -> None:
    plan = mission_to_flight_plan(load_mission(EXAMPLES / "square.plan"))
    assert not any("vehicleType" in w for w in plan.warnings)


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _manual_text() -> str:
    """README.md and every page of the manual (docs/), where the commands are documented."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return "\n".join(p.read_text(encoding="utf-8") for p in pages)


def test_readme_documents_every_command_and_option() -> None:
    readme = _manual_text()
    for name, sp in _subcommands().items():
        assert f"python -m companion {name}" in readme, name
        for action in sp._actions:
            if action.help == argparse.SUPPRESS or not action.option_strings:
                continue
            longest = max(action.option_strings, key=len)
            if longest == "--help":
                continue
            assert longest in readme, f"{name} {longest} is not documented"


def test_readme_links_stay_inside_the_repository() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for target in re.findall(r"\]\(([^)#]+)\)", readme):
        if re.match(r"[a-z]+://", target):
            continue
        resolved = (ROOT / target).resolve()
        assert resolved.is_relative_to(ROOT), f"README links outside the repository: {target}"
        assert resolved.exists(), f"README links a missing file: {target}"
    assert "shared/MATH.md" not in readme and "shared/PX4.md" not in readme


@pytest.mark.parametrize(("param", "value"), [(6, 1e300), (0, 1e300), (6, 1e15)])
def test_replay_of_out_of_range_values_exits_2_with_the_item(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, param: int, value: float
) -> None:
    """Was an OverflowError/MemoryError traceback (exit 1) or a replay that never finished."""
    doc = json.loads((EXAMPLES / "survey.plan").read_text())  # has a geofence
    doc["mission"]["items"][0]["params"][param] = value
    p = tmp_path / "edited.plan"
    p.write_text(json.dumps(doc))
    code, out, err = _run(capsys, ["replay", str(p), "--out", str(tmp_path / "out")])
    assert code == EXIT_BAD_INPUT
    assert "edited.plan: item 1:" in _one_line(err)
    assert "Traceback" not in out + err


_SQUARE = str(EXAMPLES / "square.plan")


@pytest.mark.parametrize(
    ("args", "option", "kind"),
    [
        (["demo", "--out", "{f}"], "--out", "folder"),
        (["replay", _SQUARE, "--out", "{f}"], "--out", "folder"),
        (["campaign", _SQUARE, "--runs", "1", "--out", "{f}"], "--out", "folder"),
        (["serve", "--connect", "udpin://127.0.0.1:14540", "--log-dir", "{f}"], "--log-dir",
         "folder"),
        (["demo", "--out", "{f}/sub"], "--out", "folder"),
        (["replay", _SQUARE, "--out", "{f}/sub"], "--out", "folder"),
        (["fly", "square", "--log", "{d}"], "--log", "file"),
        (["fly", "square", "--log", "{f}/x.tlog"], "--log", "folder"),
    ],
)
def test_output_path_of_the_wrong_kind_is_bad_input(
    capsys: pytest.CaptureFixture[str], never_start_mock: None, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, args: list[str], option: str, kind: str
) -> None:
    """An output folder that is a file, a path under a file, or an output file that is a folder:
    exit 2 naming the option and the path, nothing written, no traceback."""
    a_file = tmp_path / "taken"
    a_file.write_text("keep me\n")
    a_dir = tmp_path / "a_folder"
    a_dir.mkdir()
    monkeypatch.setattr(companion.replay.runner, "replay_file", _no_mock)
    argv = [x.format(f=a_file, d=a_dir) for x in args]
    code, _out, err = _run(capsys, argv)
    text = _one_line(err)
    assert code == EXIT_BAD_INPUT, text
    assert "Traceback" not in err and "Errno" not in err
    assert option in text and str(a_file if kind == "folder" else a_dir) in text
    assert f"not a {kind}" in text
    assert a_file.read_text() == "keep me\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_folder", "taken"]


@pytest.mark.parametrize(("command", "default"), [
    (["demo"], "demo_out"), (["replay", _SQUARE], "replay_out"),
    (["campaign", _SQUARE, "--runs", "1"], "campaign_out"),
    (["serve", "--connect", "udpin://127.0.0.1:14540"], "ecca-logs"),
])
def test_default_output_folder_taken_by_a_file_is_bad_input(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    command: list[str], default: str
) -> None:
    """The default output folder is checked like a given one."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(companion.replay.runner, "replay_file", _no_mock)
    (tmp_path / default).write_text("")
    code, _out, err = _run(capsys, command)
    assert code == EXIT_BAD_INPUT
    assert f"{default}: exists and is a file, not a folder" in _one_line(err)
    assert "Traceback" not in err
