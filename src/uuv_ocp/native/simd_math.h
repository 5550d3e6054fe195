/* ---------------------------------------------------------------------------------------
 * uuv_ocp: lane-vectorised double arithmetic for the SIMD population kernels
 * (uuv_ocp/codegen_simd.py).  GCC/clang vector extensions: one `uuv_vd` holds the same
 * quantity for UUV_LANES candidates; + - * / act lane-wise with IEEE results identical to the
 * scalar ones (compile with -ffp-contract=off: no fused multiply-add).  UUV_LANES follows the
 * target's widest vector register (8 with AVX-512, 4 with AVX, 2 otherwise).
 *
 * sin and cos are fdlibm's kernels (__kernel_sin / __kernel_cos, |error| < 1 ulp on
 * [-pi/4, pi/4]) after a Cody-Waite reduction by pi/2 split in 33 + 33 + 53 bits (fdlibm's
 * medium-size path, accurate for |x| < 2^19 pi/2 even next to multiples of pi/2); arguments with |x| > UUV_TRIG_LIMIT (or NaN/inf) take libm lane by lane.
 * Every lane's result depends only on its own argument, so a candidate gets the same value
 * in whichever lane and batch it is evaluated.  Accuracy against libm: a few ulp.
 * ------------------------------------------------------------------------------------- */
#ifndef UUV_OCP_SIMD_MATH_H
#define UUV_OCP_SIMD_MATH_H
#include <math.h>
#include <stddef.h>

/* lanes per vector: one register of the target (build with -march=native to use it all) */
#ifndef UUV_LANES
#if defined(__AVX512F__)
#define UUV_LANES 8
#elif defined(__AVX__)
#define UUV_LANES 4
#else
#define UUV_LANES 2
#endif
#endif
#define UUV_TRIG_LIMIT 1.0e5

typedef double uuv_vd __attribute__((vector_size(8 * UUV_LANES)));
typedef long long uuv_vl __attribute__((vector_size(8 * UUV_LANES)));

#if UUV_LANES == 8 && defined(__AVX512F__)
#include <immintrin.h>
#endif

/* Whether any lane of a comparison mask is set (one mask instruction on AVX-512). */
static inline int uuv_any(uuv_vl mask) {
#if UUV_LANES == 8 && defined(__AVX512F__)
  return _mm512_test_epi64_mask((__m512i)mask, (__m512i)mask) != 0;
#else
  long long any = 0;
  int l;
  for (l = 0; l < UUV_LANES; ++l) any |= mask[l];
  return any != 0;
#endif
}

static inline uuv_vd uuv_bcast(double s) {
  uuv_vd v;
  int l;
  for (l = 0; l < UUV_LANES; ++l) v[l] = s;
  return v;
}

static inline uuv_vd uuv_select(uuv_vl mask, uuv_vd yes, uuv_vd no) {
  return (uuv_vd)((mask & (uuv_vl)yes) | (~mask & (uuv_vl)no));
}

static inline uuv_vd uuv_fabs(uuv_vd x) {
  return (uuv_vd)((uuv_vl)x & ~(uuv_vl)uuv_bcast(-0.0));
}

/* C99 fmax/fmin: a NaN argument loses against a number. */
static inline uuv_vd uuv_fmax(uuv_vd x, uuv_vd y) {
  return uuv_select((y > x) | (x != x), y, x);
}

static inline uuv_vd uuv_fmin(uuv_vd x, uuv_vd y) {
  return uuv_select((y < x) | (x != x), y, x);
}

/* fdlibm __kernel_sin(x, 0, 0) and __kernel_cos(x, 0), |x| <= pi/4. */
static inline uuv_vd uuv_kernel_sin(uuv_vd x) {
  const uuv_vd z = x * x;
  const uuv_vd r = 8.33333333332248946124e-03 +
                   z * (-1.98412698298579493134e-04 +
                        z * (2.75573137070700676789e-06 +
                             z * (-2.50507602534068634195e-08 + z * 1.58969099521155010221e-10)));
  return x + (z * x) * (-1.66666666666666324348e-01 + z * r);
}

static inline uuv_vd uuv_kernel_cos(uuv_vd x) {
  const uuv_vd z = x * x;
  const uuv_vd r =
      z * (4.16666666666666019037e-02 +
           z * (-1.38888888888741095749e-03 +
                z * (2.48015872894767294178e-05 +
                     z * (-2.75573143513906633035e-07 +
                          z * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11)))));
  const uuv_vd hz = 0.5 * z;
  const uuv_vd w = 1.0 - hz;
  return w + (((1.0 - w) - hz) + z * r);
}

/* sin and cos of every lane; either output pointer may be NULL. */
static inline void uuv_sincos(uuv_vd x, uuv_vd* sine, uuv_vd* cosine) {
  const double magic = 6755399441055744.0; /* 1.5 * 2^52: round to nearest integer */
  const uuv_vd shifted = x * 6.36619772367581382433e-01 + magic;
  const uuv_vd q = shifted - magic;
  const uuv_vl quadrant = (uuv_vl)shifted;
  /* fdlibm's three-part pi/2 (33 + 33 + 53 bits): the first two products are exact and the
   * subtractions exact by Sterbenz's lemma when x is close to a multiple of pi/2 */
  const uuv_vd r = ((x - q * 1.57079632673412561417e+00) - q * 6.07710050630396597660e-11) -
                   q * 2.02226624879595063154e-21;
  const uuv_vd s = uuv_kernel_sin(r), c = uuv_kernel_cos(r);
  const uuv_vl odd = (quadrant & 1) != 0;
  const uuv_vl flip_sin = (quadrant & 2) != 0;
  const uuv_vl flip_cos = ((quadrant + 1) & 2) != 0;
  const uuv_vl sign = (uuv_vl)uuv_bcast(-0.0);
  const uuv_vl large = ~(uuv_fabs(x) <= UUV_TRIG_LIMIT);
  int l;
  if (sine) *sine = (uuv_vd)((uuv_vl)uuv_select(odd, c, s) ^ (flip_sin & sign));
  if (cosine) *cosine = (uuv_vd)((uuv_vl)uuv_select(odd, s, c) ^ (flip_cos & sign));
  if (uuv_any(large)) {
    for (l = 0; l < UUV_LANES; ++l) {
      if (large[l]) {
        if (sine) (*sine)[l] = sin(x[l]);
        if (cosine) (*cosine)[l] = cos(x[l]);
      }
    }
  }
}

static inline uuv_vd uuv_sin(uuv_vd x) {
  uuv_vd s;
  uuv_sincos(x, &s, 0);
  return s;
}

static inline uuv_vd uuv_cos(uuv_vd x) {
  uuv_vd c;
  uuv_sincos(x, 0, &c);
  return c;
}

#endif /* UUV_OCP_SIMD_MATH_H */
