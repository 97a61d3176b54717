"""Long fuzz campaigns without extra dependencies: seeded mutation of the seed corpora, one
process (one core), every input timed and checked.

    nice -n 15 python -m tests.fuzz.campaign --target mission --inputs 1000000 --out fuzz_out

Per input: the target's properties (targets.py; a `Finding` or any undocumented exception is a
crash), wall time (over --slow-s, default 2 s, is recorded as slow; over --hang-s, default 30 s,
the input is interrupted and recorded as a hang) and the process's peak memory (a jump of more
than --memory-mb in one input is recorded). Crashing, slow and hanging inputs are written to
OUT/TARGET/ with their traceback; a summary line (inputs, rate, findings, peak RSS) is printed
every --report-s seconds and at the end, and written to OUT/TARGET/summary.json.

The mission target plans through a bounded `PlanMemo` (--memo entries; targets.MissionTarget):
a stop-to-stop piece whose exact planner input was planned before (by an earlier input, whose
time was measured then) is served from it; the summary's "memo" says how many inputs planned
and how many were served wholly from it, and every --memo-verify-th served input is planned
again without it and must give the same schedule bit for bit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import re
import resource
import signal
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][+-]?\d+)?")
INTERESTING = [b"0", b"-1", b"1e300", b"-1e300", b"1e15", b"1e8", b"10000", b"10001", b"3600",
               b"3601", b"40", b"40.5", b"200", b"201", b"65535", b"65536", b"2147483648", b"nan",
               b"NaN", b"Infinity", b"-0", b"1e-300", b"47.397742", b"8.545594", b"null", b"177",
               b"178", b"16", b"22", b"21", b"20", b"2", b"3", b"10"]


def mutate(data: bytes, rng: random.Random, seeds: list[bytes]) -> bytes:
    """One random mutation: bit flip, byte set, insert, delete, duplicate, splice with another
    seed, a number replaced by an interesting one, or a truncation."""
    op = rng.randrange(8)
    n = len(data)
    if n == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))
    i = rng.randrange(n)
    if op == 0:
        return data[:i] + bytes((data[i] ^ (1 << rng.randrange(8)),)) + data[i + 1:]
    if op == 1:
        return data[:i] + bytes((rng.randrange(256),)) + data[i + 1:]
    if op == 2:
        return data[:i] + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 9))) + data[i:]
    if op == 3:
        return data[:i] + data[i + rng.randrange(1, 33):]
    if op == 4:
        j = min(n, i + rng.randrange(1, 65))
        return data[:j] + data[i:j] + data[j:]
    if op == 5:
        other = rng.choice(seeds)
        k = rng.randrange(len(other) + 1)
        return data[:i] + other[k:k + rng.randrange(1, 200)] + data[i:]
    if op == 6:
        spans = [m.span() for m in _NUMBER.finditer(data)]
        if spans:
            a, b = rng.choice(spans)
            return data[:a] + rng.choice(INTERESTING) + data[b:]
        return data
    return data[:i]


class _Hang(Exception):
    pass


def _alarm(_sig: int, _frame: Any) -> None:
    raise _Hang()


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _targets(memo_entries: int = 0, memo_verify: int = 100,
             ) -> dict[str, tuple[Callable[[bytes], Any], list[bytes]]]:
    from tests.fuzz import corpus
    from tests.fuzz.targets import (
        LINK_CLASSES,
        LinkTarget,
        MissionTarget,
        MockTarget,
        mission_target,
    )

    mock = MockTarget()
    mission = (MissionTarget(memo_entries, memo_verify) if memo_entries > 0 else mission_target)
    return {
        "mission": (mission, corpus.mission_seeds()),
        "link": (LinkTarget(), corpus.datagram_seeds(len(LINK_CLASSES), 80)),
        "mock": (mock, corpus.datagram_seeds(len(mock.classes), len(mock.param_names))),
    }


def run(target: str, inputs: int, seconds: float, seed: int, out: Path, slow_s: float,
        hang_s: float, memory_mb: float, report_s: float, memo: int = 0,
        memo_verify: int = 100) -> dict[str, Any]:
    """Fuzz one target until `inputs` inputs or `seconds` seconds; returns the summary."""
    fn, seeds = _targets(memo, memo_verify)[target]
    rng = random.Random(seed)
    folder = out / target
    folder.mkdir(parents=True, exist_ok=True)
    pool = list(seeds)
    stats: dict[str, Any] = {"target": target, "seed": seed, "inputs": 0, "crashes": 0,
                             "slow": 0, "hangs": 0, "memory_jumps": 0, "max_input_s": 0.0,
                             "outcomes": {}}
    signal.signal(signal.SIGALRM, _alarm)
    t0 = last_report = time.perf_counter()
    k = 0
    # the seeds first, as they are; then mutants
    while k < inputs and time.perf_counter() - t0 < seconds:
        data = seeds[k] if k < len(seeds) else rng.choice(pool)
        if k >= len(seeds):
            for _ in range(1 + int(rng.expovariate(1.0))):
                data = mutate(data, rng, seeds)
            data = data[:20_000]
        rss0 = _peak_rss_mb()
        start = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, hang_s)
        kind = None
        try:
            result = fn(data)
        except _Hang:
            kind, result = "hang", None
        except Exception:  # a Finding or anything undocumented
            kind, result = "crash", traceback.format_exc()
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        dt = time.perf_counter() - start
        k += 1
        stats["inputs"] = k
        stats["max_input_s"] = max(stats["max_input_s"], dt)
        if kind is None and dt > slow_s:
            kind = "slow"
        if kind is None and _peak_rss_mb() - rss0 > memory_mb:
            kind = "memory_jump"
        if kind is not None:
            key = {"crash": "crashes", "slow": "slow", "hang": "hangs",
                   "memory_jump": "memory_jumps"}[kind]
            stats[key] += 1
            h = hashlib.sha1(data).hexdigest()[:12]
            (folder / f"{kind}-{h}.bin").write_bytes(data)
            note = result if kind == "crash" else f"{dt:.2f} s, outcome {result!r}"
            (folder / f"{kind}-{h}.txt").write_text(note)
        elif isinstance(result, str):
            stats["outcomes"][result] = stats["outcomes"].get(result, 0) + 1
            if result == "flown" and len(pool) < len(seeds) + 2000:
                pool.append(data)  # accepted inputs reach deeper: mutate them further
        now = time.perf_counter()
        if now - last_report >= report_s:
            last_report = now
            _report(stats, now - t0, folder, fn)
    _report(stats, time.perf_counter() - t0, folder, fn)
    return stats


def _report(stats: dict[str, Any], elapsed: float, folder: Path, fn: Any) -> None:
    if hasattr(fn, "stats"):
        stats["memo"] = fn.stats()
    stats["elapsed_s"] = round(elapsed, 1)
    stats["rate_per_s"] = round(stats["inputs"] / elapsed, 1) if elapsed > 0 else 0.0
    stats["peak_rss_mb"] = round(_peak_rss_mb(), 1)
    stats["max_input_s"] = round(stats["max_input_s"], 3)
    (folder / "summary.json").write_text(json.dumps(stats, indent=1))
    print(json.dumps(stats), flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz.campaign", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", choices=("mission", "link", "mock"), required=True)
    ap.add_argument("--inputs", type=int, default=1_000_000)
    ap.add_argument("--seconds", type=float, default=float("inf"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("fuzz_out"))
    ap.add_argument("--slow-s", type=float, default=2.0)
    ap.add_argument("--hang-s", type=float, default=30.0)
    ap.add_argument("--memory-mb", type=float, default=256.0)
    ap.add_argument("--report-s", type=float, default=60.0)
    ap.add_argument("--memo", type=int, default=4096, metavar="ENTRIES",
                    help="mission: planned chunks kept for reuse (0: plan every chunk)")
    ap.add_argument("--memo-verify", type=int, default=100, metavar="N",
                    help="mission: every N-th input served from the memo is also planned "
                         "without it and must give the same schedule bit for bit (0: never)")
    a = ap.parse_args(argv)
    import logging

    logging.disable(logging.CRITICAL)  # the loaders' warnings are expected by the thousand
    if a.memo < 0 or a.memo_verify < 0:
        ap.error("--memo and --memo-verify must be >= 0")
    stats = run(a.target, a.inputs, a.seconds, a.seed, a.out, a.slow_s, a.hang_s, a.memory_mb,
                a.report_s, a.memo, a.memo_verify)
    return 1 if stats["crashes"] or stats["hangs"] else 0


if __name__ == "__main__":
    sys.exit(main())
