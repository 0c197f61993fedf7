"""A CasADi step called in a plain C loop, timed: the floor a C programmer would write, against
which the library's rollouts and the hybrid step's pieces are timed (``analysis/bench_rollout.py``,
``analysis/bench_step_pieces.py``). The loop feeds each step's output back as the next input,
so the time per call is the step's latency as a rollout sees it."""

from __future__ import annotations

import os
import statistics
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.integrate.compiler import DEFAULT_FLAGS, find_compiler

HARNESS = """
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "step.h"
int main(int argc, char** argv) {{
  static double x[2][{nx}], u[{nu}], p[{np}], dt = {dt};
  double* out = malloc(sizeof(double) * {nx} * {N});
  FILE* fp = fopen(argv[1], "rb");
  if (!fp || fread(x[0], 8, {nx}, fp) != {nx} || fread(u, 8, {nu}, fp) != {nu}
      || fread(p, 8, {np}, fp) != {np}) return 2;
  fclose(fp);
  static casadi_int iw[{sz_iw} + 1];
  static double w[{sz_w} + 1];
  const double* arg[{sz_arg}];
  double* res[{sz_res}];
  for (int rep = 0; rep < {repeats}; ++rep) {{
    struct timespec a, b;
    const double* xin = x[0];
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (long k = 0; k < {N}; ++k) {{
      arg[0] = xin; arg[1] = u; arg[2] = p; arg[3] = &dt; res[0] = out + k * {nx};
      step(arg, res, iw, w, 0);
      xin = out + k * {nx};
    }}
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.6f\\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / {N} / 1000.0);
  }}
  return out[0] == out[0] ? 0 : 3;
}}
"""


def c_loop_us(function: ca.Function, x0, u, p, dt: float, n: int, repeats: int) -> float:
    """Median us per sample of ``function`` called ``n`` times in a plain C loop (the command
    held: the loop's cost does not depend on the values)."""
    inner = function if function.is_a("SXFunction") else function.expand()
    step = ca.Function("step", inner.sx_in(), inner.call(inner.sx_in()))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        gen = ca.CodeGenerator("step.c", {"with_header": True})
        gen.add(step)
        gen.generate(str(folder) + os.sep)
        (folder / "main.c").write_text(HARNESS.format(
            nx=step.size1_in(0), nu=step.size1_in(1), np=step.size1_in(2), dt=dt, N=n,
            sz_iw=step.sz_iw(), sz_w=step.sz_w(), sz_arg=step.sz_arg(), sz_res=step.sz_res(),
            repeats=repeats))
        (folder / "in.bin").write_bytes(np.concatenate([x0, u, p]).astype(float).tobytes())
        flags = [f for f in DEFAULT_FLAGS if f not in ("-shared", "-fPIC")]
        subprocess.run([find_compiler(), *flags, "-o", str(folder / "loop"),
                        str(folder / "main.c"), str(folder / "step.c"), "-lm"], check=True)
        out = subprocess.run([str(folder / "loop"), str(folder / "in.bin")],
                             capture_output=True, text=True, check=True).stdout
    return statistics.median(float(v) for v in out.split())
