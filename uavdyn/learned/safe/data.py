"""The safe trainer's data: rollout windows cut from the sorties
(:func:`uavdyn.flightdata.make_windows`) with the augmented start states, parameters and
physics-only predictions the trainer needs; the network's normalisation, envelope and output
bound from the training data; and the loss normalisation that scores the physics as 1."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from uavdyn.airframes import Airframe
from uavdyn.flightdata import FlightDataError, Sortie, Windows, lowpass, make_windows
from uavdyn.integrate import DIVERGENCE_BOUND, StateLayout, compile_function, rollout
from uavdyn.integrate.start_fit import (
    fit_starts,
    start_fit_function,
    start_fit_summary,
    with_starts,
)
from uavdyn.learned.envelope import Envelope, SteadyBox, steady_samples
from uavdyn.learned.formulations import DYNAMIC_INPUTS, CorrectionLayout, network_inputs
from uavdyn.learned.safe.config import SafeConfig, SafeSetup, SafeTrainingError
from uavdyn.learned.torch_model import DTYPE
from uavdyn.linear.stiffness import step_stiffness
from uavdyn.model import sortie_params


def as_tensor(a) -> torch.Tensor:
    """A float64 torch tensor of an array (contiguous copy where needed)."""
    return torch.as_tensor(np.ascontiguousarray(a), dtype=DTYPE)


@dataclass(frozen=True)
class TrainingWindows:
    """Rollout windows from recorded states (``windows``) and what the trainer adds to them."""

    windows: Windows
    z0: np.ndarray       # (W, nz) augmented state (actuators, delays, memory) at each start
    u: np.ndarray        # (W, H, nu) commands, row k held over sample k
    y: np.ndarray        # (W, H, 4) recorded body states after each sample
    p: np.ndarray        # (W, np) the window's sortie parameters (density at its altitude)
    physics: np.ndarray  # (W, H, 4) physics-only prediction
    inputs: np.ndarray   # (N, n_in) the network's inputs at every recorded sample
    gains: np.ndarray    # (W, 3) what turns the network's outputs into accelerations at
                         # each window's start (1 for an acceleration output)
    start_fit: dict | None = None  # how the physics fitted the starts (start_fit_span)
    sample_counts: tuple[int, ...] = ()  # samples of each sortie in ``inputs``, in order

    @property
    def sortie(self) -> np.ndarray:
        """Index of the sortie each window comes from ``(W,)``."""
        return self.windows.sortie_index


def physics_rollout(setup: SafeSetup):
    """The compiled physics-only rollout over one window (mapped over windows)."""
    return compile_function(rollout(setup.physics, setup.horizon), warn=False)


def start_states(sortie: Sortie, cutoff_hz: float) -> np.ndarray:
    """The states windows start from: the records, or with ``cutoff_hz`` > 0 their zero-phase
    low-pass (the targets stay the records). A window started from a noisy record carries the
    start's noise through the whole horizon (2 mrad in pitch and 5 mrad/s in pitch rate give
    about 3 mrad at 1 s, ten times a calm sortie's model error), and a network can lower that
    error by damping the start's noise out, which makes the true dynamics worse."""
    if cutoff_hz <= 0:
        return sortie.states
    return lowpass(sortie, cutoff_hz).states


def training_windows(airframe: Airframe, setup: SafeSetup, sorties: list[Sortie],
                     physics_sim, start_lowpass_hz: float | None = None) -> TrainingWindows:
    """Windows of ``setup.horizon`` samples every ``setup.stride`` samples of ``sorties``,
    starting from :func:`start_states` at ``start_lowpass_hz`` (default: the configuration's
    ``start_lowpass_hz``).

    Raises
    ------
    SafeTrainingError
        If no sortie is longer than a window.
    """
    H, layout = setup.horizon, setup.layout
    try:
        windows = make_windows(sorties, H, every=setup.stride)
    except FlightDataError:
        raise SafeTrainingError(f"no sortie is longer than the {H}-sample rollout window") \
            from None
    states = StateLayout(layout.structure, layout.memory_tau)
    params, z = [], []
    for s in sorties:
        params.append(sortie_params(airframe, s.altitude_m))
        cutoff = setup.config.start_lowpass_hz if start_lowpass_hz is None else start_lowpass_hz
        z.append(states.states(start_states(s, cutoff), s.controls,
                               params[-1], setup.sample_dt))
    features = [network_inputs(layout, zi, s.controls, pi)
                for zi, s, pi in zip(z, sorties, params)]
    inputs = np.vstack([f for f, _ in features])
    gains = np.array([features[i][1][k] for i, k in windows.starts])
    z0 = np.array([z[i][k] for i, k in windows.starts])
    p = np.array([params[i] for i, _ in windows.starts])
    pred = _physics_prediction(physics_sim, z0[:, :layout.n_physics], windows.u, p,
                               setup.sample_dt)
    _check_physics_flies(pred.transpose(2, 0, 1), airframe, setup.sample_dt, H)
    return TrainingWindows(windows, z0, windows.u, windows.y, p, pred, inputs, gains,
                           sample_counts=tuple(len(f) for f, _ in features))


def _physics_prediction(physics_sim, z0: np.ndarray, u: np.ndarray, p: np.ndarray,
                        dt: float) -> np.ndarray:
    """Body states ``(W, H, 4)`` of the physics' run through each window."""
    W, H = u.shape[:2]
    pred = np.array(physics_sim.map(W)(z0.T, u.reshape(W * H, -1).T, p.T, dt))
    return pred[:4].reshape(4, W, H).transpose(1, 2, 0)


def start_fit_span(setup: SafeSetup) -> int:
    """Records fitted per validation window start (:mod:`uavdyn.integrate.start_fit`; 0: the
    records are the starts)."""
    n = int(round(setup.config.start_fit_s / setup.sample_dt)) + 1
    return min(n, setup.horizon) if n >= 2 else 0


def physics_fitted(w: TrainingWindows, setup: SafeSetup, physics_sim, noise: np.ndarray
                   ) -> TrainingWindows:
    """``w`` started where the physics fits each window's first records best
    (:func:`start_fit_span`; ``noise``: ``(W, 4)`` the records' white noise), with the
    physics' runs from there."""
    span, n = start_fit_span(setup), setup.layout.n_physics
    fit = start_fit_function(setup.physics.function, span)
    fits = fit_starts(fit, w.z0[:, :n], w.u, w.y, w.p.T, setup.sample_dt, noise, span)
    z0 = with_starts(w.z0, fits)
    pred = _physics_prediction(physics_sim, z0[:, :n], w.u, w.p, setup.sample_dt)
    return replace(w, z0=z0, physics=pred, start_fit=start_fit_summary(fits, w.z0, noise))


def _check_physics_flies(pred: np.ndarray, airframe: Airframe, dt: float, horizon: int) -> None:
    """Refuse, in one line, physics whose own rollouts (``pred``: body states ``(4, W, H)``)
    diverge within the windows: no loss can be scaled to it (the usual cause: a fitted model
    too stiff for one RK4 step per sample, :mod:`uavdyn.linear.stiffness`)."""
    with np.errstate(invalid="ignore"):
        bad = ~np.all(np.abs(pred) <= DIVERGENCE_BOUND, axis=(0, 2))
    n_bad = int(np.count_nonzero(bad))
    if not n_bad:
        return
    stiff = step_stiffness(airframe, dt)
    why = (f"; {stiff.describe()}: identify with the term it lacks or check the "
           "parameters that moved most" if stiff is not None and stiff.too_stiff else "")
    raise SafeTrainingError(f"the physics of '{airframe.name}' diverges within {n_bad} of "
                            f"{len(bad)} training windows of {horizon * dt:g} s from recorded "
                            f"states{why}")


STEADY_RATE_SHARE = 0.1  # a steady sample's pitch rate input: within this share of its spread
# over the training data (the trainer's level survey legs hold about 0.03 of it, its
# manoeuvres pass through it for a few samples only)
STEADY_HOLD_S = 1.0      # ... held this long either side of the sample


@dataclass(frozen=True)
class NetworkScaling:
    """The network's input normalisation, envelope and output scale and bound, from the
    training inputs and one-step residual accelerations."""

    in_mean: np.ndarray
    in_scale: np.ndarray
    envelope: Envelope
    out_scale: np.ndarray
    bound: np.ndarray

    def layout(self, setup: SafeSetup) -> CorrectionLayout:
        """The correction's layout with this envelope's gate and this bound."""
        return replace(setup.layout, gate=self.envelope.gate, bound=self.bound)


def steady_box(tr: TrainingWindows, va: TrainingWindows, names: tuple[str, ...],
               hold: int, quantile: float) -> SteadyBox | None:
    """The box of the steady flight in the training data (:class:`SteadyBox`), fading as far
    as the steady validation samples reach; None where the training data hold no steady
    stretch of ``2 hold + 1`` samples. A sample is steady while its pitch rate input stays
    within ``STEADY_RATE_SHARE`` of that input's spread over the training data for ``hold``
    samples either side."""
    rate = names.index("q_hat") if "q_hat" in names else names.index("q")
    free = [i for i, n in enumerate(names) if n in DYNAMIC_INPUTS]
    limit = STEADY_RATE_SHARE * float(np.std(tr.inputs[:, rate]))
    mask = steady_samples(tr.inputs[:, rate], tr.sample_counts, hold, limit)
    if mask.sum() < 2 * hold + 1:
        return None
    mask_va = steady_samples(va.inputs[:, rate], va.sample_counts, hold, limit)
    return SteadyBox.from_steady(tr.inputs[mask], va.inputs[mask_va] if mask_va.any() else None,
                                 free, rate, quantile)


def network_scaling(tr: TrainingWindows, cfg: SafeConfig, dt: float,
                    checked: np.ndarray | None = None, steady: SteadyBox | None = None
                    ) -> NetworkScaling:
    """:class:`NetworkScaling` of the training windows ``tr``; ``checked``: the network's
    inputs on the validation data, which with ``tr``'s set how far the gate reaches
    (``cfg.envelope_fade`` None); ``steady``: the steady box the gate adds (None: none)."""
    rows = tr.inputs
    in_mean = rows.mean(axis=0)
    in_scale = rows.std(axis=0)
    in_scale = np.where(in_scale > 1e-9 * (1 + np.abs(in_mean)), in_scale, 1.0)
    if cfg.envelope_fade is None:
        envelope = Envelope.from_evidence(rows, checked, cfg.envelope_quantile)
    else:
        envelope = Envelope.from_samples(rows, cfg.envelope_quantile, cfg.envelope_fade)
    if steady is not None:
        envelope = replace(envelope, steady=steady)
    # the residual acceleration of the first step, in the network's output units
    one_step = (tr.y[:, 0, :3] - tr.physics[:, 0, :3]) / dt / tr.gains
    out_scale = np.sqrt(np.mean(one_step**2, axis=0))
    out_scale = np.where(out_scale > 0, out_scale, 1.0)
    bound = cfg.bound_factor * np.maximum(np.quantile(np.abs(one_step), 0.999, axis=0),
                                          1e-6 * (1 + out_scale))
    return NetworkScaling(in_mean, in_scale, envelope, out_scale, bound)


@dataclass(frozen=True)
class LossScales:
    """Loss normalisation: the physics-only step scores exactly 1, per state by the physics'
    rollout error, per horizon step by the physics' error growth."""

    state: np.ndarray   # (4,)
    growth: np.ndarray  # (H,)

    def window_weights(self, err: np.ndarray) -> torch.Tensor:
        """Per-window weights from the physics' error ``err`` (W, H, 4) on each window: one
        over its normalised error, floored at 5 % of the median."""
        per_window = np.mean(np.mean((err / self.state) ** 2, axis=2) / self.growth, axis=1)
        return as_tensor(1.0 / np.maximum(per_window, 0.05 * np.median(per_window)))


def loss_scales(tr: TrainingWindows) -> LossScales:
    """:class:`LossScales` from the physics' errors on the training windows."""
    err_p = tr.physics - tr.y                                      # (W, H, 4)
    state_scale = np.sqrt(np.mean(err_p**2, axis=(0, 1)))
    state_scale = np.where(state_scale > 0, state_scale, 1.0)
    growth = np.mean((err_p / state_scale) ** 2, axis=(0, 2))       # (H,)
    return LossScales(state_scale, np.where(growth > 0, growth, 1.0))


@dataclass(frozen=True)
class WindowTensors:
    """Windows as torch tensors, with each window's loss weight."""

    z0: torch.Tensor
    u: torch.Tensor
    y: torch.Tensor
    p: torch.Tensor
    weight: torch.Tensor

    @property
    def count(self) -> int:
        return len(self.z0)

    def take(self, idx: torch.Tensor) -> WindowTensors:
        """The windows ``idx``."""
        return WindowTensors(self.z0[idx], self.u[idx], self.y[idx], self.p[idx],
                             self.weight[idx])


def window_tensors(w: TrainingWindows, scales: LossScales) -> WindowTensors:
    """``w`` as :class:`WindowTensors`, weighted by :meth:`LossScales.window_weights`."""
    return WindowTensors(as_tensor(w.z0), as_tensor(w.u), as_tensor(w.y), as_tensor(w.p),
                         scales.window_weights(w.physics - w.y))
