/* qp_dense.c: Goldfarb-Idnani dual active-set QP solver (see qp_dense.h). Written for uavdyn;
 * BSD-3-Clause like the rest of uavdyn. */
#include <math.h>
#include <stddef.h>
#include "qp_dense.h"

/* |s|^2 / |d|^2 below which a normal is dependent; violation (relative to 1 + |bound|) above
 * which a constraint is added: a few hundred roundoffs of the real type */
#ifdef QPD_FLOAT
#define EPS_DEP ((qpd_real)1e-6)
#define DEFAULT_TOL ((qpd_real)1e-5)
#else
#define EPS_DEP ((qpd_real)1e-14)
#define DEFAULT_TOL ((qpd_real)1e-10)
#endif

void qpd_init(qpd_solver* s, int n, int m, qpd_real* rwork, int* iwork) {
  s->n = n;
  s->m = m;
  s->w = rwork;
  s->iw = iwork;
  s->max_iter = 5 * (n + m) + 50;
  s->tol = DEFAULT_TOL;
  s->iterations = 0;
  s->n_active = 0;
}

/* y := L^-1 y for lower-triangular L (leading dimension ld), entries before `from` zero. */
static void forward(const qpd_real* L, int ld, int n, qpd_real* y, int from) {
  int i, j;
  for (j = from; j < n; ++j) {
    qpd_real yj = y[j] / L[j + j * ld];
    y[j] = yj;
    for (i = j + 1; i < n; ++i) y[i] -= L[i + j * ld] * yj;
  }
}

/* y := L^-T y */
static void backward(const qpd_real* L, int ld, int n, qpd_real* y) {
  int i, j;
  for (j = n - 1; j >= 0; --j) {
    qpd_real acc = y[j];
    for (i = j + 1; i < n; ++i) acc -= L[i + j * ld] * y[i];
    y[j] = acc / L[j + j * ld];
  }
}

static qpd_real dot(const qpd_real* a, const qpd_real* b, int n) {
  qpd_real acc = 0;
  int i;
  for (i = 0; i < n; ++i) acc += a[i] * b[i];
  return acc;
}

/* value of constraint c (bounds first, then the rows of A) at z */
static qpd_real row_value(const qpd_solver* s, const qpd_real* A, int c, const qpd_real* z) {
  int n = s->n, m = s->m, k;
  qpd_real acc = 0;
  if (c < n) return z[c];
  for (k = 0; k < n; ++k) acc += A[(c - n) + k * m] * z[k];
  return acc;
}

static int cholesky(const qpd_real* H, qpd_real* L, int n) {
  int i, j, k;
  for (j = 0; j < n; ++j) {
    qpd_real d = H[j + j * n];
    for (k = 0; k < j; ++k) d -= L[j + k * n] * L[j + k * n];
    if (!(d > 0)) return 1;
    d = sqrt(d);
    L[j + j * n] = d;
    for (i = j + 1; i < n; ++i) {
      qpd_real acc = H[i + j * n];
      for (k = 0; k < j; ++k) acc -= L[i + k * n] * L[j + k * n];
      L[i + j * n] = acc / d;
    }
  }
  return 0;
}

/* remove active constraint k: shift the lists, delete row k of R, restore R with Givens */
static void remove_active(qpd_real* R, qpd_real* D, qpd_real* lam, int* idx, int* side,
                          int* flag, int ld, int n, int q, int k) {
  int i, row, col;
  flag[idx[k]] = 0;
  for (i = k; i < q - 1; ++i) {
    lam[i] = lam[i + 1];
    idx[i] = idx[i + 1];
    side[i] = side[i + 1];
    for (row = 0; row < n; ++row) D[row + i * ld] = D[row + (i + 1) * ld];
  }
  for (row = k; row < q - 1; ++row)
    for (col = 0; col <= row + 1; ++col) R[row + col * ld] = R[row + 1 + col * ld];
  for (i = k; i < q - 1; ++i) {
    qpd_real a = R[i + i * ld], b = R[i + (i + 1) * ld];
    qpd_real h = (qpd_real)sqrt(a * a + b * b), c = a / h, sn = b / h;
    for (row = i; row < q - 1; ++row) {
      qpd_real x = R[row + i * ld], y = R[row + (i + 1) * ld];
      R[row + i * ld] = c * x + sn * y;
      R[row + (i + 1) * ld] = -sn * x + c * y;
    }
    R[i + i * ld] = h;
    R[i + (i + 1) * ld] = 0;
  }
}

/* the most violated inactive constraint (-1: none); its side (+1 lower, -1 upper) */
static int most_violated(const qpd_solver* s, const qpd_real* A, const qpd_real* lba,
                         const qpd_real* uba, const qpd_real* lbx, const qpd_real* ubx,
                         const qpd_real* z, const int* flag, int* side) {
  int n = s->n, c, best = -1;
  qpd_real worst = 0;
  for (c = 0; c < n + s->m; ++c) {
    qpd_real lo = c < n ? lbx[c] : lba[c - n], hi = c < n ? ubx[c] : uba[c - n], v, tol;
    if (flag[c] || (isinf(lo) && isinf(hi))) continue;
    v = row_value(s, A, c, z);
    if (!isinf(lo)) {
      tol = s->tol * (1 + fabs(lo));
      if (lo - v > tol && lo - v > worst) { worst = lo - v; best = c; *side = 1; }
    }
    if (!isinf(hi)) {
      tol = s->tol * (1 + fabs(hi));
      if (v - hi > tol && v - hi > worst) { worst = v - hi; best = c; *side = -1; }
    }
  }
  return best;
}

static int bad_data(const qpd_solver* s, const qpd_real* g, const qpd_real* lba,
                    const qpd_real* uba, const qpd_real* lbx, const qpd_real* ubx) {
  int i;
  for (i = 0; i < s->n; ++i)
    if (!isfinite(g[i]) || isnan(lbx[i]) || isnan(ubx[i]) || lbx[i] > ubx[i]) return 1;
  for (i = 0; i < s->m; ++i)
    if (isnan(lba[i]) || isnan(uba[i]) || lba[i] > uba[i]) return 1;
  return 0;
}

int qpd_solve(qpd_solver* s, const qpd_real* H, const qpd_real* g, const qpd_real* A,
              const qpd_real* lba, const qpd_real* uba, const qpd_real* lbx,
              const qpd_real* ubx, qpd_real* z, qpd_real* cost) {
  const int n = s->n, m = s->m, ld = n;
  qpd_real *L = s->w, *R = L + n * n, *D = R + n * n, *v = D + n * n, *dj = v + n;
  qpd_real *sv = dj + n, *y = sv + n, *r = y + n, *lam = r + n, *tmp = lam + n;
  int *idx = s->iw, *side = idx + n, *flag = side + n;
  int q = 0, i, k, c, sgn = 1, status = QPD_SOLVED;
  s->iterations = 0;
  s->n_active = 0;
  for (i = 0; i < n + m; ++i) flag[i] = 0;
  if (bad_data(s, g, lba, uba, lbx, ubx)) return QPD_BAD_DATA;
  if (cholesky(H, L, n)) return QPD_NOT_CONVEX;
  for (i = 0; i < n; ++i) v[i] = g[i];
  forward(L, ld, n, v, 0);                       /* v = L^-1 g */
  for (i = 0; i < n; ++i) z[i] = -v[i];
  backward(L, ld, n, z);                         /* z = -H^-1 g */
  while ((c = most_violated(s, A, lba, uba, lbx, ubx, z, flag, &sgn)) >= 0) {
    qpd_real bj = sgn > 0 ? (c < n ? lbx[c] : lba[c - n]) : -(c < n ? ubx[c] : uba[c - n]);
    qpd_real lam_j = 0, dd;
    int from = 0;
    if (c < n) {                                 /* dj = L^-1 (sgn e_c) */
      for (i = 0; i < n; ++i) dj[i] = 0;
      dj[c] = (qpd_real)sgn;
      from = c;
    } else {
      for (i = 0; i < n; ++i) dj[i] = sgn * A[(c - n) + i * m];
    }
    forward(L, ld, n, dj, from);
    dd = dot(dj, dj, n);
    for (;;) {
      qpd_real ss, t1, t2 = INFINITY, t, viol;
      int block = -1;
      if (++s->iterations > s->max_iter) { status = QPD_MAX_ITER; goto done; }
      for (k = 0; k < q; ++k) y[k] = dot(D + k * ld, dj, n);  /* D_A' dj */
      forward(R, ld, q, y, 0);                                  /* y = R^-1 D_A' dj */
      for (k = 0; k < q; ++k) r[k] = y[k];
      backward(R, ld, q, r);                                    /* r = G^-1 D_A' dj */
      for (i = 0; i < n; ++i) sv[i] = dj[i];
      for (k = 0; k < q; ++k)
        for (i = 0; i < n; ++i) sv[i] -= D[i + k * ld] * r[k];  /* s = dj - D_A r */
      ss = dot(sv, sv, n);
      viol = bj - sgn * row_value(s, A, c, z);
      t1 = ss > EPS_DEP * dd ? viol / ss : INFINITY;
      for (k = 0; k < q; ++k)
        if (r[k] > 0 && lam[k] / r[k] < t2) { t2 = lam[k] / r[k]; block = k; }
      if (isinf(t1) && isinf(t2)) { status = QPD_INFEASIBLE; goto done; }
      t = t1 < t2 ? t1 : t2;
      if (!isinf(t1)) {                          /* primal step along L^-T s */
        for (i = 0; i < n; ++i) tmp[i] = sv[i];
        backward(L, ld, n, tmp);
        for (i = 0; i < n; ++i) z[i] += t * tmp[i];
      }
      for (k = 0; k < q; ++k) lam[k] -= t * r[k];
      lam_j += t;
      if (t1 <= t2) {                            /* full step: j joins the active set */
        for (i = 0; i < n; ++i) D[i + q * ld] = dj[i];
        for (k = 0; k < q; ++k) R[q + k * ld] = y[k];
        R[q + q * ld] = (qpd_real)sqrt(ss);
        lam[q] = lam_j;
        idx[q] = c;
        side[q] = sgn;
        flag[c] = 1;
        ++q;
        break;
      }
      remove_active(R, D, lam, idx, side, flag, ld, n, q, block);  /* partial step */
      --q;
      ++s->iterations;
    }
  }
  /* the final active set solved directly: G lam = b_A + D_A' v, z = L^-T (D_A lam - v) */
  for (k = 0; k < q; ++k) {
    c = idx[k];
    lam[k] = (side[k] > 0 ? (c < n ? lbx[c] : lba[c - n]) : -(c < n ? ubx[c] : uba[c - n]))
             + dot(D + k * ld, v, n);
  }
  forward(R, ld, q, lam, 0);
  backward(R, ld, q, lam);
  for (i = 0; i < n; ++i) z[i] = -v[i];
  for (k = 0; k < q; ++k)
    for (i = 0; i < n; ++i) z[i] += D[i + k * ld] * lam[k];
  backward(L, ld, n, z);
done:
  s->n_active = q;
  if (cost != NULL) {
    qpd_real acc = 0;
    for (i = 0; i < n; ++i) {
      qpd_real hz = 0;
      for (k = 0; k < n; ++k)   /* (Hz)_i from the lower triangle */
        hz += (i >= k ? H[i + k * n] : H[k + i * n]) * z[k];
      acc += z[i] * (0.5 * hz + g[i]);
    }
    *cost = acc;
  }
  return status;
}
