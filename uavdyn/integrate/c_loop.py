"""Rollouts as a plain C loop around the step's generated code.

CasADi's ``mapaccum`` generates a tree of calls that copies the accumulator (state, parameters,
step size) in and out of work vectors at every level and every sample; on a 6-state step that
costs more than the step itself (1.7 us against 0.65 us per sample). Here the rollout is the
loop a C programmer would write: the step writes each state straight into its column of the
output and reads the previous column as its input, with the commands and parameters passed by
pointer. The library exposes CasADi's external-function interface (the compile cache builds
and verifies it like any other), and :class:`NativeRollout` calls it through ``ctypes`` on
NumPy buffers: CasADi's own conversion of a NumPy array to and from its matrices costs about
0.7 us per sample of a long rollout, more than the step.
"""

from __future__ import annotations

import ctypes
import re
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.integrate.csource import generate_c
from uavdyn.interrupts import reraise_interrupt


def loop_step(step: ca.Function, name: str) -> ca.Function:
    """The step under the loop's own name, as one SX graph where it can be (an MX step, e.g.
    the hybrid one, expanded: scalar code without call levels), else as it is."""
    if not step.is_a("SXFunction"):
        try:
            step = step.expand()
        except RuntimeError as exc:  # not expandable: keep the MX graph
            reraise_interrupt(exc)
            inputs = step.mx_in()
            return ca.Function(name, inputs, step.call(inputs), step.name_in(),
                               step.name_out())
    inputs = step.sx_in()
    return ca.Function(name, inputs, step.call(inputs), step.name_in(), step.name_out())


def loop_work_sizes(step: ca.Function) -> tuple[int, int, int, int]:
    """``(sz_arg, sz_res, sz_iw, sz_w)`` the loop around ``step`` needs (its ``_work``)."""
    inner = loop_step(step, "work")
    nx, nu, n_p = (step.size1_in(i) for i in range(3))
    return (max(inner.sz_arg(), 5), max(inner.sz_res(), 1), inner.sz_iw(),
            inner.sz_w() + 3 * nx + nu + n_p)


def generated_body(source: str, name: str) -> str:
    """The generated static function the exported ``name`` wraps (called directly by the
    loop: a call through the exported symbol of a shared library cannot be inlined), or
    ``name`` itself where the wrapper is not found."""
    found = re.search(rf"int {re.escape(name)}\(const casadi_real\*\* arg, casadi_real\*\* "
                      rf"res, casadi_int\* iw, casadi_real\* w, int mem\)\s*\{{\s*"
                      rf"return (casadi_f\d+)\(arg, res, iw, w, mem\);", source)
    return found.group(1) if found else name


def external_interface(name: str, inputs: list[tuple[str, int, int]],
                       outputs: list[tuple[str, int, int]],
                       work: tuple[int, int, int, int]) -> str:
    """C of CasADi's external-function interface for a hand-written ``name``: dense inputs and
    outputs ``(name, rows, columns)`` and the work sizes ``(sz_arg, sz_res, sz_iw, sz_w)``
    (``casadi.external`` and the compile cache's verification read these)."""
    def sparsity(side: str, entries: list[tuple[str, int, int]]) -> str:
        lines = [f"static const casadi_int {name}_sp_{side}{i}[3] = {{{r}, {c}, 1}};"
                 for i, (_, r, c) in enumerate(entries)]
        cases = "\n".join(f"    case {i}: return {name}_sp_{side}{i};"
                           for i in range(len(entries)))
        names = ", ".join(f'"{n}"' for n, _, _ in entries)
        return "\n".join([
            *lines,
            f"static const char* {name}_{side}_names[{len(entries)}] = {{{names}}};",
            f"CASADI_SYMBOL_EXPORT casadi_int {name}_n_{side}(void) {{ return {len(entries)}; }}",
            f"CASADI_SYMBOL_EXPORT const char* {name}_name_{side}(casadi_int i) {{",
            f"  return (i >= 0 && i < {len(entries)}) ? {name}_{side}_names[i] : 0;", "}",
            f"CASADI_SYMBOL_EXPORT const casadi_int* {name}_sparsity_{side}(casadi_int i) {{",
            "  switch (i) {", cases, "    default: return 0;", "  }", "}"])
    sz_arg, sz_res, sz_iw, sz_w = work
    return "\n".join([
        f"\n/* ---- the external interface of {name} (uavdyn.integrate.c_loop) ---- */",
        sparsity("in", inputs), sparsity("out", outputs),
        f"CASADI_SYMBOL_EXPORT int {name}_work(casadi_int* sz_arg, casadi_int* sz_res, "
        "casadi_int* sz_iw, casadi_int* sz_w) {",
        f"  if (sz_arg) *sz_arg = {sz_arg};", f"  if (sz_res) *sz_res = {sz_res};",
        f"  if (sz_iw) *sz_iw = {sz_iw};", f"  if (sz_w) *sz_w = {sz_w};", "  return 0;", "}",
        ""])


def column_major_buffers(args, shapes: list[tuple[int, ...]], what: str) -> list[np.ndarray]:
    """Each argument as a contiguous float64 buffer in CasADi's column-major layout, its size
    checked against ``shapes`` (a transposed row-per-sample array passes without a copy)."""
    buffers = []
    for k, (value, shape) in enumerate(zip(args, shapes)):
        a = np.asarray(value, dtype=float)
        if a.size != int(np.prod(shape)):
            raise ValueError(f"{what} input {k} has {a.size} values, expected "
                             f"{int(np.prod(shape))} (shape {shape})")
        buffers.append(np.ascontiguousarray(a.reshape(shape or (1,), order="F")
                                            .ravel(order="F")))
    return buffers


def work_sizes(library: ctypes.CDLL, name: str) -> tuple[int, int, int, int]:
    """``(sz_arg, sz_res, sz_iw, sz_w)`` as the library's ``<name>_work`` reports them."""
    sizes = [ctypes.c_longlong() for _ in range(4)]
    getattr(library, f"{name}_work")(*(ctypes.byref(v) for v in sizes))
    return tuple(int(v.value) for v in sizes)


def write_loop_source(step: ca.Function, n_samples: int, substeps: int, name: str,
                      folder: Path, file_name: str | None = None,
                      casadi_real: str = "double") -> Path:
    """Write ``<file_name or name>.c``: the step's generated code and the loop ``name(x0, u,
    p, dt[, t0]) -> x`` (the signature of :func:`uavdyn.integrate.rollout`: ``u`` is ``nu x
    N``, ``x`` the ``nx x N`` states after each interval of ``substeps`` steps; a
    time-dependent step gets ``t0`` plus the elapsed time), in ``casadi_real`` arithmetic."""
    inner = loop_step(step, f"{name}_step")
    source = generate_c(inner, folder, file_name or name, casadi_real=casadi_real)
    nx, nu, n_p = (step.size1_in(i) for i in range(3))
    timed = step.n_in() == 5
    sz_arg, sz_res, sz_iw, sz_w = loop_work_sizes(step)
    values = {"name": name, "nx": nx, "nu": nu, "np": n_p, "N": n_samples, "S": substeps,
              "sz_arg": sz_arg, "sz_res": sz_res, "sz_w_step": inner.sz_w(),
              "timed": int(timed)}
    text = source.read_text()
    values["call"] = generated_body(text, f"{name}_step")
    inputs = [("x0", nx, 1), ("u", nu, n_samples), ("p", n_p, 1), ("dt", 1, 1),
              ("t0", 1, 1)][:5 if timed else 4]
    interface = external_interface(name, inputs, [("x", nx, n_samples)],
                                   (sz_arg, sz_res, sz_iw, sz_w))
    source.write_text(text + interface + _LOOP.format(**values))
    return source


class NativeRollout:
    """The compiled loop called on NumPy buffers (``ctypes``): ``rollout(x0, u, p, dt[, t0])``
    returns the ``nx x N`` states as a NumPy array (a transposed view of a row-per-sample
    array), like the Function it replaces returns a matrix. ``function`` is that Function
    (the ``mapaccum`` rollout) for callers that need CasADi's own (``map``, symbolic calls)."""

    def __init__(self, library: ctypes.CDLL, name: str, function: ca.Function):
        self._library, self.function = library, function
        self._call = getattr(library, name)
        self._call.restype = ctypes.c_int
        self._call.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        self._sz_arg, self._sz_res, self._sz_iw, self._sz_w = work_sizes(library, name)
        self.nx, self.nu, self.np = (function.size1_in(i) for i in range(3))
        self.n_samples = function.size2_in(1)
        self.n_in = function.n_in()

    def __call__(self, *args) -> np.ndarray:
        if len(args) != self.n_in:
            raise TypeError(f"rollout takes {self.n_in} inputs (x0, u, p, dt[, t0]), got "
                            f"{len(args)}")
        shapes = [(self.nx,), (self.nu, self.n_samples), (self.np,), (), ()]
        buffers = column_major_buffers(args, shapes, "rollout")
        out = np.empty((self.n_samples, self.nx))  # row k: the states after sample k
        arg = (ctypes.c_void_p * self._sz_arg)(*(b.ctypes.data for b in buffers))
        res = (ctypes.c_void_p * self._sz_res)(out.ctypes.data)
        iw = np.zeros(max(self._sz_iw, 1), dtype=np.int64)
        w = np.zeros(max(self._sz_w, 1))
        if self._call(arg, res, iw.ctypes.data, w.ctypes.data, 0):
            raise RuntimeError("the compiled rollout reported an error")
        return out.T


_LOOP = """
/* ---- the rollout loop (uavdyn.integrate.c_loop) ---- */
CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                                casadi_real* w, int mem) {{
  const casadi_real *x_in, *u_k, *p;
  const casadi_real* step_arg[{sz_arg}];
  casadi_real* step_res[{sz_res}];
  casadi_real *buffer = w + {sz_w_step}, *zeros = buffer + 2 * {nx}, *x_out, *target;
  casadi_real dt, t;
  casadi_int i, k, s;
  if (!res[0]) return 0;
  for (i = 0; i < {nx} + {nu} + {np}; ++i) zeros[i] = 0;
  x_out = res[0];
  x_in = arg[0] ? arg[0] : zeros;
  p = arg[2] ? arg[2] : zeros;
  dt = arg[3] ? *arg[3] : 0;
  t = ({timed} && arg[4]) ? *arg[4] : 0;
  for (i = 0; i < {sz_arg}; ++i) step_arg[i] = 0;
  for (i = 0; i < {sz_res}; ++i) step_res[i] = 0;
  step_arg[2] = p;
  step_arg[3] = &dt;
  if ({timed}) step_arg[4] = &t;
  for (k = 0; k < {N}; ++k) {{
    u_k = arg[1] ? arg[1] + k * {nu} : zeros;
    for (s = 0; s < {S}; ++s) {{
      target = (s == {S} - 1) ? x_out + k * {nx} : buffer + (s & 1) * {nx};
      step_arg[0] = x_in;
      step_arg[1] = u_k;
      step_res[0] = target;
      if ({call}(step_arg, step_res, iw, w, mem)) return 1;
      x_in = target;
      t += dt;
    }}
  }}
  return 0;
}}
"""
