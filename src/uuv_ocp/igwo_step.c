/* ---------------------------------------------------------------------------------------
 * uuv_ocp: the IGWO step of the paper (Electronics 2023, 12, 921, section 3.3.1) in C.
 *
 * Appended by uuv_ocp.codegen.generate_c to the CasADi-generated source, so it calls the
 * generated population cost `cost_batch` directly.  It mirrors uuv_ocp/solvers/swarm.py
 * (ImprovedGreyWolf, frame "origin") operation by operation:
 *   - leaders alpha, beta, delta: the three best of (previous leaders, new wolves), ties to
 *     the earlier entry (numpy's stable argsort);
 *   - X(t+1) = (w G + (c1 r1)(pbest - X)) + (c2 r2)(alpha - X),
 *     G = ((X1 + X2) + X3) / 3, X_k = L_k - (2a r - a) |2 r' L_k - X|;
 *   - positions clipped to [lower, upper]; personal bests replaced on strict improvement.
 * Random numbers and the schedules a(t), w(t) are inputs (draws[t][plane][wolf][dim], planes
 * 0..5 for the GWO moves, 6 and 7 for the memory terms), so the same draws give the same
 * result as the Python implementation.  Compile with -ffp-contract=off.
 * ------------------------------------------------------------------------------------- */
#include <math.h>
#include <stdlib.h>

static int uuv_ocp_fitness(const double* p, const double* offset, const double* positions,
                           int n, int dim, double* candidates, double* costs,
                           const casadi_real** arg, casadi_real** res, casadi_int* iw,
                           casadi_real* w) {
  int i, j;
  for (i = 0; i < n; ++i)
    for (j = 0; j < dim; ++j) candidates[i * dim + j] = positions[i * dim + j] + offset[j];
  arg[0] = candidates;
  arg[1] = p;
  res[0] = costs;
  if (cost_batch(arg, res, iw, w, 0)) return 1;
  for (i = 0; i < n; ++i)
    if (!isfinite(costs[i])) costs[i] = INFINITY;
  return 0;
}

/* Keep the three best (cost, row) pairs, stable: a later entry must be strictly better. */
static void uuv_ocp_offer(double cost, const double* row, int dim, double* top_cost,
                          double* top_rows, int* count) {
  int slot, k, j;
  if (*count == 3 && !(cost < top_cost[2])) return;
  slot = *count < 3 ? *count : 2;
  while (slot > 0 && cost < top_cost[slot - 1]) slot--;
  for (k = (*count < 3 ? *count : 2); k > slot; --k) {
    top_cost[k] = top_cost[k - 1];
    for (j = 0; j < dim; ++j) top_rows[k * dim + j] = top_rows[(k - 1) * dim + j];
  }
  top_cost[slot] = cost;
  for (j = 0; j < dim; ++j) top_rows[slot * dim + j] = row[j];
  if (*count < 3) (*count)++;
}

static void uuv_ocp_leaders(const double* costs, const double* positions, int n, int dim,
                            double* leader_cost, double* leaders, int* count) {
  double pool_cost[3];
  double* pool_rows;
  int k, i, pooled = 0;
  pool_rows = (double*)malloc(sizeof(double) * 3 * dim);
  for (k = 0; k < *count; ++k)
    uuv_ocp_offer(leader_cost[k], leaders + k * dim, dim, pool_cost, pool_rows, &pooled);
  for (i = 0; i < n; ++i)
    uuv_ocp_offer(costs[i], positions + i * dim, dim, pool_cost, pool_rows, &pooled);
  for (k = 0; k < pooled; ++k) {
    leader_cost[k] = pool_cost[k];
    for (i = 0; i < dim; ++i) leaders[k * dim + i] = pool_rows[k * dim + i];
  }
  *count = pooled;
  free(pool_rows);
}

CASADI_SYMBOL_EXPORT int uuv_ocp_igwo(const double* p, const double* offset, const double* lower,
                                      const double* upper, const double* positions0,
                                      const double* draws, const double* a_schedule,
                                      const double* w_schedule, double c1, double c2, int n,
                                      int dim, int iterations, double* best_x, double* best_f,
                                      double* history, double* final_positions) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  double *positions, *next, *pbest, *pbest_cost, *costs, *candidates, leaders_cost[3], *leaders;
  int count = 0, status = 0, t, i, j, k, best_index;
  cost_batch_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = (const casadi_real**)malloc(sizeof(casadi_real*) * (sz_arg > 2 ? sz_arg : 2));
  res = (casadi_real**)malloc(sizeof(casadi_real*) * (sz_res > 1 ? sz_res : 1));
  iw = (casadi_int*)malloc(sizeof(casadi_int) * (sz_iw > 0 ? sz_iw : 1));
  w = (casadi_real*)malloc(sizeof(casadi_real) * (sz_w > 0 ? sz_w : 1));
  positions = (double*)malloc(sizeof(double) * n * dim);
  next = (double*)malloc(sizeof(double) * n * dim);
  pbest = (double*)malloc(sizeof(double) * n * dim);
  candidates = (double*)malloc(sizeof(double) * n * dim);
  leaders = (double*)malloc(sizeof(double) * 3 * dim);
  pbest_cost = (double*)malloc(sizeof(double) * n);
  costs = (double*)malloc(sizeof(double) * n);

  for (i = 0; i < n * dim; ++i) positions[i] = positions0[i];
  if (uuv_ocp_fitness(p, offset, positions, n, dim, candidates, costs, arg, res, iw, w)) {
    status = 1;
    goto cleanup;
  }
  uuv_ocp_leaders(costs, positions, n, dim, leaders_cost, leaders, &count);
  for (i = 0; i < n * dim; ++i) pbest[i] = positions[i];
  for (i = 0; i < n; ++i) pbest_cost[i] = costs[i];
  best_index = 0;
  for (i = 1; i < n; ++i)
    if (costs[i] < costs[best_index]) best_index = i;
  *best_f = costs[best_index];
  for (j = 0; j < dim; ++j) best_x[j] = positions[best_index * dim + j];
  history[0] = *best_f;

  for (t = 0; t < iterations; ++t) {
    const double a = a_schedule[t], inertia = w_schedule[t], twice_a = 2.0 * a;
    const double* block = draws + (size_t)t * 8 * n * dim;
    for (i = 0; i < n; ++i) {
      for (j = 0; j < dim; ++j) {
        const size_t e = (size_t)i * dim + j, plane = (size_t)n * dim;
        const double x = positions[e];
        double moves[3], grey, value;
        for (k = 0; k < 3; ++k) {
          const double leader = leaders[k * dim + j];
          const double A = twice_a * block[(2 * k) * plane + e] - a;
          const double C = 2.0 * block[(2 * k + 1) * plane + e];
          moves[k] = leader - A * fabs(C * leader - x);
        }
        grey = ((moves[0] + moves[1]) + moves[2]) / 3.0;
        value = (inertia * grey + (c1 * block[6 * plane + e]) * (pbest[e] - x)) +
                (c2 * block[7 * plane + e]) * (leaders[j] - x);
        value = value > lower[j] ? value : lower[j];  /* np.clip: min(max(v, lo), hi) */
        value = value < upper[j] ? value : upper[j];
        next[e] = value;
      }
    }
    for (i = 0; i < n * dim; ++i) positions[i] = next[i];
    if (uuv_ocp_fitness(p, offset, positions, n, dim, candidates, costs, arg, res, iw, w)) {
      status = 1;
      goto cleanup;
    }
    uuv_ocp_leaders(costs, positions, n, dim, leaders_cost, leaders, &count);
    for (i = 0; i < n; ++i) {
      if (costs[i] < pbest_cost[i]) {
        pbest_cost[i] = costs[i];
        for (j = 0; j < dim; ++j) pbest[i * dim + j] = positions[i * dim + j];
      }
    }
    best_index = 0;
    for (i = 1; i < n; ++i)
      if (costs[i] < costs[best_index]) best_index = i;
    if (costs[best_index] < *best_f) {
      *best_f = costs[best_index];
      for (j = 0; j < dim; ++j) best_x[j] = positions[best_index * dim + j];
    }
    history[t + 1] = *best_f;
  }
  for (i = 0; i < n * dim; ++i) final_positions[i] = positions[i];

cleanup:
  free(arg); free(res); free(iw); free(w); free(positions); free(next); free(pbest);
  free(candidates); free(leaders); free(pbest_cost); free(costs);
  return status;
}
