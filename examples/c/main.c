/* Standalone use of a uuv_ocp-generated library (no Python at run time).
 *
 *   uuv-ocp codegen --reference s2 --out build/        # writes uuv_ocp_gen_<hash>.{c,so}
 *   cc main.c -Ibuild build/uuv_ocp_gen_<hash>.so -Wl,-rpath,'$ORIGIN' -lm -o build/igwo_demo
 *   (uuv_ocp_igwo is declared in the generated header; $ORIGIN: the program finds the
 *   library next to itself from any working directory)
 *   ./igwo_demo input.txt
 *
 * input.txt (whitespace-separated numbers, written by examples/c/write_input.py):
 *   n dim T np
 *   p[np] offset[dim] lower[dim] upper[dim] positions[n*dim] draws[T*8*n*dim] a[T] w[T]
 *   controls[dim]            (scaled control sequence U whose cost is printed)
 * Output: the IGWO step's best fitness and the cost(U, p) terms, with 17 significant digits.
 */
#include <stdio.h>
#include <stdlib.h>

#include "uuv_ocp_gen.h"

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

int main(int argc, char** argv) {
  FILE* file;
  int n, dim, iterations, np_;
  double *p, *offset, *lower, *upper, *positions, *draws, *a, *w, *controls;
  double *best_x, best_f, *history, *final_positions, objective = 0, penalty = 0;
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* work;
  if (argc != 2) {
    fprintf(stderr, "usage: %s input.txt\n", argv[0]);
    return 2;
  }
  file = fopen(argv[1], "r");
  if (!file || fscanf(file, "%d %d %d %d", &n, &dim, &iterations, &np_) != 4) {
    fprintf(stderr, "cannot read the header of %s\n", argv[1]);
    return 2;
  }
  p = read_block(file, np_);
  offset = read_block(file, dim);
  lower = read_block(file, dim);
  upper = read_block(file, dim);
  positions = read_block(file, (long)n * dim);
  draws = read_block(file, (long)iterations * 8 * n * dim);
  a = read_block(file, iterations);
  w = read_block(file, iterations);
  controls = read_block(file, dim);
  fclose(file);

  best_x = (double*)malloc(sizeof(double) * dim);
  history = (double*)malloc(sizeof(double) * (iterations + 1));
  final_positions = (double*)malloc(sizeof(double) * n * dim);
  if (uuv_ocp_igwo(p, offset, lower, upper, positions, draws, a, w, 0.5, 0.5, n, dim, iterations,
                   best_x, &best_f, history, final_positions)) {
    fprintf(stderr, "uuv_ocp_igwo failed\n");
    return 1;
  }
  printf("igwo_best_fitness %.17g\n", best_f);

  cost_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = (const casadi_real**)malloc(sizeof(casadi_real*) * sz_arg);
  res = (casadi_real**)malloc(sizeof(casadi_real*) * sz_res);
  iw = (casadi_int*)malloc(sizeof(casadi_int) * (sz_iw > 0 ? sz_iw : 1));
  work = (casadi_real*)malloc(sizeof(casadi_real) * (sz_w > 0 ? sz_w : 1));
  arg[0] = controls;
  arg[1] = p;
  res[0] = &objective;
  res[1] = &penalty;
  if (cost(arg, res, iw, work, 0)) {
    fprintf(stderr, "cost evaluation failed\n");
    return 1;
  }
  printf("cost %.17g\npenalty %.17g\n", objective, penalty);
  return 0;
}
