"""Dependency-free C deployment bundle of a step Function (plain RK4 or hybrid): generated
``.c``, a documented ``.h``, a README, a Makefile and an example ``main.c`` that simulates a
doublet and prints the trajectory as CSV. No CasADi and no malloc at run time; builds with
``cc -std=c99 -Wall -Wextra -Werror``; ``double`` by default, ``float`` for microcontrollers.

An airframe with actuator lags or transport delays is exported on its augmented state (the
step of :func:`uavdyn.integrate.physics_step`); the header and README list the states in
order, and the trim state has every actuator at its command and every buffer full of it
(:func:`model_bundle_spec` fills all of it in from a discrete model and a trim point).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.integrate import DiscreteModel, generate_c
from uavdyn.integrate.c_loop import loop_work_sizes, write_loop_source
from uavdyn.linear import TrimPoint, point_params
from uavdyn.linear.trim import step_inputs
from uavdyn.outputs import output_folder

C_FLAGS = "-std=c99 -O2 -Wall -Wextra -Werror"
_FUNC_DEF = re.compile(
    r"^(?:static |CASADI_SYMBOL_EXPORT )?[A-Za-z_][\w \*]*?\b\w+\((?P<params>[^()]*)\) \{$",
    re.MULTILINE)


@dataclass(frozen=True)
class BundleSpec:
    """What the bundle computes and the defaults its example uses."""

    name: str
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    param_names: tuple[str, ...]
    p: np.ndarray
    x0: np.ndarray
    u_trim: np.ndarray
    dt: float
    doublet_amplitude: float
    doublet_channel: int = 0
    example_steps: int = 1000
    real: str = "double"
    rollout_steps: int = 0
    has_time_input: bool = False


def model_bundle_spec(name: str, model: DiscreteModel, point: TrimPoint, dt: float,
                      **options) -> BundleSpec:
    """The :class:`BundleSpec` of a discrete model at a trim point of its airframe: the model's
    state, control and parameter names, ``p`` at the point's altitude, the model's state at
    the trim (:meth:`DiscreteModel.initial_state`: actuators, buffers and command memory at
    rest on the trim command) and the example doublet (2 deg of elevator for a fixed wing,
    0.05 of pitch command for a multirotor) unless ``options`` say otherwise (any other
    :class:`BundleSpec` field).

    Raises
    ------
    ValueError
        If the model was built without an airframe.
    """
    if model.airframe is None:
        raise ValueError(f"model '{model.name}' was built without an airframe: build it with "
                         "one (uavdyn.physics_step(airframe), hybrid_step(weights, airframe))")
    fixed_wing = model.kind == "fixed_wing"
    options.setdefault("doublet_amplitude", math.radians(2.0) if fixed_wing else 0.05)
    options.setdefault("doublet_channel", 0 if fixed_wing else 1)
    options.setdefault("has_time_input", model.takes_time)
    p = point_params(model.airframe, point)
    x = np.asarray(point.x, float)
    if model.layout.with_position:
        x = np.concatenate([x, [0.0, point.altitude_m or 0.0]])
    u = step_inputs(model.airframe, point.u)  # lateral inputs (turning flight): wings level
    return BundleSpec(name, model.state_names, model.control_names, model.param_names, p,
                      model.initial_state(x, u, p, dt), u, dt, **options)


def _state_notes(state_names: tuple[str, ...]) -> list[str]:
    """One line per augmented state kind present (actuator lags, delay buffers)."""
    notes = []
    if any(n.endswith("_actuator") for n in state_names):
        notes.append("'<control>_actuator': the actuator, following its (delayed) command with "
                     "a first-order lag.")
    if any("_delay_" in n for n in state_names):
        notes.append("'<control>_delay_k': the command given k calls ago (a delay of d "
                     "samples: the command of call n acts from call n + d).")
    if any("_memory_" in n for n in state_names):
        notes.append("'<control>_memory_<tau>s': the command low-passed with time constant tau "
                     "(the learned correction's command memory).")
    if notes:
        notes.append("Start at rest: each actuator at its command, each buffer full of it (as "
                     "the trim state is).")
    return notes


def silence_unused_parameters(source: str) -> str:
    """Insert ``(void)param;`` into every generated function so ``-Wextra -Werror`` accepts
    CasADi's uniform signatures (work vectors a given function does not use)."""
    def add_voids(match: re.Match) -> str:
        names = [re.findall(r"\w+", p)[-1] for p in match.group("params").split(",")
                 if p.strip() and p.strip() != "void"]
        voids = " ".join(f"(void){n};" for n in names)
        return match.group(0) + (f"\n  {voids}" if voids else "")

    return _FUNC_DEF.sub(add_voids, source)


def _c_array(values) -> str:
    return ", ".join(f"{float(v):.17g}" for v in np.ravel(values))


def _renamed(func: ca.Function, name: str) -> ca.Function:
    args = func.mx_in()
    return ca.Function(name, args, func.call(args), func.name_in(), func.name_out())


def export_bundle(step: DiscreteModel | ca.Function, spec: BundleSpec, out_dir: str | Path,
                  force: bool = False) -> Path:
    """Write the bundle for ``step`` (a model, or a Function ``(x, u, p, dt) -> x_next``, or
    ``(x, u, p, dt, t)`` for the paper formulation) into ``out_dir``.

    The bundle is written into a temporary sibling folder and renamed into place when complete;
    a non-empty ``out_dir`` that is not an earlier bundle is refused unless ``force``."""
    if spec.real not in ("double", "float"):
        raise ValueError(f"real must be 'double' or 'float', got {spec.real!r}")
    if not re.fullmatch(r"[A-Za-z_]\w*", spec.name):
        raise ValueError(f"bundle name must be a C identifier, got {spec.name!r}")
    if spec.doublet_channel not in range(len(spec.control_names)):
        raise ValueError(f"doublet_channel must index a control, got {spec.doublet_channel}")
    if spec.rollout_steps and spec.has_time_input:
        raise ValueError("a rollout bundle needs a time-free step (the 'improved' formulation "
                         "or plain RK4)")
    if isinstance(step, DiscreteModel):
        if step.dt is not None:
            step.check_use(spec.dt)
        step = step.function
    nz = step.size1_in(0)
    if len(spec.state_names) != nz or np.size(spec.x0) != nz:
        raise ValueError(f"step '{step.name()}' has {nz} states; the spec names "
                         f"{len(spec.state_names)} and its x0 has {np.size(spec.x0)} "
                         "(a model's own spec: model_bundle_spec)")
    with output_folder(out_dir, "export-c", force) as tmp:
        _write_bundle(step, spec, tmp)
    return Path(out_dir)


def _write_bundle(step: ca.Function, spec: BundleSpec, out: Path) -> Path:
    n, N = spec.name, spec.name.upper()
    if spec.rollout_steps:  # a plain C loop around the step: no per-step copies
        source = write_loop_source(step, spec.rollout_steps, 1, f"{n}_casadi", out,
                                   file_name=f"{n}_generated", casadi_real=spec.real)
        sz_arg, sz_res, sz_iw, sz_w = loop_work_sizes(step)
    else:
        func = _renamed(step, f"{n}_casadi")
        source = generate_c(func, out, name=f"{n}_generated", casadi_real=spec.real)
        sz_arg, sz_res, sz_iw, sz_w = func.sz_arg(), func.sz_res(), func.sz_iw(), func.sz_w()
    source.write_text(silence_unused_parameters(source.read_text()))
    real = spec.real
    nx, nu, n_p = len(spec.state_names), len(spec.control_names), len(spec.param_names)
    t_param = f"{real} t, " if spec.has_time_input else ""  # after dt, as in the step
    t_doc = "t is the absolute time in s (paper formulation). " if spec.has_time_input else ""
    if spec.rollout_steps:
        doc = (f"Rollout of {N}_ROLLOUT_STEPS steps: u holds NU x N controls, step k uses "
               f"u[k*NU .. k*NU+NU-1]; x_out receives the NX x N states after each step.")
    else:
        doc = "One step: x_out = state after one step of dt from x with u held constant."
    notes = "".join(f"\n *   {line}" for line in _state_notes(spec.state_names))
    (out / f"{n}.h").write_text(f"""\
/* {n}.h: longitudinal flight-dynamics step generated by uavdyn.
 *
 * State   x = [{", ".join(spec.state_names)}]  (SI units, radians; body axes, x fwd, z down){notes}
 * Control u = [{", ".join(spec.control_names)}]
 * Parameters p[{n_p}], in this order: {", ".join(spec.param_names)}
 * Real type: {real}. No dynamic memory: work arrays are static in {n}.c (not re-entrant).
 */
#ifndef {N}_H
#define {N}_H

#define {N}_NX {nx}
#define {N}_NU {nu}
#define {N}_NP {n_p}
#define {N}_ROLLOUT_STEPS {spec.rollout_steps}

/* Parameter vector of the exported airframe, its trim state/control, the step size. */
extern const {real} {n}_default_p[{n_p}];
extern const {real} {n}_trim_x[{nx}];
extern const {real} {n}_trim_u[{nu}];
extern const {real} {n}_default_dt;

/* {doc}
 * {t_doc}Returns 0 on success. */
int {n}(const {real}* x, const {real}* u, const {real}* p, {real} dt, {t_param}{real}* x_out);

#endif
""")
    inputs = ["x", "u", "p", "&dt"] + (["&t"] if spec.has_time_input else [])
    assign = " ".join(f"arg_buf[{i}] = {a};" for i, a in enumerate(inputs))
    (out / f"{n}.c").write_text(f"""\
/* {n}.c: allocation-free wrapper around the CasADi-generated code in {n}_generated.c. */
#include "{n}.h"

#define casadi_real {real}
#define casadi_int long long int
int {n}_casadi(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
               int mem);

const {real} {n}_default_p[{n_p}] = {{{_c_array(spec.p)}}};
const {real} {n}_trim_x[{nx}] = {{{_c_array(spec.x0)}}};
const {real} {n}_trim_u[{nu}] = {{{_c_array(spec.u_trim)}}};
const {real} {n}_default_dt = {spec.dt:.17g};

static const casadi_real* arg_buf[{max(sz_arg, 1)}];
static casadi_real* res_buf[{max(sz_res, 1)}];
static casadi_int iw_buf[{max(sz_iw, 1)}];
static casadi_real w_buf[{max(sz_w, 1)}];

int {n}(const {real}* x, const {real}* u, const {real}* p, {real} dt, {t_param}{real}* x_out) {{
  {assign}
  res_buf[0] = x_out;
  return {n}_casadi(arg_buf, res_buf, iw_buf, w_buf, 0);
}}
""")
    _write_example(spec, out)
    _write_readme(spec, out)
    (out / "Makefile").write_text(f"""\
# Build and run the example: make && ./example > trajectory.csv
CC ?= cc
CFLAGS ?= {C_FLAGS}

example: main.c {n}.c {n}_generated.c {n}.h
\t$(CC) $(CFLAGS) -o $@ main.c {n}.c {n}_generated.c -lm

clean:
\trm -f example
""")
    return out


def _write_readme(spec: BundleSpec, out: Path) -> None:
    n = spec.name
    states = "\n".join(f"{i}. `{name}` (trim {float(v):.17g})"
                        for i, (name, v) in enumerate(zip(spec.state_names,
                                                          np.ravel(spec.x0))))
    controls = "\n".join(f"{i}. `{name}` (trim {float(v):.17g})"
                          for i, (name, v) in enumerate(zip(spec.control_names,
                                                            np.ravel(spec.u_trim))))
    notes = "".join(f"\n{line}\n" for line in _state_notes(spec.state_names))
    (out / "README.md").write_text(f"""\
# {n}: longitudinal flight-dynamics step (generated by uavdyn)

`{n}(x, u, p, dt, {"t, " if spec.has_time_input else ""}x_out)` in `{n}.h`; real type `{spec.real}`;
no CasADi and no dynamic memory at run time. Build and run the example:
`make && ./example > trajectory.csv`.

## State x, in order ({len(spec.state_names)} values; SI units, radians, body axes)

{states}
{notes}
## Control u, in order

{controls}

## Parameters p, in order ({len(spec.param_names)} values; defaults in `{n}_default_p`)

{", ".join(spec.param_names)}
""")


def _write_example(spec: BundleSpec, out: Path) -> None:
    n, N = spec.name, spec.name.upper()
    steps = spec.rollout_steps or spec.example_steps
    fmt = "%.17g" if spec.real == "double" else "%.9g"
    n_cols = 1 + len(spec.state_names) + len(spec.control_names)
    header = ",".join(("time",) + spec.state_names + spec.control_names)
    row_args = ", ".join(
        ["(double)k * (double)dt"]
        + [f"(double)x[{i}]" for i in range(len(spec.state_names))]
        + [f"(double)u[(k < STEPS ? k : STEPS - 1) * {N}_NU + {i}]"
           for i in range(len(spec.control_names))])
    t_arg = "(double)k * (double)dt, " if spec.has_time_input else ""
    if spec.rollout_steps:
        loop = f"""\
  static {spec.real} traj[{N}_NX * STEPS];
  if ({n}(x, u, {n}_default_p, dt, traj) != 0) return 1;
  for (k = 0; k <= STEPS; ++k) {{
    if (k > 0) for (i = 0; i < {N}_NX; ++i) x[i] = traj[(k - 1) * {N}_NX + i];
    printf("{",".join([fmt] * n_cols)}\\n", {row_args});
  }}"""
    else:
        loop = f"""\
  for (k = 0; k <= STEPS; ++k) {{
    printf("{",".join([fmt] * n_cols)}\\n", {row_args});
    if (k == STEPS) break;
    if ({n}(x, u + k * {N}_NU, {n}_default_p, dt, {t_arg}x_next) != 0) return 1;
    for (i = 0; i < {N}_NX; ++i) x[i] = x_next[i];
  }}"""
    (out / "main.c").write_text(f"""\
/* Example: a doublet on control {spec.doublet_channel} from trim, printed as CSV on stdout. */
#include <stdio.h>
#include "{n}.h"

#define STEPS {steps}
#define DOUBLET_AMPLITUDE {spec.doublet_amplitude:.17g}
#define CH {spec.doublet_channel}

int main(void) {{
  static {spec.real} u[{N}_NU * STEPS];
  {spec.real} x[{N}_NX], x_next[{N}_NX];
  const {spec.real} dt = {n}_default_dt;
  int k, i;
  (void)x_next;
  for (i = 0; i < {N}_NX; ++i) x[i] = {n}_trim_x[i];
  for (k = 0; k < STEPS; ++k) {{
    /* the doublet switches on the step grid: +A on [0.5, 1) s, -A on [1, 1.5) s */
    long ms = (long)(k * (double)dt * 1e6 + 0.5);
    for (i = 0; i < {N}_NU; ++i) u[k * {N}_NU + i] = {n}_trim_u[i];
    if (ms >= 500000 && ms < 1000000) u[k * {N}_NU + CH] += ({spec.real})DOUBLET_AMPLITUDE;
    else if (ms >= 1000000 && ms < 1500000) u[k * {N}_NU + CH] -= ({spec.real})DOUBLET_AMPLITUDE;
  }}
  printf("{header}\\n");
{loop}
  return 0;
}}
""")


def doublet_controls(spec: BundleSpec) -> np.ndarray:
    """The example's control sequence in Python (``steps x nu``), for checking its output."""
    steps = spec.rollout_steps or spec.example_steps
    u = np.tile(np.asarray(spec.u_trim, float), (steps, 1))
    us = np.rint(np.arange(steps) * spec.dt * 1e6)
    ch = spec.doublet_channel
    u[(us >= 500000) & (us < 1000000), ch] += spec.doublet_amplitude
    u[(us >= 1000000) & (us < 1500000), ch] -= spec.doublet_amplitude
    return u
