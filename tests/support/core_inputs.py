"""Random inputs of the tracking law's core (`companion.control.core.CORE_INPUTS`), in the
ranges a multirotor flies: tests of the core on floats, on CasADi symbols and in generated C."""

from __future__ import annotations

import math

import numpy as np

from companion.control.core import CORE_INPUTS, CORE_N_IN

#: offset of each named input in the flattened vector
OFFSET = {name: sum(n for _, n in CORE_INPUTS[:i]) for i, (name, _) in enumerate(CORE_INPUTS)}


def random_core_inputs(rng: np.random.Generator, n: int) -> np.ndarray:
    """`n` input vectors (rows): references and estimates a few metres / m/s apart, gains,
    limits and vehicles as configured in the field; a third of them far from the reference
    (the thrust limits act), half with the integrator running, some with the feedback jerk."""
    x = np.zeros((n, CORE_N_IN))

    def put(name: str, v: np.ndarray) -> None:
        o = OFFSET[name]
        x[:, o:o + v.shape[1]] = v

    far = rng.random(n) < 1 / 3
    err = np.where(far[:, None], 8.0, 1.0)
    put("ref_pos", rng.uniform(-50, 50, (n, 3)))
    put("ref_vel", rng.uniform(-8, 8, (n, 3)))
    put("ref_acc", rng.uniform(-6, 6, (n, 3)))
    put("acc_ff", x[:, OFFSET["ref_acc"]:OFFSET["ref_acc"] + 3] + rng.normal(0, 0.5, (n, 3)))
    put("jerk_ff", rng.uniform(-20, 20, (n, 3)))
    put("snap_ff", rng.uniform(-60, 60, (n, 3)))
    put("pos", x[:, 0:3] + rng.normal(0, 1, (n, 3)) * err)
    put("vel", x[:, 3:6] + rng.normal(0, 1, (n, 3)) * err)
    put("acc_meas", rng.uniform(-8, 8, (n, 3)))
    i_max = rng.uniform(0.5, 3.0, (n, 3))
    put("i_max", i_max)
    put("integ", rng.uniform(-1, 1, (n, 3)) * i_max)
    put("kp", rng.uniform(0.5, 6.0, (n, 3)))
    put("kd", rng.uniform(0.5, 5.0, (n, 3)))
    put("ki", rng.uniform(0.0, 1.5, (n, 3)))
    put("dist_ne", rng.uniform(-3, 3, (n, 2)))
    put("yaw", np.c_[rng.uniform(-math.pi, math.pi, n), rng.uniform(-1, 1, n),
                     rng.uniform(-2, 2, n)])
    drag = np.where(rng.random(n) < 0.2, 0.0, rng.uniform(0.0, 1.5, n))
    put("drag", drag[:, None])
    put("drag_map", np.round(drag, 4)[:, None])
    put("hover", rng.uniform(0.3, 0.7, (n, 1)))
    put("mass", rng.uniform(0.5, 3.0, (n, 1)))
    put("g", np.full((n, 1), 9.80665))
    put("thrust_min", rng.uniform(0.05, 0.15, (n, 1)))
    put("thrust_max", rng.uniform(0.8, 1.0, (n, 1)))
    tilt = np.radians(rng.uniform(20, 60, n))
    put("cos_tilt", np.cos(tilt)[:, None])
    put("tan_tilt", np.tan(tilt)[:, None])
    put("fb_share", rng.choice([0.0, 0.5, 1.0], (n, 1)))
    put("drag_est", rng.choice([0.0, 1.0], (n, 1)))
    put("dt", np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.004, 0.02, n))[:, None])
    put("learn", rng.choice([0.0, 1.0], (n, 1)))
    return x
