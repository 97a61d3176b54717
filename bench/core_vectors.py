"""Golden vectors of the tracking law's core (companion.control.core) from real flights.

Flies the figure-8 at 6 m/s on a fresh autopilot (real PX4 SITL by default) through the public
API, as `bench_tracking.py --target px4` does, once in attitude mode at the nominal mass and
once in rates mode with `SIH_MASS` 0.8 (the companion not told: the thrust limits act on the
lobes), and records the core's input vector at every setpoint. A selection, spread over each
flight, half of it from setpoints where a thrust limit acted, goes to
`gen_c/tests/core_vectors.json` (inputs only: tests/gen_c/test_tracking_core.py evaluates the
Python core and the generated C on them and compares).

Usage (~2 min; a fresh PX4 SITL per flight, started as bench_tracking.py starts it):
  python bench/core_vectors.py [--target px4|mock] [--per-flight 100] [--out FILE]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import companion.control.law as law  # noqa: E402
import companion.flatness._formulas as fm  # noqa: E402
from companion.control.core import CORE_INPUTS, CORE_N_IN, tracking_core  # noqa: E402

OUT = HERE.parent / "gen_c" / "tests" / "core_vectors.json"
FLIGHTS = (("attitude", {}), ("rates", {"SIH_MASS": 0.8}))


def _select(xs: list[tuple[float, ...]], n: int) -> list[list[float]]:
    """`n` vectors evenly spread over the flight, half (as far as there are) saturated."""
    sat = [x for x in xs if tracking_core(fm.FLOAT, x)[8] == 1.0]
    free = [x for x in xs if tracking_core(fm.FLOAT, x)[8] != 1.0]
    n_sat = min(len(sat), n // 2)
    pick: list[list[float]] = []
    for group, k in ((sat, n_sat), (free, n - n_sat)):
        if k and group:
            idx = np.unique(np.linspace(0, len(group) - 1, k).round().astype(int))
            pick += [list(map(float, group[i])) for i in idx]
    return pick


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", choices=("px4", "mock"), default="px4")
    ap.add_argument("--per-flight", type=int, default=100)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--work", type=Path, default=Path("bench_out/core_vectors"))
    args = ap.parse_args(argv)
    import bench_tracking as B  # noqa: N812

    recorded: list[tuple[float, ...]] = []
    real_pre = law.tracking_pre

    def recording_pre(ops: fm.Backend, x: Any) -> dict[str, Any]:
        recorded.append(tuple(float(v) for v in x))
        return real_pre(ops, x)

    law.tracking_pre = recording_pre  # type: ignore[assignment]
    flights, vectors = [], []
    try:
        for i, (mode, params) in enumerate(FLIGHTS):
            recorded.clear()
            res = B._api_cell(args.target, mode, 6.0, args.work, i, [], None, dict(params))
            assert all(len(x) == CORE_N_IN for x in recorded)
            pick = _select(recorded, args.per_flight)
            n_sat = sum(tracking_core(fm.FLOAT, x)[8] == 1.0 for x in pick)
            print(f"{args.target} {mode} {params}: {len(recorded)} setpoints, RMS "
                  f"{res['rms']:.3f} m; kept {len(pick)} ({n_sat} saturated)", flush=True)
            flights.append({"target": args.target, "mode": mode, "params": params,
                            "setpoints": len(recorded), "rms_m": res["rms"],
                            "kept": len(pick), "saturated": n_sat})
            vectors += pick
    finally:
        law.tracking_pre = real_pre  # type: ignore[assignment]
    doc = {
        "about": "inputs of companion.control.core (CORE_INPUTS order) recorded at the "
                 "setpoints of real flights by bench/core_vectors.py (figure-8 at 6 m/s)",
        "date": dt.date.today().isoformat(),
        "inputs_layout": [[name, n] for name, n in CORE_INPUTS],
        "flights": flights,
        "inputs": vectors,
    }
    args.out.write_text(json.dumps(doc, separators=(",", ":")) + "\n", encoding="utf-8")
    print(f"wrote {len(vectors)} vectors to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
