/* ecca_setpoint.c: the stable API of ecca_setpoint.h over the generated CasADi code
 * (hand-written). The wrapper bodies live in ecca_setpoint_impl.inc and are compiled twice:
 * over the double code (ecca_gen_d.c) and over the float code (ecca_gen_f.c, names with
 * suffix _f). Define ECCA_SETPOINT_NO_DOUBLE or ECCA_SETPOINT_NO_FLOAT to build one variant
 * only (then ecca_gen_d.c resp. ecca_gen_f.c is not needed).
 * C99, <math.h> only, no allocation, no mutable globals, re-entrant.
 */
#include <math.h>

#include "ecca_setpoint.h"
#include "ecca_setpoint_gen.h"
#include "ecca_gen_d.h"
#include "ecca_gen_f.h"

/* The NaN/inf checks rely on IEEE semantics (NaN compares false and propagates through + and
 * *); -ffast-math or -ffinite-math-only would let the compiler delete them. */
#if defined(__FINITE_MATH_ONLY__) && __FINITE_MATH_ONLY__
#error "ecca_setpoint must not be compiled with -ffast-math/-ffinite-math-only (its NaN checks)"
#endif

#if ECCA_GEN_BEZIER_DEGREE != ECCA_BEZIER_DEGREE
#error "generated code and ecca_setpoint.h disagree on the Bezier degree: run python -m gen_c"
#endif
#if ECCA_GEN_CORE_N_IN != ECCA_CORE_N_IN || ECCA_GEN_CORE_N_OUT != ECCA_CORE_N_OUT
#error "generated code and ecca_setpoint.h disagree on the tracking core's sizes: run python -m gen_c"
#endif
#if ECCA_GEN_DIST_N_IN != ECCA_DIST_N_IN || ECCA_GEN_DIST_N_OUT != ECCA_DIST_N_OUT
#error "generated code and ecca_setpoint.h disagree on the disturbance step's sizes: run python -m gen_c"
#endif
#if ECCA_GEN_VCORR_N_IN != ECCA_VCORR_N_IN || ECCA_GEN_VCORR_N_OUT != ECCA_VCORR_N_OUT
#error "generated code and ecca_setpoint.h disagree on the velocity correction's sizes: run python -m gen_c"
#endif

const char *ecca_setpoint_casadi_version(void) { return ECCA_GEN_CASADI_VERSION; }

#ifndef ECCA_SETPOINT_NO_DOUBLE
#define ECCA_REAL double
#define ECCA_API(n) n
#define ECCA_GEN(n) ecca_d_##n
#define ECCA_SZ(n, k) ecca_d_##n##_SZ_##k
#define ECCA_ISFINITE(x) isfinite(x)
#define ECCA_FABS(x) fabs(x)
#include "ecca_setpoint_impl.inc"
#undef ECCA_REAL
#undef ECCA_API
#undef ECCA_GEN
#undef ECCA_SZ
#undef ECCA_ISFINITE
#undef ECCA_FABS

#endif /* ECCA_SETPOINT_NO_DOUBLE */

#ifndef ECCA_SETPOINT_NO_FLOAT
#define ECCA_REAL float
#define ECCA_API(n) n##_f
#define ECCA_GEN(n) ecca_f_##n
#define ECCA_SZ(n, k) ecca_f_##n##_SZ_##k
#define ECCA_ISFINITE(x) isfinite(x)
#define ECCA_FABS(x) fabsf(x)
#include "ecca_setpoint_impl.inc"
#undef ECCA_REAL
#undef ECCA_API
#undef ECCA_GEN
#undef ECCA_SZ
#undef ECCA_ISFINITE
#undef ECCA_FABS
#endif /* ECCA_SETPOINT_NO_FLOAT */
