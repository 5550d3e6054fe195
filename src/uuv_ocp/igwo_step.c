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
 * Random numbers are either an input array (draws[t][plane][wolf][dim], planes 0..5 for the
 * GWO moves, 6 and 7 for the memory terms) or drawn here, one iteration's block at a time, by
 * numpy's PCG64 (XSL-RR 128/64, doubles as (next >> 11) * 2^-53) from the Generator's state:
 * the same numbers `Generator.random` gives, in the same order, so the same seed gives the
 * same result as the Python implementation.  The schedules a(t), w(t) are inputs.
 * Compile with -ffp-contract=off.
 * ------------------------------------------------------------------------------------- */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

/* ---- numpy's PCG64 ------------------------------------------------------------------ */
typedef __uint128_t uuv_u128;
#define UUV_PCG_MULTIPLIER (((uuv_u128)2549297995355413924ULL << 64) | 4865540595714422341ULL)
#define UUV_PCG_CHAINS 4

typedef struct {
  uuv_u128 multiplier, increment; /* the affine map state -> multiplier * state + increment */
} uuv_pcg_jump;

/* The LCG advanced by `delta` steps, as one affine map (Brown, "Random number generation with
 * arbitrary strides", 1994; pcg_advance_lcg_128 of the PCG library). */
static uuv_pcg_jump uuv_pcg_jump_by(uint64_t delta, uuv_u128 inc) {
  uuv_u128 multiplier = UUV_PCG_MULTIPLIER, plus = inc, acc_mult = 1, acc_plus = 0;
  uuv_pcg_jump jump;
  while (delta > 0) {
    if (delta & 1) {
      acc_mult *= multiplier;
      acc_plus = acc_plus * multiplier + plus;
    }
    plus = (multiplier + 1) * plus;
    multiplier *= multiplier;
    delta >>= 1;
  }
  jump.multiplier = acc_mult;
  jump.increment = acc_plus;
  return jump;
}

static inline double uuv_pcg_output(uuv_u128 state) {
  const uint64_t folded = (uint64_t)(state >> 64) ^ (uint64_t)state;
  const unsigned rotation = (unsigned)(state >> 122);
  const uint64_t value = (folded >> rotation) | (folded << ((64 - rotation) & 63));
  return (double)(value >> 11) * (1.0 / 9007199254740992.0);
}

/* `count` doubles into `out`, advancing *state; UUV_PCG_CHAINS interleaved sub-streams, each
 * started by a jump, break the multiply's dependency chain (same numbers, same order). */
static void uuv_pcg_fill(uuv_u128* state, uuv_u128 inc, const uuv_pcg_jump* jumps, size_t segment,
                         double* out, size_t count) {
  uuv_u128 chain[UUV_PCG_CHAINS];
  size_t i;
  int c;
  for (c = 0; c < UUV_PCG_CHAINS; ++c) chain[c] = jumps[c].multiplier * *state + jumps[c].increment;
  if (segment * UUV_PCG_CHAINS == count) {
    for (i = 0; i < segment; ++i) {
      for (c = 0; c < UUV_PCG_CHAINS; ++c) {
        chain[c] = chain[c] * UUV_PCG_MULTIPLIER + inc;
        out[(size_t)c * segment + i] = uuv_pcg_output(chain[c]);
      }
    }
  } else {
    for (i = 0; i < segment; ++i) {
      for (c = 0; c < UUV_PCG_CHAINS; ++c) {
        const size_t index = (size_t)c * segment + i;
        chain[c] = chain[c] * UUV_PCG_MULTIPLIER + inc;
        if (index < count) out[index] = uuv_pcg_output(chain[c]);
      }
    }
  }
  *state = jumps[UUV_PCG_CHAINS].multiplier * *state + jumps[UUV_PCG_CHAINS].increment;
}

/* `count` draws of numpy's Generator(PCG64).random() from the state (hi, lo) and increment. */
/* One IGWO move of the whole pack into `next` (restrict: lets the compiler vectorise over j). */
static void uuv_ocp_igwo_move(const double* restrict positions, const double* restrict pbest,
                              const double* restrict leaders, const double* restrict block,
                              const double* restrict lower, const double* restrict upper,
                              double a, double twice_a, double inertia, double c1, double c2,
                              int n, int dim, double* restrict next) {
  const size_t plane = (size_t)n * dim;
  int i, j;
  for (i = 0; i < n; ++i) {
    const size_t row = (size_t)i * dim;
    for (j = 0; j < dim; ++j) {
      const size_t e = row + j;
      const double x = positions[e];
      const double alpha = leaders[j], beta = leaders[dim + j], delta = leaders[2 * dim + j];
      const double move_alpha = alpha - (twice_a * block[e] - a) * fabs(2.0 * block[plane + e] * alpha - x);
      const double move_beta =
          beta - (twice_a * block[2 * plane + e] - a) * fabs(2.0 * block[3 * plane + e] * beta - x);
      const double move_delta =
          delta - (twice_a * block[4 * plane + e] - a) * fabs(2.0 * block[5 * plane + e] * delta - x);
      const double grey = ((move_alpha + move_beta) + move_delta) / 3.0;
      double value = (inertia * grey + (c1 * block[6 * plane + e]) * (pbest[e] - x)) +
                     (c2 * block[7 * plane + e]) * (alpha - x);
      value = value > lower[j] ? value : lower[j]; /* np.clip: min(max(v, lo), hi) */
      value = value < upper[j] ? value : upper[j];
      next[e] = value;
    }
  }
}

CASADI_SYMBOL_EXPORT void uuv_ocp_pcg64_random(uint64_t state_hi, uint64_t state_lo, uint64_t inc_hi,
                                               uint64_t inc_lo, double* out, size_t count) {
  uuv_u128 state = ((uuv_u128)state_hi << 64) | state_lo, inc = ((uuv_u128)inc_hi << 64) | inc_lo;
  uuv_pcg_jump jumps[UUV_PCG_CHAINS + 1];
  const size_t segment = (count + UUV_PCG_CHAINS - 1) / UUV_PCG_CHAINS;
  int c;
  for (c = 0; c < UUV_PCG_CHAINS; ++c) jumps[c] = uuv_pcg_jump_by((uint64_t)c * segment, inc);
  jumps[UUV_PCG_CHAINS] = uuv_pcg_jump_by(count, inc);
  uuv_pcg_fill(&state, inc, jumps, segment, out, count);
}

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

/* draws != NULL: take the random numbers from it; else draw them with PCG64 from pcg[4] =
 * {state_hi, state_lo, inc_hi, inc_lo}, which is advanced in place. */
static int uuv_ocp_igwo_core(const double* p, const double* offset, const double* lower,
                             const double* upper, const double* positions0, const double* draws,
                             uint64_t* pcg, const double* a_schedule, const double* w_schedule,
                             double c1, double c2, int n, int dim, int iterations, double* best_x,
                             double* best_f, double* history, double* final_positions) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  double *positions, *next, *pbest, *pbest_cost, *costs, *candidates, leaders_cost[3], *leaders;
  double* drawn = NULL;
  const size_t block_size = (size_t)8 * n * dim;
  size_t segment = 0;
  uuv_u128 rng_state = 0, rng_inc = 0;
  uuv_pcg_jump jumps[UUV_PCG_CHAINS + 1];
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
  if (!draws) {
    drawn = (double*)malloc(sizeof(double) * block_size);
    rng_state = ((uuv_u128)pcg[0] << 64) | pcg[1];
    rng_inc = ((uuv_u128)pcg[2] << 64) | pcg[3];
    segment = (block_size + UUV_PCG_CHAINS - 1) / UUV_PCG_CHAINS;
    for (k = 0; k < UUV_PCG_CHAINS; ++k) jumps[k] = uuv_pcg_jump_by((uint64_t)k * segment, rng_inc);
    jumps[UUV_PCG_CHAINS] = uuv_pcg_jump_by(block_size, rng_inc);
  }

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
    const double* block = drawn;
    if (draws) {
      block = draws + (size_t)t * block_size;
    } else {
      uuv_pcg_fill(&rng_state, rng_inc, jumps, segment, drawn, block_size);
    }
    uuv_ocp_igwo_move(positions, pbest, leaders, block, lower, upper, a, twice_a, inertia, c1, c2,
                      n, dim, next);
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
  if (!draws) {
    pcg[0] = (uint64_t)(rng_state >> 64);
    pcg[1] = (uint64_t)rng_state;
  }
  free(arg); free(res); free(iw); free(w); free(positions); free(next); free(pbest);
  free(candidates); free(leaders); free(pbest_cost); free(costs); free(drawn);
  return status;
}

/* The IGWO run with the random numbers given: draws[iterations][8][n][dim]. */
CASADI_SYMBOL_EXPORT int uuv_ocp_igwo(const double* p, const double* offset, const double* lower,
                                      const double* upper, const double* positions0,
                                      const double* draws, const double* a_schedule,
                                      const double* w_schedule, double c1, double c2, int n,
                                      int dim, int iterations, double* best_x, double* best_f,
                                      double* history, double* final_positions) {
  return uuv_ocp_igwo_core(p, offset, lower, upper, positions0, draws, NULL, a_schedule,
                           w_schedule, c1, c2, n, dim, iterations, best_x, best_f, history,
                           final_positions);
}

/* The IGWO run drawing its random numbers like numpy's Generator(PCG64).random(): pcg[4] =
 * {state_hi, state_lo, inc_hi, inc_lo} on entry; the state after the draws on return. */
CASADI_SYMBOL_EXPORT int uuv_ocp_igwo_pcg64(const double* p, const double* offset,
                                            const double* lower, const double* upper,
                                            const double* positions0, uint64_t* pcg,
                                            const double* a_schedule, const double* w_schedule,
                                            double c1, double c2, int n, int dim, int iterations,
                                            double* best_x, double* best_f, double* history,
                                            double* final_positions) {
  return uuv_ocp_igwo_core(p, offset, lower, upper, positions0, NULL, pcg, a_schedule,
                           w_schedule, c1, c2, n, dim, iterations, best_x, best_f, history,
                           final_positions);
}
