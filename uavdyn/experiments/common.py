"""Helpers shared by the reproduce pipeline and its figures: which steps are compared, what a
sortie's target states are and which condition it was flown in."""

from __future__ import annotations

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.learned import hybrid_step

FORMULATIONS = ("improved", "paper")
TARGETS = ("data", "reference")
NOMINAL_PHYSICS = "RK4 nominal physics"
IDENTIFIED_PHYSICS = "RK4 identified physics"
# What the pipeline identifies before it learns (aerodynamic/propulsive terms, not geometry);
# the same lists as analysis/bench_identify.py measures.
IDENTIFY_PARAMS = {
    "fixed_wing": ("C_m_alpha", "C_m_q", "C_m_0", "C_m_delta_e", "C_L_alpha", "C_D_0"),
    "multirotor": ("pitch_mix", "pitch_damping", "drag_linear", "CdA_x", "CdA_z", "c_T"),
}


def target_states(sortie: Sortie) -> np.ndarray:
    """The flight-data target: noise-free true states where the data has them."""
    return sortie.true_states if sortie.true_states is not None else sortie.states


def condition(sortie: Sortie) -> str:
    return str(sortie.meta.get("condition", "") or "unknown")


def hybrid_steps(airframe: Airframe, nets: dict, target: str = "data", suffix: str = "") -> dict:
    """``{"hybrid <formulation><suffix>": step}`` for every formulation with weights for
    ``target`` (uncompiled SX steps: exact derivatives, compiled where a rollout is timed)."""

    return {f"hybrid {f}{suffix}": hybrid_step(nets[(f, target)], airframe, compile=False)
            for f in FORMULATIONS if nets.get((f, target)) is not None}


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
    from pathlib import Path

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
