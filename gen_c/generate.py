"""Generator of the freestanding C setpoint library ``gen_c/ecca_setpoint``.

The math comes from one place: the CasADi SX functions of ``companion.flatness.symbolic()``
(multirotor and rover differential flatness) plus the Bezier segment evaluation built here from
the Bernstein / derivative-control-point rule of docs/theory/trajectory.md. Each is re-wrapped
into a function with a fixed, documented argument layout (the one the hand-written
``ecca_setpoint.c`` relies on) and emitted by CasADi's ``CodeGenerator`` twice: ``casadi_real``
= ``double`` (prefix ``ecca_d_``) and ``float`` (prefix ``ecca_f_``).

The CasADi output is post-processed deterministically so that it passes
``-std=c99 -Wall -Wextra -Werror -pedantic`` (and PX4's extra warnings) and so that both
variants can be included in one translation unit:

1. ``casadi_real`` / ``casadi_int`` become ``double``/``float`` and ``int`` (their ``#define``
   blocks are removed);
2. CasADi's helper functions (``casadi_sq``, ``casadi_fmax``...) become ``static``;
3. ``(void)`` casts are added for unused ``iw``/``w``/``mem`` parameters;
4. each source includes its own header (prototypes for ``-Wmissing-prototypes``);
5. float variant only: ``<math.h>`` calls use the ``f`` functions (``sqrtf``, ``atan2f``...) and
   floating literals get an ``f`` suffix, so no double arithmetic is left on single-precision FPUs;
6. CasADi's NULL guards on every argument read / result write are removed (the wrapper always
   passes every argument and result) and ``casadi_fmax``/``casadi_fmin`` become inline selects
   with fmax/fmin's exact NaN semantics instead of libm calls (speed: a call spills every live
   register of the kernel); ``-ffinite-math-only`` builds are refused with ``#error``.

Usage: ``python -m gen_c [--check] [--out DIR] [--vectors]``.
"""

from __future__ import annotations

import difflib
import json
import re
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from math import comb
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

CASADI_VERSION = "3.8.2"
"""The exact CasADi version the checked-in C was generated with (pinned in pyproject.toml)."""

BEZIER_DEGREE = 7
"""Degree of the Bezier segments the C library evaluates (8 control points)."""

PACKAGE_DIR = Path(__file__).resolve().parent
LIB_DIR = PACKAGE_DIR / "ecca_setpoint"
VECTORS_PATH = PACKAGE_DIR / "tests" / "vectors.json"

VARIANTS: dict[str, str] = {"d": "double", "f": "float"}
"""Variant letter -> C floating type."""

HAND_WRITTEN = ("ecca_setpoint.h", "ecca_setpoint.c", "ecca_setpoint_impl.inc",
                "CMakeLists.txt", "README.md")
"""Hand-written files of the library (copied by ``--out``, never regenerated)."""


class GeneratorError(RuntimeError):
    """The generator cannot run (wrong CasADi version, missing or changed flatness API)."""


def check_casadi_version() -> None:
    """Refuse to generate with any CasADi other than the pinned one (the C embeds its version)."""
    version = getattr(ca, "__version__", "unknown")
    if version != CASADI_VERSION:
        raise GeneratorError(
            f"gen_c must be generated with CasADi {CASADI_VERSION} (pinned in pyproject.toml); "
            f"this environment has CasADi {version}"
        )


# --------------------------------------------------------------------------------------------
# Symbolic functions with the fixed C layout
# --------------------------------------------------------------------------------------------

BEZIER_IN = ("ctrl_pts_ned_m", "yaw_ctrl_pts_rad", "duration_s", "t_s")
BEZIER_OUT = ("pos_ned_m", "vel_ned_m_s", "acc_ned_m_s2", "jerk_ned_m_s3", "snap_ned_m_s4",
              "yaw_rad", "yaw_rate_rad_s", "yaw_acc_rad_s2")


def _bernstein_basis(m: int, tau_pow: list[ca.SX], u_pow: list[ca.SX]) -> list[ca.SX]:
    """Bernstein polynomials ``C(m, i) tau^i (1 - tau)^(m - i)``, i = 0..m."""
    return [comb(m, i) * tau_pow[i] * u_pow[m - i] for i in range(m + 1)]


def _differences(points: list[ca.SX], order: int) -> list[ca.SX]:
    """``order``-th forward differences of the control points (unscaled)."""
    pts = points
    for _ in range(order):
        pts = [pts[i + 1] - pts[i] for i in range(len(pts) - 1)]
    return pts


def _pairwise_sum(terms: list[ca.SX]) -> ca.SX:
    """Sum as a balanced tree (short dependency chains in the generated C)."""
    while len(terms) > 1:
        terms = [terms[i] + terms[i + 1] if i + 1 < len(terms) else terms[i]
                 for i in range(0, len(terms), 2)]
    return terms[0]


def _falling(n: int, k: int) -> int:
    """n (n-1) ... (n-k+1)."""
    out = 1
    for j in range(k):
        out *= n - j
    return out


def bezier_function(name: str) -> ca.Function:
    """Degree-7 Bezier segment evaluation, position..snap (3-D) and yaw..yaw_acc (1-D).

    Inputs: ``ctrl_pts_ned_m`` (24: 8 points x 3, row-major, i.e. ``double[8][3]`` in C),
    ``yaw_ctrl_pts_rad`` (8), ``duration_s`` (h > 0), ``t_s`` (local time, clamped to [0, h]).
    """
    n = BEZIER_DEGREE
    cp = ca.SX.sym("ctrl_pts_ned_m", 3 * (n + 1))
    ycp = ca.SX.sym("yaw_ctrl_pts_rad", n + 1)
    h = ca.SX.sym("duration_s")
    t = ca.SX.sym("t_s")
    tau = ca.fmin(ca.fmax(t, 0), h) / h
    u = 1 - tau
    tau_pow: list[ca.SX] = [ca.SX(1), tau]
    u_pow: list[ca.SX] = [ca.SX(1), u]
    for _ in range(2, n + 1):
        tau_pow.append(tau_pow[-1] * tau)
        u_pow.append(u_pow[-1] * u)
    basis = {m: _bernstein_basis(m, tau_pow, u_pow) for m in range(n - 4, n + 1)}
    inv_h = 1 / h
    inv_h_pow: list[ca.SX] = [ca.SX(1), inv_h]
    for _ in range(2, 5):
        inv_h_pow.append(inv_h_pow[-1] * inv_h)
    pos_pts = [cp[3 * i : 3 * i + 3] for i in range(n + 1)]
    yaw_pts = [ycp[i] for i in range(n + 1)]
    outs: list[ca.SX] = []
    # k-th derivative: degree n-k Bezier with control points n!/(n-k)!/h^k * (k-th differences).
    for pts, orders in ((pos_pts, 5), (yaw_pts, 3)):
        for k in range(orders):
            diffs = _differences(pts, k)
            b = basis[n - k]
            val = _pairwise_sum([d * bi for d, bi in zip(diffs, b, strict=True)])
            outs.append(val * (_falling(n, k) * inv_h_pow[k]) if k else val)
    outs = list(ca.cse(outs))
    return ca.Function(name, [cp, ycp, h, t], outs, list(BEZIER_IN), list(BEZIER_OUT))


# --------------------------------------------------------------------------------------------
# Code generation and deterministic post-processing
# --------------------------------------------------------------------------------------------

_MATH_FUNCS = ("sqrt", "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh",
               "tanh", "asinh", "acosh", "atanh", "exp", "expm1", "log", "log1p", "log10", "pow",
               "floor", "ceil", "fabs", "fmin", "fmax", "fmod", "hypot", "copysign", "erf",
               "erfc", "trunc", "round", "cbrt", "remainder")
_MATH_CALL = re.compile(r"(?<![\w.])(" + "|".join(_MATH_FUNCS) + r")\(")
_FLOAT_LITERAL = re.compile(r"(?<![\w.])(\d+\.\d*(?:[eE][+-]?\d+)?)(?![\w.])")
_TYPE_BLOCK = re.compile(r"#ifndef (casadi_real|casadi_int)\n#define \1 [^\n]*\n#endif\n\n?")
_HELPER_DEF = re.compile(r"^(casadi_real|casadi_int|int|void) (casadi_\w+)\(", re.MULTILINE)
_KERNEL_DEF = re.compile(
    r"^(static int casadi_f\d+\(const casadi_real\*\* arg, casadi_real\*\* res, "
    r"casadi_int\* iw, casadi_real\* w, int mem\) \{\n)",
    re.MULTILINE,
)
_RELEASE_DEF = re.compile(r"^(CASADI_SYMBOL_EXPORT void \w+_release\(int mem\) \{\n)", re.MULTILINE)
# CasADi guards every input read and output write against NULL arg/res entries (optional
# arguments). ecca_setpoint.c always passes every input and output, so the guards are dropped:
# the generated kernels require all arg[i] and res[i] to be valid (said in the banner).
# casadi_fmax/fmin call libm's fmax/fmin, which GCC does not inline on x86 (a call makes the
# kernel spill every live register). Replaced by inline selects with the same result for every
# input, NaN included (IEEE maxNum/minNum: a NaN operand yields the other one); only the sign
# of a zero result of fmax(+0, -0) may differ, which C99 leaves unspecified too.
_MINMAX_DEF = re.compile(
    r"^(casadi_real casadi_(fmax|fmin)\(casadi_real x, casadi_real y\) "
    r"\{\n)/\* Pre-c99 compatibility \*/\n#if __STDC_VERSION__ < 199901L\n  return [^\n]*\n"
    r"#else\n  return fm(?:ax|in)\(x, y\);\n#endif\n\}",
    re.MULTILINE,
)


def _minmax(m: re.Match[str]) -> str:
    op = ">" if m.group(2) == "fmax" else "<"
    body = f"  return (x {op} y || y != y) ? x : y; /* {m.group(2)}(x, y), inline */\n}}"
    return m.group(1) + body


_ARG_READ = re.compile(r"\barg\[(\d+)\]\? arg\[\1\]\[(\d+)\] : 0\b")
_RES_WRITE = re.compile(r"\bif \(res\[(\d+)\]!=0\) res\[\1\]\[(\d+)\]=")


def _banner(filename: str, ctype: str) -> str:
    return (
        "/* ecca_setpoint: " + filename + "\n"
        " * GENERATED FILE, DO NOT EDIT. Regenerate with `python -m gen_c` (check: `--check`).\n"
        f" * Source: companion.flatness.symbolic() and gen_c/generate.py (Bezier degree "
        f"{BEZIER_DEGREE}),\n"
        f" * emitted by CasADi {CASADI_VERSION} CodeGenerator with casadi_real = {ctype}, then\n"
        " * post-processed by gen_c/generate.py: concrete real/int types, static helpers,\n"
        " * (void) casts for unused parameters, own-header include, -Wfloat-equal pragma,\n"
        " * no NULL guards (every arg[i]/res[i] must be valid), inline fmax/fmin"
        + (",\n * float math functions (sqrtf...), f-suffixed literals (clamped to float's normal"
           " range).\n" if ctype == "float" else ".\n")
        + " */\n"
    )


_FLT_MIN = 1.17549435e-38
_FLT_MAX = 3.40282347e38
_PRAGMA = (
    "/* Flags are stored as 0/1 reals and tested with ?: (exact by construction). */\n"
    "#if defined(__GNUC__)\n#pragma GCC diagnostic ignored \"-Wfloat-equal\"\n#endif\n"
    "/* NaN handling (fmax/fmin below, the callers' checks) needs IEEE semantics. */\n"
    "#if defined(__FINITE_MATH_ONLY__) && __FINITE_MATH_ONLY__\n"
    "#error \"ecca_setpoint must not be compiled with -ffast-math/-ffinite-math-only\"\n#endif\n"
)


def _float_literal(m: re.Match[str]) -> str:
    """f-suffixed literal; magnitudes outside float's normal range are clamped into it
    (a tiny positive guard such as 1e-300 stays tiny and positive instead of becoming 0)."""
    value = float(m.group(1))
    if value != 0.0 and abs(value) < _FLT_MIN:
        return "1.17549435e-38f"
    if abs(value) > _FLT_MAX:
        return "3.40282347e+38f"
    return m.group(1) + "f"


def _postprocess(text: str, ctype: str, own_header: str | None) -> str:
    text = _TYPE_BLOCK.sub("", text)
    text = _KERNEL_DEF.sub(r"\1  (void)iw; (void)w; (void)mem;\n", text)
    text = _RELEASE_DEF.sub(r"\1  (void)mem;\n", text)
    text, n_minmax = _MINMAX_DEF.subn(_minmax, text)
    if "casadi_fmax" in text and n_minmax == 0:
        raise GeneratorError("CasADi's casadi_fmax/fmin helpers changed: update _MINMAX_DEF")
    text = _ARG_READ.sub(r"arg[\1][\2]", text)
    text = _RES_WRITE.sub(r"res[\1][\2]=", text)
    text = _HELPER_DEF.sub(r"static \1 \2(", text)
    text = re.sub(r"\bcasadi_real\b", ctype, text)
    text = re.sub(r"\bcasadi_int\b", "int", text)
    if ctype == "float":
        lines = []
        for line in text.split("\n"):
            stripped = line.lstrip()
            if not (stripped.startswith(("/*", "*", "#"))):
                line = _MATH_CALL.sub(lambda m: m.group(1) + "f(", line)
                line = _FLOAT_LITERAL.sub(_float_literal, line)
            lines.append(line)
        text = "\n".join(lines)
    text = "\n".join(line.rstrip() for line in text.split("\n"))
    if own_header is not None:
        text = text.replace("#include <math.h>\n",
                            f'#include <math.h>\n#include "{own_header}"\n\n{_PRAGMA}', 1)
    return text


def _codegen(functions: Sequence[ca.Function], stem: str, ctype: str) -> dict[str, str]:
    """Run CasADi's CodeGenerator into a temporary folder; return {filename: text}."""
    opts: dict[str, Any] = {
        "with_header": True, "casadi_real": ctype, "casadi_int": "int", "main": False,
        "mex": False, "verbose": False, "with_mem": False, "indent": 2,
    }
    cg = ca.CodeGenerator(stem + ".c", opts)
    for f in functions:
        cg.add(f)
    with tempfile.TemporaryDirectory(prefix="ecca_gen_c_") as tmp:
        cg.generate(tmp + "/")
        c_text = (Path(tmp) / f"{stem}.c").read_text(encoding="utf-8")
        h_text = (Path(tmp) / f"{stem}.h").read_text(encoding="utf-8")
    c_text = _banner(stem + ".c", ctype) + _postprocess(c_text, ctype, stem + ".h")
    guard = stem.upper() + "_H"
    h_body = _postprocess(h_text, ctype, None)
    h_text = (_banner(stem + ".h", ctype) + f"#ifndef {guard}\n#define {guard}\n\n" + h_body
              + f"\n#endif /* {guard} */\n")
    return {f"{stem}.c": c_text, f"{stem}.h": h_text}


MULTIROTOR_IN = ("vel_ned_m_s", "acc_ned_m_s2", "jerk_ned_m_s3", "snap_ned_m_s4", "yaw_rad",
                 "yaw_rate_rad_s", "yaw_acc_rad_s2", "mass_kg", "inertia_frd_kg_m2",
                 "gravity_m_s2", "hover_thrust", "drag_n_s_m")
MULTIROTOR_OUT = ("thrust_n", "thrust_dot_n_s", "thrust_ddot_n_s2", "thrust_norm", "q_wxyz",
                  "omega_frd_rad_s", "omega_dot_frd_rad_s2", "moment_frd_n_m", "flags",
                  "singular")
ROVER_IN = ("vel_ned_m_s", "acc_ned_m_s2", "jerk_ned_m_s3")
ROVER_OUT = ("yaw_rad", "speed_m_s", "speed_dot_m_s2", "yaw_rate_rad_s", "yaw_acc_rad_s2",
             "singular")
ACKERMANN_IN = (*ROVER_IN, "wheel_base_m")
ACKERMANN_OUT = (*ROVER_OUT, "curvature_1_m", "curvature_rate_1_m_s", "steer_angle_rad",
                 "steer_rate_rad_s")

# C layout name -> companion.flatness Function input/output name.
_MR_IN_MAP = dict(zip(MULTIROTOR_IN, ("vel_ned", "acc_ned", "jerk_ned", "snap_ned", "yaw",
                                      "yaw_rate", "yaw_acc", "mass", "inertia", "g",
                                      "hover_thrust", "drag"), strict=True))
_MR_OUT_MAP = dict(zip(MULTIROTOR_OUT, ("thrust", "thrust_dot", "thrust_ddot", "thrust_norm",
                                        "q_wxyz", "omega_frd", "omega_dot_frd", "moment_frd",
                                        "flags", "singular"), strict=True))
_RV_OUT_MAP = dict(zip(ROVER_OUT, ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc",
                                   "singular"), strict=True))
_AK_OUT_MAP = {**_RV_OUT_MAP, **dict(zip(ACKERMANN_OUT[len(ROVER_OUT):],
                                         ("curvature", "curvature_rate", "steer_angle",
                                          "steer_rate"), strict=True))}


def _call_by_name(f: ca.Function, args: dict[str, ca.SX]) -> dict[str, ca.SX]:
    """Call ``f`` with named SX arguments (inlines it); fail clearly if the API changed."""
    missing = sorted(set(f.name_in()) - set(args))
    extra = sorted(set(args) - set(f.name_in()))
    if missing or extra:
        raise GeneratorError(
            f"companion.flatness function {f.name()!r} changed its inputs (missing {missing}, "
            f"unexpected {extra}): update gen_c/generate.py and ecca_setpoint_impl.inc"
        )
    for name, value in args.items():
        if f.size_in(name) != value.shape:
            raise GeneratorError(
                f"companion.flatness function {f.name()!r} input {name!r} has shape "
                f"{f.size_in(name)}, gen_c expects {value.shape}"
            )
    out: dict[str, ca.SX] = f.call(args)
    return out


def multirotor_function(name: str, source: ca.Function) -> ca.Function:
    """``source`` (companion.flatness multirotor) re-wrapped with the C layout of ecca_setpoint.

    ``inertia_frd_kg_m2`` is 9 reals in row-major order (``double[3][3]`` in C); ``C_eb`` is
    dropped (the quaternion carries the attitude).
    """
    sizes = {"vel_ned_m_s": 3, "acc_ned_m_s2": 3, "jerk_ned_m_s3": 3, "snap_ned_m_s4": 3,
             "inertia_frd_kg_m2": 9}
    sym = {n: ca.SX.sym(n, sizes.get(n, 1)) for n in MULTIROTOR_IN}
    args = {_MR_IN_MAP[n]: s for n, s in sym.items()}
    args["inertia"] = ca.reshape(sym["inertia_frd_kg_m2"], 3, 3).T  # row-major -> matrix
    res = _call_by_name(source, args)
    for n in _MR_OUT_MAP.values():
        if n not in res:
            raise GeneratorError(f"companion.flatness {source.name()!r} has no output {n!r}")
    outs = list(ca.cse([res[_MR_OUT_MAP[n]] for n in MULTIROTOR_OUT]))
    return ca.Function(name, [sym[n] for n in MULTIROTOR_IN], outs, list(MULTIROTOR_IN),
                       list(MULTIROTOR_OUT))


def _rover_call(source: ca.Function, sym: dict[str, ca.SX], wheel_base: ca.SX,
                out_map: dict[str, str]) -> list[ca.SX]:
    """The outputs ``out_map`` (C name -> flatness name) of ``source`` (companion.flatness
    rover) at the C inputs ``sym`` (x, y of vel/acc/jerk, NED) and ``wheel_base``."""
    res = _call_by_name(source, {"vel_xy": sym["vel_ned_m_s"], "acc_xy": sym["acc_ned_m_s2"],
                                 "jerk_xy": sym["jerk_ned_m_s3"], "wheel_base": wheel_base})
    for n in out_map.values():
        if n not in res:
            raise GeneratorError(f"companion.flatness {source.name()!r} has no output {n!r}")
    return list(ca.cse([res[n] for n in out_map.values()]))


def rover_function(name: str, source: ca.Function) -> ca.Function:
    """``source`` (companion.flatness rover) with the C layout: x, y of vel/acc/jerk (NED);
    the unicycle outputs only (the Ackermann ones, at wheel base 0, are dropped)."""
    sym = {n: ca.SX.sym(n, 2) for n in ROVER_IN}
    outs = _rover_call(source, sym, ca.SX(0.0), _RV_OUT_MAP)
    return ca.Function(name, [sym[n] for n in ROVER_IN], outs, list(ROVER_IN), list(ROVER_OUT))


def ackermann_function(name: str, source: ca.Function) -> ca.Function:
    """``source`` (companion.flatness rover) with the C layout of the Ackermann setpoint: x, y of
    vel/acc/jerk (NED) and the wheel base (m); the unicycle outputs, then curvature, its rate,
    the steering angle and its rate."""
    sym = {n: ca.SX.sym(n, 2) for n in ROVER_IN}
    sym["wheel_base_m"] = ca.SX.sym("wheel_base_m")
    outs = _rover_call(source, sym, sym["wheel_base_m"], _AK_OUT_MAP)
    return ca.Function(name, [sym[n] for n in ACKERMANN_IN], outs, list(ACKERMANN_IN),
                       list(ACKERMANN_OUT))


FULL_IN = BEZIER_IN + MULTIROTOR_IN[7:]
FULL_OUT = MULTIROTOR_OUT + BEZIER_OUT


def full_function(name: str, bezier: ca.Function, multirotor: ca.Function) -> ca.Function:
    """Fused evaluate + multirotor flatness: ``multirotor(bezier(segment, t)[vel..], params)``.

    Inputs: the segment and time of :func:`bezier_function`, then the parameters of
    :func:`multirotor_function`; outputs: the multirotor outputs, then the Bezier outputs (the
    attitude first, so CasADi's depth-first order starts the flatness chain early). The same
    operations as the two separate functions (bit-identical results), one kernel: the C
    compiler overlaps the flatness with the higher derivatives (~8 % faster full setpoint).
    """
    sym = [ca.SX.sym(n, bezier.size1_in(i)) for i, n in enumerate(BEZIER_IN)]
    par = [ca.SX.sym(n, multirotor.size1_in(7 + i))
           for i, n in enumerate(MULTIROTOR_IN[7:])]
    state = bezier(*sym)
    att = multirotor(*state[1:], *par)
    outs = list(ca.cse([*att, *state]))
    return ca.Function(name, [*sym, *par], outs, list(FULL_IN), list(FULL_OUT))


def library_functions(variant: str) -> list[ca.Function]:
    """The generated functions of one variant (``"d"`` or ``"f"``), C names ``ecca_<v>_*``."""
    from companion.flatness import symbolic

    sf = symbolic()
    bezier = bezier_function(f"ecca_{variant}_bezier")
    multirotor = multirotor_function(f"ecca_{variant}_multirotor", sf.multirotor)
    return [
        bezier,
        multirotor,
        rover_function(f"ecca_{variant}_rover", sf.rover),
        # ~9 KB more flash per variant (drop it with --gc-sections if unused).
        full_function(f"ecca_{variant}_full", bezier, multirotor),
        ackermann_function(f"ecca_{variant}_ackermann", sf.rover),
        tracking_core_function(f"ecca_{variant}_tracking_core"),
        disturbance_step_function(f"ecca_{variant}_disturbance_step"),
        velocity_correction_step_function(f"ecca_{variant}_velocity_correction_step"),
    ]


def _shared(f: ca.Function) -> ca.Function:
    """`f` (one input vector, one output vector) with its common subexpressions shared."""
    x = ca.SX.sym("x", f.size1_in(0))
    return ca.Function(f.name(), [x], [ca.cse(f(x))], ["x"], ["y"])


def tracking_core_function(name: str) -> ca.Function:
    """The tracking law's core (``companion.control.core``, the expressions the companion
    flies): one input vector (``CORE_INPUTS``), one output vector (``CORE_OUTPUTS``), common
    subexpressions shared."""
    from companion.control.core import symbolic_core

    return _shared(symbolic_core(name))


def disturbance_step_function(name: str) -> ca.Function:
    """The disturbance observer's update step (``companion.control.observer``, the expressions
    `DisturbanceObserver` runs): one input vector (``DIST_INPUTS``), one output vector
    (``DIST_OUTPUTS``), common subexpressions shared."""
    from companion.control.observer import symbolic_disturbance_step

    return _shared(symbolic_disturbance_step(name))


def velocity_correction_step_function(name: str) -> ca.Function:
    """The horizontal velocity correction's update step
    (``companion.mavlink.velocity_correction``, the expressions `VelocityCorrection` runs): one
    input vector (``VCORR_INPUTS``), one output vector (``VCORR_OUTPUTS``), common
    subexpressions shared."""
    from companion.mavlink.velocity_correction import symbolic_velocity_correction_step

    return _shared(symbolic_velocity_correction_step(name))


def _info_header() -> str:
    from companion.control.core import CORE_N_IN, CORE_N_OUT
    from companion.control.observer import DIST_N_IN, DIST_N_OUT
    from companion.mavlink.velocity_correction import VCORR_N_IN, VCORR_N_OUT

    return (
        "/* ecca_setpoint: ecca_setpoint_gen.h\n"
        " * GENERATED FILE, DO NOT EDIT. Regenerate with `python -m gen_c` (check: `--check`).\n"
        " * Facts about the generated ecca_gen_d.c / ecca_gen_f.c.\n */\n"
        + "#ifndef ECCA_SETPOINT_GEN_H\n#define ECCA_SETPOINT_GEN_H\n\n"
        + f'#define ECCA_GEN_CASADI_VERSION "{CASADI_VERSION}"\n'
        + f"#define ECCA_GEN_BEZIER_DEGREE {BEZIER_DEGREE}\n"
        + f"#define ECCA_GEN_CORE_N_IN {CORE_N_IN}\n"
        + f"#define ECCA_GEN_CORE_N_OUT {CORE_N_OUT}\n"
        + f"#define ECCA_GEN_DIST_N_IN {DIST_N_IN}\n"
        + f"#define ECCA_GEN_DIST_N_OUT {DIST_N_OUT}\n"
        + f"#define ECCA_GEN_VCORR_N_IN {VCORR_N_IN}\n"
        + f"#define ECCA_GEN_VCORR_N_OUT {VCORR_N_OUT}\n"
        + "\n#endif /* ECCA_SETPOINT_GEN_H */\n"
    )


def generate_sources() -> dict[str, str]:
    """All generated files of the library: {file name: text}. Deterministic."""
    check_casadi_version()
    files: dict[str, str] = {"ecca_setpoint_gen.h": _info_header()}
    for v, ctype in VARIANTS.items():
        files.update(_codegen(library_functions(v), f"ecca_gen_{v}", ctype))
    return dict(sorted(files.items()))


def write_library(out_dir: Path, *, copy_hand_written: bool) -> list[Path]:
    """Write the generated files (and optionally the hand-written ones) into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in generate_sources().items():
        path = out_dir / name
        path.write_text(text, encoding="utf-8", newline="\n")
        written.append(path)
    if copy_hand_written and out_dir.resolve() != LIB_DIR.resolve():
        for name in HAND_WRITTEN:
            shutil.copyfile(LIB_DIR / name, out_dir / name)
            written.append(out_dir / name)
    return written


def check_library(lib_dir: Path = LIB_DIR) -> str:
    """Regenerate into a temporary folder and diff against ``lib_dir``.

    Returns '' if every generated file is identical, else a unified diff (checked in ->
    regenerated).
    """
    diffs: list[str] = []
    with tempfile.TemporaryDirectory(prefix="ecca_gen_c_check_") as tmp:
        for fresh in write_library(Path(tmp), copy_hand_written=False):
            path = lib_dir / fresh.name
            text = fresh.read_text(encoding="utf-8")
            if not path.exists():
                diffs.append(f"missing generated file: {path}\n")
                old = ""
            else:
                old = path.read_text(encoding="utf-8")
            if old != text:
                diffs.extend(difflib.unified_diff(
                    old.splitlines(keepends=True), text.splitlines(keepends=True),
                    fromfile=f"{path} (checked in)", tofile=f"{fresh.name} (regenerated)"))
    return "".join(diffs)


# --------------------------------------------------------------------------------------------
# Golden vectors (from the Python implementation, read by gen_c/tests/test_ecca_setpoint.c)
# --------------------------------------------------------------------------------------------

VECTORS_SEED = 20261122


def _f32(x: Any) -> Any:
    """Round to a float32-representable double, so the float variant sees the same inputs."""
    arr = np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)
    return float(arr) if arr.ndim == 0 else arr


def _lst(x: Any) -> Any:
    return np.asarray(x, dtype=np.float64).tolist()


@dataclass(frozen=True)
class _MrCase:
    name: str
    vel: Any
    acc: Any
    jerk: Any
    snap: Any
    yaw: float
    yaw_rate: float
    yaw_acc: float
    mass: float
    inertia: Any
    g: float
    hover: float
    drag: float


def _state_dict(vel: Any, acc: Any, jerk: Any, snap: Any, yaw: float, yaw_rate: float,
                yaw_acc: float, pos: Any = (0.0, 0.0, 0.0)) -> dict[str, Any]:
    return {"pos_ned_m": _lst(pos), "vel_ned_m_s": _lst(vel), "acc_ned_m_s2": _lst(acc),
            "jerk_ned_m_s3": _lst(jerk), "snap_ned_m_s4": _lst(snap), "yaw_rad": float(yaw),
            "yaw_rate_rad_s": float(yaw_rate), "yaw_acc_rad_s2": float(yaw_acc)}


def _multirotor_expect(c: _MrCase) -> dict[str, Any]:
    from companion.flatness import MultirotorParams, multirotor_setpoint

    params = MultirotorParams(mass=c.mass, inertia=c.inertia, g=c.g, hover_thrust=c.hover,
                              drag=c.drag)
    sp = multirotor_setpoint(c.vel, c.acc, c.jerk, c.snap, c.yaw, c.yaw_rate, c.yaw_acc, params)
    return {"thrust_n": float(sp.thrust), "thrust_dot_n_s": float(sp.thrust_dot),
            "thrust_ddot_n_s2": float(sp.thrust_ddot), "thrust_norm": float(sp.thrust_norm),
            "q_wxyz": _lst(sp.q_wxyz), "omega_frd_rad_s": _lst(sp.omega_frd),
            "omega_dot_frd_rad_s2": _lst(sp.omega_dot_frd), "moment_frd_n_m": _lst(sp.moment_frd),
            "flags": int(sp.flags), "singular": int(bool(sp.singular))}


def _params_dict(c: _MrCase) -> dict[str, Any]:
    return {"mass_kg": c.mass, "inertia_frd_kg_m2": _lst(c.inertia), "gravity_m_s2": c.g,
            "hover_thrust": c.hover, "drag_n_s_m": c.drag}


def _random_segment(rng: np.random.Generator) -> tuple[Any, Any, float]:
    cp = _f32(rng.uniform(-20.0, 20.0, size=(BEZIER_DEGREE + 1, 3)))
    ycp = _f32(np.cumsum(rng.uniform(-0.6, 0.6, size=BEZIER_DEGREE + 1)) + rng.uniform(-4, 4))
    h = _f32(rng.uniform(0.5, 6.0))
    return cp, ycp, h


def _bezier_expect(cp: Any, ycp: Any, h: float, t: float) -> dict[str, Any]:
    from companion.trajectory import Bezier

    tc = min(max(t, 0.0), h)
    pos, yaw = Bezier(cp, h), Bezier(np.asarray(ycp)[:, None], h)
    names = ("pos_ned_m", "vel_ned_m_s", "acc_ned_m_s2", "jerk_ned_m_s3", "snap_ned_m_s4")
    out: dict[str, Any] = {n: _lst(pos.evaluate(tc, k)) for k, n in enumerate(names)}
    for k, n in enumerate(("yaw_rad", "yaw_rate_rad_s", "yaw_acc_rad_s2")):
        out[n] = float(yaw.evaluate(tc, k)[0])
    return out


def _ackermann_expect(v: Any, a: Any, j: Any, wheel_base_m: float) -> dict[str, Any]:
    from companion.flatness import rover_setpoint

    rs = rover_setpoint(v, a, j, wheel_base_m=wheel_base_m)
    return {"yaw_rad": float(rs.yaw), "speed_m_s": float(rs.speed),
            "speed_dot_m_s2": float(rs.speed_dot), "yaw_rate_rad_s": float(rs.yaw_rate),
            "yaw_acc_rad_s2": float(rs.yaw_acc or 0.0), "singular": int(bool(rs.singular)),
            "curvature_1_m": float(rs.curvature or 0.0),
            "curvature_rate_1_m_s": float(rs.curvature_rate or 0.0),
            "steer_angle_rad": float(rs.steer_angle or 0.0),
            "steer_rate_rad_s": float(rs.steer_rate or 0.0)}


def make_vectors() -> dict[str, Any]:
    """Golden input/output vectors from the Python path (companion.trajectory.Bezier,
    companion.flatness numeric). Inputs are float32-representable doubles."""
    from companion.flatness import rover_setpoint

    rng = np.random.default_rng(VECTORS_SEED)
    g0 = 9.80665
    j_x500 = [[0.029125, 0.0, 0.0], [0.0, 0.029125, 0.0], [0.0, 0.0, 0.055225]]
    j_full = _f32([[0.03, 0.002, -0.001], [0.002, 0.04, 0.0015], [-0.001, 0.0015, 0.06]])
    z3 = [0.0, 0.0, 0.0]

    # --- Bezier segments: random, at both ends, inside and outside [0, h] (clamped).
    bezier = []
    for i in range(8):
        cp, ycp, h = _random_segment(rng)
        for t in (0.0, h, _f32(rng.uniform(0.0, h)), _f32(rng.uniform(0.0, h)),
                  (-0.5 if i % 2 else h + 0.75)):
            bezier.append({
                "segment": {"ctrl_pts_ned_m": _lst(cp), "yaw_ctrl_pts_rad": _lst(ycp),
                            "duration_s": float(h)},
                "t_s": float(t), "expect": _bezier_expect(cp, ycp, float(h), float(t))})

    # --- Multirotor: named edge cases + random smooth states (moderate and aggressive).
    cases = [
        _MrCase("hover", z3, z3, z3, z3, 0.0, 0.0, 0.0, 1.5, j_x500, g0, 0.6, 0.0),
        _MrCase("hover_yawing", z3, z3, z3, z3, 1.25, 0.5, -0.25, 2.0, j_x500, g0, 0.5, 0.0),
        _MrCase("free_fall_low_thrust", [1.0, 0.0, 2.0], [0.0, 0.0, g0], [0.5, 0.0, 0.0], z3,
                0.3, 0.1, 0.0, 1.0, j_x500, g0, 0.5, 0.0),
        _MrCase("heading_singular", z3, [0.0, -5.0, g0], [0.25, 0.5, 0.0], z3, 0.0, 0.2, 0.0,
                1.0, j_x500, g0, 0.5, 0.0),
        _MrCase("inverted", z3, [0.5, -0.25, 2.5 * g0], [1.0, 0.5, -0.5], [0.25, 0.0, 1.0],
                0.5, 0.25, 0.125, 1.0, j_x500, g0, 0.5, 0.0),
        _MrCase("drag_cruise", [6.0, -2.0, -0.5], [0.5, 1.5, -0.25], [1.0, -0.5, 0.25],
                [-2.0, 1.0, 0.5], -2.5, 0.75, -0.5, 1.0, j_full, g0, 0.45, 1.0),
        _MrCase("unwrapped_yaw", [1.0, 1.0, 0.0], [2.0, -1.0, 0.5], [0.5, 0.5, -1.0],
                [1.0, 2.0, 0.0], 7.5, -1.5, 2.0, 1.2, j_full, g0, 0.5, 0.3),
        _MrCase("thrust_norm_saturated", z3, [0.0, 0.0, -2.0 * g0], z3, z3, 0.0, 0.0, 0.0,
                1.0, j_x500, g0, 0.7, 0.0),
    ]
    for i in range(16):
        aggressive = i % 4 == 3
        amax = 2.0 * g0 if aggressive else 4.0
        cases.append(_MrCase(
            f"random_{'aggressive' if aggressive else 'smooth'}_{i}",
            _f32(rng.uniform(-8, 8, 3)), _f32(rng.uniform(-amax, amax, 3) * [1, 1, 0.5]),
            _f32(rng.uniform(-10, 10, 3)), _f32(rng.uniform(-40, 40, 3)),
            _f32(rng.uniform(-np.pi, np.pi)), _f32(rng.uniform(-2, 2)), _f32(rng.uniform(-5, 5)),
            _f32(rng.uniform(0.5, 3.0)), j_full if i % 2 else j_x500, g0,
            _f32(rng.uniform(0.3, 0.8)), _f32(rng.uniform(0.0, 1.5) if i % 3 else 0.0)))
    multirotor = []
    for c in cases:
        multirotor.append({"name": c.name,
                           "state": _state_dict(c.vel, c.acc, c.jerk, c.snap, c.yaw, c.yaw_rate,
                                                c.yaw_acc),
                           "params": _params_dict(c), "expect": _multirotor_expect(c)})

    # --- Rover.
    rover_inputs = [("moving", [2.0, 1.0], [0.5, -0.25], [0.1, 0.2]),
                    ("stopped", [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]),
                    ("from_rest", [0.0, 0.0], [-0.5, 0.75], [0.0, 0.0]),
                    ("reversing_west", [-1.5, -0.001], [0.25, 1.0], [-0.5, 0.25])]
    for i in range(6):
        rover_inputs.append((f"random_{i}", _f32(rng.uniform(-5, 5, 2)),
                             _f32(rng.uniform(-3, 3, 2)), _f32(rng.uniform(-2, 2, 2))))
    rover = []
    for name, v, a, j in rover_inputs:
        rs = rover_setpoint(v, a, j)
        rover.append({"name": name,
                      "state": _state_dict([*v, 0.0], [*a, 0.0], [*j, 0.0], z3, 0.0, 0.0, 0.0),
                      "expect": {"yaw_rad": float(rs.yaw), "speed_m_s": float(rs.speed),
                                 "speed_dot_m_s2": float(rs.speed_dot),
                                 "yaw_rate_rad_s": float(rs.yaw_rate),
                                 "yaw_acc_rad_s2": float(rs.yaw_acc or 0.0),
                                 "singular": int(bool(rs.singular))}})

    # --- Full setpoint: evaluate a segment, then multirotor flatness of the evaluated state.
    full = []
    for _ in range(6):
        cp, ycp, h = _random_segment(rng)
        cp = _f32(cp * 0.2)  # gentler segment: accelerations of a few m/s^2
        t = _f32(rng.uniform(0.0, h))
        st = _bezier_expect(cp, ycp, float(h), float(t))
        c = _MrCase("full", st["vel_ned_m_s"], st["acc_ned_m_s2"], st["jerk_ned_m_s3"],
                    st["snap_ned_m_s4"], st["yaw_rad"], st["yaw_rate_rad_s"],
                    st["yaw_acc_rad_s2"], 1.5, j_full, g0, 0.5, 0.5)
        full.append({"segment": {"ctrl_pts_ned_m": _lst(cp), "yaw_ctrl_pts_rad": _lst(ycp),
                                 "duration_s": float(h)},
                     "t_s": float(t), "params": _params_dict(c), "expect_state": st,
                     "expect": _multirotor_expect(c)})

    # --- Ackermann rover (drawn after the others: their random cases stay unchanged).
    ack_inputs = [("circle_right", [0.0, 2.0], [-0.8, 0.0], [0.0, -0.32], 0.5),
                  ("stopped", [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 0.5),
                  ("from_rest", [0.0, 0.0], [-0.5, 0.75], [0.25, 0.0], 0.3),
                  ("just_below_stop", [0.0005, -0.0002], [1.0, 2.0], [-1.0, 0.5], 0.3),
                  ("just_above_stop", [0.00125, -0.0005], [0.5, 1.0], [-1.0, 0.5], 0.3),
                  ("tight_left", [1.0, 0.5], [1.5, -3.0], [-2.0, -1.0], 2.0)]
    for i in range(6):
        ack_inputs.append((f"random_{i}", _f32(rng.uniform(-5, 5, 2)),
                           _f32(rng.uniform(-3, 3, 2)), _f32(rng.uniform(-2, 2, 2)),
                           float(_f32(rng.uniform(0.1, 3.0)))))
    ackermann = []
    for name, v, a, j, L in ack_inputs:
        v, a, j = _lst(_f32(v)), _lst(_f32(a)), _lst(_f32(j))
        ackermann.append({"name": name,
                          "state": _state_dict([*v, 0.0], [*a, 0.0], [*j, 0.0], z3, 0.0, 0.0, 0.0),
                          "wheel_base_m": L, "expect": _ackermann_expect(v, a, j, L)})
    full_ackermann = []
    for _ in range(4):
        cp, ycp, h = _random_segment(rng)
        t = _f32(rng.uniform(0.0, h))
        L = float(_f32(rng.uniform(0.2, 2.0)))
        st = _bezier_expect(cp, ycp, float(h), float(t))
        full_ackermann.append({
            "segment": {"ctrl_pts_ned_m": _lst(cp), "yaw_ctrl_pts_rad": _lst(ycp),
                        "duration_s": float(h)},
            "t_s": float(t), "wheel_base_m": L, "expect_state": st,
            "expect": _ackermann_expect(st["vel_ned_m_s"][:2], st["acc_ned_m_s2"][:2],
                                        st["jerk_ned_m_s3"][:2], L)})

    return {
        "about": ("Golden vectors for gen_c/ecca_setpoint, written by `python -m gen_c --vectors` "
                  "from the Python path (companion.trajectory.Bezier de Casteljau, "
                  "companion.flatness numeric). Inputs are float32-representable. Check: "
                  "|c - expect| <= rtol * max(|expect|, max |expect field|, 1), rtol 1e-12 "
                  "(double) / 1e-4 (float); flags and singular exactly."),
        "casadi_version": CASADI_VERSION,
        "bezier_degree": BEZIER_DEGREE,
        "bezier": bezier,
        "multirotor": multirotor,
        "rover": rover,
        "full": full,
        "ackermann": ackermann,
        "full_ackermann": full_ackermann,
    }


def write_vectors(path: Path = VECTORS_PATH) -> Path:
    """Write :func:`make_vectors` as JSON (stable key order, one case per line group)."""
    check_casadi_version()
    path.parent.mkdir(parents=True, exist_ok=True)
    vectors = make_vectors()
    parts = []
    for key, value in vectors.items():
        if isinstance(value, list):
            cases = ",\n  ".join(json.dumps(c, separators=(",", ":")) for c in value)
            parts.append(f' {json.dumps(key)}: [\n  {cases}\n ]')
        else:
            parts.append(f" {json.dumps(key)}: {json.dumps(value)}")
    text = "{\n" + ",\n".join(parts) + "\n}\n"
    assert json.loads(text) == vectors
    path.write_text(text, encoding="utf-8", newline="\n")
    return path
