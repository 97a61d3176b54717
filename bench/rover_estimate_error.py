"""The rover's estimate error against its truth (issue 29): PX4 main's EKF2 on SIH's Ackermann
rover, or the mock rover's SIM_EST_* model, from the traces bench_rover_fidelity.py records.

Error = estimate - truth: LOCAL_POSITION_NED (x, y, vx, vy) and ATTITUDE (yaw) minus
HIL_STATE_QUATERNION (the simulator's state; position projected about PX4 SITL's home), the truth
interpolated at each estimate sample on the receive clock: PX4 main sends HIL_STATE_QUATERNION
with time_usec 0, so the truth has only its receive times; each estimate sample is placed at its
time_boot_ms mapped onto the receive clock by the lower envelope of receive - boot time per 5 s
block (the link's delay left out, the autopilot clock's drift followed). The truth's own receive
jitter remains: at 2.6 rad/s in a turn 10 ms are 1.5 deg, hence the heading figure at low yaw
rates. Per flight the mean error is removed (each
PX4 start has its own EKF origin; the means and the RMS with them are reported too); then per
axis (north, east):
- standing (true speed < 0.05 m/s) and driving (> 0.3 m/s): std of the position error [m], of
  the velocity error [m/s], and of the heading error [deg] (driving: also only where the true
  yaw rate is below 0.3 rad/s, where sample timing cannot matter);
- time constant [s]: the autocorrelation of each error over the whole flight (resampled to
  20 Hz, lags 0-6 s, averaged over flights and axes) fitted by the second-order Gauss-Markov
  process the mock uses, (1 + t / tau) exp(-t / tau); and its value at 1 s and 5 s.

The same per kind of flight (offboard: the speed step, stop and full-steering turn; mission:
rover_square; standing) under "by_flight". `--fly-standing S` first records S seconds of a
standing PX4 rover (fresh PX4, under the flight lock) next to the other traces, the long quiet
stretch the autocorrelation wants.
Lead and heading (traces with GLOBAL_POSITION_INT, "gpos": the estimate in latitude/longitude,
free of the EKF's origin): the position error along the true velocity, least squares against the
true speed over samples above LEAD_MIN_M_S, is a lead in seconds of travel ("lead_s", and per
speed band); the error left after lead x velocity, per axis while driving, and its time constant
("residual"); on rover_square's four legs (mission traces, 5 m after a corner to 3 m before the
next) each leg's mean heading error, its RMS over flights' means (a heading off for a whole start)
and about them, and the estimate's mean offset from the leg, with the gain k of offset =
-k tan(heading error) (pure pursuit's look-ahead: "legs").
Usage: `python bench/rover_estimate_error.py [--out DIR] [--kind px4] [--fly-standing 90]`
(DIR: bench_rover_fidelity.py's --out; reads DIR/KIND-*/{offboard,mission,standing}-trace.json).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize_scalar

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

import bench_rover_fidelity as fid  # noqa: E402

FloatArray = npt.NDArray[np.float64]
STANDING_M_S = 0.05
DRIVING_M_S = 0.3
STRAIGHT_RAD_S = 0.3
GRID_S = 0.05
MAX_LAG_S = 6.0
LEAD_MIN_M_S = 0.5


def to_receive_clock(boot_s: FloatArray, recv_s: FloatArray, block_s: float = 5.0
                     ) -> FloatArray:
    """Autopilot time stamps [s] on the receive clock: plus the least receive - boot offset of
    their `block_s` block, interpolated between blocks (linearly extrapolated past the first and
    the last: the autopilot's clock drifts, PX4 SITL's ~1 % against the wall)."""
    off = recv_s - boot_s
    blk = np.floor((boot_s - boot_s[0]) / block_s).astype(np.int64)
    mids, mins = [], []
    for b in np.unique(blk):
        sel = blk == b
        k = int(np.argmin(off[sel]))
        mids.append(float(boot_s[sel][k]))
        mins.append(float(off[sel][k]))
    x, y = np.array(mids), np.array(mins)
    off_at = np.interp(boot_s, x, y)
    if len(x) > 1:
        lo, hi = boot_s < x[0], boot_s > x[-1]
        off_at[lo] = y[0] + (boot_s[lo] - x[0]) * (y[1] - y[0]) / (x[1] - x[0])
        off_at[hi] = y[-1] + (boot_s[hi] - x[-1]) * (y[-1] - y[-2]) / (x[-1] - x[-2])
    return boot_s + off_at


def flight_errors(rec: dict[str, Any]) -> dict[str, FloatArray]:
    """Errors of one flight's trace at the estimate samples: t (receive clock [s]), pos (N, 2),
    vel (N, 2), speed (true), and at the ATTITUDE samples t_att, yaw (wrapped), yaw_rate (true)."""
    lp = np.asarray(rec["lpos"], dtype=float)
    tr = np.asarray(rec["truth"], dtype=float)
    at = np.asarray(rec["att"], dtype=float)
    if lp.shape[1] < 6 or at.shape[1] < 4:
        raise ValueError("trace without autopilot time stamps (recorded before they were)")
    tt = tr[:, 0]
    t = to_receive_clock(lp[:, 5], lp[:, 0])
    inside = (t >= tt[0]) & (t <= tt[-1])
    lp, t = lp[inside], t[inside]

    def at_t(col: int, when: FloatArray) -> FloatArray:
        return np.interp(when, tt, tr[:, col])

    pos = lp[:, 1:3] - np.column_stack([at_t(1, t), at_t(2, t)])
    vel = lp[:, 3:5] - np.column_stack([at_t(3, t), at_t(4, t)])
    speed = np.hypot(at_t(3, t), at_t(4, t))
    ta = to_receive_clock(at[:, 3], at[:, 0])
    ins = (ta >= tt[0]) & (ta <= tt[-1])
    at, ta = at[ins], ta[ins]
    yaw_true = np.interp(ta, tt, np.unwrap(tr[:, 5]))
    yaw = np.angle(np.exp(1j * (at[:, 1] - yaw_true)))
    return {"t": t, "pos": pos, "vel": vel, "speed": speed, "t_att": ta, "yaw": yaw,
            "yaw_rate": np.abs(np.interp(ta, tt, tr[:, 6])),
            "speed_att": np.hypot(np.interp(ta, tt, tr[:, 3]), np.interp(ta, tt, tr[:, 4]))}


def acf(t: FloatArray, x: FloatArray) -> FloatArray:
    """Normalised autocorrelation of `x` (sampled at `t`, mean removed) every GRID_S up to
    MAX_LAG_S, from the series resampled onto a uniform grid."""
    g = np.arange(t[0], t[-1], GRID_S)
    y = np.interp(g, t, x)
    y = y - y.mean()
    n = int(MAX_LAG_S / GRID_S) + 1
    if len(y) < 2 * n:
        return np.full(n, np.nan)
    v = float(np.dot(y, y)) / len(y)
    return np.array([float(np.dot(y[: len(y) - k], y[k:])) / (len(y) - k) / v
                     for k in range(n)])


def fit_tau(rho: FloatArray) -> float:
    """Time constant [s] of (1 + t / tau) exp(-t / tau) fitted to the autocorrelation `rho`
    (lags 0, GRID_S, ...; least squares)."""
    lags = np.arange(len(rho)) * GRID_S
    ok = np.isfinite(rho)

    def cost(tau: float) -> float:
        m = (1.0 + lags / tau) * np.exp(-lags / tau)
        return float(np.sum((m[ok] - rho[ok]) ** 2))

    return float(minimize_scalar(cost, bounds=(0.05, 60.0), method="bounded").x)


def summarise(flights: list[dict[str, FloatArray]]) -> dict[str, Any]:
    """The statistics of the module docstring over `flights` (their samples pooled)."""
    out: dict[str, Any] = {"flights": len(flights)}
    pos = [f["pos"] - f["pos"].mean(axis=0) for f in flights]
    vel = [f["vel"] - f["vel"].mean(axis=0) for f in flights]
    yaw = [f["yaw"] - f["yaw"].mean() for f in flights]
    out["pos_mean_m"] = [[round(float(v), 3) for v in f["pos"].mean(axis=0)] for f in flights]
    out["yaw_mean_deg"] = [round(math.degrees(float(f["yaw"].mean())), 2) for f in flights]
    for name, lo, hi in (("standing", -1.0, STANDING_M_S), ("driving", DRIVING_M_S, math.inf)):
        sel = [(f["speed"] >= lo) & (f["speed"] < hi) for f in flights]
        sel_a = [(f["speed_att"] >= lo) & (f["speed_att"] < hi) for f in flights]
        p = np.vstack([x[s] for x, s in zip(pos, sel, strict=True)])
        raw = np.vstack([f["pos"][s] for f, s in zip(flights, sel, strict=True)])
        raw_y = np.concatenate([f["yaw"][s] for f, s in zip(flights, sel_a, strict=True)])
        v = np.vstack([x[s] for x, s in zip(vel, sel, strict=True)])
        y = np.concatenate([x[s] for x, s in zip(yaw, sel_a, strict=True)])
        st = np.concatenate([(f["yaw_rate"] < STRAIGHT_RAD_S)[s]
                             for f, s in zip(flights, sel_a, strict=True)])
        out[name] = {
            "samples": len(p),
            "pos_std_ne_m": [round(float(c), 3) for c in p.std(axis=0)] if len(p) else None,
            "pos_rms_ne_m": ([round(float(c), 3) for c in np.sqrt(np.mean(raw**2, axis=0))]
                             if len(raw) else None),
            "yaw_rms_deg": (round(math.degrees(float(np.sqrt(np.mean(raw_y**2)))), 2)
                            if len(raw_y) else None),
            "vel_std_ne_m_s": [round(float(c), 3) for c in v.std(axis=0)] if len(v) else None,
            "yaw_std_deg": round(math.degrees(float(y.std())), 2) if len(y) else None,
            "yaw_std_straight_deg": (round(math.degrees(float(y[st].std())), 2)
                                     if st.any() else None),
        }
    for key, series, tcol in (("pos", pos, "t"), ("vel", vel, "t"), ("yaw", yaw, "t_att")):
        rhos = []
        for f, x in zip(flights, series, strict=True):
            cols = x if x.ndim == 2 else x[:, None]
            rhos += [acf(f[tcol], cols[:, j]) for j in range(cols.shape[1])]
        rho = np.nanmean(np.array(rhos), axis=0) if rhos else np.full(2, np.nan)
        k1, k5 = round(1.0 / GRID_S), round(5.0 / GRID_S)
        out[f"{key}_tau_s"] = round(fit_tau(rho), 2) if np.isfinite(rho).any() else None
        out[f"{key}_acf_1s_5s"] = [round(float(rho[k1]), 2), round(float(rho[k5]), 2)]
    return out


def _gpos_and_truth(rec: dict[str, Any]
                    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """(t on the receive clock, the GLOBAL_POSITION_INT rows within the truth's span, the truth's
    north, east, v north, v east at those times); None for a trace without them."""
    g = np.asarray(rec.get("gpos", []), dtype=float)
    if len(g) < 50:
        return None
    tr = np.asarray(rec["truth"], dtype=float)
    t = to_receive_clock(g[:, 3], g[:, 0])
    ok = (t >= tr[0, 0]) & (t <= tr[-1, 0])
    t, g = t[ok], g[ok]
    return t, g, np.column_stack([np.interp(t, tr[:, 0], tr[:, c]) for c in (1, 2, 3, 4)])


def lead_and_heading(traces: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """The lead, the residual and the legs' heading of the module docstring, from the raw traces
    by kind of flight ({"offboard": [...], "mission": [...]}); {} without GLOBAL_POSITION_INT."""
    along, speed, res, rhos = [], [], [], []
    pairs = [x for x in (_gpos_and_truth(r) for group in traces.values() for r in group) if x]
    for _t, g, tru in pairs:
        err = g[:, 1:3] - tru[:, :2]
        v = np.hypot(tru[:, 2], tru[:, 3])
        u = tru[:, 2:4] / np.maximum(v, 1e-9)[:, None]
        moving = v > LEAD_MIN_M_S
        along.append(np.sum(err * u, axis=1)[moving])
        speed.append(v[moving])
    if not along:
        return {}
    a, v = np.concatenate(along), np.concatenate(speed)
    lead = float(np.dot(a, v) / np.dot(v, v))
    bands = {}
    for lo, hi in ((0.5, 1.5), (1.5, 2.5), (2.5, 3.5)):
        sel = (v >= lo) & (v < hi)
        if sel.sum() > 20:
            bands[f"{lo:g}-{hi:g} m/s"] = round(float(a[sel].mean() / v[sel].mean()), 3)
    for t, g, tru in pairs:
        r = g[:, 1:3] - tru[:, :2] - lead * tru[:, 2:4]
        drive = np.hypot(tru[:, 2], tru[:, 3]) > DRIVING_M_S
        res.append(r[drive] - r[drive].mean(axis=0))
        rhos += [acf(t, r[:, j] - r[:, j].mean()) for j in (0, 1)]
    rr = np.vstack(res)
    out: dict[str, Any] = {
        "lead_s": round(lead, 3), "lead_s_by_speed": bands,
        "residual": {"pos_std_ne_m": [round(float(c), 3) for c in rr.std(axis=0)],
                     "pos_std_by_flight_m": [round(float(np.mean(x.std(axis=0))), 3)
                                             for x in res],
                     "tau_s": round(fit_tau(np.nanmean(np.array(rhos), axis=0)), 2)}}
    legs = mission_legs(traces.get("mission", []))
    if legs:
        out["legs"] = legs
    return out


def mission_legs(recs: list[dict[str, Any]]) -> dict[str, Any]:
    """rover_square's legs in the mission traces: heading error and the estimate's offset."""
    _items, home, wps = fid.plan_items(fid.PLAN)
    shift = fid._ne(np.array([home[0]]), np.array([home[1]]), *fid.HOME)[0]
    corners = np.vstack([[0.0, 0.0], fid._ne(np.array([w[0] for w in wps]),
                                             np.array([w[1] for w in wps]), *home)])
    heading, offset, by_flight = [], [], []
    for rec in recs:
        g = np.asarray(rec.get("gpos", []), dtype=float)
        at = np.asarray(rec["att"], dtype=float)
        if len(g) < 50:
            continue
        tr = np.asarray(rec["truth"], dtype=float)
        tr = tr[tr[:, 0] >= rec["marks"]["arm"]]
        tg = to_receive_clock(g[:, 3], g[:, 0])
        ta = to_receive_clock(at[:, 3], at[:, 0])
        est = np.column_stack([np.interp(tr[:, 0], tg, g[:, c]) for c in (1, 2)]) - shift
        p = tr[:, 1:3] - shift
        yaw_est = np.interp(tr[:, 0], ta, np.unwrap(at[:, 1]))
        mine = []
        for k in range(len(corners) - 1):
            a, b = corners[k], corners[k + 1]
            length = float(np.hypot(*(b - a)))
            u = (b - a) / length
            n = np.array([-u[1], u[0]])
            s_tr, c_tr = (p - a) @ u, (p - a) @ n
            sel = (s_tr > 5.0) & (s_tr < length - 3.0) & (np.abs(c_tr) < 2.0)
            if sel.sum() < 20:
                continue
            e = np.angle(np.exp(1j * (yaw_est[sel] - tr[sel, 5])))
            heading.append(float(np.mean(e)))
            offset.append(float(np.mean((est[sel] - a) @ n)))
            mine.append(heading[-1])
        if mine:
            by_flight.append(float(np.mean(mine)))
    if not heading:
        return {}
    h, o = np.array(heading), np.array(offset)
    tan = np.tan(h)
    return {"legs": len(h),
            "heading_mean_by_flight_deg": [round(math.degrees(x), 2) for x in by_flight],
            "heading_rms_of_flight_means_deg": round(math.degrees(
                float(np.sqrt(np.mean(np.square(by_flight))))), 2),
            "heading_rms_deg": round(math.degrees(float(np.sqrt(np.mean(h * h)))), 2),
            "offset_rms_m": round(float(np.sqrt(np.mean(o * o))), 3),
            "offset_gain_k_m": round(float(-np.dot(o, tan) / np.dot(tan, tan)), 2)}


def fly_standing(folder: Path, seconds: float) -> Path:
    """A fresh PX4 rover standing (disarmed, in Hold) for `seconds`; its trace."""
    trace = folder / "standing-trace.json"
    with fid.launch("px4", folder / "standing") as ep:
        link = fid.Link(ep)
        try:
            link.wait_heartbeat()
            link.pump(seconds)
        finally:
            link.close()
    trace.write_text(json.dumps(link.rec.__dict__))
    return trace


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/ecca-bench-rover-fidelity"))
    ap.add_argument("--kind", default="px4", choices=("px4", "mock"))
    ap.add_argument("--fly-standing", type=float, default=0.0, metavar="S")
    args = ap.parse_args(argv)
    if args.fly_standing > 0.0:
        fly_standing(args.out / f"{args.kind}-standing", args.fly_standing)
    flights: dict[str, list[dict[str, FloatArray]]] = {}
    raw: dict[str, list[dict[str, Any]]] = {}
    for trace in sorted(args.out.glob(f"{args.kind}-*/*-trace.json")):
        rec = json.loads(trace.read_text())
        fl = flight_errors(rec)
        kind = trace.name.removesuffix("-trace.json")
        flights.setdefault(kind, []).append(fl)
        raw.setdefault(kind, []).append(rec)
        print(f"  {trace.relative_to(args.out)}: {len(fl['t'])} samples")
    if not flights:
        ap.error(f"no {args.kind} traces in {args.out}")
    res = summarise([f for group in flights.values() for f in group])
    res["by_flight"] = {name: summarise(group) for name, group in flights.items()}
    res["lead_and_heading"] = lead_and_heading(raw)
    (args.out / f"estimate-error-{args.kind}.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
