/* ecca_setpoint: ecca_setpoint_gen.h
 * GENERATED FILE, DO NOT EDIT. Regenerate with `python -m gen_c` (check: `--check`).
 * Facts about the generated ecca_gen_d.c / ecca_gen_f.c.
 */
#ifndef ECCA_SETPOINT_GEN_H
#define ECCA_SETPOINT_GEN_H

#define ECCA_GEN_CASADI_VERSION "3.8.2"
#define ECCA_GEN_BEZIER_DEGREE 7
#define ECCA_GEN_CORE_N_IN 60
#define ECCA_GEN_CORE_N_OUT 16
#define ECCA_GEN_DIST_N_IN 12
#define ECCA_GEN_DIST_N_OUT 4
#define ECCA_GEN_VCORR_N_IN 15
#define ECCA_GEN_VCORR_N_OUT 4

#endif /* ECCA_SETPOINT_GEN_H */
