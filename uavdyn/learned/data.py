"""Training data of the paper-formulation trainer (:mod:`uavdyn.learned.train`) from sorties:
the target trajectories (recorded data or the baseline model's fine-step reference), one-step
pairs and rollout windows (:class:`uavdyn.flightdata.Windows`).

Everything works on lists of :class:`uavdyn.flightdata.Sortie`, so emulated, imported or
generated sorties plug in the same way. Row k's controls are held over ``[t_k, t_k+1)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import FlightDataError, Sortie, Windows, make_windows
from uavdyn.integrate import EvalGrid, GridError, compile_function, rk4_step, rollout
from uavdyn.model import build_model

TARGETS = ("data", "reference")
REFERENCE_DT = 1e-4  # fine step of the baseline reference (RK4 error ~1e-12 rad)


class DatasetError(ValueError):
    """The sorties cannot be turned into training data; the message says which and why."""


@dataclass
class Trajectory:
    """A target trajectory on the training grid: ``states[k+1]`` follows ``states[k]`` under
    ``controls[k]`` held for ``substeps`` hybrid steps of ``dt``."""

    name: str
    time: np.ndarray       # (M,)
    states: np.ndarray     # (M, 4)
    controls: np.ndarray   # (M-1, 2)
    dt: float
    substeps: int
    kind: str = ""

    def as_sortie(self) -> Sortie:
        """The trajectory as a sortie on its grid (its last command row repeats the one
        before: no step starts there)."""
        return Sortie(self.name, self.kind, self.time, self.states,
                      np.vstack([self.controls, self.controls[-1:]]))


@dataclass
class Pairs:
    """One-step pairs: from ``x0`` at time ``t`` under ``u`` to ``x1`` one grid interval on."""

    t: np.ndarray
    x0: np.ndarray
    u: np.ndarray
    x1: np.ndarray


def _check_sortie(s: Sortie, kind: str) -> float:
    if s.kind != kind:
        raise DatasetError(f"sortie '{s.name}' is of kind '{s.kind}', the airframe is '{kind}'")
    if s.lateral:
        raise DatasetError(f"sortie '{s.name}' carries the turning-flight inputs phi, p, r, "
                           "beta: train the safe correction (--formulation improved --target "
                           "data), the only one that takes them")
    if s.states.shape != (len(s.time), 4) or s.controls.shape != (len(s.time), 2):
        raise DatasetError(f"sortie '{s.name}': states/controls must be N x 4 / N x 2 for "
                           f"{len(s.time)} samples")
    if len(s.time) < 3:
        raise DatasetError(f"sortie '{s.name}' has fewer than 3 samples")
    steps = np.diff(s.time)
    if np.any(steps <= 0) or np.ptp(steps) > 1e-6 * np.median(steps) + 1e-12:
        raise DatasetError(f"sortie '{s.name}': time must be uniform and increasing")
    if not (np.all(np.isfinite(s.states)) and np.all(np.isfinite(s.controls))):
        raise DatasetError(f"sortie '{s.name}' contains non-finite values")
    return float(np.median(steps))


def target_trajectories(sorties: list[Sortie], airframe: Airframe, target: str, dt: float
                        ) -> list[Trajectory]:
    """The trajectories the hybrid step is trained to reproduce.

    ``data``: the recorded states (model-discrepancy correction). ``reference``: the baseline
    model integrated at a fine step from each sortie's first state with the sortie's controls
    held over each grid interval (pure numerical correction; it has little to fix unless ``dt``
    is coarse, SPEC section 8).
    """
    if target not in TARGETS:
        raise DatasetError(f"unknown target '{target}'; expected one of {TARGETS}")
    if not sorties:
        raise DatasetError("no sorties given")
    out = []
    ref_sims: dict[tuple[int, int], object] = {}
    for s in sorties:
        sample_dt = _check_sortie(s, airframe.kind)
        try:
            g = EvalGrid(sample_dt, dt)
            stride, substeps = g.stride, g.substeps
        except GridError as exc:
            raise DatasetError(f"sortie '{s.name}': {exc}") from None
        time = s.time[::stride]
        states = s.states[::stride]
        controls = s.controls[::stride][:-1]
        if target == "reference":
            interval = dt * substeps
            fine = max(1, int(math.ceil(interval / REFERENCE_DT - 1e-9)))
            n = len(controls)
            if (n, fine) not in ref_sims:
                ref_sims[n, fine] = compile_function(
                    rollout(rk4_step(build_model(airframe).f), n, fine))
            traj = np.array(ref_sims[n, fine](states[0], controls.T, airframe.p, interval / fine))
            states = np.vstack([states[0], traj.T])
            finite = np.all(np.isfinite(states), axis=1)
            if not finite.all():  # keep the part before a divergence of the baseline
                last = int(np.argmin(finite))
                states, time, controls = states[:last], time[:last], controls[:last - 1]
        if len(time) >= 3:
            out.append(Trajectory(s.name, time - s.time[0], states, controls, dt, substeps,
                                  s.kind))
    if not out:
        raise DatasetError("no usable trajectory (all shorter than 3 grid points)")
    return out


def one_step_pairs(trajs: list[Trajectory]) -> Pairs:
    """All consecutive (x_k, u_k) -> x_{k+1} pairs of all trajectories."""
    return Pairs(t=np.concatenate([tr.time[:-1] for tr in trajs]),
                 x0=np.vstack([tr.states[:-1] for tr in trajs]),
                 u=np.vstack([tr.controls for tr in trajs]),
                 x1=np.vstack([tr.states[1:] for tr in trajs]))


def rollout_windows(trajs: list[Trajectory], horizon: int, stride: int | None = None
                    ) -> Windows:
    """Windows of ``horizon`` grid intervals, starting every ``stride`` intervals (default half
    a window), over the trajectories as sorties (:meth:`Trajectory.as_sortie`)."""
    if horizon < 1:
        raise DatasetError(f"rollout horizon must be >= 1, got {horizon}")
    try:
        return make_windows([tr.as_sortie() for tr in trajs], horizon,
                            every=stride or max(1, horizon // 2))
    except FlightDataError:
        raise DatasetError(f"no trajectory is longer than the rollout horizon ({horizon})") \
            from None


def window_times(windows: Windows) -> np.ndarray:
    """Time since its sortie's start of every step of every window ``(W, H)`` (s)."""
    return np.array([windows.sorties[i].time[k:k + windows.length] for i, k in windows.starts])
