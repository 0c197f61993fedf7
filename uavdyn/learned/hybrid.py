"""The hybrid step: the physics RK4 step plus the learned correction as ONE CasADi Function
``(x, u, p, dt) -> x_next`` (a time-dependent formulation adds the named input ``t``), compiled
to C, with exact Jacobians for ``nlpsol``/``Opti``.

No torch at run time: the network comes from a weight file (:mod:`uavdyn.learned.weights`).
A formulation valid only at its trained step size or time range returns a :class:`HybridStep`
that knows those limits; :func:`uavdyn.integrate.check_use` (called by every rollout of the
library) refuses a use outside them.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import partial
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.integrate import STEP_INPUTS, augment_states, compile_function
from uavdyn.learned.formulations import CorrectionLayout, memory_update
from uavdyn.learned.weights import CorrectionNet, WeightFileError, load_weights
from uavdyn.model import CASADI_OPS, NUMPY_OPS, ModelStructure, make_rhs, structure_of
from uavdyn.model.equations import as_structure

SHIPPED = "uavdyn.learned.shipped"


class HybridStep(ca.Function):
    """A CasADi Function (use it like any other) that also knows the step size and time range
    its network was trained at (``None`` where the formulation is not tied to them) and, for a
    step on an augmented state, how to build that state from recorded data
    (``start_states(states, controls, p, sample_dt)``, else None)."""

    def __init__(self, func: ca.Function, trained_dt: float | None,
                 t_range: tuple[float, float] | None, strict: bool = True,
                 start_states: Callable | None = None):
        super().__init__(func)
        self.trained_dt = trained_dt
        self.t_range = t_range
        self.strict = strict
        self.start_states = start_states


def command_memory(controls, taus: tuple[float, ...], sample_dt: float) -> np.ndarray:
    """Each command low-passed at each time constant along a recorded history (``N x nu``, row
    k held over sample k; at rest on the first command): row k is the memory at sample k,
    laid out ``[tau0: u1 u2, tau1: u1 u2, ...]`` like the step's memory states."""
    controls = np.atleast_2d(np.asarray(controls, float))
    out = np.empty((controls.shape[0], controls.shape[1] * len(taus)))
    memory = list(np.tile(controls[0], len(taus)))
    for k, u in enumerate(controls):
        out[k] = memory
        memory = memory_update(memory, u, taus, sample_dt, NUMPY_OPS)
    return out


def layout_states(layout: CorrectionLayout, states, controls, p, sample_dt: float
                  ) -> np.ndarray:
    """The correction step's state at every recorded sample: the recorded body states, the
    actuator/buffer states and command memory the recorded commands imply (at rest on the first
    command)."""
    states = np.atleast_2d(np.asarray(states, float))
    z = (augment_states(layout.structure, states, controls, p, sample_dt)
         if layout.structure is not None else states)
    if layout.memory_tau:
        z = np.hstack([z, command_memory(controls, layout.memory_tau, sample_dt)])
    return z


def shipped_weights(airframe_name: str, formulation: str = "improved",
                    target: str = "data") -> Path:
    """Path of a shipped weight file (package data) for a preset (``aerosonde`` or ``f450``).

    Raises
    ------
    WeightFileError
        If no such file ships with the package.
    """
    suffix = "" if target == "data" else f"_{target}"
    name = f"{airframe_name}_{formulation}{suffix}.npz"
    path = Path(str(resources.files(SHIPPED).joinpath(name)))
    if not path.is_file():
        raise WeightFileError(f"{name}: no shipped weights for airframe '{airframe_name}', "
                              f"formulation '{formulation}', target '{target}'")
    return path


def shipped_identified(airframe_name: str) -> Airframe:
    """The airframe identified from the preset's emulated dataset (shipped beside its
    correction, and shipped alone when the correction trained on it was not kept).

    Raises
    ------
    WeightFileError
        If the package ships no identified airframe for ``airframe_name``.
    """
    toml = Path(str(resources.files(SHIPPED).joinpath(f"{airframe_name}_identified.toml")))
    if not toml.is_file():
        raise WeightFileError(f"no shipped identified airframe for '{airframe_name}'")
    return load_airframe(toml)


def shipped_correction(airframe_name: str) -> tuple[Path, Airframe]:
    """The default correction shipped for a preset: the safe weight file and the identified
    airframe it was trained on (the weights are tied to that airframe's parameter hash, so the
    pair is what ``--hybrid`` commands use when no ``--weights`` is given).

    Raises
    ------
    WeightFileError
        If the package ships no safe correction for ``airframe_name``; when its training ran
        but did not keep a correction, the message gives the trainer's reason.
    """
    base = resources.files(SHIPPED)
    weights = Path(str(base.joinpath(f"{airframe_name}_safe.npz")))
    toml = Path(str(base.joinpath(f"{airframe_name}_identified.toml")))
    if weights.is_file() and toml.is_file():
        return weights, load_airframe(toml)
    reason = not_kept_reason(airframe_name)
    if reason:
        raise WeightFileError(f"no correction ships for '{airframe_name}': its training did "
                              f"not keep one ({reason}); the identified physics ships alone "
                              f"({toml.name}); give --weights FILE for another correction")
    raise WeightFileError(f"no shipped safe correction for airframe '{airframe_name}' "
                          f"(shipped: {', '.join(shipped_corrections()) or 'none'}); give "
                          "--weights FILE")


def shipped_history(airframe_name: str) -> Path | None:
    """The shipped training history of a preset's safe correction (None if none ships)."""
    path = Path(str(resources.files(SHIPPED).joinpath(f"{airframe_name}_safe_history.json")))
    return path if path.is_file() else None


def not_kept_reason(airframe_name: str) -> str | None:
    """Why the shipped training run of a preset kept no correction (None if it kept one or
    never ran): the reason recorded in its shipped history."""
    history = shipped_history(airframe_name)
    if history is None:
        return None
    try:
        doc = json.loads(history.read_text())
    except (OSError, ValueError):
        return None
    return None if doc.get("kept", True) else str(doc.get("reason", "not kept"))


def shipped_corrections() -> list[str]:
    """Names of the presets with a shipped safe correction."""
    return sorted(str(f.name)[:-len("_safe.npz")] for f in resources.files(SHIPPED).iterdir()
                  if str(f.name).endswith("_safe.npz"))


def _resolve(net: CorrectionNet | str | Path, airframe: Airframe | None) -> CorrectionNet:
    if not isinstance(net, CorrectionNet):
        return load_weights(net, airframe)
    if airframe is not None and airframe.param_hash() != net.airframe_hash:
        raise WeightFileError(f"correction network key 'airframe_hash' is {net.airframe_hash} "
                              f"but airframe '{airframe.name}' has {airframe.param_hash()}")
    return net


def correction_structure(airframe: Airframe | None, kind: str,
                         formulation: str = "improved") -> ModelStructure:
    """The physics structure a correction runs on: the airframe's (tables, density, alpha-dot
    terms, actuator lags and delays), or the kind's default without an airframe.

    Raises
    ------
    WeightFileError
        For an airframe with actuator lags or transport delays and a formulation other than
        ``improved`` (only that one carries actuator states).
    """
    if airframe is None:
        return as_structure(kind)
    structure = structure_of(airframe)
    if structure.augmented and formulation != "improved":
        raise WeightFileError(
            f"airframe '{airframe.name}' has actuator lags or transport delays (tau_*, "
            f"[delays]); the '{formulation}' formulation works on the 4 body states only: use "
            "the 'improved' formulation")
    return structure


def hybrid_expression(net: CorrectionNet, relu_smoothing: float | None = None,
                      name: str = "hybrid_step", alpha_dot: bool | None = None,
                      structure: ModelStructure | None = None) -> ca.Function:
    """The uncompiled SX Function of the hybrid step of ``net`` on the physics ``structure``
    (default: the kind's; ``alpha_dot=False``: without the fixed-wing alpha-dot terms, for an
    airframe that does not set them)."""
    form = net.form
    structure = as_structure(structure or net.kind, alpha_dot)
    layout = net.layout(structure) if form.name == "improved" else None
    f = make_rhs(structure)
    x = ca.SX.sym("x", layout.n_state if layout is not None else 4)
    u = ca.SX.sym("u", 2)
    p, dt, t = ca.SX.sym("p", structure.np), ca.SX.sym("dt"), ca.SX.sym("t")
    x_next = form.step(f, x, u, p, dt, lambda inp: net.casadi(inp, relu_smoothing), CASADI_OPS,
                       t if form.takes_time else None, layout)
    inputs, names = [x, u, p, dt], list(STEP_INPUTS)
    if form.takes_time:
        inputs, names = [*inputs, t], [*names, "t"]
    return ca.Function(name, inputs, [x_next], names, ["x_next"])


def hybrid_step(net: CorrectionNet | str | Path, airframe: Airframe | None = None,
                compile: bool = True, name: str = "hybrid_step",
                relu_smoothing: float | None = None, strict: bool = True) -> HybridStep:
    """Build the hybrid step of ``net`` (a :class:`CorrectionNet` or a weight-file path).

    Parameters
    ----------
    net : CorrectionNet or path
        The correction.
    airframe : Airframe, optional
        Checked against the weights' airframe hash.
    compile : bool
        Compile to C (cached); the VM with one warning where no compiler exists.
    relu_smoothing : float, optional
        Softplus sharpness replacing ReLU, for gradient-based optimisers only.
    strict : bool
        Whether a use at another ``dt`` or time range raises (default) or only warns.

    Returns
    -------
    HybridStep
        One Function ``(x, u, p, dt[, t]) -> x_next``.
    """
    net = _resolve(net, airframe)
    structure = correction_structure(airframe, net.kind, net.formulation)
    step = hybrid_expression(net, relu_smoothing, name, structure=structure)
    if compile:
        step = compile_function(step)
    # delay buffers count calls of the step: such a step is tied to the step size it was
    # trained at (the data's sample period), like a formulation that is dt-bound
    tied = net.form.dt_bound or structure.n_buffer > 0
    start = None
    if net.formulation == "improved" and net.n_state != 4:
        start = partial(layout_states, net.layout(structure))
    return HybridStep(step, net.dt if tied else None,
                      net.t_range if net.form.takes_time else None, strict, start)


def hybrid_jacobian(net: CorrectionNet | str | Path, airframe: Airframe | None = None,
                    compile: bool = True, name: str = "hybrid_jacobian") -> ca.Function:
    """``(x, u, p, dt[, t]) -> (x_next, A = dx_next/dx, B = dx_next/du)`` by exact algorithmic
    differentiation of the hybrid step, compiled to C like the step itself."""
    net = _resolve(net, airframe)
    step = hybrid_expression(net, structure=correction_structure(airframe, net.kind,
                                                                 net.formulation))
    args = [ca.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
    x_next = step(*args)
    jac = ca.Function(name, args, [x_next, ca.jacobian(x_next, args[0]),
                                   ca.jacobian(x_next, args[1])],
                      [step.name_in(i) for i in range(step.n_in())], ["x_next", "A", "B"])
    return compile_function(jac) if compile else jac
