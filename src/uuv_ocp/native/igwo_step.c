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
 * same result as the Python implementation run on the same compiled `cost_batch` (the SIMD
 * kernel's sin/cos may differ from libm's in the last bits, so against the Python IGWO on
 * CasADi's virtual machine the agreement is to that rounding).  The schedules a(t), w(t) are
 * inputs.
 * Compile with -ffp-contract=off.
 * ------------------------------------------------------------------------------------- */
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#if defined(__AVX512IFMA__) && defined(__AVX512DQ__) && defined(__x86_64__)
#include <immintrin.h>
#define UUV_PCG_IFMA 1 /* eight draws per vector step: see uuv_pcg_run_ifma */
#else
#define UUV_PCG_IFMA 0
#endif

/* ---- numpy's PCG64 ------------------------------------------------------------------ */
typedef __uint128_t uuv_u128;
#define UUV_PCG_MULTIPLIER (((uuv_u128)2549297995355413924ULL << 64) | 4865540595714422341ULL)
#define UUV_PCG_SEGMENTS 16  /* a block of draws = 16 jump-started segments */
#define UUV_PCG_INTERLEAVE 4 /* segments advanced together: independent multiply chains */

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

static inline uuv_u128 uuv_pcg_apply(uuv_pcg_jump jump, uuv_u128 state) {
  return jump.multiplier * state + jump.increment;
}

/* Segments [first, last) of the `count` numbers that follow `state`: segment k holds numbers
 * k * segment ... (k + 1) * segment - 1, started by jumps[k] (jumps[k] = advance by
 * k * segment).  UUV_PCG_INTERLEAVE segments are advanced together, breaking the multiply's
 * dependency chain; the numbers and their order are exactly the sequential ones. */
static inline void uuv_pcg_run(uuv_u128* chain, int width, uuv_u128 inc, size_t segment,
                               double* out) {
  size_t i;
  int c;
  for (i = 0; i < segment; ++i) {
    for (c = 0; c < width; ++c) {
      chain[c] = chain[c] * UUV_PCG_MULTIPLIER + inc;
      out[(size_t)c * segment + i] = uuv_pcg_output(chain[c]);
    }
  }
}

#if UUV_PCG_IFMA
/* The same segments eight numbers per step with AVX-512 IFMA (52-bit multiply-add), about 2.5x
 * the scalar throughput, whose three 64-bit multiplications per number saturate the one
 * multiplier port.  Lane l of a chain's vector holds the state of number 8 i + l and steps by
 * `jump8` (the LCG advanced by 8): the eight outputs of a step are consecutive, one store.  The
 * 128-bit state is three 52-bit limbs (52 + 52 + 24 bits); only the products below 2^128 are
 * formed.  Integer arithmetic throughout: the numbers are bit for bit the scalar ones. */
typedef struct {
  __m512i l0, l1, l2;
} uuv_pcg_limbs;

static inline uuv_pcg_limbs uuv_pcg_broadcast(uuv_u128 value) {
  uuv_pcg_limbs out;
  out.l0 = _mm512_set1_epi64((long long)((uint64_t)value & 0xFFFFFFFFFFFFFULL));
  out.l1 = _mm512_set1_epi64((long long)((uint64_t)(value >> 52) & 0xFFFFFFFFFFFFFULL));
  out.l2 = _mm512_set1_epi64((long long)(uint64_t)(value >> 104));
  return out;
}

static inline uuv_u128 uuv_pcg_lane(const uuv_pcg_limbs* state, int lane) {
  uint64_t l0[8], l1[8], l2[8];
  _mm512_storeu_si512((void*)l0, state->l0);
  _mm512_storeu_si512((void*)l1, state->l1);
  _mm512_storeu_si512((void*)l2, state->l2);
  return (uuv_u128)l0[lane] | ((uuv_u128)l1[lane] << 52) | ((uuv_u128)l2[lane] << 104);
}

/* state -> multiplier * state + increment (mod 2^128), limb by limb with the carries. */
static inline uuv_pcg_limbs uuv_pcg_step8(uuv_pcg_limbs s, const uuv_pcg_limbs* m,
                                          const uuv_pcg_limbs* c) {
  const __m512i mask52 = _mm512_set1_epi64(0xFFFFFFFFFFFFFLL), mask24 = _mm512_set1_epi64(0xFFFFFF);
  __m512i r0 = _mm512_madd52lo_epu64(c->l0, s.l0, m->l0);
  __m512i r1 = _mm512_madd52hi_epu64(c->l1, s.l0, m->l0);
  __m512i r2 = _mm512_madd52hi_epu64(c->l2, s.l0, m->l1);
  __m512i r1b = _mm512_madd52lo_epu64(_mm512_setzero_si512(), s.l1, m->l0);
  __m512i r2b = _mm512_madd52hi_epu64(_mm512_setzero_si512(), s.l1, m->l0);
  uuv_pcg_limbs out;
  r1 = _mm512_madd52lo_epu64(r1, s.l0, m->l1);
  r2 = _mm512_madd52lo_epu64(r2, s.l0, m->l2);
  r2b = _mm512_madd52lo_epu64(r2b, s.l1, m->l1);
  r2 = _mm512_madd52lo_epu64(r2, s.l2, m->l0);
  r1 = _mm512_add_epi64(_mm512_add_epi64(r1, r1b), _mm512_srli_epi64(r0, 52));
  r2 = _mm512_add_epi64(_mm512_add_epi64(r2, r2b), _mm512_srli_epi64(r1, 52));
  out.l0 = _mm512_and_si512(r0, mask52);
  out.l1 = _mm512_and_si512(r1, mask52);
  out.l2 = _mm512_and_si512(r2, mask24);
  return out;
}

/* uuv_pcg_output of each lane: XSL-RR, then (value >> 11) * 2^-53 (exact conversion). */
static inline __m512d uuv_pcg_output8(uuv_pcg_limbs s) {
  const __m512i low = _mm512_or_si512(s.l0, _mm512_slli_epi64(s.l1, 52));
  const __m512i high = _mm512_or_si512(_mm512_srli_epi64(s.l1, 12), _mm512_slli_epi64(s.l2, 40));
  const __m512i value = _mm512_rorv_epi64(_mm512_xor_si512(low, high), _mm512_srli_epi64(s.l2, 18));
  return _mm512_mul_pd(_mm512_cvtepi64_pd(_mm512_srli_epi64(value, 11)),
                       _mm512_set1_pd(1.0 / 9007199254740992.0));
}

static inline void uuv_pcg_run_ifma(uuv_u128* chain, int width, uuv_u128 inc, uuv_pcg_jump jump8,
                                    size_t segment, double* out) {
  uuv_pcg_limbs lanes[UUV_PCG_INTERLEAVE];
  const uuv_pcg_limbs m = uuv_pcg_broadcast(jump8.multiplier), c = uuv_pcg_broadcast(jump8.increment);
  const size_t steps = segment / 8;
  size_t i;
  int k, l;
  for (k = 0; k < width; ++k) { /* lane l: the state of number l (l + 1 steps on) */
    uint64_t l0[8], l1[8], l2[8];
    uuv_u128 s = chain[k];
    for (l = 0; l < 8; ++l) {
      s = s * UUV_PCG_MULTIPLIER + inc;
      l0[l] = (uint64_t)s & 0xFFFFFFFFFFFFFULL;
      l1[l] = (uint64_t)(s >> 52) & 0xFFFFFFFFFFFFFULL;
      l2[l] = (uint64_t)(s >> 104);
    }
    lanes[k].l0 = _mm512_loadu_si512((const void*)l0);
    lanes[k].l1 = _mm512_loadu_si512((const void*)l1);
    lanes[k].l2 = _mm512_loadu_si512((const void*)l2);
  }
  for (i = 0; i < steps; ++i) {
    for (k = 0; k < width; ++k) {
      _mm512_storeu_pd(out + (size_t)k * segment + 8 * i, uuv_pcg_output8(lanes[k]));
      lanes[k] = uuv_pcg_step8(lanes[k], &m, &c);
    }
  }
  for (k = 0; k < width; ++k) { /* the tail of a segment that is not a multiple of 8, scalar */
    uuv_u128 s = uuv_pcg_lane(&lanes[k], 0);
    for (i = 8 * steps; i < segment; ++i) {
      out[(size_t)k * segment + i] = uuv_pcg_output(s);
      s = s * UUV_PCG_MULTIPLIER + inc;
    }
  }
}
#endif

static void uuv_pcg_fill(uuv_u128 state, uuv_u128 inc, const uuv_pcg_jump* jumps, size_t segment,
                         double* out, size_t count, int first, int last) {
  uuv_u128 chain[UUV_PCG_INTERLEAVE];
  size_t i, start;
  int group, width, c;
  for (group = first; group < last; group += UUV_PCG_INTERLEAVE) {
    width = last - group < UUV_PCG_INTERLEAVE ? last - group : UUV_PCG_INTERLEAVE;
    start = (size_t)group * segment;
    for (c = 0; c < width; ++c) chain[c] = uuv_pcg_apply(jumps[group + c], state);
    if (start + (size_t)width * segment <= count) {
#if UUV_PCG_IFMA
      uuv_pcg_run_ifma(chain, width, inc, jumps[UUV_PCG_SEGMENTS + 1], segment, out + start);
#else
      /* constant widths: the compiler keeps the chains in registers */
      switch (width) {
        case 4: uuv_pcg_run(chain, 4, inc, segment, out + start); break;
        case 3: uuv_pcg_run(chain, 3, inc, segment, out + start); break;
        case 2: uuv_pcg_run(chain, 2, inc, segment, out + start); break;
        default: uuv_pcg_run(chain, 1, inc, segment, out + start); break;
      }
#endif
    } else {
      for (i = 0; i < segment; ++i) {
        for (c = 0; c < width; ++c) {
          const size_t index = start + (size_t)c * segment + i;
          chain[c] = chain[c] * UUV_PCG_MULTIPLIER + inc;
          if (index < count) out[index] = uuv_pcg_output(chain[c]);
        }
      }
    }
  }
}

/* jumps[k] = advance by k * segment (k < UUV_PCG_SEGMENTS), jumps[UUV_PCG_SEGMENTS] = by count,
 * jumps[UUV_PCG_SEGMENTS + 1] = by 8 (the vector step of uuv_pcg_run_ifma). */
static size_t uuv_pcg_jumps(uuv_u128 inc, size_t count, uuv_pcg_jump* jumps) {
  const size_t segment = (count + UUV_PCG_SEGMENTS - 1) / UUV_PCG_SEGMENTS;
  int k;
  for (k = 0; k < UUV_PCG_SEGMENTS; ++k) jumps[k] = uuv_pcg_jump_by((uint64_t)k * segment, inc);
  jumps[UUV_PCG_SEGMENTS] = uuv_pcg_jump_by(count, inc);
  jumps[UUV_PCG_SEGMENTS + 1] = uuv_pcg_jump_by(8, inc);
  return segment;
}

/* Numbers per step of the PCG64 draws in this build: 8 with AVX-512 IFMA, else 1.  The solver
 * keeps the step on one thread by default when 8: the draws then cost less than the worker's
 * blocks take to cross to the step's core (docs/codegen.md). */
CASADI_SYMBOL_EXPORT int uuv_ocp_pcg64_lanes(void) { return UUV_PCG_IFMA ? 8 : 1; }

/* `count` draws of numpy's Generator(PCG64).random() from the state (hi, lo) and increment. */
CASADI_SYMBOL_EXPORT void uuv_ocp_pcg64_random(uint64_t state_hi, uint64_t state_lo, uint64_t inc_hi,
                                               uint64_t inc_lo, double* out, size_t count) {
  const uuv_u128 state = ((uuv_u128)state_hi << 64) | state_lo;
  const uuv_u128 inc = ((uuv_u128)inc_hi << 64) | inc_lo;
  uuv_pcg_jump jumps[UUV_PCG_SEGMENTS + 2];
  const size_t segment = uuv_pcg_jumps(inc, count, jumps);
  uuv_pcg_fill(state, inc, jumps, segment, out, count, 0, UUV_PCG_SEGMENTS);
}

/* The IGWO's random numbers, one iteration's block at a time, shared between the step's thread
 * and (rng_thread) a worker on another CPU.  Each block is split into UUV_PCG_GROUPS groups of
 * UUV_PCG_INTERLEAVE jump-started segments; either thread claims a group with a compare-and-swap
 * on its flag and draws it, so no group is drawn twice and neither thread waits for work the
 * other has not started.  The worker runs up to UUV_PCG_RING blocks ahead into a ring of
 * buffers (started before the first fitness evaluation, it usually delivers every block); the
 * step's thread, when it needs block t, draws the groups still free itself and waits only for
 * groups the worker is drawing at that moment (a few microseconds).  A worker that holds a
 * group longer than the stream's patience (descheduled by the operating system) is left
 * behind: the step draws that block and every later one alone into its own buffer, which the
 * worker never touches.  Each thread advances its own copy of the generator state by one
 * block per block: the same numbers in the same order, whoever draws them.
 * rng_thread: 0 one thread; 1 a worker; for tests: 2 a worker whose groups are never used
 * (the step's thread draws every block), 3 the step's thread draws the odd blocks and waits
 * for the worker's even ones however long it takes. */
#define UUV_PCG_RING 4 /* blocks the worker may run ahead: 4 x 77 kB for a 20 x 60 pack */
#define UUV_PCG_GROUPS (UUV_PCG_SEGMENTS / UUV_PCG_INTERLEAVE)
enum { UUV_GROUP_FREE = 0, UUV_GROUP_WORKER = 1, UUV_GROUP_DONE = 2, UUV_GROUP_STEP = 3 };

typedef struct {
  uuv_u128 state, worker_state, inc; /* state: the step's, at the start of its next block */
  uuv_pcg_jump jumps[UUV_PCG_SEGMENTS + 2];
  size_t segment, block_size;
  double* ring; /* UUV_PCG_RING blocks: block t in slot t % UUV_PCG_RING */
  double* own;  /* the step thread's block: test modes and after a worker was left behind */
  atomic_int* claims; /* blocks x UUV_PCG_GROUPS flags UUV_GROUP_* */
  int blocks, threaded, test_mode, solo, late;
  double patience; /* s: how long the step waits for a group the worker is drawing */
  pthread_t worker;
  atomic_int consumed, stop;
} uuv_pcg_stream;

static inline void uuv_pause(void) {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#elif defined(__aarch64__)
  __asm__ __volatile__("yield");
#endif
}

static void uuv_wait(int spins) {
  if (spins < 1000) {
    uuv_pause();
  } else {
    sched_yield();
  }
}

static double uuv_seconds(void) {
  struct timespec now;
  clock_gettime(CLOCK_MONOTONIC, &now);
  return (double)now.tv_sec + 1e-9 * (double)now.tv_nsec;
}

static int uuv_pcg_claim(uuv_pcg_stream* stream, int t, int group, int who) {
  int expected = UUV_GROUP_FREE;
  return atomic_compare_exchange_strong_explicit(&stream->claims[t * UUV_PCG_GROUPS + group],
                                                 &expected, who, memory_order_acq_rel,
                                                 memory_order_acquire);
}

static inline void uuv_pcg_group(const uuv_pcg_stream* stream, uuv_u128 state, int group,
                                 double* block) {
  uuv_pcg_fill(state, stream->inc, stream->jumps, stream->segment, block, stream->block_size,
               group * UUV_PCG_INTERLEAVE, (group + 1) * UUV_PCG_INTERLEAVE);
}

static void* uuv_pcg_worker(void* argument) {
  uuv_pcg_stream* stream = (uuv_pcg_stream*)argument;
  uuv_u128 state = stream->worker_state; /* block 0's */
  int t, group, spins;
  for (t = 0; t < stream->blocks; ++t) {
    double* block = stream->ring + (size_t)(t % UUV_PCG_RING) * stream->block_size;
    /* slot t % RING is free once the step has released block t - RING */
    for (spins = 0;
         t >= atomic_load_explicit(&stream->consumed, memory_order_acquire) + UUV_PCG_RING;
         ++spins) {
      if (atomic_load_explicit(&stream->stop, memory_order_relaxed)) return NULL;
      uuv_wait(spins);
    }
    for (group = 0; group < UUV_PCG_GROUPS; ++group) {
      if (atomic_load_explicit(&stream->stop, memory_order_relaxed)) return NULL;
      if (uuv_pcg_claim(stream, t, group, UUV_GROUP_WORKER)) {
        uuv_pcg_group(stream, state, group, block);
        atomic_store_explicit(&stream->claims[t * UUV_PCG_GROUPS + group], UUV_GROUP_DONE,
                              memory_order_release);
      }
    }
    state = uuv_pcg_apply(stream->jumps[UUV_PCG_SEGMENTS], state);
  }
  return NULL;
}

/* Start the worker on another CPU than this thread's: a new thread starts on its parent's CPU,
 * where it would only take turns with the step's own thread. */
static int uuv_start_worker(uuv_pcg_stream* stream) {
  pthread_attr_t attributes;
  int started, placed = 0;
#if defined(__linux__) && defined(_GNU_SOURCE) /* codegen compiles with -D_GNU_SOURCE */
  cpu_set_t allowed;
  const int here = sched_getcpu();
  if (here >= 0 && sched_getaffinity(0, sizeof(allowed), &allowed) == 0) {
    CPU_CLR(here, &allowed);
    placed = CPU_COUNT(&allowed) > 0;
  }
#endif
  if (pthread_attr_init(&attributes) != 0) return 0;
#if defined(__linux__) && defined(_GNU_SOURCE)
  if (placed) pthread_attr_setaffinity_np(&attributes, sizeof(allowed), &allowed);
#endif
  started = pthread_create(&stream->worker, &attributes, uuv_pcg_worker, stream) == 0;
  pthread_attr_destroy(&attributes);
  return started;
}

static int uuv_pcg_stream_open(uuv_pcg_stream* stream, const uint64_t* pcg, size_t block_size,
                               int blocks, int rng_thread) {
  const int wanted = rng_thread != 0 && blocks > 1;
  int k;
  stream->state = ((uuv_u128)pcg[0] << 64) | pcg[1];
  stream->worker_state = stream->state;
  stream->inc = ((uuv_u128)pcg[2] << 64) | pcg[3];
  stream->block_size = block_size;
  stream->segment = uuv_pcg_jumps(stream->inc, block_size, stream->jumps);
  stream->blocks = blocks;
  stream->test_mode = rng_thread == 2 || rng_thread == 3 ? rng_thread : 0;
  stream->solo = 0;
  stream->late = 0;
  stream->patience = 20e-6;
  stream->ring = NULL;
  stream->claims = NULL;
  stream->threaded = 0;
  stream->own = (double*)malloc(sizeof(double) * block_size);
  if (stream->own == NULL) return 1;
  if (wanted) {
    stream->ring = (double*)malloc(sizeof(double) * block_size * UUV_PCG_RING);
    stream->claims = (atomic_int*)malloc(sizeof(atomic_int) * (size_t)blocks * UUV_PCG_GROUPS);
    if (stream->ring == NULL || stream->claims == NULL) {
      free(stream->own);
      free(stream->ring);
      free(stream->claims);
      return 1;
    }
    for (k = 0; k < blocks * UUV_PCG_GROUPS; ++k) atomic_init(&stream->claims[k], UUV_GROUP_FREE);
  }
  atomic_init(&stream->consumed, 0);
  atomic_init(&stream->stop, 0);
  stream->threaded = wanted && uuv_start_worker(stream);
  return 0;
}

/* Wait until the worker has drawn group `group` of block t: 1, or 0 after the stream's
 * patience (never in test mode 3, which waits however long it takes). */
static int uuv_pcg_stream_wait(uuv_pcg_stream* stream, int t, int group) {
  const atomic_int* flag = &stream->claims[t * UUV_PCG_GROUPS + group];
  double deadline = 0.0;
  int spins;
  int state;
  /* FREE only in test mode 3, where the step claims nothing of the blocks it waits for */
  for (spins = 0; (state = atomic_load_explicit(flag, memory_order_acquire)) != UUV_GROUP_DONE &&
                  state != UUV_GROUP_STEP;
       ++spins) {
    /* a clock read costs ~25 ns: look at it now and then */
    if ((spins & 31) == 31 && stream->test_mode == 0) {
      const double now = uuv_seconds();
      if (deadline == 0.0) deadline = now + stream->patience;
      else if (now > deadline) return 0;
    }
    uuv_pause();
  }
  return 1;
}

/* Block t, drawn by whichever thread got to each group first. */
static const double* uuv_pcg_stream_take(uuv_pcg_stream* stream, int t) {
  const uuv_u128 state = stream->state;
  double* block;
  int group, mine = 0;
  stream->state = uuv_pcg_apply(stream->jumps[UUV_PCG_SEGMENTS], state);
  if (stream->threaded && !stream->solo &&
      !(stream->test_mode == 2 || (stream->test_mode == 3 && (t & 1)))) {
    block = stream->ring + (size_t)(t % UUV_PCG_RING) * stream->block_size;
    for (group = 0; group < UUV_PCG_GROUPS && stream->test_mode != 3; ++group) {
      if (uuv_pcg_claim(stream, t, group, UUV_GROUP_STEP)) {
        const double started = mine ? 0.0 : uuv_seconds();
        uuv_pcg_group(stream, state, group, block);
        /* the first group drawn here sets the patience: about two block-times */
        if (!mine) {
          const double wait = 2.0 * UUV_PCG_GROUPS * (uuv_seconds() - started);
          if (wait > stream->patience) stream->patience = wait;
        }
        mine = 1;
      }
    }
    for (group = 0; group < UUV_PCG_GROUPS; ++group) {
      if (!uuv_pcg_stream_wait(stream, t, group)) { /* the worker is descheduled: go alone */
        stream->solo = 1;
        atomic_store_explicit(&stream->stop, 1, memory_order_relaxed);
        break;
      }
    }
    if (!stream->solo) {
      if (mine && t > 0) stream->late += 1;
      return block;
    }
  }
  if (stream->threaded) {
    /* the worker skips the groups claimed here; a block drawn here after block 0 is late */
    for (group = 0; group < UUV_PCG_GROUPS; ++group) uuv_pcg_claim(stream, t, group, UUV_GROUP_STEP);
    if (t > 0) stream->late += 1;
  }
  uuv_pcg_fill(state, stream->inc, stream->jumps, stream->segment, stream->own, stream->block_size,
               0, UUV_PCG_SEGMENTS);
  return stream->own;
}

/* Block t is no longer read: its ring slot may be refilled. */
static void uuv_pcg_stream_release(uuv_pcg_stream* stream, int t) {
  if (stream->threaded) atomic_store_explicit(&stream->consumed, t + 1, memory_order_release);
}

/* Stop the worker and write the generator's state after the blocks taken back to pcg[0..1];
 * pcg[4] = the number of blocks after the first that the step's thread drew (partly) itself
 * because the worker was late. */
static void uuv_pcg_stream_close(uuv_pcg_stream* stream, uint64_t* pcg) {
  if (stream->threaded) {
    atomic_store_explicit(&stream->stop, 1, memory_order_relaxed);
    pthread_join(stream->worker, NULL);
  }
  pcg[0] = (uint64_t)(stream->state >> 64);
  pcg[1] = (uint64_t)stream->state;
  pcg[4] = (uint64_t)stream->late;
  free(stream->own);
  free(stream->ring);
  free(stream->claims);
  stream->own = stream->ring = NULL;
  stream->claims = NULL;
}

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

/* draws != NULL: take the random numbers from it; else draw them with PCG64 from pcg[0..3] =
 * {state_hi, state_lo, inc_hi, inc_lo}, which is advanced in place, on a second thread if
 * rng_thread (pcg[4] then counts the blocks it was late for, see uuv_pcg_stream). */
static int uuv_ocp_igwo_core(const double* p, const double* offset, const double* lower,
                             const double* upper, const double* positions0, const double* draws,
                             uint64_t* pcg, int rng_thread, const double* a_schedule,
                             const double* w_schedule,
                             double c1, double c2, int n, int dim, int iterations, double* best_x,
                             double* best_f, double* history, double* final_positions) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  double *positions, *next, *pbest, *pbest_cost, *costs, *candidates, leaders_cost[3], *leaders;
  const size_t block_size = (size_t)8 * n * dim;
  uuv_pcg_stream stream;
  int drawing = 0; /* the stream is open (closed in cleanup) */
  int count = 0, status = 0, t, i, j, best_index;
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
  if (!arg || !res || !iw || !w || !positions || !next || !pbest || !candidates || !leaders ||
      !pbest_cost || !costs) {
    status = 2; /* out of memory */
    goto cleanup;
  }
  if (!draws) {
    if (uuv_pcg_stream_open(&stream, pcg, block_size, iterations, rng_thread)) {
      status = 2;
      goto cleanup;
    }
    drawing = 1;
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
    const double* block = draws ? draws + (size_t)t * block_size : uuv_pcg_stream_take(&stream, t);
    uuv_ocp_igwo_move(positions, pbest, leaders, block, lower, upper, a, twice_a, inertia, c1, c2,
                      n, dim, next);
    if (!draws) uuv_pcg_stream_release(&stream, t);
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
  if (final_positions)
    for (i = 0; i < n * dim; ++i) final_positions[i] = positions[i];

cleanup:
  if (drawing) uuv_pcg_stream_close(&stream, pcg);
  free(arg); free(res); free(iw); free(w); free(positions); free(next); free(pbest);
  free(candidates); free(leaders); free(pbest_cost); free(costs);
  return status;
}

/* The IGWO run with the random numbers given: draws[iterations][8][n][dim]. */
CASADI_SYMBOL_EXPORT int uuv_ocp_igwo(const double* p, const double* offset, const double* lower,
                                      const double* upper, const double* positions0,
                                      const double* draws, const double* a_schedule,
                                      const double* w_schedule, double c1, double c2, int n,
                                      int dim, int iterations, double* best_x, double* best_f,
                                      double* history, double* final_positions) {
  return uuv_ocp_igwo_core(p, offset, lower, upper, positions0, draws, NULL, 0, a_schedule,
                           w_schedule, c1, c2, n, dim, iterations, best_x, best_f, history,
                           final_positions);
}

/* The IGWO run drawing its random numbers like numpy's Generator(PCG64).random(): pcg[0..3] =
 * {state_hi, state_lo, inc_hi, inc_lo} on entry; the state after the draws on return.  With
 * rng_thread != 0 the numbers are drawn on a second thread, one iteration ahead; pcg[4] on
 * return counts the blocks that thread was late for (drawn by the step's own thread). */
CASADI_SYMBOL_EXPORT int uuv_ocp_igwo_pcg64(const double* p, const double* offset,
                                            const double* lower, const double* upper,
                                            const double* positions0, uint64_t* pcg, int rng_thread,
                                            const double* a_schedule, const double* w_schedule,
                                            double c1, double c2, int n, int dim, int iterations,
                                            double* best_x, double* best_f, double* history,
                                            double* final_positions) {
  return uuv_ocp_igwo_core(p, offset, lower, upper, positions0, NULL, pcg, rng_thread, a_schedule,
                           w_schedule, c1, c2, n, dim, iterations, best_x, best_f, history,
                           final_positions);
}

/* ---- The whole default solve in one call: uuv_ocp_igwo_solve ----------------------------
 * What SwarmSolver.solve does around the step, for a numpy Generator on PCG64: the uniform
 * initial wolves (Generator.random((n - seeded, dim)) then lower + u * width), the step, and
 * the finish of the best point (np.clip(x + offset, box) -> decode -> score_terms, rollout),
 * each as the Python path computes it (the same generated functions, the same operations),
 * so the outputs are bit for bit those of the Python around the step, at ~1/5 of its time. */
typedef int (*uuv_ocp_eval)(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                            casadi_real* w, int mem);
typedef int (*uuv_ocp_work)(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw,
                            casadi_int* sz_w);

/* A solver's constants (NativeIgwo's IgwoSetup mirrors it field by field). */
typedef struct uuv_ocp_igwo_setup {
  const double* a_schedule; /* a(t), w(t): iterations each */
  const double* w_schedule;
  const double* box_lower; /* the decode box the best point + offset is clipped into (dim) */
  const double* box_upper;
  double c1, c2;
  int n, dim, iterations;
  int states_size;    /* nonzeros of rollout's output */
  int score_sizes[5]; /* nonzeros of score_terms' five outputs */
  uuv_ocp_eval decode, score_terms, rollout; /* NULL decode: no finish */
  uuv_ocp_work decode_work, score_terms_work, rollout_work;
  /* the search box of a warm start (uuv_ocp_igwo_solve_warm), as SwarmSolver and encode make it */
  int horizon, nu, u_prev;    /* N, controls per interval, where u_prev starts in p */
  int rate_bounded;           /* spec.lifted and a finite rate bound: encode projects */
  int deviation, seed_warm;   /* search="deviation"; seed_warm_start */
  const double *centre, *scale, *scaled_lower, *scaled_upper, *rate; /* nu each */
} uuv_ocp_igwo_setup;

/* numpy's bitgen_t (numpy/random/bitgen.h, public) starts with `void* state`; PCG64's state
 * struct starts with a pointer to {state, inc}, two native 128-bit integers.  NativeIgwo checks
 * this layout against Generator.bit_generator.state before it passes a generator here. */
static void* uuv_numpy_pcg64(void* bitgen) { return *(void**)(*(void**)bitgen); }

/* np.clip(value, low, high) on one double: numpy's _NPY_CLIP, NaN kept. */
static inline double uuv_clip(double value, double low, double high) {
  value = isnan(value) ? value : (value > low ? value : low);
  return isnan(value) ? value : (value < high ? value : high);
}

static int uuv_ocp_finish(const uuv_ocp_igwo_setup* s, const double* p, const double* offset,
                          const double* best_x, double* scaled, double* states, double* score) {
  const uuv_ocp_work works[3] = {s->decode_work, s->score_terms_work, s->rollout_work};
  casadi_int sz_arg = 2, sz_res = 5, sz_iw = 1, sz_w = 1, a, r, iw_size, w_size;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  double* clipped;
  int k, j, status = 0;
  for (k = 0; k < 3; ++k) {
    if (works[k](&a, &r, &iw_size, &w_size)) return 1;
    sz_arg = a > sz_arg ? a : sz_arg;
    sz_res = r > sz_res ? r : sz_res;
    sz_iw = iw_size > sz_iw ? iw_size : sz_iw;
    sz_w = w_size > sz_w ? w_size : sz_w;
  }
  arg = (const casadi_real**)malloc(sizeof(casadi_real*) * (size_t)sz_arg);
  res = (casadi_real**)malloc(sizeof(casadi_real*) * (size_t)sz_res);
  iw = (casadi_int*)malloc(sizeof(casadi_int) * (size_t)sz_iw);
  w = (casadi_real*)malloc(sizeof(casadi_real) * (size_t)sz_w);
  clipped = (double*)malloc(sizeof(double) * (size_t)s->dim);
  if (!arg || !res || !iw || !w || !clipped) {
    status = 2;
    goto done;
  }
  for (j = 0; j < s->dim; ++j) clipped[j] = uuv_clip(best_x[j] + offset[j], s->box_lower[j], s->box_upper[j]);
  arg[0] = clipped;
  arg[1] = p;
  res[0] = scaled;
  if (s->decode(arg, res, iw, w, 0)) {
    status = 1;
    goto done;
  }
  arg[0] = scaled;
  for (k = 0; k < 5; ++k) {
    res[k] = score;
    score += s->score_sizes[k];
  }
  if (s->score_terms(arg, res, iw, w, 0)) {
    status = 1;
    goto done;
  }
  res[0] = states;
  if (s->rollout(arg, res, iw, w, 0)) status = 1;
done:
  free(arg); free(res); free(iw); free(w); free(clipped);
  return status;
}

/* One solve: `box` = offset, lower, upper, width (dim each) then `seeded` initial rows (already
 * clipped into [lower, upper]); then uniform wolves in the box drawn from the Generator behind
 * `bitgen` (its bitgen_t, from the capsule), the step with the same Generator, and the finish.  `out`: best x (dim), its fitness, the history
 * (iterations + 1), the late blocks, then with a finish the scaled plan (dim), the states and
 * the five score_terms outputs.  The Generator's state moves only when the whole call succeeds
 * (status 0; 1: an evaluation failed, 2: out of memory); the caller holds its lock. */
/* numpy's maximum/minimum (NaN propagates) and Python's max/min of two floats (the first
 * unless the second is strictly beyond it): encode uses both, in its two branches. */
static inline double uuv_np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }
static inline double uuv_np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }
static inline double uuv_py_max(double a, double b) { return b > a ? b : a; }
static inline double uuv_py_min(double a, double b) { return b < a ? b : a; }

/* uuv_ocp.transcription.condensed.encode(spec, plan, previous) into `w` (horizon * nu): the
 * same operations in the same order in both of its branches (a plan inside both bounds, which
 * projects onto itself, and the stage-by-stage projection). */
static void uuv_ocp_encode(const uuv_ocp_igwo_setup* s, const double* plan, const double* previous,
                           double* w) {
  const int n = s->horizon, nu = s->nu;
  int k, i, inside = 1;
  double prior[64];
  if (!s->rate_bounded) {
    for (k = 0; k < n * nu; ++k) w[k] = plan[k];
    return;
  }
  for (k = 0; k < n && inside; ++k) {
    for (i = 0; i < nu; ++i) {
      const double before = k == 0 ? previous[i] : plan[(k - 1) * nu + i], value = plan[k * nu + i];
      const double low = uuv_np_max(s->scaled_lower[i], before - s->rate[i]);
      const double high = uuv_np_min(s->scaled_upper[i], before + s->rate[i]);
      if (!(value >= low && value <= high)) inside = 0;
    }
  }
  if (inside) {
    for (k = 0; k < n; ++k) {
      for (i = 0; i < nu; ++i) {
        const double before = k == 0 ? previous[i] : plan[(k - 1) * nu + i], value = plan[k * nu + i];
        const double low = uuv_np_max(s->scaled_lower[i], before - s->rate[i]);
        const double high = uuv_np_min(s->scaled_upper[i], before + s->rate[i]);
        const double width = high - low;
        w[k * nu + i] = uuv_clip(width > 0 ? 2.0 * (value - low) / width - 1.0 : 0.0, -1.0, 1.0);
      }
    }
    return;
  }
  for (i = 0; i < nu; ++i) prior[i] = previous[i];
  for (k = 0; k < n; ++k) {
    for (i = 0; i < nu; ++i) {
      const double value = plan[k * nu + i];
      const double low = uuv_py_max(s->scaled_lower[i], prior[i] - s->rate[i]);
      const double high = uuv_py_min(s->scaled_upper[i], prior[i] + s->rate[i]);
      const double z = value == value ? uuv_py_min(uuv_py_max(value, low), high) : value;
      const double width = high - low;
      const double coordinate = width > 0 ? 2.0 * (z - low) / width - 1.0 : 0.0;
      w[k * nu + i] = coordinate == coordinate ? uuv_py_min(uuv_py_max(coordinate, -1.0), 1.0) : coordinate;
      prior[i] = z;
    }
  }
}

CASADI_SYMBOL_EXPORT int uuv_ocp_igwo_solve(const uuv_ocp_igwo_setup* s, const double* p,
                                            const double* box, int seeded, void* bitgen,
                                            int rng_thread, double* out) {
  const int n = s->n, dim = s->dim, iterations = s->iterations;
  const double *offset = box, *lower = box + dim, *upper = box + 2 * dim, *width = box + 3 * dim;
  const double* seeds = box + 4 * dim;
  const size_t drawn = (size_t)(n - seeded) * (size_t)dim;
  double* positions = (double*)malloc(sizeof(double) * (size_t)n * (size_t)dim);
  double* late = out + dim + 2 + iterations;
  unsigned char* numpy_state = (unsigned char*)uuv_numpy_pcg64(bitgen);
  uuv_u128 state, inc;
  uint64_t pcg[5];
  size_t i;
  int status;
  if (!positions) return 2;
  memcpy(&state, numpy_state, sizeof state);
  memcpy(&inc, numpy_state + sizeof state, sizeof inc);
  for (i = 0; i < (size_t)seeded * (size_t)dim; ++i) positions[i] = seeds[i];
  if (drawn > 0) {
    uuv_pcg_jump jumps[UUV_PCG_SEGMENTS + 2];
    double* uniform = positions + (size_t)seeded * dim;
    const size_t segment = uuv_pcg_jumps(inc, drawn, jumps);
    uuv_pcg_fill(state, inc, jumps, segment, uniform, drawn, 0, UUV_PCG_SEGMENTS);
    for (i = 0; i < drawn; ++i) uniform[i] = lower[i % dim] + uniform[i] * width[i % dim];
    state = uuv_pcg_apply(jumps[UUV_PCG_SEGMENTS], state);
  }
  pcg[0] = (uint64_t)(state >> 64);
  pcg[1] = (uint64_t)state;
  pcg[2] = (uint64_t)(inc >> 64);
  pcg[3] = (uint64_t)inc;
  pcg[4] = 0;
  status = uuv_ocp_igwo_core(p, offset, lower, upper, positions, NULL, pcg, rng_thread,
                             s->a_schedule, s->w_schedule, s->c1, s->c2, n, dim, iterations, out,
                             out + dim, out + dim + 1, NULL);
  free(positions);
  if (status == 0 && s->decode)
    status = uuv_ocp_finish(s, p, offset, out, late + 1, late + 1 + dim, late + 1 + dim + s->states_size);
  if (status == 0) {
    state = ((uuv_u128)pcg[0] << 64) | pcg[1];
    memcpy(numpy_state, &state, sizeof state);
    *late = (double)pcg[4];
  }
  return status;
}

/* uuv_ocp_igwo_solve from a warm plan (scaled controls, horizon x nu): its search box made here
 * as SwarmSolver._search_box makes it (previous = np.clip((u_prev - centre) / scale, scaled
 * box), centre plan = encode(plan, previous), offset, seeds, lower, upper, width), ~1 us
 * instead of ~50 us of numpy.  nu <= 64 (else status 2: the solver keeps the numpy box). */
CASADI_SYMBOL_EXPORT int uuv_ocp_igwo_solve_warm(const uuv_ocp_igwo_setup* s, const double* p,
                                                 const double* plan, void* bitgen, int rng_thread,
                                                 double* out) {
  const int dim = s->dim, nu = s->nu;
  double previous[64];
  double* box;
  double *offset, *lower, *upper, *width, *seeds;
  int i, j, seeded = s->seed_warm, status;
  if (nu > 64 || s->horizon * nu != dim) return 2;
  box = (double*)malloc(sizeof(double) * (size_t)(5 * dim));
  if (!box) return 2;
  offset = box, lower = box + dim, upper = box + 2 * dim, width = box + 3 * dim, seeds = box + 4 * dim;
  for (i = 0; i < nu; ++i)
    previous[i] = uuv_clip((p[s->u_prev + i] - s->centre[i]) / s->scale[i], s->scaled_lower[i],
                           s->scaled_upper[i]);
  uuv_ocp_encode(s, plan, previous, seeds); /* the centre plan */
  for (j = 0; j < dim; ++j) {
    const double center = seeds[j];
    offset[j] = s->deviation ? center : 0.0;
    seeds[j] = center - offset[j];
    lower[j] = s->box_lower[j] - offset[j];
    upper[j] = s->box_upper[j] - offset[j];
    width[j] = upper[j] - lower[j];
    seeds[j] = uuv_clip(seeds[j], lower[j], upper[j]);
  }
  status = uuv_ocp_igwo_solve(s, p, box, seeded, bitgen, rng_thread, out);
  free(box);
  return status;
}
