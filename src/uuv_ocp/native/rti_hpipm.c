/* Real-time iteration on HPIPM's OCP-QP API (hand-written part; constants generated above).
 *
 * One Gauss-Newton SQP step of the multiple-shooting NLP: the stage data (A, B, b, Q, S, R, q,
 * r, C, D, bounds) come from the CasADi-generated RTI_DATA(w, p); HPIPM solves the OCP-QP in
 * the step d; the NLP point moves to w + d.  All memory is allocated once by uuv_rti_create.
 * Sizes and index maps (RTI_*, rti_*) are emitted by uuv_ocp.solvers.rti_ocp for one NLP.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp_ipm.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_part_cond.h"

/* offsets of one stage's blocks in the data vector (rti_off[k][...]) */
enum { O_A, O_B, O_BV, O_Q, O_S, O_R, O_QV, O_RV, O_C, O_D, O_LG, O_UG, O_LBX, O_UBX, O_LBU, O_UBU };

/* The equality-first solve (rti_eq_solve): the Riccati factorisation of the QP without its
 * inequalities, per stage k < N: L the Cholesky factor of R + B'P B, Y = L^-1 (S + B'P A), and
 * the cost-to-go Hessian P_k (P_N = Q_N); p, w the vectors of the last pass.  The enforced rows
 * (equalities of one stage K, e.g. the terminal equality) enter by their multiplier nu. */
typedef struct {
  double P[RTI_N + 1][RTI_MAX_NX * RTI_MAX_NX];
  double L[RTI_N + 1][RTI_MAX_NU * RTI_MAX_NU];
  double Y[RTI_N + 1][RTI_MAX_NU * RTI_MAX_NX];
  double p[RTI_N + 1][RTI_MAX_NX];
  double w[RTI_N + 1][RTI_MAX_NU];
  double PA[RTI_MAX_NX * RTI_MAX_NX], PB[RTI_MAX_NX * RTI_MAX_NU], g[RTI_MAX_NX];
  double cx[RTI_MAX_NX], cu[RTI_MAX_NU];    /* extra gradient C'nu, D'nu of a pass at stage K */
  double M[RTI_MAX_NG * RTI_MAX_NG], nu[RTI_MAX_NG], rhs[RTI_MAX_NG], value[RTI_MAX_NG];
  /* pinned inputs: zero curvature, no coupling, a lower box (the exact-penalty slacks): held at
   * that bound, their KKT sign checked after the solve */
  unsigned char pinned[RTI_N + 1][RTI_MAX_NU];
  double pin[RTI_N + 1][RTI_MAX_NU];
  int K;                                    /* the stage of the enforced rows (-1: none) */
  int rows[RTI_MAX_NG];                     /* enforced rows of stage K, ne of them ... */
  int partner[RTI_MAX_NG];                  /* ... and the lower row of a slack pair (-1: none) */
  double target[RTI_MAX_NG];                /* C x + D u = target on the unpinned inputs */
  unsigned char covered[RTI_MAX_NG];        /* stage K's rows the enforced equalities stand for */
  int ne;
} rti_eq;

typedef struct {
  struct d_ocp_qp_dim dim;
  struct d_ocp_qp qp;
  struct d_ocp_qp_sol sol;
  struct d_ocp_qp_ipm_arg arg;
  struct d_ocp_qp_ipm_ws ws;
  void *dim_mem, *qp_mem, *sol_mem, *arg_mem, *ws_mem; /* HPIPM's memory, allocated once */
  /* loose_first: the first QP of each uuv_rti_iterate call is solved with these settings */
  struct d_ocp_qp_ipm_arg first_arg;
  struct d_ocp_qp_ipm_ws first_ws;
  void *first_arg_mem, *first_ws_mem;
  int loose_first;
  int loose;              /* the QP solved next is the loose first one */
  /* the rescue of a QP HPIPM did not solve (status != 0): the same settings in ROBUST mode from
   * a cold start, for the solver's settings and the loose first ones (absent where the mode
   * already is ROBUST); rescued counts the rescues of one uuv_rti_iterate call */
  struct d_ocp_qp_ipm_arg rescue_arg, first_rescue_arg;
  struct d_ocp_qp_ipm_ws rescue_ws, first_rescue_ws;
  void *rescue_arg_mem, *rescue_ws_mem, *first_rescue_arg_mem, *first_rescue_ws_mem;
  int rescue, first_rescue, rescued;
  /* partial condensing to cond_n stages (0: none): the IPM runs on pqp */
  int cond_n;
  int eq_first;           /* try rti_eq_solve before HPIPM */
  /* x_0 eliminated from HPIPM's QP (rti_x0_fixed): stage 0 has no state there, its fixed value
   * enters b_0, r_0 and the stage-0 rows' bounds (rti_set_bounds0) */
  int elim;
  double xbar[RTI_MAX_NX], b0[RTI_MAX_NX], r0[RTI_MAX_NU], lg0[RTI_MAX_NG], ug0[RTI_MAX_NG];
  double lam0[2 * (RTI_MAX_NU + RTI_MAX_NG)]; /* HPIPM's stage-0 multipliers without x_0's box */
  int qp_status;          /* HPIPM's status of the last QP (0 when rti_eq_solve solved it) */
  rti_eq eq;
  struct d_ocp_qp_dim pdim;
  struct d_ocp_qp pqp;
  struct d_ocp_qp_sol psol;
  struct d_part_cond_qp_arg cond_arg;
  struct d_part_cond_qp_ws cond_ws;
  void *pdim_mem, *pqp_mem, *psol_mem, *cond_arg_mem, *cond_ws_mem;
  int block_size[RTI_N + 1];
  double data[RTI_NDATA]; /* RTI_DATA's output: the prepared QP */
  double lbx0[RTI_NBX0];  /* stage-0 box as prepared (x0 rows moved by feedback) */
  double x0[RTI_NX0 > 0 ? RTI_NX0 : 1]; /* measured-state guess the QP was prepared with */
  double d[RTI_NW];
  double ux[RTI_NUX];     /* HPIPM's [u_k; x_k] of every stage, stacked */
  double lam[RTI_NLAM];   /* lam_lb, lam_ub, lam_lg, lam_ug per stage, stacked */
  double pi[RTI_NPI > 0 ? RTI_NPI : 1];
  double lam_x[RTI_NW];   /* multipliers of the last QP, NLP order (copied out if accepted) */
  double lam_g[RTI_NG > 0 ? RTI_NG : 1];
  const casadi_real* arg_ptr[RTI_SZ_ARG];
  casadi_real* res_ptr[RTI_SZ_RES];
  casadi_int iw[RTI_SZ_IW];
  casadi_real w[RTI_SZ_W];
  int prepared;
  double prepare_time;    /* seconds the last preparation took (its own clock) */
  /* resident warm start of uuv_rti_resident_step (uuv_rti_seed), and its working copy */
  int resident;
  double r_w[RTI_NW], r_lam_x[RTI_NW], r_lam_g[RTI_NG > 0 ? RTI_NG : 1];
  double k_w[RTI_NW], k_lam_x[RTI_NW], k_lam_g[RTI_NG > 0 ? RTI_NG : 1];
} rti_memory;

static double rti_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

void uuv_rti_free(void* memory) {
  rti_memory* m = (rti_memory*)memory;
  if (!m) return;
  free(m->ws_mem);
  free(m->arg_mem);
  free(m->first_ws_mem);
  free(m->first_arg_mem);
  free(m->rescue_ws_mem);
  free(m->rescue_arg_mem);
  free(m->first_rescue_ws_mem);
  free(m->first_rescue_arg_mem);
  free(m->sol_mem);
  free(m->qp_mem);
  free(m->dim_mem);
  free(m->pdim_mem);
  free(m->pqp_mem);
  free(m->psol_mem);
  free(m->cond_arg_mem);
  free(m->cond_ws_mem);
  free(m);
}

/* An IPM argument and workspace for QPs of size dim from settings: mode (0 speed_abs, 1 speed,
 * 2 balance, 3 robust), iter_max, tol_stat, tol_eq, tol_ineq, tol_comp, warm_start (0/1).
 * Returns 1 when out of memory. */
static int rti_ipm_create(const double* settings, struct d_ocp_qp_dim* dim, struct d_ocp_qp_ipm_arg* arg,
                          struct d_ocp_qp_ipm_ws* ws, void** arg_mem, void** ws_mem) {
  enum hpipm_mode modes[4] = {SPEED_ABS, SPEED, BALANCE, ROBUST};
  int iter_max = (int)settings[1], warm = (int)settings[6];
  double tol;
  *arg_mem = malloc(d_ocp_qp_ipm_arg_memsize(dim));
  if (!*arg_mem) return 1;
  d_ocp_qp_ipm_arg_create(dim, arg, *arg_mem);
  d_ocp_qp_ipm_arg_set_default(modes[(int)settings[0] & 3], arg);
  d_ocp_qp_ipm_arg_set_iter_max(&iter_max, arg);
  tol = settings[2]; d_ocp_qp_ipm_arg_set_tol_stat(&tol, arg);
  tol = settings[3]; d_ocp_qp_ipm_arg_set_tol_eq(&tol, arg);
  tol = settings[4]; d_ocp_qp_ipm_arg_set_tol_ineq(&tol, arg);
  tol = settings[5]; d_ocp_qp_ipm_arg_set_tol_comp(&tol, arg);
  d_ocp_qp_ipm_arg_set_warm_start(&warm, arg);
  /* the workspace's size depends on the argument: allocated after it, once */
  *ws_mem = malloc(d_ocp_qp_ipm_ws_memsize(dim, arg));
  if (!*ws_mem) return 1;
  d_ocp_qp_ipm_ws_create(dim, arg, ws, *ws_mem);
  return 0;
}

/* rti_ipm_create's rescue of a QP solved with settings: ROBUST mode (HPIPM's LQ factorisation
 * and iterative refinement), a cold start, the rest of settings.  *made: whether one was made
 * (not for settings already in ROBUST mode: the same solve again).  Returns 1 when out of memory. */
static int rti_rescue_create(const double* settings, struct d_ocp_qp_dim* dim, struct d_ocp_qp_ipm_arg* arg,
                             struct d_ocp_qp_ipm_ws* ws, void** arg_mem, void** ws_mem, int* made) {
  double robust[7];
  memcpy(robust, settings, sizeof(robust));
  *made = ((int)settings[0] & 3) != 3;
  if (!*made) return 0;
  robust[0] = 3.0;
  robust[6] = 0.0;
  return rti_ipm_create(robust, dim, arg, ws, arg_mem, ws_mem);
}

static int rti_eq_applies(void);
static int rti_x0_fixed(void);

/* options: the QP solver's settings (rti_ipm_create's seven), the partial condensing horizon
 * (0 or >= N: none), loose_first (0/1), the first QP's seven settings (read when loose_first),
 * equality_first (0/1) and eliminate_x0 (0/1: x_0 out of HPIPM's QP where rti_x0_fixed).
 * Returns NULL when out of memory. */
void* uuv_rti_create(const double* options) {
  rti_memory* m = (rti_memory*)calloc(1, sizeof(rti_memory));
  int k;
  struct d_ocp_qp_dim* ipm_dim;
  if (!m) return NULL;
  m->dim_mem = malloc(d_ocp_qp_dim_memsize(RTI_N));
  if (!m->dim_mem) goto fail;
  d_ocp_qp_dim_create(RTI_N, &m->dim, m->dim_mem);
  m->elim = options[17] != 0.0 && rti_x0_fixed();
  for (k = 0; k <= RTI_N; ++k) {
    d_ocp_qp_dim_set_nx(k, k == 0 && m->elim ? 0 : rti_nx[k], &m->dim);
    d_ocp_qp_dim_set_nu(k, rti_nu[k], &m->dim);
    d_ocp_qp_dim_set_nbx(k, k == 0 && m->elim ? 0 : rti_nbx[k], &m->dim);
    d_ocp_qp_dim_set_nbu(k, rti_nbu[k], &m->dim);
    d_ocp_qp_dim_set_ng(k, rti_ng[k], &m->dim);
    d_ocp_qp_dim_set_ns(k, 0, &m->dim);
  }
  m->qp_mem = malloc(d_ocp_qp_memsize(&m->dim));
  m->sol_mem = malloc(d_ocp_qp_sol_memsize(&m->dim));
  if (!m->qp_mem || !m->sol_mem) goto fail;
  d_ocp_qp_create(&m->dim, &m->qp, m->qp_mem);
  d_ocp_qp_sol_create(&m->dim, &m->sol, m->sol_mem);
  m->cond_n = (int)options[7];
  if (m->cond_n <= 0 || m->cond_n >= RTI_N) m->cond_n = 0;
  if (m->cond_n) {
    /* fewer, larger stages: HPIPM's per-stage overhead dominates on 9-state stages */
    d_part_cond_qp_compute_block_size(RTI_N, m->cond_n, m->block_size);
    m->pdim_mem = malloc(d_ocp_qp_dim_memsize(m->cond_n));
    if (!m->pdim_mem) goto fail;
    d_ocp_qp_dim_create(m->cond_n, &m->pdim, m->pdim_mem);
    d_part_cond_qp_compute_dim(&m->dim, m->block_size, &m->pdim);
    m->cond_arg_mem = malloc(d_part_cond_qp_arg_memsize(m->cond_n));
    if (!m->cond_arg_mem) goto fail;
    d_part_cond_qp_arg_create(m->cond_n, &m->cond_arg, m->cond_arg_mem);
    d_part_cond_qp_arg_set_default(&m->cond_arg);
    m->cond_ws_mem = malloc(d_part_cond_qp_ws_memsize(&m->dim, m->block_size, &m->pdim, &m->cond_arg));
    m->pqp_mem = malloc(d_ocp_qp_memsize(&m->pdim));
    m->psol_mem = malloc(d_ocp_qp_sol_memsize(&m->pdim));
    if (!m->cond_ws_mem || !m->pqp_mem || !m->psol_mem) goto fail;
    d_part_cond_qp_ws_create(&m->dim, m->block_size, &m->pdim, &m->cond_arg, &m->cond_ws, m->cond_ws_mem);
    d_ocp_qp_create(&m->pdim, &m->pqp, m->pqp_mem);
    d_ocp_qp_sol_create(&m->pdim, &m->psol, m->psol_mem);
  }
  ipm_dim = m->cond_n ? &m->pdim : &m->dim;
  if (rti_ipm_create(options, ipm_dim, &m->arg, &m->ws, &m->arg_mem, &m->ws_mem)) goto fail;
  if (rti_rescue_create(options, ipm_dim, &m->rescue_arg, &m->rescue_ws, &m->rescue_arg_mem, &m->rescue_ws_mem,
                        &m->rescue))
    goto fail;
  m->loose_first = options[8] != 0.0;
  m->eq_first = options[16] != 0.0 && rti_eq_applies(); /* the structure is fixed per build */
  if (m->loose_first &&
      (rti_ipm_create(options + 9, ipm_dim, &m->first_arg, &m->first_ws, &m->first_arg_mem, &m->first_ws_mem) ||
       rti_rescue_create(options + 9, ipm_dim, &m->first_rescue_arg, &m->first_rescue_ws, &m->first_rescue_arg_mem,
                         &m->first_rescue_ws_mem, &m->first_rescue)))
    goto fail;
  for (k = 0; k <= RTI_N; ++k) {
    if (rti_nbx[k] && !(k == 0 && m->elim)) d_ocp_qp_set_idxbx(k, (int*)(rti_idxbx + rti_obx[k]), &m->qp);
    if (rti_nbu[k]) d_ocp_qp_set_idxbu(k, (int*)(rti_idxbu + rti_obu[k]), &m->qp);
  }
  return m;
fail:
  uuv_rti_free(m);
  return NULL;
}

static int rti_evaluate(rti_memory* m, const double* w, const double* p) {
  m->arg_ptr[0] = w;
  m->arg_ptr[1] = p;
  m->res_ptr[0] = m->data;
  return RTI_DATA(m->arg_ptr, m->res_ptr, m->iw, m->w, 0);
}

/* Stage 0 of HPIPM's QP with x_0 = xbar eliminated: b_0 + A_0 xbar, r_0 + S_0 xbar and the
 * stage-0 rows' bounds minus C_0 xbar (xbar from the box as moved by feedback). */
static void rti_set_stage0(rti_memory* m) {
  const double* data = m->data;
  const int* o = rti_off[0];
  const int nx = rti_nx[0], nu = rti_nu[0], ng = rti_ng[0], nx1 = RTI_N ? rti_nx[1] : 0;
  int i, j;
  for (i = 0; i < rti_nbx[0]; ++i) m->xbar[rti_idxbx[rti_obx[0] + i]] = m->lbx0[i];
  for (i = 0; i < nx1; ++i) {
    double v = data[o[O_BV] + i];
    for (j = 0; j < nx; ++j) v += data[o[O_A] + i + j * nx1] * m->xbar[j];
    m->b0[i] = v;
  }
  for (i = 0; i < nu; ++i) {
    double v = data[o[O_RV] + i];
    for (j = 0; j < nx; ++j) v += data[o[O_S] + i + j * nu] * m->xbar[j];
    m->r0[i] = v;
  }
  for (i = 0; i < ng; ++i) {
    double v = 0.0;
    for (j = 0; j < nx; ++j) v += data[o[O_C] + i + j * ng] * m->xbar[j];
    m->lg0[i] = data[o[O_LG] + i] - v;
    m->ug0[i] = data[o[O_UG] + i] - v;
  }
  if (RTI_N) d_ocp_qp_set_b(0, m->b0, &m->qp);
  d_ocp_qp_set_r(0, m->r0, &m->qp);
  if (ng) {
    d_ocp_qp_set_lg(0, m->lg0, &m->qp);
    d_ocp_qp_set_ug(0, m->ug0, &m->qp);
  }
}

static void rti_set_bounds0(rti_memory* m) {
  if (m->elim) {
    rti_set_stage0(m);
    return;
  }
  if (rti_nbx[0]) {
    d_ocp_qp_set_lbx(0, m->lbx0, &m->qp);
    d_ocp_qp_set_ubx(0, m->lbx0, &m->qp); /* the measured-state rows are equalities */
    d_ocp_qp_set_lbx_mask(0, (double*)rti_lbx_mask, &m->qp);
    d_ocp_qp_set_ubx_mask(0, (double*)rti_ubx_mask, &m->qp);
  }
}

static void rti_load(rti_memory* m) {
  int k;
  double* data = m->data;
  for (k = 0; k <= RTI_N; ++k) {
    const int* o = rti_off[k];
    const int full = !(k == 0 && m->elim); /* stage 0 without x_0: B, R, D here, the rest in rti_set_stage0 */
    if (k < RTI_N) {
      if (full) d_ocp_qp_set_A(k, data + o[O_A], &m->qp);
      d_ocp_qp_set_B(k, data + o[O_B], &m->qp);
      if (full) d_ocp_qp_set_b(k, data + o[O_BV], &m->qp);
    }
    if (full) {
      d_ocp_qp_set_Q(k, data + o[O_Q], &m->qp);
      d_ocp_qp_set_S(k, data + o[O_S], &m->qp);
      d_ocp_qp_set_q(k, data + o[O_QV], &m->qp);
      d_ocp_qp_set_r(k, data + o[O_RV], &m->qp);
    }
    d_ocp_qp_set_R(k, data + o[O_R], &m->qp);
    if (rti_ng[k]) {
      if (full) {
        d_ocp_qp_set_C(k, data + o[O_C], &m->qp);
        d_ocp_qp_set_lg(k, data + o[O_LG], &m->qp);
        d_ocp_qp_set_ug(k, data + o[O_UG], &m->qp);
      }
      d_ocp_qp_set_D(k, data + o[O_D], &m->qp);
      d_ocp_qp_set_lg_mask(k, (double*)(rti_lg_mask + rti_og[k]), &m->qp);
      d_ocp_qp_set_ug_mask(k, (double*)(rti_ug_mask + rti_og[k]), &m->qp);
    }
    if (rti_nbu[k]) {
      d_ocp_qp_set_lbu(k, data + o[O_LBU], &m->qp);
      d_ocp_qp_set_ubu(k, data + o[O_UBU], &m->qp);
      d_ocp_qp_set_lbu_mask(k, (double*)(rti_lbu_mask + rti_obu[k]), &m->qp);
      d_ocp_qp_set_ubu_mask(k, (double*)(rti_ubu_mask + rti_obu[k]), &m->qp);
    }
    if (rti_nbx[k] && k > 0) {
      d_ocp_qp_set_lbx(k, data + o[O_LBX], &m->qp);
      d_ocp_qp_set_ubx(k, data + o[O_UBX], &m->qp);
      d_ocp_qp_set_lbx_mask(k, (double*)(rti_lbx_mask + rti_obx[k]), &m->qp);
      d_ocp_qp_set_ubx_mask(k, (double*)(rti_ubx_mask + rti_obx[k]), &m->qp);
    }
  }
  if (rti_nbx[0]) memcpy(m->lbx0, data + rti_off[0][O_LBX], sizeof(double) * RTI_NBX0);
}

/* Linearise at (w, p) and load the QP; the measured state of p is remembered. */
int uuv_rti_prepare(void* memory, const double* w, const double* p) {
  rti_memory* m = (rti_memory*)memory;
  double start = rti_now();
  int i;
  m->prepared = 0;
  if (rti_evaluate(m, w, p)) return 1;
  rti_load(m);
  for (i = 0; i < RTI_NX0; ++i) m->x0[i] = p[rti_x0_param[i]];
  m->prepared = 1;
  m->prepare_time = rti_now() - start;
  return 0;
}

/* Move the prepared initial-state rows to the state in p: X_0 - x0 enters linearly. */
static void rti_patch_state(rti_memory* m, const double* p) {
  int i;
  for (i = 0; i < RTI_NX0; ++i) m->lbx0[rti_x0_box[i]] += p[rti_x0_param[i]] - m->x0[i];
  for (i = 0; i < RTI_NX0; ++i) m->x0[i] = p[rti_x0_param[i]];
}

/* The larger of violation and how far v lies below lo / above hi (sides with a nonzero mask);
 * a NaN v gives NaN (the comparison fails); rti_solve_qp also checks d for finiteness. */
static inline double rti_outside(double v, double lo, double hi, double lo_mask, double hi_mask, double violation) {
  if (lo_mask != 0.0 && !(lo - v <= violation)) violation = lo - v;
  if (hi_mask != 0.0 && !(v - hi <= violation)) violation = v - hi;
  return violation;
}

/* A net multiplier (upper minus lower, HPIPM's stationarity sign) as its two sides >= 0. */
static inline void rti_split(double net, double* lower, double* upper) {
  *lower = net < 0.0 ? -net : 0.0;
  *upper = net > 0.0 ? net : 0.0;
}

/* lam_ug - lam_lg of general row i of a stage whose multipliers lam hold nbk boxes, ng rows. */
static inline double rti_row_net(const double* lam, int nbk, int ng, int i) {
  return lam[2 * nbk + ng + i] - lam[2 * nbk + i];
}

/* ---- equality first: the QP without its inequalities, by one Riccati recursion ----
 *
 * Where no inequality is active at the QP's solution, that solution is the solution of the QP
 * with its equalities alone (the dynamics, the fixed x_0, the equality rows of one stage K such
 * as the terminal equality), with zero inequality multipliers: the KKT conditions hold exactly.
 * In a tracking loop that is most steps once the transient is over, and one Riccati recursion
 * costs about one of HPIPM's interior-point iterations.  So rti_eq_solve solves the
 * equality-constrained QP and keeps the solution only if it satisfies every inequality (no
 * tolerance) and every sign condition below; otherwise HPIPM solves the QP.
 *
 * The exact-penalty NLP's slacks s (zero curvature, no dynamics, s >= 0, cost mu s, in a pair
 * of rows v - s <= 0, v + s >= 0) are pinned at their lower bound and the pair becomes the
 * equality v = 0 with multiplier nu: the soft QP's solution when |nu| <= mu (the slack bound's
 * multiplier mu - |nu| >= 0), i.e. where the penalty is exact.
 *
 * The enforced rows' multipliers nu: the solution is affine in an extra stage-K gradient
 * (C'nu, D'nu), so ne homogeneous passes give the rows' response and one small linear solve
 * gives nu.  Conventions as HPIPM's: pi_k multiplies A x + B u + b - x_{k+1}. */

/* Factorise backward from P_N = Q_N (pinned inputs: unit curvature); 0 when a pivot of
 * R + B'P B is not positive. */
static int rti_eq_factor(rti_memory* m) {
  rti_eq* e = &m->eq;
  const double* data = m->data;
  int k, i, j, l;
  {
    const int nx = rti_nx[RTI_N];
    memcpy(e->P[RTI_N], data + rti_off[RTI_N][O_Q], sizeof(double) * nx * nx);
  }
  for (k = RTI_N - 1; k >= 0; --k) {
    const int* o = rti_off[k];
    const int nx = rti_nx[k], nu = rti_nu[k], nx1 = rti_nx[k + 1];
    const double *A = data + o[O_A], *B = data + o[O_B], *P1 = e->P[k + 1];
    double *P = e->P[k], *L = e->L[k], *Y = e->Y[k], *PA = e->PA, *PB = e->PB, v;
    for (j = 0; j < nx; ++j)
      for (i = 0; i < nx1; ++i) {
        for (v = 0.0, l = 0; l < nx1; ++l) v += P1[i + l * nx1] * A[l + j * nx1];
        PA[i + j * nx1] = v;
      }
    for (j = 0; j < nu; ++j)
      for (i = 0; i < nx1; ++i) {
        for (v = 0.0, l = 0; l < nx1; ++l) v += P1[i + l * nx1] * B[l + j * nx1];
        PB[i + j * nx1] = v;
      }
    for (j = 0; j < nu; ++j) /* R + B'P B, lower triangle */
      for (i = j; i < nu; ++i) {
        for (v = data[o[O_R] + i + j * nu], l = 0; l < nx1; ++l) v += B[l + i * nx1] * PB[l + j * nx1];
        L[i + j * nu] = v;
      }
    for (j = 0; j < nu; ++j) /* a pinned input is decoupled (rti_eq_structure): unit curvature */
      if (e->pinned[k][j]) L[j + j * nu] = 1.0;
    for (j = 0; j < nx; ++j) /* S + B'P A */
      for (i = 0; i < nu; ++i) {
        for (v = data[o[O_S] + i + j * nu], l = 0; l < nx1; ++l) v += B[l + i * nx1] * PA[l + j * nx1];
        Y[i + j * nu] = v;
      }
    for (j = 0; j < nx; ++j) /* Q + A'P A */
      for (i = j; i < nx; ++i) {
        for (v = data[o[O_Q] + i + j * nx], l = 0; l < nx1; ++l) v += A[l + i * nx1] * PA[l + j * nx1];
        P[i + j * nx] = v;
      }
    for (j = 0; j < nu; ++j) { /* Cholesky: L L' = R + B'P B */
      const double diagonal = L[j + j * nu];
      for (v = diagonal, l = 0; l < j; ++l) v -= L[j + l * nu] * L[j + l * nu];
      if (!(v > 1e-12 * diagonal && v > 0.0)) return 0; /* singular or indefinite (or NaN) */
      L[j + j * nu] = v = sqrt(v);
      for (i = j + 1; i < nu; ++i) {
        double t = L[i + j * nu];
        for (l = 0; l < j; ++l) t -= L[i + l * nu] * L[j + l * nu];
        L[i + j * nu] = t / v;
      }
    }
    for (j = 0; j < nx; ++j) /* Y = L^-1 (S + B'P A) */
      for (i = 0; i < nu; ++i) {
        for (v = Y[i + j * nu], l = 0; l < i; ++l) v -= L[i + l * nu] * Y[l + j * nu];
        Y[i + j * nu] = v / L[i + i * nu];
      }
    for (j = 0; j < nx; ++j) /* P = Q + A'P A - Y'Y, both triangles */
      for (i = j; i < nx; ++i) {
        for (v = P[i + j * nx], l = 0; l < nu; ++l) v -= Y[l + i * nu] * Y[l + j * nu];
        P[i + j * nx] = P[j + i * nx] = v;
      }
  }
  return 1;
}

/* One solve with the factorisation: the QP's vectors (homogeneous: b, q, r, x_0 and the pinned
 * values zero), plus the extra stage-K gradient (cx, cu) when extra.  Writes u_k, x_k into ux. */
static void rti_eq_pass(rti_memory* m, int homogeneous, int extra, double* ux) {
  rti_eq* e = &m->eq;
  const double* data = m->data;
  int k, i, l;
  double v;
  {
    const int nx = rti_nx[RTI_N];
    double* p = e->p[RTI_N];
    for (i = 0; i < nx; ++i)
      p[i] = (homogeneous ? 0.0 : data[rti_off[RTI_N][O_QV] + i]) + (extra && e->K == RTI_N ? e->cx[i] : 0.0);
  }
  for (k = RTI_N - 1; k >= 0; --k) {
    const int* o = rti_off[k];
    const int nx = rti_nx[k], nu = rti_nu[k], nx1 = rti_nx[k + 1], here = extra && e->K == k;
    const double *A = data + o[O_A], *B = data + o[O_B], *P1 = e->P[k + 1], *p1 = e->p[k + 1];
    const double *L = e->L[k], *Y = e->Y[k];
    double *g = e->g, *w = e->w[k], *p = e->p[k];
    for (i = 0; i < nx1; ++i) g[i] = p1[i];
    if (!homogeneous)
      for (l = 0; l < nx1; ++l) {
        const double bl = data[o[O_BV] + l];
        for (i = 0; i < nx1; ++i) g[i] += P1[i + l * nx1] * bl;
      }
    for (i = 0; i < nu; ++i) { /* w = L^-1 h_u, h_u = r + B'g (+ D'nu); a pinned input's -pin */
      if (e->pinned[k][i]) {
        v = homogeneous ? 0.0 : -e->pin[k][i];
      } else {
        for (v = homogeneous ? 0.0 : data[o[O_RV] + i], l = 0; l < nx1; ++l) v += B[l + i * nx1] * g[l];
        if (here) v += e->cu[i];
      }
      for (l = 0; l < i; ++l) v -= L[i + l * nu] * w[l];
      w[i] = v / L[i + i * nu];
    }
    for (i = 0; i < nx; ++i) { /* p = q + A'g - Y'w (+ C'nu) */
      for (v = homogeneous ? 0.0 : data[o[O_QV] + i], l = 0; l < nx1; ++l) v += A[l + i * nx1] * g[l];
      for (l = 0; l < nu; ++l) v -= Y[l + i * nu] * w[l];
      p[i] = v + (here ? e->cx[i] : 0.0);
    }
  }
  { /* x_0: the fixed box values (all of x_0 is boxed: rti_eq_applies) */
    double* x = ux + rti_oux[0] + rti_nu[0];
    for (i = 0; i < rti_nbx[0]; ++i) x[rti_idxbx[rti_obx[0] + i]] = homogeneous ? 0.0 : m->lbx0[i];
  }
  for (k = 0; k < RTI_N; ++k) {
    const int* o = rti_off[k];
    const int nx = rti_nx[k], nu = rti_nu[k], nx1 = rti_nx[k + 1];
    const double *A = data + o[O_A], *B = data + o[O_B], *L = e->L[k], *Y = e->Y[k], *w = e->w[k];
    double *u = ux + rti_oux[k], *x = u + nu, *next = ux + rti_oux[k + 1] + rti_nu[k + 1];
    for (i = nu - 1; i >= 0; --i) { /* u = -L'^-1 (Y x + w) */
      for (v = -w[i], l = 0; l < nx; ++l) v -= Y[i + l * nu] * x[l];
      for (l = i + 1; l < nu; ++l) v -= L[l + i * nu] * u[l];
      u[i] = v / L[i + i * nu];
    }
    for (i = 0; i < nx1; ++i) {
      for (v = homogeneous ? 0.0 : data[o[O_BV] + i], l = 0; l < nx; ++l) v += A[i + l * nx1] * x[l];
      for (l = 0; l < nu; ++l) v += B[i + l * nx1] * u[l];
      next[i] = v;
    }
  }
}

/* C x + D u of the enforced rows at stage K, the pinned inputs left out. */
static void rti_eq_values(const rti_memory* m, const double* ux, double* out) {
  const rti_eq* e = &m->eq;
  const int K = e->K, ng = rti_ng[K], nx = rti_nx[K], nu = rti_nu[K];
  const double *C = m->data + rti_off[K][O_C], *D = m->data + rti_off[K][O_D];
  const double *u = ux + rti_oux[K], *x = u + nu;
  int i, l;
  for (i = 0; i < e->ne; ++i) {
    const int r = e->rows[i];
    double v = 0.0;
    for (l = 0; l < nx; ++l) v += C[r + l * ng] * x[l];
    for (l = 0; l < nu; ++l)
      if (!e->pinned[K][l]) v += D[r + l * ng] * u[l];
    out[i] = v;
  }
}

/* Solve M nu = rhs (ne x ne, Gaussian elimination with partial pivoting, M and rhs
 * overwritten); 0 when a pivot is below 1e-12 of M's largest entry. */
static int rti_eq_small_solve(int n, double* M, double* rhs, double* x) {
  int i, j, l, pivot;
  double scale = 0.0, t;
  for (i = 0; i < n * n; ++i)
    if (fabs(M[i]) > scale) scale = fabs(M[i]);
  for (j = 0; j < n; ++j) {
    for (pivot = j, i = j + 1; i < n; ++i)
      if (fabs(M[i + j * n]) > fabs(M[pivot + j * n])) pivot = i;
    if (!(fabs(M[pivot + j * n]) > 1e-12 * scale)) return 0;
    if (pivot != j) {
      for (l = j; l < n; ++l) { t = M[j + l * n]; M[j + l * n] = M[pivot + l * n]; M[pivot + l * n] = t; }
      t = rhs[j]; rhs[j] = rhs[pivot]; rhs[pivot] = t;
    }
    for (i = j + 1; i < n; ++i) {
      t = M[i + j * n] / M[j + j * n];
      for (l = j; l < n; ++l) M[i + l * n] -= t * M[j + l * n];
      rhs[i] -= t * rhs[j];
    }
  }
  for (i = n - 1; i >= 0; --i) {
    for (t = rhs[i], l = i + 1; l < n; ++l) t -= M[i + l * n] * x[l];
    x[i] = t / M[i + i * n];
  }
  return 1;
}

/* The structure rti_eq_solve needs: x_0 fully fixed by its box, no inputs at stage N. */
static int rti_eq_applies(void) { return rti_nu[RTI_N] == 0 && rti_x0_fixed(); }

/* x_0 wholly fixed by its stage-0 box (lbx = ubx on every entry): it can leave HPIPM's QP. */
static int rti_x0_fixed(void) {
  int i;
  if (rti_nbx[0] != rti_nx[0]) return 0;
  for (i = 0; i < rti_nbx[0]; ++i)
    if (rti_lbx_mask[rti_obx[0] + i] == 0.0 || rti_ubx_mask[rti_obx[0] + i] == 0.0) return 0;
  return 1;
}

/* The box of input j of stage k among the stage's input boxes (-1: none). */
static int rti_eq_ubox(int k, int j) {
  int i;
  for (i = 0; i < rti_nbu[k]; ++i)
    if (rti_idxbu[rti_obu[k] + i] == j) return i;
  return -1;
}

/* Find the pinned inputs (penalty slacks with no curvature, coupling or dynamics and a lower
 * box) and the enforced rows: equality rows, and pairs v - s <= ub, v + s >= lb on a pinned s
 * that fix v; all of one stage K (0 when there are enforced rows at two stages). */
static int rti_eq_structure(rti_memory* m) {
  rti_eq* e = &m->eq;
  const double* data = m->data;
  int k, i, j, l, r;
  e->K = -1;
  e->ne = 0;
  for (k = 0; k <= RTI_N; ++k) {
    const int* o = rti_off[k];
    const int nx = rti_nx[k], nu = rti_nu[k], ng = rti_ng[k], nx1 = k < RTI_N ? rti_nx[k + 1] : 0;
    for (j = 0; j < nu; ++j) {
      /* only a penalty slack (by its NLP variable): a flat control must not jump to a bound */
      int zero = rti_slack[rti_ou[k] + j], box = zero ? rti_eq_ubox(k, j) : -1;
      for (l = 0; l < nu && zero; ++l) zero = data[o[O_R] + l + j * nu] == 0.0;
      for (l = 0; l < nx && zero; ++l) zero = data[o[O_S] + j + l * nu] == 0.0;
      for (l = 0; l < nx1 && zero; ++l) zero = data[o[O_B] + l + j * nx1] == 0.0;
      e->pinned[k][j] = zero && box >= 0 && rti_lbu_mask[rti_obu[k] + box] != 0.0;
      if (e->pinned[k][j]) e->pin[k][j] = data[o[O_LBU] + box];
    }
    for (i = 0; i < ng; ++i) {
      const int lo = rti_lg_mask[rti_og[k] + i] != 0.0, hi = rti_ug_mask[rti_og[k] + i] != 0.0;
      int slack = -1, slacks = 0, partner = -1;
      double target, held = 0.0; /* the pinned inputs' part of the row */
      for (j = 0; j < nu; ++j)
        if (e->pinned[k][j] && data[o[O_D] + i + j * ng] != 0.0) {
          held += data[o[O_D] + i + j * ng] * e->pin[k][j];
          slack = j;
          slacks++;
        }
      if (lo && hi && data[o[O_LG] + i] == data[o[O_UG] + i]) {
        target = data[o[O_LG] + i] - held; /* an equality row */
      } else if (slacks == 1 && hi && !lo && data[o[O_D] + i + slack * ng] == -1.0) {
        /* v - s <= ub with s held: an equality if the row v + s >= lb says v = the same value
         * (an exact-penalty equality); otherwise both are inequalities (a softened range) */
        target = data[o[O_UG] + i] - held;
        for (r = 0; r < ng && partner < 0; ++r) {
          int same = r != i && rti_lg_mask[rti_og[k] + r] != 0.0 && rti_ug_mask[rti_og[k] + r] == 0.0 &&
                     data[o[O_D] + r + slack * ng] == 1.0 &&
                     fabs(data[o[O_LG] + r] - e->pin[k][slack] - target) <= 1e-9 * (1.0 + fabs(target));
          for (l = 0; l < nx && same; ++l) same = data[o[O_C] + r + l * ng] == data[o[O_C] + i + l * ng];
          for (l = 0; l < nu && same; ++l)
            same = l == slack || data[o[O_D] + r + l * ng] == data[o[O_D] + i + l * ng];
          if (same) partner = r;
        }
        if (partner < 0) continue;
      } else {
        continue; /* an inequality (checked after the solve, the pinned inputs held) */
      }
      if (e->K >= 0 && e->K != k) return 0;
      e->K = k;
      e->rows[e->ne] = i;
      e->partner[e->ne] = partner;
      e->target[e->ne] = target;
      e->ne++;
    }
  }
  if (e->K >= 0) {
    memset(e->covered, 0, sizeof(e->covered));
    for (i = 0; i < e->ne; ++i) {
      e->covered[e->rows[i]] = 1;
      if (e->partner[i] >= 0) e->covered[e->partner[i]] = 1;
    }
  }
  return 1;
}

static double rti_excess(const rti_memory* m, int inequalities_only);

/* x_0's box multipliers (m->lam, stage 0) from stationarity in x_0 at the solution in m->ux,
 * m->pi and the stage-0 rows' multipliers: the QPs that do not give them (rti_eq_solve, HPIPM's
 * QP with x_0 eliminated). */
static void rti_x0_multipliers(rti_memory* m) {
  const double* data = m->data;
  const int* o = rti_off[0];
  const int nx = rti_nx[0], nu = rti_nu[0], nx1 = RTI_N ? rti_nx[1] : 0, nbk = rti_nbu[0] + rti_nbx[0];
  const int ng = rti_ng[0];
  const double *u = m->ux + rti_oux[0], *x = u + nu, *pi = m->pi;
  double* lam = m->lam + rti_olam[0];
  int i, l;
  for (i = 0; i < rti_nbx[0]; ++i) {
    const int jx = rti_idxbx[rti_obx[0] + i];
    double v = data[o[O_QV] + jx]; /* Q x + S'u + q + A'pi + C'(lam_ug - lam_lg) in x_0's jx */
    for (l = 0; l < nx; ++l) v += data[o[O_Q] + jx + l * nx] * x[l];
    for (l = 0; l < nu; ++l) v += data[o[O_S] + l + jx * nu] * u[l];
    for (l = 0; l < nx1; ++l) v += data[o[O_A] + l + jx * nx1] * pi[l];
    for (l = 0; l < ng; ++l) v += data[o[O_C] + l + jx * ng] * rti_row_net(lam, nbk, ng, l);
    rti_split(-v, lam + rti_nbu[0] + i, lam + nbk + rti_nbu[0] + i); /* lam_ub - lam_lb = -v */
  }
}

/* Solve the loaded QP with its equalities alone; 1 (m->ux, m->pi, m->lam written) when that
 * solution satisfies every inequality and sign condition, else 0 (the QP goes to HPIPM). */
static int rti_eq_solve(rti_memory* m) {
  rti_eq* e = &m->eq;
  const double* data = m->data;
  int i, j, k, l;
  if (!rti_eq_structure(m) || !rti_eq_factor(m)) return 0;
  if (e->ne) {
    const int K = e->K, ng = rti_ng[K], nx = rti_nx[K], nu = rti_nu[K];
    const double *C = data + rti_off[K][O_C], *D = data + rti_off[K][O_D];
    for (i = 0; i < e->ne; ++i) { /* column i: the rows' response to the gradient of row i */
      for (l = 0; l < nx; ++l) e->cx[l] = C[e->rows[i] + l * ng];
      for (l = 0; l < nu; ++l) e->cu[l] = e->pinned[K][l] ? 0.0 : D[e->rows[i] + l * ng];
      rti_eq_pass(m, 1, 1, m->ux);
      rti_eq_values(m, m->ux, e->M + i * e->ne);
    }
    rti_eq_pass(m, 0, 0, m->ux);
    rti_eq_values(m, m->ux, e->value);
    for (i = 0; i < e->ne; ++i) e->rhs[i] = e->target[i] - e->value[i];
    if (!rti_eq_small_solve(e->ne, e->M, e->rhs, e->nu)) return 0;
    memset(e->cx, 0, sizeof(e->cx));
    memset(e->cu, 0, sizeof(e->cu));
    for (i = 0; i < e->ne; ++i) {
      for (l = 0; l < nx; ++l) e->cx[l] += C[e->rows[i] + l * ng] * e->nu[i];
      for (l = 0; l < nu; ++l)
        if (!e->pinned[K][l]) e->cu[l] += D[e->rows[i] + l * ng] * e->nu[i];
    }
    rti_eq_pass(m, 0, 1, m->ux);
    /* nearly dependent rows give a nu that does not hold them: HPIPM's QP, not a failed step */
    rti_eq_values(m, m->ux, e->value);
    for (i = 0; i < e->ne; ++i)
      if (!(fabs(e->value[i] - e->target[i]) <= 1e-9 * (1.0 + fabs(e->target[i])))) return 0;
  } else {
    rti_eq_pass(m, 0, 0, m->ux);
  }
  if (!(rti_excess(m, 1) <= 0.0)) return 0; /* an inequality is active (or NaN): HPIPM's QP */
  /* multipliers: pi_k = P_{k+1} x_{k+1} + p_{k+1}; nu on the enforced rows (a pair's upper row
   * takes its positive part, the lower row its negative part); the pinned inputs' lower boxes
   * and x_0's box from stationarity; every other inequality's zero */
  for (k = 0; k < RTI_N; ++k) {
    const int nx1 = rti_nx[k + 1];
    const double *x1 = m->ux + rti_oux[k + 1] + rti_nu[k + 1], *P1 = e->P[k + 1];
    double* pi = m->pi + rti_ox[k + 1] - rti_nx[0];
    for (i = 0; i < nx1; ++i) {
      double v = e->p[k + 1][i];
      for (l = 0; l < nx1; ++l) v += P1[i + l * nx1] * x1[l];
      pi[i] = v;
    }
  }
  memset(m->lam, 0, sizeof(double) * RTI_NLAM);
  if (e->ne) {
    const int K = e->K, ng = rti_ng[K], nbk = rti_nbu[K] + rti_nbx[K];
    double* lam = m->lam + rti_olam[K];
    for (i = 0; i < e->ne; ++i) /* a pair: lam_ug of v - s <= ub, lam_lg of v + s >= lb */
      rti_split(e->nu[i], lam + 2 * nbk + (e->partner[i] >= 0 ? e->partner[i] : e->rows[i]),
                lam + 2 * nbk + ng + e->rows[i]);
  }
  for (k = 0; k < RTI_N; ++k) { /* pinned inputs: lam_lb = r + B'pi + D'(lam_ug - lam_lg) >= 0 */
    const int* o = rti_off[k];
    const int nu = rti_nu[k], ng = rti_ng[k], nbk = rti_nbu[k] + rti_nbx[k];
    double* lam = m->lam + rti_olam[k];
    for (j = 0; j < nu; ++j) {
      double v;
      if (!e->pinned[k][j]) continue;
      v = data[o[O_RV] + j];
      for (i = 0; i < ng; ++i) v += data[o[O_D] + i + j * ng] * rti_row_net(lam, nbk, ng, i);
      if (!(v >= 0.0)) return 0; /* the penalty is not exact here: HPIPM's QP */
      lam[rti_eq_ubox(k, j)] = v;
    }
  }
  rti_x0_multipliers(m);
  return 1;
}

/* One HPIPM solve of the loaded QP (the condensed one with partial condensing) with arg and ws;
 * m->qp_status gets its status.  Returns its iterations. */
static int rti_ipm_run(rti_memory* m, struct d_ocp_qp_ipm_arg* arg, struct d_ocp_qp_ipm_ws* ws) {
  int iterations;
  if (m->cond_n) d_ocp_qp_ipm_solve(&m->pqp, &m->psol, arg, ws);
  else d_ocp_qp_ipm_solve(&m->qp, &m->sol, arg, ws);
  d_ocp_qp_ipm_get_iter(ws, &iterations);
  d_ocp_qp_ipm_get_status(ws, &m->qp_status);
  return iterations;
}

/* Solve the loaded QP with HPIPM (condensed or not) into m->ux, m->pi, m->lam; its iterations
 * (those of the rescue included).
 *
 * A QP HPIPM does not solve (max_iter, min_step: in SPEED mode its Newton steps without
 * iterative refinement stall on the ill-conditioned cold QPs of the generated nmpc_step, 67 of
 * 100 on s2 with partial condensing) is solved again in ROBUST mode: its last iterate is no
 * solution, only a feasible point, and was up to 1.2e-4 of a control's range off the QP's
 * solution (tests/solvers/test_rti.py::test_a_qp_hpipm_does_not_solve_is_rescued_in_robust_mode). */
static int rti_hpipm_solve(rti_memory* m) {
  int k, iterations;
  if (m->cond_n) {
    /* the whole QP, in the feedback: condensing only the right-hand side there (the matrices
     * condensed in the preparation) rounds differently from condensing all of it, and a step
     * from a preparation must equal the same step without one, bit for bit (3e-8 N apart on an
     * s2 control with the wheel's HPIPM, tests/solvers/test_rti.py's resident steps); with HPIPM 0.1.2
     * the right-hand side alone gave a feedback 17 N off a fresh step's
     * (tests/solvers/test_rti.py::test_prepare_then_feedback_equals_step).  Steps that rti_eq_solve
     * solves condense nothing. */
    d_part_cond_qp_cond(&m->qp, &m->pqp, &m->cond_arg, &m->cond_ws);
  }
  iterations = m->loose ? rti_ipm_run(m, &m->first_arg, &m->first_ws) : rti_ipm_run(m, &m->arg, &m->ws);
  if (m->qp_status != 0 && (m->loose ? m->first_rescue : m->rescue)) {
    iterations += m->loose ? rti_ipm_run(m, &m->first_rescue_arg, &m->first_rescue_ws)
                           : rti_ipm_run(m, &m->rescue_arg, &m->rescue_ws);
    m->rescued++;
  }
  if (m->cond_n) {
#ifdef UUV_HPIPM_OLD_PART_COND /* HPIPM <= 0.1.2 (acados' copy) also reads the condensed QP */
    d_part_cond_qp_expand_sol(&m->qp, &m->pqp, &m->psol, &m->sol, &m->cond_arg, &m->cond_ws);
#else
    d_part_cond_qp_expand_sol(&m->qp, &m->psol, &m->sol, &m->cond_arg, &m->cond_ws);
#endif
  }
  for (k = 0; k <= RTI_N; ++k) {
    double *u = m->ux + rti_oux[k], *x = u + rti_nu[k], *lam = m->lam + rti_olam[k];
    const int nbk = rti_nbu[k] + rti_nbx[k], ng = rti_ng[k];
    d_ocp_qp_sol_get_u(k, &m->sol, u);
    if (k < RTI_N) d_ocp_qp_sol_get_pi(k, &m->sol, m->pi + rti_ox[k + 1] - rti_nx[0]);
    if (k == 0 && m->elim) {
      /* HPIPM's stage 0 has the input boxes and the rows: spread them into the layout with
       * x_0's box, whose multipliers come from stationarity once pi_0 is known */
      const int nbu = rti_nbu[0];
      double* h = m->lam0;
      memcpy(x, m->xbar, sizeof(double) * rti_nx[0]);
      d_ocp_qp_sol_get_lam_lb(0, &m->sol, h);
      d_ocp_qp_sol_get_lam_ub(0, &m->sol, h + nbu);
      d_ocp_qp_sol_get_lam_lg(0, &m->sol, h + 2 * nbu);
      d_ocp_qp_sol_get_lam_ug(0, &m->sol, h + 2 * nbu + ng);
      memcpy(lam, h, sizeof(double) * nbu);
      memcpy(lam + nbk, h + nbu, sizeof(double) * nbu);
      memcpy(lam + 2 * nbk, h + 2 * nbu, sizeof(double) * 2 * ng);
      continue;
    }
    d_ocp_qp_sol_get_x(k, &m->sol, x);
    d_ocp_qp_sol_get_lam_lb(k, &m->sol, lam);
    d_ocp_qp_sol_get_lam_ub(k, &m->sol, lam + nbk);
    d_ocp_qp_sol_get_lam_lg(k, &m->sol, lam + 2 * nbk);
    d_ocp_qp_sol_get_lam_ug(k, &m->sol, lam + 2 * nbk + ng);
  }
  if (m->elim) rti_x0_multipliers(m);
  return iterations;
}

/* How far the solution in m->ux violates the linearised constraints (inf norm; 0 if it holds
 * them; NaN propagates).  inequalities_only: only the inequalities rti_eq_solve leaves out (not
 * the dynamics, x_0's box or the rows its enforced equalities stand for), with no tolerance. */
static double rti_excess(const rti_memory* m, int inequalities_only) {
  const double* data = m->data;
  int k, i, j, nx, nu, nb, ng;
  double violation = 0.0, v;
  for (k = 0; k <= RTI_N; ++k) {
    const int* o = rti_off[k];
    const double* u = m->ux + rti_oux[k];
    const double* x = u + rti_nu[k];
    nx = rti_nx[k];
    nu = rti_nu[k];
    if (k < RTI_N && !inequalities_only) {
      const double* next = m->ux + rti_oux[k + 1] + rti_nu[k + 1];
      for (i = 0; i < rti_nx[k + 1]; ++i) {
        v = data[o[O_BV] + i] - next[i];
        for (j = 0; j < nx; ++j) v += data[o[O_A] + i + j * rti_nx[k + 1]] * x[j];
        for (j = 0; j < nu; ++j) v += data[o[O_B] + i + j * rti_nx[k + 1]] * u[j];
        v = fabs(v);
        if (!(v <= violation)) violation = v; /* NaN propagates */
      }
    }
    ng = rti_ng[k];
    for (i = 0; i < ng; ++i) {
      if (inequalities_only && k == m->eq.K && m->eq.covered[i]) continue; /* enforced */
      v = 0.0;
      for (j = 0; j < nx; ++j) v += data[o[O_C] + i + j * ng] * x[j];
      for (j = 0; j < nu; ++j) v += data[o[O_D] + i + j * ng] * u[j];
      violation = rti_outside(v, data[o[O_LG] + i], data[o[O_UG] + i], rti_lg_mask[rti_og[k] + i],
                              rti_ug_mask[rti_og[k] + i], violation);
    }
    nb = rti_nbu[k];
    for (i = 0; i < nb; ++i)
      violation = rti_outside(u[rti_idxbu[rti_obu[k] + i]], data[o[O_LBU] + i], data[o[O_UBU] + i],
                              rti_lbu_mask[rti_obu[k] + i], rti_ubu_mask[rti_obu[k] + i], violation);
    nb = (inequalities_only && k == 0) ? 0 : rti_nbx[k];
    for (i = 0; i < nb; ++i)
      violation = rti_outside(x[rti_idxbx[rti_obx[k] + i]], k == 0 ? m->lbx0[i] : data[o[O_LBX] + i],
                              k == 0 ? m->lbx0[i] : data[o[O_UBX] + i], rti_lbx_mask[rti_obx[k] + i],
                              rti_ubx_mask[rti_obx[k] + i], violation);
  }
  return violation;
}

/* Solve the loaded QP (equality first where enabled, else or then HPIPM); write d (NLP order)
 * and the multipliers; return the violation of the linearised constraints (inf if the solution
 * is not finite).  qp_iter: HPIPM's iterations (0: rti_eq_solve's solution). */
static double rti_solve_qp(rti_memory* m, int* qp_iter) {
  double *lam_x = m->lam_x, *lam_g = m->lam_g, violation;
  int k, i, ng;
  rti_set_bounds0(m);
  if (m->eq_first && rti_eq_solve(m)) {
    *qp_iter = 0;
    m->qp_status = 0;
  } else {
    /* after the rescue, HPIPM's status (max_iter, min_step) is no verdict on the step: like the
     * Python path, the solution is judged by the violation of the linearised constraints below */
    *qp_iter = rti_hpipm_solve(m);
  }
  for (k = 0; k <= RTI_N; ++k) {
    const double* u = m->ux + rti_oux[k];
    const double* x = u + rti_nu[k];
    for (i = 0; i < rti_nu[k]; ++i) m->d[rti_uvar[rti_ou[k] + i]] = u[i];
    for (i = 0; i < rti_nx[k]; ++i) m->d[rti_xvar[rti_ox[k] + i]] = x[i];
  }
  violation = rti_excess(m, 0);
  /* multipliers in CasADi's convention (lam > 0 at an upper bound), NLP order */
  memset(lam_x, 0, sizeof(double) * RTI_NW);
  memset(lam_g, 0, sizeof(double) * RTI_NG);
  for (i = 0; i < RTI_NPI; ++i) lam_g[rti_dynrow[i]] = RTI_PI_SIGN * m->pi[i];
  for (k = 0; k <= RTI_N; ++k) {
    const double* lam = m->lam + rti_olam[k];
    const int nbk = rti_nbu[k] + rti_nbx[k];
    ng = rti_ng[k];
    for (i = 0; i < nbk; ++i) {
      int target = rti_blam[rti_ob[k] + i];
      double value = lam[nbk + i] - lam[i];
      if (target >= 0) lam_x[target] = value;
      else lam_g[-1 - target] = value;
    }
    for (i = 0; i < ng; ++i) lam_g[rti_genrow[rti_og[k] + i]] = rti_row_net(lam, nbk, ng, i);
  }
  if (!isfinite(violation)) return INFINITY;
  for (i = 0; i < RTI_NW; ++i)
    if (!isfinite(m->d[i])) return INFINITY;
  return violation;
}

/* Gauss-Newton iterations from w (updated in place).
 *
 * prepared: use the QP of uuv_rti_prepare (its state moved to p's), else linearise at w first.
 * With loose_first, max_iter > 1 and no budget (inf), the first QP is solved with the first
 * settings (its step is never taken as converged: only a step of the QP solver's own settings
 * is).
 * Stops after max_iter steps, at a step with |d|_inf <= tol, at a QP solution that violates
 * the linearised constraints by more than qp_tol (not taken), or when budget seconds passed
 * (checked before each further iteration).  info: [iterations, violation, last |d|_inf,
 * stop (0 max_iter, 1 converged, 2 infeasible QP, 3 deadline, 4 evaluation failed), QP
 * iterations of the last QP, HPIPM status, seconds linearising, seconds in QPs, seconds of
 * the preparation used (0: none), QPs of the call re-solved in ROBUST mode (rti_hpipm_solve)]. */
int uuv_rti_iterate(void* memory, double* w, const double* p, int prepared, int max_iter, double tol,
                    double qp_tol, double budget, double* lam_x, double* lam_g, double* info) {
  rti_memory* m = (rti_memory*)memory;
  double start = rti_now(), violation = INFINITY, norm = INFINITY, mark, t_lin = 0.0, t_qp = 0.0;
  int iterations = 0, stop = 0, qp_iter = 0, i, status = 0;
  double used_preparation = prepared && m->prepared ? m->prepare_time : 0.0;
  if (!(prepared && m->prepared)) {
    if (rti_evaluate(m, w, p)) { stop = 4; goto done; }
    rti_load(m);
    t_lin += rti_now() - start;
    for (i = 0; i < RTI_NX0; ++i) m->x0[i] = p[rti_x0_param[i]];
  } else {
    rti_patch_state(m, p);
  }
  m->prepared = 0;
  m->rescued = 0;
  /* a loose step cannot end the iteration: not where one step may be all there is */
  m->loose = m->loose_first && max_iter > 1 && isinf(budget);
  for (;;) {
    mark = rti_now();
    violation = rti_solve_qp(m, &qp_iter);
    t_qp += rti_now() - mark;
    status = m->qp_status;
    if (!(violation <= qp_tol)) { stop = 2; break; }
    iterations++;
    memcpy(lam_x, m->lam_x, sizeof(double) * RTI_NW);
    memcpy(lam_g, m->lam_g, sizeof(double) * RTI_NG);
    norm = 0.0;
    for (i = 0; i < RTI_NW; ++i) {
      w[i] += m->d[i];
      if (fabs(m->d[i]) > norm) norm = fabs(m->d[i]);
    }
    if (m->loose) m->loose = 0;
    else if (norm <= tol) { stop = 1; break; }
    if (iterations >= max_iter) { stop = 0; break; }
    if (rti_now() - start >= budget) { stop = 3; break; }
    mark = rti_now();
    if (rti_evaluate(m, w, p)) { stop = 4; break; }
    rti_load(m);
    t_lin += rti_now() - mark;
  }
done:
  info[0] = iterations;
  info[1] = violation;
  info[2] = norm;
  info[3] = stop;
  info[4] = qp_iter;
  info[5] = status;
  info[6] = t_lin;
  info[7] = t_qp;
  info[8] = used_preparation;
  info[9] = m->rescued;
  return 0;
}

/* Keep (w, lam_x, lam_g) as the warm start of the next uuv_rti_resident_step (the multipliers
 * in this step's convention: CasADi's times the objective scale). */
void uuv_rti_seed(void* memory, const double* w, const double* lam_x, const double* lam_g) {
  rti_memory* m = (rti_memory*)memory;
  memcpy(m->r_w, w, sizeof(double) * RTI_NW);
  memcpy(m->r_lam_x, lam_x, sizeof(double) * RTI_NW);
  if (RTI_NG) memcpy(m->r_lam_g, lam_g, sizeof(double) * RTI_NG);
  m->resident = 1;
}

/* One step from the resident warm start: uuv_rti_iterate on a copy of it with instance p (no
 * preparation, no budget).  Accepted when every QP solution held the linearised constraints
 * (stop 0 or 1) and, with converged_only, the iteration converged (stop 1): then w, lam_x,
 * lam_g get the new point and the resident warm start becomes that point shifted by one stage
 * (rti_primal_shift, rti_constraint_shift: Iterate.shift's maps), and 0 is returned.
 * Otherwise 1 (-1: nothing resident), with the outputs and the resident point unchanged.
 * info as uuv_rti_iterate, written in every case. */
int uuv_rti_resident_step(void* memory, const double* p, int max_iter, double tol, double qp_tol,
                          int converged_only, double* w, double* lam_x, double* lam_g, double* info) {
  rti_memory* m = (rti_memory*)memory;
  int i, stop;
  if (!m->resident) return -1;
  memcpy(m->k_w, m->r_w, sizeof(double) * RTI_NW);
  memcpy(m->k_lam_x, m->r_lam_x, sizeof(double) * RTI_NW);
  if (RTI_NG) memcpy(m->k_lam_g, m->r_lam_g, sizeof(double) * RTI_NG);
  uuv_rti_iterate(memory, m->k_w, p, 0, max_iter, tol, qp_tol, INFINITY, m->k_lam_x, m->k_lam_g, info);
  stop = (int)info[3];
  if (stop == 2 || stop == 4 || (converged_only && stop != 1)) return 1;
  memcpy(w, m->k_w, sizeof(double) * RTI_NW);
  memcpy(lam_x, m->k_lam_x, sizeof(double) * RTI_NW);
  if (RTI_NG) memcpy(lam_g, m->k_lam_g, sizeof(double) * RTI_NG);
  for (i = 0; i < RTI_NW; ++i) m->r_w[i] = m->k_w[rti_primal_shift[i]];
  for (i = 0; i < RTI_NW; ++i) m->r_lam_x[i] = m->k_lam_x[rti_primal_shift[i]];
  for (i = 0; i < RTI_NG; ++i) m->r_lam_g[i] = m->k_lam_g[rti_constraint_shift[i]];
  return 0;
}

/* What uuv_rti_closed_loop_step needs besides the step's memory: one controller's buffers and
 * constants for one NLP variant (uuv_ocp.solvers.rti.ClosedLoopEntry fills it once and owns
 * every array it points to).  Mirrored by the ctypes Structure rti_ocp.ClosedLoopSettings. */
typedef struct {
  double* p;                /* the instance: x0 at [0, nx), u_prev at [nx, nx + nu) (written by
                               the caller), the window at [window, window + rows nx) (written
                               here), every other entry a template written once */
  const double* low;        /* bounds of p[0 : nx + nu] (x0's plausibility bound, u_prev's box) */
  const double* high;
  double* out;              /* [w, lam_x, lam_g, info (10), control (nu), applied (nu)] */
  const int* index;         /* the first control's positions in w (nu) */
  const double* lower;      /* its box (scaled), then the physical scale and centre */
  const double* upper;
  const double* scale;
  const double* centre;
  const double* box_lower;  /* the applied control's box (physical) and rate step around u_prev */
  const double* box_upper;
  const double* rate;
  const int* slack;         /* the terminal slacks in w (nslack; 0: the hard NLP) */
  double slack_tol;
  double tol;
  double qp_tol;
  int nx, nu, heading, window, rows, nslack, max_iter;
} rti_closed_loop;

#define RTI_INFO_SIZE 10
#define RTI_TWO_PI 6.283185307179586 /* 2.0 * math.pi, the same double */

/* numpy's maximum and minimum of two doubles (numpy 2.4, every loop length): NaN in either
 * propagates, and a tie (-0.0 against 0.0) gives the second operand */
static inline double rti_np_max(double a, double b) { return (a > b || isnan(a)) ? a : b; }
static inline double rti_np_min(double a, double b) { return (a < b || isnan(a)) ? a : b; }

/* One closed-loop step of the common case (NMPC.step on a tracking problem with its resident
 * warm start; uuv_ocp.solvers.rti.ClosedLoopEntry): checks p[0 : nx + nu] against low/high
 * (NaN fails), writes the reference window (rows x nx, from `window`) into p and moves its
 * heading column to the branch of x0's heading (tracking._move_heading_branch's operations),
 * runs uuv_rti_resident_step in rti mode, and on success writes the first control (clipped to
 * its scaled box, then scale * z + centre: RtiSolver._c_plan's operations) and the applied
 * control (it projected on the box and the rate bound around u_prev: NMPC._admissible's).
 * Returns -2 when a check fails (nothing written but nothing run: the caller's general path
 * raises its ValueError), -1 with nothing resident, 1 when the step is not accepted (info
 * written, as uuv_rti_resident_step), else 16 + (every number of w, lam_x, lam_g, info and
 * control finite) + 2 (the plan needed the terminal relaxation: the largest slack above
 * slack_tol, as NlpSolver.relaxed). */
int uuv_rti_closed_loop_step(void* memory, const rti_closed_loop* s, const double* window) {
  rti_memory* m = (rti_memory*)memory;
  double* p = s->p;
  double *w = s->out, *lam_x = w + RTI_NW, *lam_g = lam_x + RTI_NW, *info = lam_g + RTI_NG;
  double *control = info + RTI_INFO_SIZE, *applied = control + s->nu, *column, turns, shift, v;
  volatile double product; /* no fused multiply-add: the same rounding as numpy's two steps */
  int i, n = s->nx + s->nu, finite = 1, relaxed = 0, nan_slack = 0;
  double largest = -INFINITY;
  if (!m->resident) return -1;
  for (i = 0; i < n; ++i)
    if (!(s->low[i] <= p[i] && p[i] <= s->high[i])) return -2;
  memcpy(p + s->window, window, sizeof(double) * s->rows * s->nx);
  /* _shift_heading: the multiple of 2 pi (Python's round: half to even) that brings the first
   * heading closest to x0's; a non-finite quotient propagates as it did through np.round */
  column = p + s->window + s->heading;
  turns = (p[s->heading] - column[0]) / RTI_TWO_PI;
  if (!isfinite(turns)) {
    for (i = 0; i < s->rows; ++i) column[i * s->nx] += turns;
  } else if ((turns = nearbyint(turns)) != 0.0) {
    product = RTI_TWO_PI * turns;
    shift = product;
    for (i = 0; i < s->rows; ++i) column[i * s->nx] += shift;
  }
  if (uuv_rti_resident_step(memory, p, s->max_iter, s->tol, s->qp_tol, 0, w, lam_x, lam_g, info))
    return 1;
  for (i = 0; i < s->nu; ++i) {
    v = w[s->index[i]];
    v = rti_np_max(v, s->lower[i]);
    v = rti_np_min(v, s->upper[i]);
    product = s->scale[i] * v;
    control[i] = s->centre[i] + product;
  }
  for (i = 0; i < 2 * RTI_NW + RTI_NG + RTI_INFO_SIZE + s->nu; ++i)
    if (!isfinite(w[i])) { finite = 0; break; }
  for (i = 0; i < s->nslack; ++i) {
    v = w[s->slack[i]];
    if (isnan(v)) nan_slack = 1;
    else if (v > largest) largest = v;
  }
  relaxed = s->nslack > 0 && !nan_slack && largest > s->slack_tol;
  /* NMPC._admissible with u_prev: low = max(lower, u_prev - step), high = max(low, min(upper,
   * u_prev + step)), min(max(control, low), high) */
  for (i = 0; i < s->nu; ++i) {
    double previous = p[s->nx + i], low, high;
    low = rti_np_max(s->box_lower[i], previous - s->rate[i]);
    high = rti_np_min(s->box_upper[i], previous + s->rate[i]);
    high = rti_np_max(low, high);
    applied[i] = rti_np_min(rti_np_max(control[i], low), high);
  }
  return 16 + finite + 2 * relaxed;
}
