/* mpc_rti.c: the real-time-iteration controller around the generated QP data (see
 * mpc_rti.h); the same steps, in the same order, as uavdyn.mpc.RTIController. */
#ifdef MPC_TIMING
#define _POSIX_C_SOURCE 199309L
#include <time.h>
#endif
#include <math.h>
#include <stddef.h>
#include "mpc_rti.h"

int mpc_gen_lin(const mpc_real** arg, mpc_real** res, mpc_int* iw, mpc_real* w, int mem);
int mpc_gen_cond(const mpc_real** arg, mpc_real** res, mpc_int* iw, mpc_real* w, int mem);
int mpc_gen_extra(const mpc_real** arg, mpc_real** res, mpc_int* iw, mpc_real* w, int mem);
int mpc_gen_plant(const mpc_real** arg, mpc_real** res, mpc_int* iw, mpc_real* w, int mem);

#ifdef MPC_TIMING
static double now_s(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
#define MPC_TIC(var) double var = now_s()
#define MPC_TOC(var) (now_s() - (var))
#else
#define MPC_TIC(var) double var = 0.0
#define MPC_TOC(var) ((void)(var), 0.0)
#endif

void mpc_init(mpc_workspace* ws) {
  ws->has_plan = 0;
  ws->age = 0;
  ws->has_extra = 0;
  qpd_init(&ws->qp, MPC_NZ, MPC_NC, ws->qp_rwork, ws->qp_iwork);
}

int mpc_plant_step(mpc_workspace* ws, const mpc_real* z, const mpc_real* u, const mpc_real* p,
                   mpc_real dt, mpc_real* z_next) {
  ws->arg[0] = z;
  ws->arg[1] = u;
  ws->arg[2] = p;
  ws->arg[3] = &dt;
  ws->res[0] = z_next;
  return mpc_gen_plant(ws->arg, ws->res, ws->iw, ws->w, 0);
}

/* the extra states: at rest on u_prev first, then advanced by each command applied */
static void carry_extra(mpc_workspace* ws, const mpc_real* u_prev) {
  int i;
  mpc_real next[MPC_NEXTRA + 1], dt = MPC_DT;
  if (!ws->has_extra) {
    for (i = 0; i < MPC_NEXTRA; ++i) ws->extra[i] = u_prev[mpc_rest_index[i]];
    ws->has_extra = 1;
    return;
  }
  ws->arg[0] = ws->extra;
  ws->arg[1] = u_prev;
  ws->arg[2] = mpc_model_p;
  ws->arg[3] = &dt;
  ws->res[0] = next;
  mpc_gen_extra(ws->arg, ws->res, ws->iw, ws->w, 0);
  for (i = 0; i < MPC_NEXTRA; ++i) ws->extra[i] = next[i];
}

/* the plan to linearise about: the last successful plan shifted to now (its last control
 * repeated), else u_prev held; clipped to the control bounds */
static void warm_plan(mpc_workspace* ws, const mpc_real* u_prev) {
  int k, i, s = ws->age + 1;
  for (k = 0; k < MPC_N; ++k) {
    for (i = 0; i < MPC_NU; ++i) {
      mpc_real v;
      if (!ws->has_plan || s >= MPC_N) v = u_prev[i];
      else v = ws->plan[MPC_NU * (k + s < MPC_N ? k + s : MPC_N - 1) + i];
      if (v < mpc_u_low[i]) v = mpc_u_low[i];
      if (v > mpc_u_high[i]) v = mpc_u_high[i];
      ws->Ub[MPC_NU * k + i] = v;
    }
  }
}

static int all_finite(const mpc_real* v, int n) {
  int i;
  for (i = 0; i < n; ++i)
    if (!isfinite(v[i])) return 0;
  return 1;
}

/* one real-time iteration about ws->Ub; 1 when it succeeded (plan in ws->U) */
static int iterate(mpc_workspace* ws, const mpc_real* u_prev, const mpc_real* refs,
                   const mpc_real* weights, mpc_info* info) {
  int i, status;
  MPC_TIC(t0);
  ws->arg[0] = ws->x0;
  ws->arg[1] = ws->Ub;
  ws->res[0] = ws->X;
  ws->res[1] = ws->A_lin;
  ws->res[2] = ws->B_lin;
  mpc_gen_lin(ws->arg, ws->res, ws->iw, ws->w, 0);
  info->t_lin_s = MPC_TOC(t0);
  MPC_TIC(t1);
  ws->arg[0] = ws->x0;
  ws->arg[1] = ws->Ub;
  ws->arg[2] = u_prev;
  ws->arg[3] = refs;
  ws->arg[4] = weights;
  ws->arg[5] = ws->X;
  ws->arg[6] = ws->A_lin;
  ws->arg[7] = ws->B_lin;
  ws->res[0] = ws->H;
  ws->res[1] = ws->g;
  ws->res[2] = ws->A;
  ws->res[3] = ws->lba;
  ws->res[4] = ws->uba;
  ws->res[5] = ws->lbx;
  ws->res[6] = ws->ubx;
  ws->res[7] = ws->Xall;
  ws->res[8] = &ws->check;
  mpc_gen_cond(ws->arg, ws->res, ws->iw, ws->w, 0);
  info->t_cond_s = MPC_TOC(t1);
  for (i = 0; i < MPC_NU * MPC_N; ++i) ws->U[i] = ws->Ub[i];
  if (!isfinite(ws->check)) {
    info->qp_status = -1;
    return 0;
  }
  MPC_TIC(t2);
  status = qpd_solve(&ws->qp, ws->H, ws->g, ws->A, ws->lba, ws->uba, ws->lbx, ws->ubx, ws->z,
                     NULL);
  info->t_qp_s = MPC_TOC(t2);
  info->qp_status = status;
  info->qp_iterations = ws->qp.iterations;
  if (status != QPD_SOLVED) return 0;
  for (i = 0; i < MPC_NU * MPC_N; ++i) ws->U[i] = ws->Ub[i] + ws->z[i];
  return all_finite(ws->U, MPC_NU * MPC_N) && all_finite(ws->Xall, MPC_NX * (MPC_N + 1));
}

int mpc_step(mpc_workspace* ws, const mpc_real* y, const mpc_real* u_prev,
             const mpc_real* refs, const mpc_real* weights, mpc_real* u_out, mpc_info* info) {
  int i, k;
  mpc_info local;
  if (info == NULL) info = &local;
  info->qp_iterations = 0;
  info->t_lin_s = info->t_cond_s = info->t_qp_s = 0.0;
  if (weights == NULL) weights = mpc_default_weights;
  carry_extra(ws, u_prev);
  for (i = 0; i < MPC_NY; ++i) ws->x0[i] = y[i];
  for (i = 0; i < MPC_NEXTRA; ++i) ws->x0[MPC_NY + i] = ws->extra[i];
  warm_plan(ws, u_prev);
  info->success = iterate(ws, u_prev, refs, weights, info);
  if (info->success) {
    for (k = 0; k < MPC_NU * MPC_N; ++k) ws->plan[k] = ws->U[k];
    ws->has_plan = 1;
    ws->age = 0;
    for (i = 0; i < MPC_NU; ++i) u_out[i] = ws->U[i];
    info->source = MPC_SOLVED;
  } else {
    ws->age += 1;
    if (ws->has_plan && ws->age < MPC_N) {
      for (i = 0; i < MPC_NU; ++i) u_out[i] = ws->plan[MPC_NU * ws->age + i];
      info->source = MPC_SHIFTED;
    } else {
      for (i = 0; i < MPC_NU; ++i) u_out[i] = u_prev[i];
      info->source = MPC_HELD;
    }
  }
  return info->source;
}
