"""Helpers shared by the reproduce pipeline and its figures: which steps are compared, what a
sortie's target states are and which condition it was flown in."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.evaluation import step_states
from uavdyn.flightdata import Sortie
from uavdyn.integrate import (
    DiscreteModel,
    EvalGrid,
    StepUseError,
    check_use,
    compiled_rollout,
    rollout,
    takes_time,
)

FORMULATIONS = ("improved", "paper")
NOMINAL_PHYSICS = "nominal physics"
IDENTIFIED_PHYSICS = "identified physics"
# What the pipeline identifies before it learns: aerodynamic/propulsive terms (not geometry),
# the actuator lags and the unsteady or rotor-craft terms every real airframe of the kind has
# (alpha-dot moment; rotor lag, speed-stability moment, a constant moment, axial inflow). Each
# of these, left out, is absorbed by the others: without ``M_u`` and ``M_0`` the steady pitch
# command an autopilot holds against them reads as missing authority (``pitch_mix`` ran to its
# bound), without the lags the control derivatives shrink. The same lists as
# analysis/bench_identify.py measures.
IDENTIFY_PARAMS = {
    "fixed_wing": ("C_m_alpha", "C_m_q", "C_m_0", "C_m_delta_e", "C_L_alpha", "C_D_0",
                   "tau_elevator", "tau_throttle", "C_m_alpha_dot"),
    "multirotor": ("pitch_mix", "pitch_damping", "drag_linear", "CdA_x", "CdA_z", "c_T",
                   "tau_rotor", "M_u", "M_0", "k_inflow"),
}


def target_states(sortie: Sortie) -> np.ndarray:
    """The flight-data target: noise-free true states where the data has them."""
    return sortie.true_states if sortie.true_states is not None else sortie.states


def condition(sortie: Sortie) -> str:
    return str(sortie.meta.get("condition", "") or "unknown")


def identification_sorties(sorties: list[Sortie], minimum: int = 3) -> tuple[list[Sortie], str]:
    """The sorties to identify the physics on: the calm ones where the data label at least
    ``minimum`` of them, else all. Output error has no wind model; gusts are unmodelled inputs
    that fitted coefficients would absorb (identification manoeuvres are flown in calm air)."""
    calm = [s for s in sorties if condition(s) == "calm"]
    return (calm, "calm train") if len(calm) >= minimum else (list(sorties), "train")


def provenance() -> dict:
    """What produced a result: package version, git commit of the source tree when it is a
    checkout (None for a wheel install), and the versions of the numerical stack."""
    import platform
    import subprocess

    import casadi

    import uavdyn

    commit = None
    source = Path(uavdyn.__file__).resolve().parent.parent
    if (source / ".git").exists():
        try:
            done = subprocess.run(["git", "-C", str(source), "rev-parse", "HEAD"],
                                  capture_output=True, text=True, timeout=5, check=False)
            commit = done.stdout.strip() or None
            dirty = subprocess.run(["git", "-C", str(source), "status", "--porcelain",
                                    "--untracked-files=no"], capture_output=True, text=True,
                                   timeout=5, check=False).stdout.strip()
            if commit and dirty:
                commit += " (with uncommitted changes)"
        except (OSError, subprocess.SubprocessError):
            commit = None
    return {"uavdyn": uavdyn.__version__, "commit": commit,
            "python": platform.python_version(), "numpy": np.__version__,
            "casadi": casadi.__version__, "machine": platform.machine()}


def flight_mode(kind: str) -> str:
    """How accuracy against flight data is measured: whole-sortie free run for the fixed wing;
    1 s predictions restarted from the recorded state for the quadrotor, whose open-loop pitch
    is neutrally stable (a replay of logged commands drifts away for any imperfect model)."""
    return "free_run" if kind == "fixed_wing" else "horizon_1s"


def refusal(step, dt: float, t_end: float = 0.0) -> str | None:
    """Why ``step`` may not be used at ``dt`` up to ``t_end`` s into a sortie (a correction
    tied to its trained step size or time range), or None."""
    try:
        check_use(step, dt, 0.0, t_end)
    except StepUseError as exc:
        return str(exc)
    return None


def usable(step, dt: float) -> bool:
    """Whether ``step`` may be used at ``dt`` (a dt-bound correction only at its own)."""
    return refusal(step, dt) is None


def history_path(path) -> Path:
    """The training history beside a weight file (``<stem>_history.json``), or ``path`` itself
    when it is one (a run that kept no weights leaves only its history)."""
    path = Path(path)
    return path if path.name.endswith("_history.json") else path.with_name(
        path.stem + "_history.json")


def free_run_runner(step: DiscreteModel, x0: np.ndarray, controls: np.ndarray, p: np.ndarray,
                    sample_dt: float, dt: float, compiled: bool = True):
    """A callable running one whole-sortie free run of ``step`` (``controls`` one row per log
    interval) and returning the body states at the log times, or, when ``dt`` is a multiple
    of the log interval, at the solver's own grid points: the solver samples the logged
    command at its own step start, whole steps only (as
    :func:`uavdyn.evaluation.evaluate_trajectory` does). This is what is timed (inputs
    converted once, outside the callable). A model with extra states (actuators, delay
    buffers, command memory) starts with them at rest on the first command
    (:meth:`DiscreteModel.initial_state`)."""
    g = EvalGrid(sample_dt, dt)
    if g.stride > 1:  # the solver's own grid: one command per solver step
        controls = controls[:len(controls) - len(controls) % g.stride:g.stride]
        g = EvalGrid(dt, dt)
    check_use(step, dt, 0.0, len(controls) * g.sample_dt)
    func = (compiled_rollout(step, len(controls), g.substeps) if compiled
            else rollout(step, len(controls), g.substeps))
    z0 = step_states(step, x0[None, :], controls[:1], p, g)[0]
    if isinstance(func, ca.Function):
        args = [ca.DM(z0), ca.DM(np.ascontiguousarray(controls.T)), ca.DM(p), dt]
    else:  # the compiled loop reads NumPy buffers as they are
        args = [z0, np.ascontiguousarray(controls).T, np.asarray(p, float), dt]
    if takes_time(step):
        args.append(0.0)

    def run() -> np.ndarray:
        return np.vstack([x0, np.asarray(func(*args))[:len(x0)].T])

    return run
