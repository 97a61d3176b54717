"""Replay and campaign speed (issue 27): A/B across source trees, and where the time goes.

Every figure is a ratio against a baseline tree measured in the same run, trees taking turns
(baseline, candidate, baseline, ...), so drift of the shared machine hits all of them alike.
A tree is a source checkout (e.g. `git archive START | tar -x -C /tmp/base`), or `git:REV` for a
commit of this repository unpacked into a temporary directory for the run (`git:HEAD` is the last
commit, `git:HEAD~1` the one before: the working tree against them in one command); each run is
a fresh process with the tree first on `sys.path` and as its working directory.

- `ab TREE...`: `python -m companion replay FILE --no-plot` (`--plot`: with flight.png) as a
  user runs it: the whole process (wall, from the parent), the lockstep loop alone
  (report.json's `wall_s`, the time in `fly_schedule`) and the simulated time; medians and
  ratios against the first tree.
  `--bytecode none` runs without the project's compiled bytecode (__pycache__ removed before
  each run, PYTHONDONTWRITEBYTECODE=1: what a source checkout without write access pays);
  `cached` (default) keeps it, as an installed package has it.
- `parts TREE...`: the lockstep loop of one replay (no tlog) in each tree with timers around its
  parts (the mock's physics steps, telemetry, input; the companion's setpoint computation and
  its pieces): microseconds per setpoint cycle, medians over `--rounds`, ratios against the first
  tree. Timers cost ~0.3 us per call: read the ratios, and the whole loop's time without
  timers from `ab`.
- `profile`: one replay in this process: its phases (import, plan, loop, report) and the top
  functions of the loop under cProfile (cProfile inflates small functions: read the ranking,
  not the absolute times).
- `fingerprint TREE...`: the same replays (several modes, a perturbed one, a rover, PX4's own
  mission, and two flown without a tlog as a campaign flies them) in each tree; sha256 of
  flight.tlog and of report.json without its wall-clock fields. Equal digests: the trees fly
  bit-identical flights.
- `plan TREE...`: the replay's planning phase alone (`prepare_mission`: the mock's parameters
  read, the mission planned) for each file of `--files` (default: the bundled rover missions
  as a rover, three quad missions), in a fresh process per tree and round: CPU seconds per
  file, medians, ratios against the first tree, and a digest of each schedule (its reference
  at 400 times: equal digests, the same plans).
- `instructions TREE...`: instructions of one lockstep loop under valgrind (callgrind), with
  and without a tlog: a measure the machine's load does not move (slow: ~1 min per run).
- `campaign TREE...`: a campaign of `--runs` runs per mode on a local Dask cluster of
  `--workers` processes (cluster start-up and the workers' imports outside the timed part, as
  a campaign pays them once); wall, runs/s, the 1,000-run extrapolation, and a digest of the
  flight results (equal across trees: the same flights).

Usage:
  python bench/bench_replay_speed.py ab git:HEAD . [--rounds 5] [--file F] [--mode attitude]
  python bench/bench_replay_speed.py ab /tmp/base . [--rounds 5] [--file F] [--mode attitude]
  python bench/bench_replay_speed.py parts git:HEAD . [--rounds 3]
  python bench/bench_replay_speed.py profile [--file F] [--top 30]
  python bench/bench_replay_speed.py fingerprint /tmp/base .
  python bench/bench_replay_speed.py campaign /tmp/base . [--runs 20] [--rounds 2]
  python bench/bench_replay_speed.py instructions /tmp/base .
  python bench/bench_replay_speed.py plan git:HEAD . [--rounds 3] [--files F...]
"""

from __future__ import annotations

import argparse
import atexit
import json
import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FILE = ROOT / "tests" / "data" / "missions" / "square_8ms.plan"
CAMPAIGN_FILE = ROOT / "examples" / "missions" / "one_minute.plan"
PKGS = ("companion", "sitl_mock", "gen_c")


# ----------------------------------------------------------------------------- trees


def _env(tree: Path, bytecode: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    if bytecode == "none":
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    else:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _drop_bytecode(tree: Path) -> None:
    for pkg in PKGS:
        for d in (tree / pkg).rglob("__pycache__"):
            shutil.rmtree(d, ignore_errors=True)


_UNPACKED: dict[str, Path] = {}


def resolve_tree(arg: str) -> Path:
    """A tree argument as a directory: a path, or `git:REV` unpacked (`git archive`) into a
    temporary directory (once per run; removed at exit)."""
    if not arg.startswith("git:"):
        return Path(arg).resolve()
    rev = arg[4:]
    if rev not in _UNPACKED:
        sha = subprocess.run(["git", "rev-parse", "--short", rev], cwd=ROOT, check=True,
                             capture_output=True, text=True).stdout.strip()
        d = Path(tempfile.mkdtemp(prefix="bench-replay-speed-")) / sha
        d.mkdir()
        archive = subprocess.run(["git", "archive", sha], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(d)], input=archive, check=True)
        atexit.register(shutil.rmtree, d.parent, True)
        _UNPACKED[rev] = d
    return _UNPACKED[rev]


def _check_tree(tree: Path) -> None:
    for pkg in PKGS:
        if not (tree / pkg / "__init__.py").exists():
            raise SystemExit(f"{tree} is not a source tree of this project (no {pkg}/)")


# ----------------------------------------------------------------------------- plan

PLAN_FILES = (*sorted((ROOT / "examples" / "missions").glob("rover_*.plan")),
              ROOT / "examples" / "missions" / "square.plan",
              ROOT / "examples" / "missions" / "survey.plan", DEFAULT_FILE)

_PLAN_CODE = """
import hashlib, json, sys, time
import numpy as np
from companion.replay.runner import ReplayConfig, prepare_mission
out = {}
for f in sys.argv[1:]:
    cfg = ReplayConfig(vehicle="rover" if "rover_" in f else "quad")
    t0 = time.process_time()
    prep = prepare_mission(f, cfg)
    cpu = time.process_time() - t0
    sch = prep.schedule
    h = hashlib.sha256()
    for k in range(400):
        r = sch.reference(sch.duration_s * k / 399)
        h.update(np.asarray(r.pos_ned, dtype=np.float64).tobytes())
        h.update(np.asarray(r.vel_ned, dtype=np.float64).tobytes())
        h.update(np.float64(r.yaw).tobytes())
    out[f] = {"cpu_s": cpu, "duration_s": sch.duration_s, "digest": h.hexdigest()[:16]}
print(json.dumps(out))
"""


def plan_once(tree: Path, files: list[Path]) -> dict[str, dict[str, Any]]:
    """CPU time and schedule digest of `prepare_mission` for each file, in a fresh process of
    `tree` (its imports and the first file's warm-up inside the process, before the timing of
    that file: every file pays what a replay pays)."""
    proc = subprocess.run([sys.executable, "-c", _PLAN_CODE, *map(str, files)], cwd=tree,
                          env=_env(tree, "cached"), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"planning in {tree} failed:\n{proc.stderr[-3000:]}")
    return dict(json.loads(proc.stdout.strip().splitlines()[-1]))


def cmd_plan(args: argparse.Namespace) -> str:
    trees = [resolve_tree(t) for t in args.trees]
    for tree in trees:
        _check_tree(tree)
    files = [Path(f).resolve() for f in (args.files or PLAN_FILES)]
    runs: list[list[dict[str, dict[str, Any]]]] = [[] for _ in trees]
    for _ in range(args.rounds):
        for i, tree in enumerate(trees):  # trees take turns: drift hits them alike
            runs[i].append(plan_once(tree, files))
    lines = [f"Planning (`prepare_mission`), CPU s per file, median of {args.rounds} rounds "
             f"(load {os.getloadavg()[0]:.1f}):", "",
             "| file | " + " | ".join(f"{a} [s]" for a in args.trees)
             + " | " + " | ".join(f"{a} / {args.trees[0]}" for a in args.trees[1:])
             + " | same plans |",
             "| --- |" + " ---: |" * (2 * len(trees) - 1) + " --- |"]
    for f in files:
        med = [statistics.median(r[str(f)]["cpu_s"] for r in rs) for rs in runs]
        digests = {r[str(f)]["digest"] for rs in runs for r in rs}
        lines.append(f"| {f.name} | " + " | ".join(f"{m:.3f}" for m in med) + " | "
                     + " | ".join(f"{m / med[0]:.2f}" for m in med[1:])
                     + f" | {'yes' if len(digests) == 1 else 'NO'} |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- ab


def replay_once(tree: Path, file: Path, mode: str, bytecode: str,
                plot: bool = False) -> dict[str, float]:
    """One `python -m companion replay FILE [--no-plot]` in a fresh process of `tree`."""
    if bytecode == "none":
        _drop_bytecode(tree)
    with tempfile.TemporaryDirectory() as out:
        load = os.getloadavg()[0]
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "replay", str(file), "--mode", mode,
             "--out", out, *(() if plot else ("--no-plot",))],
            cwd=tree, env=_env(tree, bytecode), capture_output=True, text=True, check=False,
        )
        wall = time.perf_counter() - t0
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode not in (0, 1):
            raise SystemExit(f"replay in {tree} failed ({proc.returncode}):\n{proc.stderr}")
        report = json.loads((Path(out) / file.stem / "report.json").read_text())
    sim = float(report["simulated_s"])
    cpu = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
    return {"sim_s": sim, "wall_s": wall, "cpu_s": cpu, "loop_s": float(report["wall_s"]),
            "x_whole": sim / wall, "x_loop": sim / float(report["wall_s"]), "load1": load}


def cmd_ab(args: argparse.Namespace) -> str:
    trees = [resolve_tree(t) for t in args.trees]
    for t in trees:
        _check_tree(t)
    file = args.file.resolve()
    if args.bytecode == "cached":
        for t in trees:  # compile once (not timed)
            replay_once(t, file, args.mode, "cached", args.plot)
    runs: dict[Path, list[dict[str, float]]] = {t: [] for t in trees}
    for r in range(args.rounds):
        for t in trees:
            res = replay_once(t, file, args.mode, args.bytecode, args.plot)
            runs[t].append(res)
            print(f"round {r + 1} {t}: whole {res['wall_s']:.3f} s ({res['x_whole']:.1f}x, "
                  f"CPU {res['cpu_s']:.3f} s), "
                  f"loop {res['loop_s']:.3f} s ({res['x_loop']:.1f}x), load {res['load1']:.2f}",
                  flush=True)
    base = trees[0]
    med = {t: {k: statistics.median(r[k] for r in rs) for k in rs[0]} for t, rs in runs.items()}
    lines = [
        f"`{file.relative_to(ROOT) if file.is_relative_to(ROOT) else file}`, {args.mode} mode, "
        f"{med[base]['sim_s']:.1f} simulated s, {'with flight.png' if args.plot else '--no-plot'}"
        f", bytecode {args.bytecode}, {args.rounds} rounds "
        f"(medians; load average {min(r['load1'] for rs in runs.values() for r in rs):.2f}-"
        f"{max(r['load1'] for rs in runs.values() for r in rs):.2f}):",
        "",
        "| tree | whole process s | x real time | CPU s | loop s | x real time | "
        "whole / baseline | loop / baseline |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for t in trees:
        m = med[t]
        lines.append(
            f"| {t.name if t != ROOT else 'this tree'} | {m['wall_s']:.3f} | {m['x_whole']:.1f} | "
            f"{m['cpu_s']:.3f} | {m['loop_s']:.3f} | {m['x_loop']:.1f} | "
            f"{m['wall_s'] / med[base]['wall_s']:.2f} | "
            f"{m['loop_s'] / med[base]['loop_s']:.2f} |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- parts

_PARTS_CHILD = r"""
import json, logging, sys, time
root, file, mode = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, root)
import companion
assert companion.__file__.startswith(root), companion.__file__
from companion.replay.flight import fly_schedule
from companion.replay.runner import ReplayConfig, prepare_mission
import companion.control.law as law
import companion.flight.tracking as tr
import companion.planning.schedule as sch
import sitl_mock.autopilot.core as core
import sitl_mock.quad as quad
logging.disable(logging.WARNING)
acc = {}
pc = time.perf_counter
def wrap(cls, name, label):
    f = getattr(cls, name, None)
    if f is None:
        return
    acc[label] = 0.0  # (the table's order)
    def w(*a, **k):
        t = pc()
        r = f(*a, **k)
        acc[label] = acc.get(label, 0.0) + pc() - t
        return r
    setattr(cls, name, w)
wrap(core.Autopilot, "advance", "mock: advance (physics, autopilot, telemetry)")
wrap(quad.Quadrotor, "step", "mock: . vehicle steps (physics, rate and attitude loops)")
wrap(core.Autopilot, "_telemetry", "mock: . telemetry streams (build, pack)")
wrap(core.Autopilot, "receive_datagram", "mock: input (setpoint decode, handlers)")
wrap(tr.TrackingSource, "__call__", "companion: setpoint (TrackingSource)")
wrap(sch.Schedule, "reference", "companion: . reference samples (Schedule.reference)")
wrap(tr.TrackingSource, "_estimate", "companion: . estimate from telemetry")
wrap(law.TrackingController, "_core", "companion: . controller (law._core)")
wrap(law.TrackingController, "_ingest", "companion: . . estimators (law._ingest)")
cfg = ReplayConfig(mode=mode)
prep = prepare_mission(file, cfg)
fly_schedule(cfg, prep.schedule, prep.home, None)  # warm-up, not timed
acc.update(dict.fromkeys(acc, 0.0))
t0 = pc()
flight, _log = fly_schedule(cfg, prep.schedule, prep.home, None)
total = pc() - t0
acc["loop (fly_schedule, no tlog, timers included)"] = total
print(json.dumps({"parts": acc, "cycles": flight.setpoints_sent}))
"""


def parts_once(tree: Path, file: Path, mode: str) -> dict[str, Any]:
    proc = subprocess.run(
        [sys.executable, "-c", _PARTS_CHILD, str(tree), str(file), mode],
        cwd=tree, env=_env(tree, "cached"), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"parts in {tree} failed:\n{proc.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def cmd_parts(args: argparse.Namespace) -> str:
    trees = [resolve_tree(t) for t in args.trees]
    file = args.file.resolve()
    runs: dict[Path, list[dict[str, Any]]] = {t: [] for t in trees}
    for r in range(args.rounds):
        for t in trees:
            runs[t].append(parts_once(t, file, args.mode))
            print(f"round {r + 1} {t}: loop "
                  f"{runs[t][-1]['parts']['loop (fly_schedule, no tlog, timers included)']:.3f} s",
                  flush=True)
    base = trees[0]
    labels = list(runs[base][0]["parts"])
    for t in trees[1:]:
        labels += [k for k in runs[t][0]["parts"] if k not in labels]
    per: dict[Path, dict[str, float]] = {}
    for t, rs in runs.items():
        per[t] = {k: statistics.median(r["parts"].get(k, math.nan) / r["cycles"] * 1e6
                                       for r in rs) for k in labels}
    names = [t.name if t != ROOT else "this tree" for t in trees]
    lines = [
        f"Parts of the lockstep loop of `{file.name}` ({args.mode} mode, no tlog), us per "
        f"setpoint cycle (medians of {args.rounds} rounds, trees alternating; a part missing "
        "in a tree: nan):",
        "",
        "| part | " + " | ".join(names) + " | " + " | ".join(f"{n} / {names[0]}"
                                                         for n in names[1:]) + " |",
        "| --- |" + " ---: |" * (2 * len(trees) - 1),
    ]
    for k in labels:
        cells = [f"{per[t][k]:.1f}" for t in trees]
        ratios = [f"{per[t][k] / per[base][k]:.2f}" for t in trees[1:]]
        lines.append(f"| {k} | " + " | ".join(cells + ratios) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- profile


def cmd_profile(args: argparse.Namespace) -> str:
    import cProfile
    import io
    import pstats

    code = "import companion.replay.runner, companion.app.cli"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT,
                   env=_env(ROOT, "cached"))
    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    t_bare = time.perf_counter() - t0

    from companion.flight.summary import summarize
    from companion.replay.flight import fly_schedule
    from companion.replay.runner import ReplayConfig, prepare_mission

    cfg = ReplayConfig(mode=args.mode)
    t0 = time.perf_counter()
    prep = prepare_mission(args.file, cfg)
    t_plan = time.perf_counter() - t0
    t0 = time.perf_counter()
    flight, log = fly_schedule(cfg, prep.schedule, prep.home, None)
    t_loop = time.perf_counter() - t0
    t0 = time.perf_counter()
    summarize(log, prep.schedule, prep.mission, flight.origin, flight_plan=prep.flight_plan,
              leg_bounds_s=prep.leg_bounds_s, bound_s=prep.bound_s)
    t_sum = time.perf_counter() - t0
    sim = flight.lk.now
    prof = cProfile.Profile()
    prof.enable()
    fly_schedule(cfg, prep.schedule, prep.home, None)
    prof.disable()
    buf = io.StringIO()
    st = pstats.Stats(prof, stream=buf)
    st.sort_stats("tottime").print_stats(args.top)
    print(buf.getvalue())
    calls = {}
    for (fname, _line, func), (cc, _nc, _tt, _ct, _callers) in st.stats.items():  # type: ignore[attr-defined]
        calls[f"{Path(fname).name}:{func}"] = cc
    counts = {k: calls.get(k, 0) for k in (
        "quad.py:_step", "core.py:advance", "tracking.py:__call__", "core.py:_telemetry")}
    lines = [
        f"Phases of one replay of `{args.file.name}` ({args.mode} mode, {sim:.1f} simulated s), "
        "in this process:",
        "",
        "| phase | s |",
        "| --- | ---: |",
        f"| interpreter start (python -c pass) | {t_bare:.3f} |",
        f"| import the replay stack and the CLI (fresh process, incl. start) | {t_import:.3f} |",
        f"| read the mock's parameters and plan (prepare_mission) | {t_plan:.3f} |",
        f"| lockstep loop (fly_schedule, no tlog) | {t_loop:.3f} ({sim / t_loop:.1f}x) |",
        f"| figures (summarize) | {t_sum:.3f} |",
        "",
        "Calls in the loop: " + ", ".join(f"{k} {v}" for k, v in counts.items()),
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- fingerprint

_FINGERPRINT_CHILD = r"""
import hashlib, json, sys, tempfile
from pathlib import Path
root, cases = sys.argv[1], json.loads(sys.argv[2])
sys.path.insert(0, root)
import companion
assert companion.__file__.startswith(root), companion.__file__
from companion.replay.runner import DEFAULT_QUAD, ReplayConfig, prepare_mission, replay_file
from companion.replay.runner import run_prepared
import dataclasses
out = {}
for name, (file, kw) in cases.items():
    no_tlog = kw.pop("no_tlog", False)
    params = kw.pop("hover_thrust", None)
    if "mock_params" in kw:
        kw["mock_params"] = tuple(tuple(p) for p in kw["mock_params"])
    if "start_offset_ne_m" in kw:
        kw["start_offset_ne_m"] = tuple(kw["start_offset_ne_m"])
    if params is not None:
        kw["params"] = dataclasses.replace(DEFAULT_QUAD, hover_thrust=params)
    if no_tlog:  # a campaign's first flight: no tlog, the report only
        cfg = ReplayConfig(**kw)
        rep = run_prepared(prepare_mission(file, cfg), cfg, None).report.to_dict()
        rep = json.loads(json.dumps(rep, default=float))
        tlog = b""
    else:
        with tempfile.TemporaryDirectory() as d:
            r = replay_file(file, d, ReplayConfig(**kw))
            tlog = (r.out_dir / "flight.tlog").read_bytes()
            rep = json.loads((r.out_dir / "report.json").read_text())
    for k in ("wall_s", "real_time_factor"):
        rep.pop(k, None)
    rep_bytes = json.dumps(rep, sort_keys=True).encode()
    out[name] = {"tlog": hashlib.sha256(tlog).hexdigest()[:16],
                 "report": hashlib.sha256(rep_bytes).hexdigest()[:16],
                 "frames": rep.get("tlog_frames"), "rms": rep.get("rms_error_m")}
print(json.dumps(out))
"""


def fingerprint_cases() -> dict[str, tuple[str, dict[str, Any]]]:
    """Replays that exercise every path: the modes, perturbations, a rover, PX4's mission."""
    sq8 = str(ROOT / "tests" / "data" / "missions" / "square_8ms.plan")
    sq = str(ROOT / "examples" / "missions" / "square.plan")
    return {
        "square_8ms attitude": (sq8, {"mode": "attitude"}),
        "square_8ms position": (sq8, {"mode": "position"}),
        "square_8ms rates": (sq8, {"mode": "rates"}),
        "square attitude": (sq, {"mode": "attitude"}),
        "square perturbed, attitude": (sq, {
            "mode": "attitude", "seed": 7, "wind_m_s": 4.0, "wind_from_deg": 200.0,
            "latency_s": 0.03, "jitter_s": 0.01, "loss_pct": 2.0, "hover_thrust": 0.54,
            "start_offset_ne_m": [0.6, -0.4],
            "mock_params": [["SIH_MASS", 1.1], ["SIM_WIND_GUST", 1.0], ["SIM_POS_NOISE", 0.05],
                            ["SIM_VEL_NOISE", 0.025], ["SIH_KDV", 1.2]]}),
        "square perturbed, attitude, no tlog": (sq, {
            "mode": "attitude", "seed": 7, "wind_m_s": 4.0, "wind_from_deg": 200.0,
            "latency_s": 0.03, "jitter_s": 0.01, "loss_pct": 2.0, "hover_thrust": 0.54,
            "start_offset_ne_m": [0.6, -0.4], "no_tlog": True,
            "mock_params": [["SIH_MASS", 1.1], ["SIM_WIND_GUST", 1.0], ["SIM_POS_NOISE", 0.05],
                            ["SIM_VEL_NOISE", 0.025], ["SIH_KDV", 1.2]]}),
        "square_8ms rates, no tlog": (sq8, {"mode": "rates", "no_tlog": True}),
        "square perturbed, rates": (sq, {
            "mode": "rates", "seed": 3, "wind_m_s": 2.0, "loss_pct": 1.0,
            "mock_params": [["SIM_WIND_GUST", 0.5], ["SIM_POS_NOISE", 0.05]]}),
        "square attitude + PX4 mission": (sq, {"mode": "attitude",
                                               "compare_px4_mission": True}),
        "rover_square": (str(ROOT / "examples" / "missions" / "rover_square.plan"),
                         {"vehicle": "rover", "mode": "position"}),
    }


def fingerprint(tree: Path) -> dict[str, dict[str, Any]]:
    """Digests of the fingerprint cases flown by `tree`'s code."""
    proc = subprocess.run(
        [sys.executable, "-c", _FINGERPRINT_CHILD, str(tree), json.dumps(fingerprint_cases())],
        cwd=tree, env=_env(tree, "cached"), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"fingerprint in {tree} failed:\n{proc.stderr}")
    result: dict[str, dict[str, Any]] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def cmd_fingerprint(args: argparse.Namespace) -> str:
    trees = [resolve_tree(t) for t in args.trees]
    prints = {t: fingerprint(t) for t in trees}
    base = prints[trees[0]]
    lines = ["| case | " + " | ".join(t.name or str(t) for t in trees) + " | same |",
             "| --- |" + " --- |" * len(trees) + " --- |"]
    all_same = True
    for case in base:
        cells = [f"{p[case]['tlog']} / {p[case]['report']}" for p in prints.values()]
        same = len(set(cells)) == 1
        all_same &= same
        lines.append(f"| {case} | " + " | ".join(cells) + f" | {'yes' if same else 'NO'} |")
    lines.append("")
    lines.append("Cells: sha256 (16 hex) of flight.tlog / of report.json without wall-clock "
                 f"fields. {'All equal.' if all_same else 'DIFFERENCES: see the rows marked NO.'}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- campaign

_CAMPAIGN_CHILD = r"""
import hashlib, json, sys, tempfile, time
from pathlib import Path
root, file, modes = sys.argv[1], sys.argv[2], sys.argv[5].split(",")
runs, workers = int(sys.argv[3]), int(sys.argv[4])
sys.path.insert(0, root)
import companion
assert companion.__file__.startswith(root), companion.__file__
from companion.campaign.perturb import PerturbationRanges
from companion.campaign.runner import (WALL_CLOCK_COLUMNS, CampaignProgress, ResultStore,
                                       dask_client, make_tasks, run_tasks)
tasks = make_tasks([file], modes, runs, 1, PerturbationRanges(), keep="failed")
with tempfile.TemporaryDirectory() as out:
    with dask_client(None, workers) as client:
        client.wait_for_workers(workers, timeout=120)
        client.run(lambda: __import__("companion.replay.runner"))
        t0 = time.perf_counter()
        rows = run_tasks(client, tasks, ResultStore(Path(out)), CampaignProgress())
        wall = time.perf_counter() - t0
flights = sorted(json.dumps({k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS},
                            sort_keys=True) for r in rows)
print(json.dumps({"wall_s": wall, "runs": len(rows), "ok": sum(r["ok"] for r in rows),
                  "task_s": sum(r["task_s"] for r in rows),
                  "digest": hashlib.sha256("\n".join(flights).encode()).hexdigest()[:16]}))
"""


def campaign_once(tree: Path, runs: int, workers: int, modes: str) -> dict[str, Any]:
    proc = subprocess.run(
        [sys.executable, "-c", _CAMPAIGN_CHILD, str(tree), str(CAMPAIGN_FILE), str(runs),
         str(workers), modes],
        cwd=tree, env=_env(tree, "cached"), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"campaign in {tree} failed:\n{proc.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def cmd_campaign(args: argparse.Namespace) -> str:
    trees = [resolve_tree(t) for t in args.trees]
    res: dict[Path, list[dict[str, Any]]] = {t: [] for t in trees}
    for r in range(args.rounds):
        for t in trees:
            out = campaign_once(t, args.runs, args.workers, args.modes)
            res[t].append(out)
            print(f"round {r + 1} {t}: {out['runs']} runs in {out['wall_s']:.1f} s "
                  f"({out['runs'] / out['wall_s']:.2f} runs/s), ok {out['ok']}, "
                  f"digest {out['digest']}", flush=True)
    base = trees[0]
    med = {t: statistics.median(o["wall_s"] for o in os_) for t, os_ in res.items()}
    n = res[base][0]["runs"]
    lines = [
        f"`examples/missions/one_minute.plan`, modes {args.modes}, {args.runs} runs per mode "
        f"({n} runs; campaign defaults, seed 1), {args.workers} Dask workers, {args.rounds} "
        "rounds (median wall of the runs, cluster start-up and imports excluded):",
        "",
        "| tree | wall s | runs/s | 1,000 runs at this rate [min] | wall / baseline | "
        "flight results digest |",
        "| --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for t in trees:
        w = med[t]
        digests = ",".join(sorted({o["digest"] for o in res[t]}))
        lines.append(f"| {t.name if t != ROOT else 'this tree'} | {w:.1f} | {n / w:.2f} | "
                     f"{1000 * w / n / 60:.1f} | {w / med[base]:.2f} | {digests} |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- instructions

_LOOPS_CHILD = r"""
import logging, os, sys, tempfile
root, file, mode, n, tlog = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5]
sys.path.insert(0, root)
import companion
assert companion.__file__.startswith(root), companion.__file__
from companion.aio.tlog import TlogWriter
from companion.replay.flight import fly_schedule
from companion.replay.runner import ReplayConfig, prepare_mission
logging.disable(logging.WARNING)
cfg = ReplayConfig(mode=mode)
prep = prepare_mission(file, cfg)
d = tempfile.mkdtemp()
for i in range(n):
    if tlog == "tlog":
        with TlogWriter(os.path.join(d, f"{i}.tlog"), buffer_bytes=1 << 20) as w:
            fly_schedule(cfg, prep.schedule, prep.home, w)
    else:
        fly_schedule(cfg, prep.schedule, prep.home, None)
"""


def loop_instructions(tree: Path, file: Path, mode: str, tlog: bool) -> int:
    """Instructions of one lockstep loop (valgrind's callgrind: a process flying it twice
    minus one flying it once), independent of the machine's load."""
    counts = []
    for n in (1, 2):
        proc = subprocess.run(
            ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", sys.executable,
             "-c", _LOOPS_CHILD, str(tree), str(file), mode, str(n), "tlog" if tlog else "none"],
            cwd=tree, env=_env(tree, "cached"), capture_output=True, text=True, check=False)
        line = [ln for ln in proc.stderr.splitlines() if "Collected" in ln]
        if proc.returncode != 0 or not line:
            raise SystemExit(f"callgrind in {tree} failed:\n{proc.stderr[-2000:]}")
        counts.append(int(line[-1].split()[-1]))
    return counts[1] - counts[0]


def cmd_instructions(args: argparse.Namespace) -> str:
    if shutil.which("valgrind") is None:
        raise SystemExit("valgrind not found")
    trees = [resolve_tree(t) for t in args.trees]
    file = args.file.resolve()
    rows = []
    for tlog in (True, False):
        counts = {t: loop_instructions(t, file, args.mode, tlog) for t in trees}
        base = counts[trees[0]]
        for t in trees:
            rows.append(f"| {t.name if t != ROOT else 'this tree'} | "
                        f"{'with' if tlog else 'without'} | {counts[t] / 1e9:.3f} | "
                        f"{counts[t] / base:.3f} |")
            print(rows[-1], flush=True)
    return "\n".join([
        f"Instructions of one lockstep loop of `{file.name}` ({args.mode} mode; valgrind "
        "callgrind, a process flying it twice minus one flying it once; independent of the "
        "machine's load):",
        "",
        "| tree | tlog | instructions [1e9] | / baseline |",
        "| --- | --- | ---: | ---: |",
        *rows,
    ])


# ----------------------------------------------------------------------------- main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("ab")
    a.add_argument("trees", nargs="+")
    a.add_argument("--file", type=Path, default=DEFAULT_FILE)
    a.add_argument("--mode", default="attitude", choices=("attitude", "position", "rates"))
    a.add_argument("--rounds", type=int, default=5)
    a.add_argument("--bytecode", default="cached", choices=("cached", "none"))
    a.add_argument("--plot", action="store_true", help="draw flight.png (default: --no-plot)")
    q = sub.add_parser("parts")
    q.add_argument("trees", nargs="+")
    q.add_argument("--file", type=Path, default=DEFAULT_FILE)
    q.add_argument("--mode", default="attitude", choices=("attitude", "position", "rates"))
    q.add_argument("--rounds", type=int, default=3)
    p = sub.add_parser("profile")
    p.add_argument("--file", type=Path, default=DEFAULT_FILE)
    p.add_argument("--mode", default="attitude", choices=("attitude", "position", "rates"))
    p.add_argument("--top", type=int, default=30)
    f = sub.add_parser("fingerprint")
    f.add_argument("trees", nargs="+")
    c = sub.add_parser("campaign")
    c.add_argument("trees", nargs="+")
    c.add_argument("--runs", type=int, default=20, help="runs per mode")
    c.add_argument("--workers", type=int, default=2)
    c.add_argument("--rounds", type=int, default=1)
    c.add_argument("--modes", default="attitude,position,rates")
    pl = sub.add_parser("plan")
    pl.add_argument("trees", nargs="+")
    pl.add_argument("--files", nargs="+", default=None)
    pl.add_argument("--rounds", type=int, default=3)
    n = sub.add_parser("instructions")
    n.add_argument("trees", nargs="+")
    n.add_argument("--file", type=Path, default=DEFAULT_FILE)
    n.add_argument("--mode", default="attitude", choices=("attitude", "position", "rates"))
    args = ap.parse_args()
    text = {"ab": cmd_ab, "profile": cmd_profile, "fingerprint": cmd_fingerprint,
            "campaign": cmd_campaign, "instructions": cmd_instructions,
            "parts": cmd_parts, "plan": cmd_plan}[args.cmd](args)
    print()
    print(text)


if __name__ == "__main__":
    main()
