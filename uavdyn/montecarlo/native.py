"""A chunk of Monte-Carlo runs as one plain C loop, four runs advanced together.

The ``mapaccum`` run (:func:`uavdyn.montecarlo.batch.run_function`) copies the whole accumulator
(state, parameters, statistics) through work vectors at every call level and sample: mapped
over a chunk it cost 1.7 us per run-step against 0.55 us for the step alone. Here the runs of a
chunk go :data:`LANES` at a time through the loop a C programmer writes: each run's ``start``
(:class:`~uavdyn.montecarlo.batch.RunPieces`, CasADi's generated code), then ``body`` per sample
for the four runs at once (:func:`uavdyn.integrate.lanes.lanes_c`: every operation over the four
side by side, which the compiler turns into vector instructions; each run bit for bit what the
scalar code gives), the history read straight out of the accumulators every ``stride`` samples.
When every run of the four has diverged the loop stops (their statistics are frozen from their
divergence on in both routes; their later history is NaN here, which the chunk masks from the
divergence time in any case).

The library exports CasADi's external-function interface with the mapped run's inputs and
outputs (the compile cache verifies it against them), and a ``<name>_runs`` entry for a range of
runs, which :class:`NativeBatch` calls on NumPy buffers from as many threads as asked
(``ctypes`` releases the GIL).
"""

from __future__ import annotations

import copy
import ctypes
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.integrate import compile_function
from uavdyn.integrate.c_loop import (
    column_major_buffers,
    external_interface,
    generated_body,
    loop_step,
    work_sizes,
)
from uavdyn.integrate.compiler import DEFAULT_FLAGS, CodegenWarning
from uavdyn.integrate.csource import generate_c
from uavdyn.integrate.lanes import VECTOR_FLAGS, LanesError, lanes_c
from uavdyn.montecarlo.batch import N_GUST, N_LIMITS, SIGNALS, STAT_NAMES, RunPieces

LANES = 4  # runs advanced together: 4 measured fastest (2-16 tried, 2-core x86-64)
# no floating-point contraction (each lane bit for bit the scalar code); no errno from libm
# (square roots become one instruction over the lanes)
FLAGS = (*DEFAULT_FLAGS, "-ffp-contract=off", "-fno-math-errno")


def _shapes(pieces: RunPieces, n_runs: int, n_steps: int, n_hist: int, gusts: bool,
            feedback: bool) -> tuple[list, list]:
    """The mapped run's ``(name, rows, columns)`` inputs and outputs."""
    inputs = [("x0", pieces.nx, n_runs), ("u0", pieces.nu, n_runs), ("p", pieces.np, n_runs),
              ("du", pieces.nu, n_steps)]
    inputs += [("g", N_GUST, n_steps * n_runs)] if gusts else []
    inputs += [("dt", 1, 1), ("limits", N_LIMITS, 1)]
    inputs += [("xref", 4, n_runs)] if feedback else []
    outputs = [("stats", len(STAT_NAMES), n_runs), ("hist", len(SIGNALS), n_hist * n_runs)]
    return inputs, outputs


def write_batch_source(pieces: RunPieces, n_runs: int, n_steps: int, stride: int, gusts: bool,
                       feedback: bool, name: str, folder: Path, vector_math: bool = False
                       ) -> Path:
    """Write ``<name>.c``: the run's start (CasADi's code) and body (in :data:`LANES` lanes,
    :func:`uavdyn.integrate.lanes.lanes_c`), the loop over a range of runs (``<name>_runs``)
    and the mapped run's external interface (``<name>``); ``vector_math``: the lanes' maths
    functions through glibc's ``libmvec`` (:func:`uavdyn.integrate.lanes.lanes_c`).

    Raises
    ------
    LanesError
        If the body has an operation without a lane C form.
    """
    stride = min(stride, n_steps)
    n_hist = n_steps // stride + 1
    start = loop_step(pieces.start, f"{name}_start")
    body = lanes_c(loop_step(pieces.body, f"{name}_body"), f"{name}_lanes", LANES, vector_math)
    source = generate_c(start, folder, name)
    text = source.read_text()
    n_zero = max(pieces.nx, pieces.nu, pieces.np, N_GUST, N_LIMITS, len(SIGNALS))
    sz_arg, sz_res = max(start.sz_arg(), 8), max(start.sz_res(), 2)
    lane_block = (2 * pieces.n_acc + pieces.n_in) * LANES
    sz_w = start.sz_w() + pieces.n_acc + lane_block + n_zero + len(SIGNALS)
    inputs, outputs = _shapes(pieces, n_runs, n_steps, n_hist, gusts, feedback)
    index = {entry[0]: i for i, entry in enumerate(inputs)}
    lane = "acc[{row} * " + str(LANES) + " + b]"
    values = {
        "name": name, "start": generated_body(text, f"{name}_start"), "B": LANES,
        "R": n_runs, "N": n_steps, "S": stride, "K": n_hist - 1, "nx": pieces.nx,
        "nu": pieces.nu, "np": pieces.np, "n_in": pieces.n_in, "na": pieces.n_acc,
        "n_zero": n_zero, "n_sig": len(SIGNALS), "n_stat": len(STAT_NAMES), "n_g": N_GUST,
        "sz_arg": sz_arg, "sz_res": sz_res, "sz_w_start": start.sz_w(),
        "i_dt": index["dt"], "i_lim": index["limits"],
        "g_run": f"(arg[{index['g']}] ? arg[{index['g']}] + rr * {n_steps * N_GUST} : 0)"
        if gusts else "0",
        "xr_run": f"(arg[{index['xref']}] ? arg[{index['xref']}] + rr * 4 : zeros)"
        if feedback else "zeros",
        "signal_copy": " ".join(f"h[{i}] = {lane.format(row=row)};"
                                for i, row in enumerate(pieces.signal_rows)),
        "stat_copy": " ".join(f"st[{i}] = {lane.format(row=row)};"
                              for i, row in enumerate(pieces.stat_rows)),
        "t_div": pieces.stat_rows[-1],
    }
    work = (sz_arg, sz_res, start.sz_iw(), sz_w)
    source.write_text(text + "\n" + body + external_interface(name, inputs, outputs, work)
                      + _RUNS.format(**values))
    return source


_PER_RUN = ("x0", "u0", "p", "g", "xref")  # inputs with one block of columns per run


class NativeBatch:
    """The compiled chunk loop called on NumPy buffers: ``batch(*inputs)`` returns ``(stats,
    hist)`` like the mapped run it replaces (``function``, for ``capacity`` runs), for any
    number of runs up to ``capacity`` (every run's inputs and outputs are a block of its own,
    so a smaller chunk is the first blocks), split over ``threads`` threads (each run is
    independent: the same numbers on any thread count)."""

    def __init__(self, library: ctypes.CDLL, name: str, function: ca.Function,
                 threads: int = 1):
        self._library, self.function, self.threads = library, function, threads
        self._runs = getattr(library, f"{name}_runs")
        self._runs.restype = ctypes.c_int
        self._runs.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_longlong] * 2
        self._sz_arg, self._sz_res, self._sz_iw, self._sz_w = work_sizes(library, name)
        self.capacity = function.size2_in(0)

    def on_threads(self, threads: int) -> NativeBatch:
        """The same compiled loop, its runs split over ``threads`` threads."""
        view = copy.copy(self)
        view.threads = threads
        return view

    def _range(self, arg, res, r0: int, r1: int) -> int:
        iw = np.zeros(max(self._sz_iw, 1), dtype=np.int64)
        w = np.zeros(max(self._sz_w, 1))
        return self._runs(arg, res, iw.ctypes.data, w.ctypes.data, r0, r1)

    def _shape(self, i: int, side: str, n: int) -> tuple[int, int]:
        """Input or output ``i``'s shape for ``n`` runs."""
        f = self.function
        rows, cols = f.size_in(i) if side == "in" else f.size_out(i)
        per_run = f.name_in(i) in _PER_RUN if side == "in" else True
        return (rows, cols // self.capacity * n) if per_run else (rows, cols)

    def __call__(self, *args) -> tuple[np.ndarray, np.ndarray]:
        f = self.function
        if len(args) != f.n_in():
            raise TypeError(f"the batch takes {f.n_in()} inputs ({', '.join(f.name_in())}), "
                            f"got {len(args)}")
        n = np.asarray(args[0]).size // f.size1_in(0)
        if not 1 <= n <= self.capacity:
            raise ValueError(f"the batch flies 1 to {self.capacity} runs, got {n}")
        buffers = column_major_buffers(args, [self._shape(i, "in", n) for i in range(f.n_in())],
                                       "Monte-Carlo batch")
        outputs = [np.empty(self._shape(i, "out", n), order="F") for i in range(f.n_out())]
        arg = (ctypes.c_void_p * self._sz_arg)(*(b.ctypes.data for b in buffers))
        res = (ctypes.c_void_p * self._sz_res)(*(o.ctypes.data for o in outputs))
        bounds = np.linspace(0, n, min(self.threads, n) + 1).astype(int)
        ranges = list(zip(bounds[:-1], bounds[1:]))
        if len(ranges) == 1:
            codes = [self._range(arg, res, *ranges[0])]
        else:
            with ThreadPoolExecutor(len(ranges)) as pool:
                codes = list(pool.map(lambda r: self._range(arg, res, *r), ranges))
        if any(codes):
            raise RuntimeError("the compiled Monte-Carlo batch reported an error")
        return outputs[0], outputs[1]


def native_batch(pieces: RunPieces, mapped: ca.Function, n_steps: int, stride: int,
                 gusts: bool, feedback: bool, vector_math: bool = False) -> NativeBatch | None:
    """The chunk loop for up to ``mapped``'s runs (``mapped``: the uncompiled serial map of the
    run, :func:`batch_function`, whose inputs and outputs the library is checked against),
    compiled and cached like every compiled Function; None without a compiler or for a body
    with an operation that has no lane form (:class:`~uavdyn.integrate.lanes.LanesError`,
    said in a :class:`CodegenWarning`): the caller then flies CasADi's map. ``vector_math``:
    the lanes' maths functions through ``libmvec`` (the caller checks it is available:
    :func:`uavdyn.integrate.lanes.vector_math_unavailable`)."""
    try:
        lanes_c(loop_step(pieces.body, "check"), "check", LANES)
    except LanesError as exc:
        warnings.warn(f"Monte-Carlo runs one at a time through CasADi's map: {exc}",
                      CodegenWarning, stacklevel=2)
        return None
    flags = (*FLAGS, *VECTOR_FLAGS) if vector_math else FLAGS
    batch = compile_function(
        mapped, flags, warn=False, opener=lambda n, path: NativeBatch(ctypes.CDLL(path), n, mapped),
        source=lambda folder, n: write_batch_source(pieces, mapped.size2_in(0), n_steps, stride,
                                                    gusts, feedback, n, folder, vector_math))
    return batch if isinstance(batch, NativeBatch) else None


_RUNS = """
/* ---- the runs of a Monte-Carlo chunk, {B} at a time (uavdyn.montecarlo.native) ---- */
CASADI_SYMBOL_EXPORT int {name}_runs(const casadi_real** arg, casadi_real** res,
                                     casadi_int* iw, casadi_real* w, long long r0,
                                     long long r1) {{
  const casadi_real* s_arg[{sz_arg}];
  casadi_real* s_res[{sz_res}];
  casadi_real *first = w + {sz_w_start}, *acc0 = first + {na}, *acc1 = acc0 + {na} * {B};
  casadi_real *inp = acc1 + {na} * {B}, *zeros = inp + {n_in} * {B}, *scratch = zeros + {n_zero};
  const casadi_real *du = arg[3], *g[{B}];
  const casadi_real* lane_arg[2];
  casadi_real* lane_res[1];
  casadi_real dt = arg[{i_dt}] ? *arg[{i_dt}] : 0;
  casadi_real *acc, *next, *tmp, *h, *st;
  long long r, rr;
  casadi_int i, j, k, b, nb, last, alive;
  for (i = 0; i < {n_zero}; ++i) zeros[i] = 0;
  for (i = 0; i < {sz_arg}; ++i) s_arg[i] = 0;
  for (i = 0; i < {sz_res}; ++i) s_res[i] = 0;
  for (r = r0; r < r1; r += {B}) {{
    nb = (r1 - r < {B}) ? (casadi_int)(r1 - r) : {B};
    acc = acc0;
    next = acc1;
    for (b = 0; b < {B}; ++b) {{ /* lanes past the range repeat its last run, unstored */
      rr = r + (b < nb ? b : nb - 1);
      g[b] = {g_run};
      s_arg[0] = arg[0] ? arg[0] + rr * {nx} : zeros;
      s_arg[1] = arg[1] ? arg[1] + rr * {nu} : zeros;
      s_arg[2] = arg[2] ? arg[2] + rr * {np} : zeros;
      s_arg[3] = du ? du : zeros;
      s_arg[4] = g[b] ? g[b] : zeros;
      s_arg[5] = &dt;
      s_arg[6] = arg[{i_lim}] ? arg[{i_lim}] : zeros;
      s_arg[7] = {xr_run};
      s_res[0] = first;
      s_res[1] = (res[1] && b < nb) ? res[1] + rr * ({K} + 1) * {n_sig} : scratch;
      if ({start}(s_arg, s_res, iw, w, 0)) return 1;
      for (j = 0; j < {na}; ++j) acc[j * {B} + b] = first[j];
    }}
    last = 0;
    for (k = 0; k < {N}; ++k) {{
      for (b = 0; b < {B}; ++b) {{
        for (i = 0; i < {nu}; ++i) inp[i * {B} + b] = du ? du[k * {nu} + i] : 0;
        for (i = {nu}; i < {n_in}; ++i)
          inp[i * {B} + b] = g[b] ? g[b][k * {n_g} + i - {nu}] : 0;
      }}
      lane_arg[0] = acc;
      lane_arg[1] = inp;
      lane_res[0] = next;
      {name}_lanes(lane_arg, lane_res);
      tmp = acc; acc = next; next = tmp;
      if ((k + 1) % {S} == 0) {{
        last = (k + 1) / {S};
        if (res[1])
          for (b = 0; b < nb; ++b) {{
            h = res[1] + ((r + b) * ({K} + 1) + last) * {n_sig};
            {signal_copy}
          }}
      }}
      alive = 0;
      for (b = 0; b < nb; ++b) alive |= !(acc[{t_div} * {B} + b] >= 0);
      if (!alive) break; /* every run diverged: their statistics are frozen from here on */
    }}
    for (b = 0; b < nb; ++b) {{
      if (res[1])
        for (j = last + 1; j <= {K}; ++j)
          for (i = 0; i < {n_sig}; ++i) res[1][((r + b) * ({K} + 1) + j) * {n_sig} + i] = NAN;
      if (res[0]) {{
        st = res[0] + (r + b) * {n_stat};
        {stat_copy}
      }}
    }}
  }}
  return 0;
}}

CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                                casadi_real* w, int mem) {{
  (void)mem;
  return {name}_runs(arg, res, iw, w, 0, {R});
}}
"""
