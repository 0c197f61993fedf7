/* main.c: the exported controller flies the exported scenario against the exported model step
 * (the plant) and prints the closed loop as CSV on stdout. Built with -DMPC_TIMING (make
 * bench), it flies the scenario `repeats` times (argument, default 20) and prints the solve
 * times as JSON instead: median, p99 and max of the whole mpc_step (wall clock, and the
 * thread's CPU time: what the solve costs without the time other processes took the core) and
 * of its phases (wall clock). */
#ifdef MPC_TIMING
#define _POSIX_C_SOURCE 199309L
#include <stdlib.h>
#include <time.h>
#endif
#include <stdio.h>
#include "mpc_rti.h"

static mpc_workspace ws;  /* the whole controller: static, no allocation */

/* references over the horizon of the step at time index k (see mpc_config.h) */
static void references(int k, mpc_real* refs) {
  int i;
  for (i = 0; i < MPC_N; ++i) {
    double t = (double)(k + 1 + i) * (double)MPC_DT, late = t - mpc_example_on;
    refs[3 * i + 0] = (mpc_real)(mpc_example_theta0 + (t >= mpc_example_on ? mpc_example_dtheta
                                                                            : 0.0));
    refs[3 * i + 1] = (mpc_real)(mpc_example_h0 + mpc_example_climb * (late > 0 ? late : 0.0));
    refs[3 * i + 2] = (mpc_real)(mpc_example_v0 + (t >= mpc_example_on ? mpc_example_dv : 0.0));
  }
}

static void observe(const mpc_real* z, mpc_real* y) {
  int i;
  for (i = 0; i < MPC_NY; ++i) y[i] = z[mpc_plant_observed[i]];
}

/* one closed loop; row k of the CSV (print != 0): time, measured y, applied u, source */
static int fly(int print, double* times, int n_phase) {
  mpc_real z[MPC_PLANT_NX], z_next[MPC_PLANT_NX], y[MPC_NY], u[MPC_NU], u_new[MPC_NU];
  mpc_real refs[3 * MPC_N];
  mpc_info info;
  int k, i;
  for (i = 0; i < MPC_PLANT_NX; ++i) z[i] = mpc_plant_x0[i];
  for (i = 0; i < MPC_NU; ++i) u[i] = mpc_example_u0[i];
  mpc_init(&ws);
  observe(z, y);
  for (k = 0; k < MPC_EXAMPLE_STEPS; ++k) {
    references(k, refs);
#ifdef MPC_TIMING
    struct timespec a, b, ca, cb;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ca);
    clock_gettime(CLOCK_MONOTONIC, &a);
#endif
    mpc_step(&ws, y, u, refs, mpc_example_weights, u_new, &info);
#ifdef MPC_TIMING
    clock_gettime(CLOCK_MONOTONIC, &b);
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cb);
    times[(0 * n_phase) + k] = (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
    times[(4 * n_phase) + k] = (double)(cb.tv_sec - ca.tv_sec)
                               + 1e-9 * (double)(cb.tv_nsec - ca.tv_nsec);
    times[(1 * n_phase) + k] = info.t_lin_s;
    times[(2 * n_phase) + k] = info.t_cond_s;
    times[(3 * n_phase) + k] = info.t_qp_s;
#else
    (void)times;
    (void)n_phase;
#endif
    if (print) {
      printf("%.17g", (double)k * (double)MPC_DT);
      for (i = 0; i < MPC_NY; ++i) printf(",%.17g", (double)y[i]);
      printf(",%.17g,%.17g,%d,%d\n", (double)u_new[0], (double)u_new[1], info.source,
             info.qp_iterations);
    }
    for (i = 0; i < MPC_NU; ++i) u[i] = u_new[i];
    if (mpc_plant_step(&ws, z, u, mpc_plant_p, (mpc_real)MPC_DT, z_next) != 0) return 1;
    for (i = 0; i < MPC_PLANT_NX; ++i) z[i] = z_next[i];
    observe(z, y);
  }
  if (print) {
    printf("%.17g", (double)MPC_EXAMPLE_STEPS * (double)MPC_DT);
    for (i = 0; i < MPC_NY; ++i) printf(",%.17g", (double)y[i]);
    printf(",,,,\n");
  }
  return 0;
}

#ifdef MPC_TIMING
static int compare(const void* a, const void* b) {
  double x = *(const double*)a, y = *(const double*)b;
  return (x > y) - (x < y);
}

static void stats(const char* name, double* t, int n, int last) {
  qsort(t, (size_t)n, sizeof(double), compare);
  printf("  \"%s\": {\"median_us\": %.3f, \"p99_us\": %.3f, \"max_us\": %.3f, \"min_us\": %.3f}%s\n",
         name, 1e6 * t[n / 2], 1e6 * t[(int)(0.99 * (n - 1))], 1e6 * t[n - 1], 1e6 * t[0],
         last ? "" : ",");
}

int main(int argc, char** argv) {
  int repeats = argc > 1 ? atoi(argv[1]) : 20, r, k, p;
  int n = MPC_EXAMPLE_STEPS * (repeats > 0 ? repeats : 1);
  static double per_run[5 * MPC_EXAMPLE_STEPS];
  double* all = malloc(sizeof(double) * 5 * (size_t)n);  /* the harness's, not the controller's */
  const char* names[5] = {"mpc_step", "linearisation", "condensing", "qp", "mpc_step_cpu"};
  if (all == NULL) return 1;
  if (fly(0, per_run, MPC_EXAMPLE_STEPS) != 0) return 1;  /* warm-up */
  for (r = 0; r < n / MPC_EXAMPLE_STEPS; ++r) {
    if (fly(0, per_run, MPC_EXAMPLE_STEPS) != 0) return 1;
    for (p = 0; p < 5; ++p)
      for (k = 0; k < MPC_EXAMPLE_STEPS; ++k)
        all[p * n + r * MPC_EXAMPLE_STEPS + k] = per_run[p * MPC_EXAMPLE_STEPS + k];
  }
  printf("{\n  \"solves\": %d,\n  \"workspace_bytes\": %lu,\n", n, (unsigned long)sizeof(ws));
  for (p = 0; p < 5; ++p) stats(names[p], all + p * n, n, p == 4);
  printf("}\n");
  free(all);
  return 0;
}
#else
int main(void) {
  int i;
  printf("time");
  for (i = 0; i < MPC_NY; ++i) printf(",%s", mpc_measured_names[i]);
  printf(",control_1,control_2,source,qp_iterations\n");
  return fly(1, NULL, 0);
}
#endif
