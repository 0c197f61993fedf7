"""The hybrid step: the physics RK4 step plus the learned correction as ONE CasADi Function
``(x, u, p, dt) -> x_next`` (a time-dependent formulation adds the named input ``t``), compiled
to C, with exact Jacobians for ``nlpsol``/``Opti``.

No torch at run time: the network comes from a weight file (:mod:`uavdyn.learned.weights`).
:func:`hybrid_step` returns a :class:`uavdyn.integrate.DiscreteModel`: a formulation valid
only at its trained step size or time range carries those limits, and every rollout of the
library refuses a use outside them.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import casadi as ca

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.integrate import (
    STEP_INPUTS,
    DiscreteModel,
    StateLayout,
    compile_function,
    step_jacobians,
)
from uavdyn.learned.weights import CorrectionNet, WeightFileError, load_weights
from uavdyn.model import CASADI_OPS, ModelStructure, make_rhs, structure_of
from uavdyn.model.equations import as_structure

SHIPPED = "uavdyn.learned.shipped"


SHIPPED_FORMULATIONS = ("safe", "paper")


def shipped_weights(airframe_name: str, formulation: str = "safe") -> Path:
    """Path of a shipped weight file (package data) for a preset (``aerosonde`` or ``f450``):
    ``"safe"``, the default correction (trained on the preset's identified airframe: pair it
    with :func:`shipped_identified`, or use :func:`shipped_correction`), or ``"paper"``, the
    paper's own formulation (time and state in, state increment out) on the nominal preset,
    kept for the report's Table 1 column of the paper's method.

    Raises
    ------
    WeightFileError
        If no such file ships with the package (e.g. the preset's training kept no safe
        correction: the message gives the trainer's reason).
    """
    if formulation not in SHIPPED_FORMULATIONS:
        raise WeightFileError(f"no shipped weights of formulation '{formulation}'; shipped "
                              f"formulations: {', '.join(SHIPPED_FORMULATIONS)}")
    if formulation == "safe":
        return shipped_correction(airframe_name)[0]
    name = f"{airframe_name}_{formulation}.npz"
    path = Path(str(resources.files(SHIPPED).joinpath(name)))
    if not path.is_file():
        raise WeightFileError(f"{name}: no shipped weights for airframe '{airframe_name}', "
                              f"formulation '{formulation}'")
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
    u = ca.SX.sym("u", structure.nu)
    p, dt, t = ca.SX.sym("p", structure.np), ca.SX.sym("dt"), ca.SX.sym("t")
    x_next = form.step(f, x, u, p, dt, lambda inp: net.casadi(inp, relu_smoothing), CASADI_OPS,
                       t if form.takes_time else None, layout)
    inputs, names = [x, u, p, dt], list(STEP_INPUTS)
    if form.takes_time:
        inputs, names = [*inputs, t], [*names, "t"]
    return ca.Function(name, inputs, [x_next], names, ["x_next"])


def hybrid_step(net: CorrectionNet | str | Path, airframe: Airframe | None = None,
                compile: bool = True, name: str = "hybrid_step",
                relu_smoothing: float | None = None, strict: bool = True) -> DiscreteModel:
    """Build the hybrid step of ``net`` (a :class:`CorrectionNet` or a weight-file path).

    Parameters
    ----------
    net : CorrectionNet or path
        The correction.
    airframe : Airframe, optional
        Checked against the weights' airframe hash; its structure (actuator lags, delays,
        tables, density) is the physics the correction runs on.
    compile : bool
        Compile to C (cached); the VM with one warning where no compiler exists.
    relu_smoothing : float, optional
        Softplus sharpness replacing ReLU, for gradient-based optimisers only.
    strict : bool
        Whether a use at another ``dt`` or time range raises (default) or only warns.

    Returns
    -------
    DiscreteModel
        ``(x, u, p, dt[, t]) -> x_next`` on the body, actuator, delay-buffer and command-memory
        states (``state_names``), with the step size and time range it may be used at.
    """
    net = _resolve(net, airframe)
    structure = correction_structure(airframe, net.kind, net.formulation)
    function = hybrid_expression(net, relu_smoothing, name, structure=structure)
    # delay buffers count calls of the step: such a step is tied to the step size it was
    # trained at (the data's sample period), like a formulation that is dt-bound
    tied = net.form.dt_bound or structure.n_buffer > 0
    memory = tuple(net.memory_tau) if net.formulation == "improved" else ()
    model = DiscreteModel(function, StateLayout(structure, memory), dt=net.dt if tied else None,
                          t_range=net.t_range if net.form.takes_time else None, strict=strict,
                          airframe=airframe,
                          description=f"physics + {net.formulation} correction")
    return model.compiled() if compile else model


def hybrid_jacobian(net: CorrectionNet | str | Path, airframe: Airframe | None = None,
                    compile: bool = True, name: str = "hybrid_jacobian") -> ca.Function:
    """``(x, u, p, dt[, t]) -> (x_next, A = dx_next/dx, B = dx_next/du)`` by exact algorithmic
    differentiation of the hybrid step, compiled to C like the step itself."""
    net = _resolve(net, airframe)
    step = hybrid_expression(net, structure=correction_structure(airframe, net.kind,
                                                                 net.formulation))
    jac = step_jacobians(step, name)
    return compile_function(jac) if compile else jac
