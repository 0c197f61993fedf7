/* qp_dense.h: a small dense QP solver for the exported MPC (uavdyn), plain C99, no allocation.
 *
 *   minimise    1/2 z'Hz + g'z
 *   subject to  lbx <= z <= ubx,  lba <= A z <= uba
 *
 * H (n x n) symmetric positive definite (only its lower triangle is read), A (m x n); both
 * dense, column-major (CasADi's layout). Infinite bounds (+-INFINITY) are absent constraints.
 * Method: Goldfarb-Idnani dual active set on the Cholesky factor H = L L': it starts from the
 * unconstrained minimum and adds the most violated constraint (partial steps remove active
 * constraints whose multiplier would turn negative), keeping a Cholesky factor of the active
 * normals' Gram matrix up to date (append a row on adding, Givens rotations on removing). The
 * final active set is solved once more directly, so the solution is as exact as a direct
 * solve of its KKT system. Every array lives in the caller's work arrays of
 * QPD_REAL_WORK(n, m) reals and QPD_INT_WORK(n, m) ints.
 */
#ifndef QP_DENSE_H
#define QP_DENSE_H

#ifdef QPD_FLOAT
typedef float qpd_real;
#else
typedef double qpd_real;
#endif

#define QPD_REAL_WORK(n, m) (3 * (n) * (n) + (m) + 10 * (n) + 8)
#define QPD_INT_WORK(n, m) (3 * (n) + (m) + 4)

/* return codes of qpd_solve */
#define QPD_SOLVED 0
#define QPD_NOT_CONVEX 1     /* H not positive definite (Cholesky failed) */
#define QPD_INFEASIBLE 2     /* the constraints admit no point */
#define QPD_MAX_ITER 3       /* iteration limit reached */
#define QPD_BAD_DATA 4       /* NaN in the data, or a lower bound above its upper bound */

typedef struct {
  int n, m;            /* variables, general constraints */
  qpd_real* w;         /* QPD_REAL_WORK(n, m) reals, owned by the caller */
  int* iw;             /* QPD_INT_WORK(n, m) ints, owned by the caller */
  int max_iter;        /* iteration limit (default 5 (n + m) + 50) */
  qpd_real tol;        /* violation above which a constraint is added, times 1 + |bound|
                          (default 1e-10 in double, 1e-5 in float) */
  int iterations;      /* of the last solve: constraints added plus removed */
  int n_active;        /* of the last solve */
} qpd_solver;

/* Bind the work arrays (no allocation) and set the defaults. */
void qpd_init(qpd_solver* s, int n, int m, qpd_real* rwork, int* iwork);

/* Solve; z receives the solution (n), *cost (if not NULL) the objective. Returns QPD_SOLVED
 * or one of the codes above (z then holds the last iterate). */
int qpd_solve(qpd_solver* s, const qpd_real* H, const qpd_real* g, const qpd_real* A,
              const qpd_real* lba, const qpd_real* uba, const qpd_real* lbx,
              const qpd_real* ubx, qpd_real* z, qpd_real* cost);

#endif
