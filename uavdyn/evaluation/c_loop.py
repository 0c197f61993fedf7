"""A CasADi step called in a plain C loop, timed: the floor a C programmer would write, against
which the library's rollouts and the hybrid step's pieces are timed (``analysis/bench_rollout.py``,
``analysis/bench_step_pieces.py``). The loop feeds each step's output back as the next input,
so the time per call is the step's latency as a rollout sees it.

Several steps compile into one program that runs them in turn, pass after pass: a ratio of two
steps' times within one pass compares them under the same load (on a shared machine the speed
of a core can change by a third from one second to the next). The workload is one chain under
a held command (the trim benchmark) or recorded flight: windows restarted from given states and
driven by a command per step. The second matters because a step's cost depends on the values
it meets: at an exact hover the physics' ``sin``/``cos`` of a zero pitch angle take the C
library's shortcut, and a step that stays there looks cheaper than it is in flight."""

from __future__ import annotations

import os
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.integrate.compiler import DEFAULT_FLAGS, find_compiler

PROLOGUE = """
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "steps.h"
static double elapsed_us(struct timespec a, struct timespec b, long n) {
  return ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / n / 1000.0;
}
"""
# one block per step {i}: its data, read from the input file, and a timed pass
DATA = """
static double starts{i}[{m}][{nx}], u{i}[{n_u}][{nu}], p{i}[{np}], dt{i} = {dt};
static double out{i}[{N}][{nx}];
static casadi_int iw{i}[{sz_iw} + 1];
static double w{i}[{sz_w} + 1];
static int read{i}(FILE* fp) {{
  return fread(starts{i}, 8, {m} * {nx}, fp) == {m} * {nx}
      && fread(u{i}, 8, {n_u} * {nu}, fp) == {n_u} * {nu} && fread(p{i}, 8, {np}, fp) == {np};
}}
static double pass{i}(void) {{
  const double* arg[{sz_arg}];
  double* res[{sz_res}];
  const double* xin = starts{i}[0];
  struct timespec a, b;
  clock_gettime(CLOCK_MONOTONIC, &a);
  for (long k = 0; k < {N}; ++k) {{
    if (k % {window} == 0) xin = starts{i}[k / {window}];
    arg[0] = xin; arg[1] = u{i}[k % {n_u}]; arg[2] = p{i}; arg[3] = &dt{i}; res[0] = out{i}[k];
    step{i}(arg, res, iw{i}, w{i}, 0);
    xin = out{i}[k];
  }}
  clock_gettime(CLOCK_MONOTONIC, &b);
  return elapsed_us(a, b, {N});
}}
"""
MAIN = """
int main(int argc, char** argv) {{
  FILE* fp = fopen(argv[1], "rb");
  if (!fp || !({reads})) return 2;
  fclose(fp);
  int passes = atoi(argv[3]);
  for (int rep = 0; rep < passes; ++rep) {{
{timed}
    printf("\\n");
  }}
  FILE* fo = fopen(argv[2], "wb");
  if (!fo || !({writes})) return 4;
  fclose(fo);
  return 0;
}}
"""


@dataclass(frozen=True)
class LoopWork:
    """What one step of a :class:`CLoop` runs.

    Attributes
    ----------
    function : casadi.Function
        A step ``x_next = f(x, u, p, dt)`` (SX, or MX that expands).
    starts : array_like
        ``(nx,)`` one start, or ``(m, nx)``: the ``n`` steps are cut into ``m`` equal windows,
        each restarted from its row (``n`` a multiple of ``m``).
    controls : array_like
        ``(nu,)`` a command held throughout, or ``(n, nu)`` one per step.
    p : array_like
        Parameters, held.
    dt : float
        Step size (s).
    n : int
        Steps per timed pass.
    """

    function: ca.Function
    starts: object
    controls: object
    p: object
    dt: float
    n: int


@dataclass(frozen=True)
class CLoopRun:
    """Timed passes of a :class:`CLoop`: microseconds per step, one row per pass and one column
    per step, and each step's state after its last call (what the loop computed)."""

    pass_us: np.ndarray            # (passes, steps)
    final_states: list[np.ndarray]

    @property
    def us_per_step(self) -> np.ndarray:
        """Each step's median over the passes."""
        return np.median(self.pass_us, axis=0)

    def ratios(self, numerator: int, denominator: int) -> np.ndarray:
        """Per pass, step ``numerator``'s time over step ``denominator``'s (same pass, same
        load)."""
        return self.pass_us[:, numerator] / self.pass_us[:, denominator]


def _block(i: int, work: LoopWork) -> tuple[ca.Function, str, bytes]:
    """Step ``i``'s renamed Function, its C block and its input bytes (checked)."""
    inner = work.function if work.function.is_a("SXFunction") else work.function.expand()
    step = ca.Function(f"step{i}", inner.sx_in(), inner.call(inner.sx_in()))
    nx, nu, n = step.size1_in(0), step.size1_in(1), int(work.n)
    starts = np.atleast_2d(np.asarray(work.starts, float))
    controls = np.atleast_2d(np.asarray(work.controls, float))
    m = len(starts)
    if starts.shape[1] != nx or n % m:
        raise ValueError(f"starts must be (m, {nx}) with n = {n} a multiple of m; got "
                         f"{starts.shape}")
    if controls.shape[1] != nu or len(controls) not in (1, n):
        raise ValueError(f"controls must be ({nu},) or ({n}, {nu}); got {controls.shape}")
    text = DATA.format(i=i, nx=nx, nu=nu, np=step.size1_in(2), dt=repr(float(work.dt)), N=n,
                       m=m, window=n // m, n_u=len(controls), sz_iw=step.sz_iw(),
                       sz_w=step.sz_w(), sz_arg=step.sz_arg(), sz_res=step.sz_res())
    data = np.concatenate([starts.ravel(), controls.ravel(),
                           np.asarray(work.p, float).ravel()]).tobytes()
    return step, text, data


class CLoop:
    """Steps compiled once into one plain C program that times each in turn, pass after pass
    (:meth:`run`); use it as a context manager (the build lives in a temporary folder).

    Parameters
    ----------
    works : sequence of LoopWork
        The steps and what each runs.

    Raises
    ------
    ValueError
        If a step's ``n`` is not a multiple of its windows or its arrays do not fit it.
    """

    def __init__(self, works: Sequence[LoopWork]) -> None:
        blocks = [_block(i, w) for i, w in enumerate(works)]
        self._tmp = tempfile.TemporaryDirectory()
        self.folder = Path(self._tmp.name)
        self.sizes = [step.size1_in(0) for step, _, _ in blocks]
        gen = ca.CodeGenerator("steps.c", {"with_header": True})
        for step, _, _ in blocks:
            gen.add(step)
        gen.generate(str(self.folder) + os.sep)
        k = range(len(blocks))
        main = MAIN.format(
            reads=" && ".join(f"read{i}(fp)" for i in k),
            timed="\n".join(f'    printf("%.6f ", pass{i}());' for i in k),
            writes=" && ".join(f"fwrite(out{i}[{works[i].n - 1}], 8, {self.sizes[i]}, fo) "
                               f"== {self.sizes[i]}" for i in k))
        (self.folder / "main.c").write_text(
            PROLOGUE + "".join(text for _, text, _ in blocks) + main)
        (self.folder / "in.bin").write_bytes(b"".join(data for _, _, data in blocks))
        flags = [f for f in DEFAULT_FLAGS if f not in ("-shared", "-fPIC")]
        subprocess.run([find_compiler(), *flags, "-o", str(self.folder / "loop"),
                        str(self.folder / "main.c"), str(self.folder / "steps.c"), "-lm"],
                       check=True)

    def run(self, passes: int) -> CLoopRun:
        """Time ``passes`` passes (each runs every step once through its workload)."""
        out = subprocess.run([str(self.folder / "loop"), str(self.folder / "in.bin"),
                              str(self.folder / "out.bin"), str(int(passes))],
                             capture_output=True, text=True, check=True).stdout
        rows = np.array([[float(v) for v in line.split()] for line in out.splitlines()
                         if line.strip()])
        flat = np.frombuffer((self.folder / "out.bin").read_bytes(), float)
        ends = np.cumsum([0, *self.sizes])
        return CLoopRun(rows, [flat[a:b].copy() for a, b in zip(ends[:-1], ends[1:])])

    def close(self) -> None:
        self._tmp.cleanup()

    def __enter__(self) -> CLoop:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class RecordedWorkload:
    """Windows of recorded flight for a :class:`LoopWork`: each window's start (the step's own
    state from the records) and the recorded command of every step, in order."""

    starts: np.ndarray    # (m, nx)
    controls: np.ndarray  # (m * window, nu)
    window: int           # steps per window

    @property
    def steps(self) -> int:
        return len(self.controls)


def recorded_workload(model, sorties: list, window_s: float, p) -> RecordedWorkload:
    """Back-to-back windows of ``window_s`` seconds from every sortie of ``sorties`` (one
    sample rate), each started from the step ``model``'s state at its first record
    (:meth:`uavdyn.integrate.DiscreteModel.initial_state`) and driven by the recorded commands:
    the states and commands the step meets when it predicts flight.

    Raises
    ------
    ValueError
        If the sorties' command columns do not fit the step or no sortie is a window long.
    """
    nu = model.function.size1_in(1)
    starts, controls = [], []
    window = 0
    for s in sorties:
        window = max(1, int(round(window_s / s.dt)))
        if s.controls.shape[1] != nu:
            raise ValueError(f"sortie {s.name}: {s.controls.shape[1]} command columns, the "
                             f"step takes {nu}")
        first = np.arange(0, len(s.time) - window, window)
        if not len(first):
            continue
        state = np.atleast_2d(model.initial_state(s.states, s.controls, p, s.dt))
        starts.append(state[first])
        controls.extend(s.controls[k:k + window] for k in first)
    if not starts:
        raise ValueError(f"no sortie is longer than one window of {window_s:g} s")
    return RecordedWorkload(np.vstack(starts), np.vstack(controls), window)
