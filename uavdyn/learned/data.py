"""Training data from sorties: the target trajectories (recorded data or the baseline model's
fine-step reference), one-step pairs, rollout windows, and a stand-in data generator.

Everything works on lists of :class:`uavdyn.flightdata.Sortie`, so emulated, imported or
generated sorties plug in the same way. Row k's controls are held over ``[t_k, t_k+1)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe, load_airframe, perturb
from uavdyn.flightdata import Sortie
from uavdyn.integrate import EvalGrid, GridError, compile_function, rk4_step, rollout, substepped
from uavdyn.integrate.inputs import chirp, doublet, multistep_3211
from uavdyn.linear import trim
from uavdyn.model import CONTROL_BOUNDS, build_model

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


@dataclass
class Pairs:
    """One-step pairs: from ``x0`` at time ``t`` under ``u`` to ``x1`` one grid interval on."""

    t: np.ndarray
    x0: np.ndarray
    u: np.ndarray
    x1: np.ndarray


@dataclass
class Windows:
    """Rollout windows: ``x[:, 0]`` is the start, ``x[:, k+1]`` the target after ``u[:, k]``."""

    t: np.ndarray   # (W, H+1)
    x: np.ndarray   # (W, H+1, 4)
    u: np.ndarray   # (W, H, 2)


def _check_sortie(s: Sortie, kind: str) -> float:
    if s.kind != kind:
        raise DatasetError(f"sortie '{s.name}' is of kind '{s.kind}', the airframe is '{kind}'")
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
            out.append(Trajectory(s.name, time - s.time[0], states, controls, dt, substeps))
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
    """Windows of ``horizon`` grid intervals, starting every ``stride`` intervals."""
    if horizon < 1:
        raise DatasetError(f"rollout horizon must be >= 1, got {horizon}")
    stride = stride or max(1, horizon // 2)
    ts, xs, us = [], [], []
    for tr in trajs:
        for k in range(0, len(tr.time) - horizon, stride):
            ts.append(tr.time[k:k + horizon + 1])
            xs.append(tr.states[k:k + horizon + 1])
            us.append(tr.controls[k:k + horizon])
    if not xs:
        raise DatasetError(f"no trajectory is longer than the rollout horizon ({horizon})")
    return Windows(t=np.array(ts), x=np.array(xs), u=np.array(us))


# --- stand-in flight data: a perturbed airframe the baseline cannot reproduce ------------------

def truth_airframe(airframe: Airframe) -> Airframe:
    """A 'truth' airframe differing from the baseline in its aerodynamics and inertia.

    Fixed wing: the paper's +15 % on stability derivatives and mass terms. Multirotor: a plain
    +15 % scales mass, thrust, drag and inertia together and leaves the pitch-plane dynamics
    unchanged, so instead inertia, drag, damping and the pitch mixing gain are altered.
    """
    if airframe.kind == "fixed_wing":
        return perturb(airframe, 1.15)
    P = airframe.params
    return airframe.replace(Jy=P.Jy * 1.3, drag_linear=P.drag_linear * 1.6,
                            pitch_damping=P.pitch_damping * 2.0 + 0.01,
                            pitch_mix=P.pitch_mix * 0.85, CdA_x=P.CdA_x * 1.5 + 0.01)


def synthetic_sorties(airframe: Airframe | str, n: int, seed: int = 0, duration: float = 20.0,
                      sample_rate_hz: float = 100.0, truth: Airframe | None = None,
                      fine_dt: float = 0.001) -> list[Sortie]:
    """``n`` calm sorties of ``truth`` (default :func:`truth_airframe`) sampled at
    ``sample_rate_hz``, integrated by RK4 at ``fine_dt``: doublet, 3-2-1-1 and chirp inputs
    around trim at varied speeds. The multirotor is flown with a pitch-attitude PD loop (it is
    neutrally stable in pitch); its logged controls are the loop's commands."""
    af = load_airframe(airframe) if isinstance(airframe, str) else airframe
    truth = truth or truth_airframe(af)
    rng = np.random.default_rng(seed)
    sample_dt = 1.0 / sample_rate_hz
    sub = max(1, int(round(sample_dt / fine_dt)))
    m = int(round(duration * sample_rate_hz))
    t = np.arange(m + 1) * sample_dt
    profiles = ("doublet", "3211", "chirp")
    step = compile_function(substepped(rk4_step(build_model(truth).f), sub))
    lo, hi = np.array(CONTROL_BOUNDS[af.kind]).T
    out = []
    for i in range(n):
        profile = profiles[i % 3]
        start = rng.uniform(0.5, 2.0)
        if af.kind == "fixed_wing":
            tp = trim(truth, rng.uniform(20.0, 30.0))
            amp, channel = math.radians(rng.uniform(1.0, 4.0)) * rng.choice([-1, 1]), 0
        else:
            tp = trim(truth, 0.0)
            amp, channel = rng.uniform(0.03, 0.08) * rng.choice([-1, 1]), 1
        if profile == "doublet":
            sig = doublet(t, amp, start=start, width=rng.uniform(0.3, 1.0))
        elif profile == "3211":
            sig = multistep_3211(t, amp, start=start, unit=rng.uniform(0.2, 0.5))
        else:
            sig = chirp(t, amp, start=start, duration=min(12.0, duration - start - 1),
                        f0=0.1, f1=rng.uniform(1.0, 3.0))
        x = np.asarray(tp.x, float)
        states = np.empty((m + 1, 4))
        controls = np.empty((m + 1, 2))
        for k in range(m + 1):
            u = np.asarray(tp.u, float).copy()
            if af.kind == "fixed_wing":
                u[channel] += sig[k]
                u[1] += 0.05 * math.sin(0.3 * t[k] + i)  # gentle throttle variation
            else:
                theta_ref = 0.15 * sig[k] / 0.08
                u[1] = -1.2 * (x[3] - theta_ref) - 0.35 * x[2]
                u[0] += 0.3 * sig[k] * (1 if profile == "chirp" else 0) + 0.08 * x[1]
            u = np.clip(u, lo, hi)
            states[k], controls[k] = x, u
            x = np.array(step(x, u, truth.p, sample_dt)).ravel()
        out.append(Sortie(name=f"{af.name}_{profile}_{i:03d}", kind=af.kind, time=t.copy(),
                          states=states, controls=controls, mission=f"sysid_{profile}",
                          meta={"source": "perturbed-model stand-in", "truth": truth.name,
                                "seed": seed}))
    return out


def split_sorties(sorties: list[Sortie], fractions=(0.7, 0.15, 0.15), seed: int = 0
                  ) -> tuple[list[Sortie], list[Sortie], list[Sortie]]:
    """Train/validation/test split by sortie (never by sample), seeded."""
    idx = np.random.default_rng(seed).permutation(len(sorties))
    n_train = max(1, int(round(fractions[0] * len(sorties))))
    n_val = max(1, int(round(fractions[1] * len(sorties))))
    pick = [sorties[i] for i in idx]
    return pick[:n_train], pick[n_train:n_train + n_val], pick[n_train + n_val:]
