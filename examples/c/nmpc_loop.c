/* Closed loop with the generated exact NMPC step (one real-time iteration on HPIPM).
 *
 *   generate_c(problem, "build", functions=("model_step", "nmpc_step"))
 *   cc nmpc_loop.c -Ibuild build/uuv_ocp_nmpc_<hash>.so build/uuv_ocp_gen_<hash>.so \
 *      -Wl,-rpath,'$ORIGIN' -lm -o build/nmpc_loop
 *   ./build/nmpc_loop loop.txt          (written by tests/solvers/test_rti_export.py)
 *
 * loop.txt: nx nu np nw steps, then x0[nx] u_prev[nu] w[nw] and p[steps][np] (the reference
 * window of each step; nmpc_step replaces its state and last-control blocks).  The plant is the
 * controller's own model_step (still water).  Prints per step the control and the QP's
 * linearised violation with 17 significant digits, and at the end on stderr the median wall
 * and thread-CPU time of nmpc_step (the C-only time of one real-time iteration; the CPU time
 * is what a loaded machine's other processes do not inflate).
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "uuv_ocp_gen.h"
#include "uuv_ocp_nmpc.h"

static double* read_block(FILE* file, long count) {
  double* values = (double*)malloc(sizeof(double) * (count > 0 ? count : 1));
  long i;
  for (i = 0; i < count; ++i) {
    if (fscanf(file, "%lf", &values[i]) != 1) {
      fprintf(stderr, "input ended after %ld of %ld numbers\n", i, count);
      exit(2);
    }
  }
  return values;
}

static void* work(casadi_int n, size_t size) { return malloc(size * (n > 0 ? (size_t)n : 1)); }

static double seconds(clockid_t clock) {
  struct timespec t;
  clock_gettime(clock, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int ascending(const void* a, const void* b) {
  double x = *(const double*)a, y = *(const double*)b;
  return (x > y) - (x < y);
}

static double median(double* values, int count) {
  qsort(values, (size_t)count, sizeof(double), ascending);
  return count % 2 ? values[count / 2] : 0.5 * (values[count / 2 - 1] + values[count / 2]);
}

int main(int argc, char** argv) {
  FILE* file;
  int nx, nu, np_, nw, steps, k, i;
  double *x, *u_prev, *w, *p, *u, *w_next, *x_next, *stage, violation, *wall, *cpu, start, start_cpu;
  casadi_int sz_arg, sz_res, sz_iw, sz_w, m_arg, m_res, m_iw, m_w;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* mem;
  if (argc != 2 || !(file = fopen(argv[1], "r"))) {
    fprintf(stderr, "usage: %s loop.txt\n", argv[0]);
    return 2;
  }
  if (fscanf(file, "%d %d %d %d %d", &nx, &nu, &np_, &nw, &steps) != 5) return 2;
  x = read_block(file, nx);
  u_prev = read_block(file, nu);
  w = read_block(file, nw);
  p = read_block(file, (long)steps * np_);
  fclose(file);
  wall = (double*)malloc(sizeof(double) * (steps > 0 ? steps : 1));
  cpu = (double*)malloc(sizeof(double) * (steps > 0 ? steps : 1));
  u = (double*)malloc(sizeof(double) * nu);
  w_next = (double*)malloc(sizeof(double) * nw);
  x_next = (double*)malloc(sizeof(double) * nx);
  /* model_step(x, u, p_stage, p_global): stage parameters (reference node, current) zero */
  stage = (double*)calloc((size_t)model_step_sparsity_in(2)[0] + 1, sizeof(double));
  nmpc_step_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  model_step_work(&m_arg, &m_res, &m_iw, &m_w);
  if (m_arg > sz_arg) sz_arg = m_arg;
  if (m_res > sz_res) sz_res = m_res;
  if (m_iw > sz_iw) sz_iw = m_iw;
  if (m_w > sz_w) sz_w = m_w;
  arg = (const casadi_real**)work(sz_arg, sizeof(casadi_real*));
  res = (casadi_real**)work(sz_res, sizeof(casadi_real*));
  iw = (casadi_int*)work(sz_iw, sizeof(casadi_int));
  mem = (casadi_real*)work(sz_w, sizeof(casadi_real));
  for (k = 0; k < steps; ++k) {
    arg[0] = x;
    arg[1] = u_prev;
    arg[2] = p + (long)k * np_;
    arg[3] = w;
    res[0] = u;
    res[1] = w_next;
    res[2] = &violation;
    start = seconds(CLOCK_MONOTONIC);
    start_cpu = seconds(CLOCK_THREAD_CPUTIME_ID);
    if (nmpc_step(arg, res, iw, mem, 0)) {
      fprintf(stderr, "nmpc_step failed at step %d\n", k);
      return 1;
    }
    cpu[k] = seconds(CLOCK_THREAD_CPUTIME_ID) - start_cpu;
    wall[k] = seconds(CLOCK_MONOTONIC) - start;
    printf("step %d", k);
    for (i = 0; i < nu; ++i) printf(" %.17g", u[i]);
    printf(" %.17g\n", violation);
    arg[0] = x;
    arg[1] = u;
    arg[2] = stage;
    arg[3] = stage;
    res[0] = x_next;
    if (model_step(arg, res, iw, mem, 0)) return 1;
    for (i = 0; i < nx; ++i) x[i] = x_next[i];
    for (i = 0; i < nu; ++i) u_prev[i] = u[i];
    for (i = 0; i < nw; ++i) w[i] = w_next[i];
  }
  if (steps > 1) /* the first call allocates HPIPM's memory: left out */
    fprintf(stderr, "nmpc_step over %d steps: median wall %.4f ms, median thread CPU %.4f ms\n",
            steps - 1, 1e3 * median(wall + 1, steps - 1), 1e3 * median(cpu + 1, steps - 1));
  return 0;
}
