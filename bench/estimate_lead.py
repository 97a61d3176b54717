"""How far an autopilot's position estimate leads (or lags) its truth along the motion, from
.tlog files: GLOBAL_POSITION_INT (the estimate in latitude/longitude, free of the EKF's origin)
against HIL_STATE_QUATERNION (the simulator's state, on request in PX4 SITL and the mock), both
placed on the tlog's receive clock, the estimate interpolated at each truth sample. The error
along the true horizontal velocity, least squares against the true speed over samples above
1 m/s, is the lead in seconds of travel (positive: the estimate is ahead); also per speed band.

PX4 main's SIH rover leads by ~0.11 s (BENCHMARKS.md, "The estimate leads, and its heading is off
for a whole start"); this asks the same of any flight's tlog, e.g. the quad's:
`python bench/estimate_lead.py OUT/px4-attitude-6-0/flight.tlog` after
`python bench/bench_tracking.py --target px4 --speeds 6 --modes attitude --out OUT`.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from pymavlink import mavutil

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

from bench_rover_fidelity import _ne  # noqa: E402  (equirectangular north, east about a point)

BANDS = ((1.0, 3.0), (3.0, 5.0), (5.0, 7.0), (7.0, 9.0))


def lead(path: Path, sysid: int | None = None) -> dict[str, float]:
    """{"lead_s", "samples", and "lead_s <lo>-<hi> m/s" per band with > 20 samples}; NaN lead
    without enough of both messages. `sysid`: the autopilot's (default: any, component 1)."""
    conn = mavutil.mavlink_connection(str(path), dialect="common")
    est, tru = [], []
    while (m := conn.recv_match(type=["GLOBAL_POSITION_INT", "HIL_STATE_QUATERNION"])) is not None:
        if m.get_srcComponent() != 1 or (sysid is not None and m.get_srcSystem() != sysid):
            continue
        t = float(getattr(m, "_timestamp", 0.0))
        if m.get_type() == "GLOBAL_POSITION_INT":
            est.append((t, m.lat * 1e-7, m.lon * 1e-7))
        else:
            tru.append((t, m.lat * 1e-7, m.lon * 1e-7, m.vx * 0.01, m.vy * 0.01))
    conn.close()
    if len(est) < 50 or len(tru) < 50:
        return {"lead_s": math.nan, "samples": 0.0}
    e, h = np.array(est), np.array(tru)
    lat0, lon0 = float(h[0, 1]), float(h[0, 2])
    ok = (h[:, 0] > e[0, 0]) & (h[:, 0] < e[-1, 0])
    h = h[ok]
    ge = _ne(e[:, 1], e[:, 2], lat0, lon0)
    at = np.column_stack([np.interp(h[:, 0], e[:, 0], ge[:, j]) for j in (0, 1)])
    err = at - _ne(h[:, 1], h[:, 2], lat0, lon0)
    v = np.hypot(h[:, 3], h[:, 4])
    u = h[:, 3:5] / np.maximum(v, 1e-9)[:, None]
    along = np.sum(err * u, axis=1)
    mv = v > 1.0
    out = {"lead_s": float(np.dot(along[mv], v[mv]) / np.dot(v[mv], v[mv])) if mv.any()
           else math.nan, "samples": float(mv.sum())}
    for lo, hi in BANDS:
        sel = (v >= lo) & (v < hi)
        if sel.sum() > 20:
            out[f"lead_s {lo:g}-{hi:g} m/s"] = float(along[sel].mean() / v[sel].mean())
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tlogs", nargs="+", type=Path)
    ap.add_argument("--sysid", type=int, default=None)
    args = ap.parse_args(argv)
    for p in args.tlogs:
        r = lead(p, args.sysid)
        print(f"{p}: " + ", ".join(f"{k} {v:.3f}" if k != "samples" else f"{k} {v:.0f}"
                                   for k, v in r.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
