"""Pure summary of a flown trajectory: waypoints reached, tracking error, duration.

Shared by `fly` and `serve` (replay has its own, richer report from its lockstep log). Inputs are
position samples (NED, m) and the reference each was compared with; nothing here reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def closest_approach(points: FloatArray, wps: FloatArray) -> FloatArray:
    """Smallest distance [m] of `points` (N, 3) to each waypoint of `wps` (K, 3); inf if no
    points."""
    if len(points) == 0 or len(wps) == 0:
        return np.full(len(wps), math.inf)
    out = np.empty(len(wps))
    for i, w in enumerate(wps):
        out[i] = float(np.min(np.linalg.norm(points - w, axis=1)))
    return out


@dataclass
class TrackRecorder:
    """Collects (time [s], flown position NED [m], reference position NED [m]) samples."""

    t_s: list[float] = field(default_factory=list)
    pos_ned: list[tuple[float, float, float]] = field(default_factory=list)
    ref_ned: list[tuple[float, float, float]] = field(default_factory=list)

    def add(self, t_s: float, pos_ned: Sequence[float] | FloatArray,
            ref_ned: Sequence[float] | FloatArray) -> None:
        """Record one sample."""
        self.t_s.append(float(t_s))
        self.pos_ned.append((float(pos_ned[0]), float(pos_ned[1]), float(pos_ned[2])))
        self.ref_ned.append((float(ref_ned[0]), float(ref_ned[1]), float(ref_ned[2])))

    def summary(
        self,
        waypoints_ned: FloatArray | None,
        acceptance_m: Sequence[float],
        *,
        duration_s: float,
        planned_duration_s: float,
    ) -> dict[str, Any]:
        """Report dict (keys carry units): duration, RMS/max error of flown vs reference,
        closest approach to and reached flag of every waypoint (within its acceptance radius)."""
        pos = np.asarray(self.pos_ned, dtype=np.float64).reshape(-1, 3)
        ref = np.asarray(self.ref_ned, dtype=np.float64).reshape(-1, 3)
        err = np.linalg.norm(pos - ref, axis=1)
        wps = (np.zeros((0, 3)) if waypoints_ned is None
               else np.asarray(waypoints_ned, dtype=np.float64).reshape(-1, 3))
        acc = np.asarray(list(acceptance_m), dtype=np.float64)
        if len(acc) != len(wps):
            raise ValueError(f"{len(wps)} waypoints but {len(acc)} acceptance radii")
        closest = closest_approach(pos, wps)
        return {
            "duration_s": round(float(duration_s), 3),
            "planned_duration_s": round(float(planned_duration_s), 3),
            "samples": len(err),
            "rms_error_m": float(np.sqrt(np.mean(err**2))) if len(err) else None,
            "max_error_m": float(np.max(err)) if len(err) else None,
            "waypoints": [
                {"north_m": float(w[0]), "east_m": float(w[1]), "down_m": float(w[2]),
                 "acceptance_radius_m": float(a),
                 "closest_approach_m": float(c) if math.isfinite(c) else None,
                 "reached": bool(c <= a)}
                for w, a, c in zip(wps, acc, closest, strict=True)
            ],
            "waypoints_reached": int(np.count_nonzero(closest <= acc)),
        }
