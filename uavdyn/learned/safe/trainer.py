"""``train_safe``: the safe correction's training run, as a chain of stages (setup, windows,
scaling, epochs, final checks, verdict; one module each)."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.integrate import StateLayout, find_compiler
from uavdyn.learned.envelope import SteadyBox
from uavdyn.learned.formulations import airspeed_input, rate_inputs
from uavdyn.learned.rules import state_noise
from uavdyn.learned.safe.config import SafeConfig, SafeResult, SafeSetup, safe_setup
from uavdyn.learned.safe.data import (
    STEADY_HOLD_S,
    STEADY_RATE_SHARE,
    LossScales,
    TrainingWindows,
    WindowTensors,
    loss_scales,
    network_scaling,
    physics_fitted,
    physics_rollout,
    start_fit_span,
    steady_box,
    training_windows,
    window_tensors,
)
from uavdyn.learned.safe.epochs import StabilityTargets, TrainingData, screened_start
from uavdyn.learned.safe.freerun import FreeRunGuard
from uavdyn.learned.safe.repair import stability_repair
from uavdyn.learned.safe.scoring import WindowLoss, fixed_windows, validation_reference
from uavdyn.learned.safe.selection import Checks, RunFacts, SeenSorties, fallback, search
from uavdyn.learned.safe.twin import CompiledTwin, FittedStartPredictor
from uavdyn.learned.safe.verdict import kept_reason, refusal_reason, validation_summary
from uavdyn.learned.stability import (
    gate_trims,
    penalty_trims,
)
from uavdyn.learned.torch_model import TorchCorrection, seeded_generator


def _seen_sorties(tr: TrainingWindows, sorties: list[Sortie], noise: np.ndarray,
                  setup: SafeSetup, physics_sim, scales: LossScales,
                  fitter: CompiledTwin | None, twin: CompiledTwin | None) -> SeenSorties:
    """The training windows as the final checks score them: from the starts each model fits
    (as the validation windows, with ``fitter``), against each sortie's own ``noise`` (per
    window)."""
    span = start_fit_span(setup)
    if span:
        tr = physics_fitted(tr, setup, physics_sim, noise)
        predict = FittedStartPredictor(fitter, noise, span)
    else:
        predict = twin.predict if twin is not None else None
    return SeenSorties(window_tensors(tr, scales),
                       validation_reference(tr, sorties, setup.horizon_sel), predict)


def _refitted_starts(cfg: SafeConfig, span: int, fitter: CompiledTwin | None,
                     records: WindowTensors, noise: np.ndarray
                     ) -> Callable[[TorchCorrection], torch.Tensor] | None:
    """The training windows' starts as a network fits them from their ``records``
    (``SafeConfig.train_refit_every``), or None (they start from the records)."""
    if not (span and cfg.train_refit_every and fitter is not None):
        return None
    refitter = FittedStartPredictor(fitter, noise, span)
    return lambda net: refitter.starts(net, records)


def _steady(cfg: SafeConfig, setup: SafeSetup, tr: TrainingWindows, va: TrainingWindows
            ) -> tuple[SteadyBox | None, str]:
    """The steady box (``cfg.steady_gate``) and one line on it; a warning where the training
    data hold no steady flight (the gate is then the training box alone)."""
    if not cfg.steady_gate:
        return None, ""
    box = steady_box(tr, va, setup.layout.input_names(),
                     max(1, round(STEADY_HOLD_S / setup.sample_dt)), cfg.envelope_quantile)
    if box is None:
        note = ("steady gate: no steady flight in the training data (the pitch rate never "
                f"held within {STEADY_RATE_SHARE:g} of its spread for {STEADY_HOLD_S:g} s "
                "either side), so the gate is the training box alone")
        warnings.warn(note, stacklevel=2)
        return None, note
    return box, "steady gate: in steady flight the network acts only inside the training "\
                "data's steady flight"


def _with_steady_box(model: TorchCorrection, layout, steady: SteadyBox):
    """Put the steady box into the trained ``model``'s envelope and gate (and return the
    layout the final checks scale from, with the same gate)."""
    envelope = replace(model.envelope, steady=steady)
    model.envelope = envelope
    model.layout = replace(model.layout, gate=envelope.gate)
    return replace(layout, gate=envelope.gate)


def train_safe(train_sorties: list[Sortie], val_sorties: list[Sortie], airframe: Airframe,
               config: SafeConfig | None = None) -> SafeResult:
    """Train the safe correction on top of ``airframe``'s physics (the identified airframe).

    Parameters
    ----------
    train_sorties, val_sorties : list of Sortie
        Training and validation sorties (one sample rate); windows restart from recorded
        states, so closed-loop data are fine.
    airframe : Airframe
        The physics the correction sits on; its lags and delays become inputs.
    config : SafeConfig, optional
        Hyper-parameters.

    Returns
    -------
    SafeResult
        ``kept`` is False, with the reason, when the correction fails the stability check or
        does not beat the physics at the selection horizon on the validation split.

    Raises
    ------
    SafeTrainingError
        If a split is empty or no sortie is longer than a rollout window.
    """
    cfg = config or SafeConfig()
    rng = seeded_generator(cfg.seed, cfg.threads)
    start = time.perf_counter()
    setup = safe_setup(train_sorties, val_sorties, airframe, cfg)
    cfg, dt = setup.config, setup.dt
    physics_sim = physics_rollout(setup)
    tr = training_windows(airframe, setup, train_sorties, physics_sim)
    va = training_windows(airframe, setup, val_sorties, physics_sim,
                          cfg.validation_start_lowpass_hz or cfg.start_lowpass_hz)
    span = start_fit_span(setup)
    sortie_noise = np.array([state_noise(s) for s in val_sorties])  # (n_val, 4)
    val_noise = sortie_noise[va.sortie]
    train_noise = np.array([state_noise(s) for s in train_sorties])[tr.sortie]
    if span:
        va = physics_fitted(va, setup, physics_sim, val_noise)
    fits = {"validation": va.start_fit} if span else {}
    steady, steady_note = _steady(cfg, setup, tr, va)
    # trained with a neutral steady box (the gate is the envelope's own, the twin already
    # has the box's terms); the real one is put in for the final checks
    neutral = (None if steady is None
               else SteadyBox.neutral(len(steady.low), int(np.argmax(steady.rate))))
    scaling = network_scaling(tr, cfg, dt, va.inputs, neutral)  # from the records' starts
    layout = scaling.layout(setup)
    if span and cfg.train_start_fit:
        tr = physics_fitted(tr, setup, physics_sim, train_noise)
        fits["train"] = tr.start_fit

    def network(seed: int) -> TorchCorrection:
        return TorchCorrection(airframe.kind, "improved", cfg.hidden, cfg.activation,
                               scaling.in_mean, scaling.in_scale, scaling.out_scale, dt,
                               seed=seed, structure=setup.structure, layout=layout,
                               envelope=scaling.envelope, linear=cfg.linear,
                               linear_only=(tuple(range(layout.n_inputs)) if cfg.all_linear
                                            else rate_inputs(layout) if cfg.rates_linear
                                            else ()))

    model = network(cfg.seed)
    scales = loss_scales(tr)
    gates = gate_trims(airframe, scaling.envelope, StateLayout(setup.structure,
                                                                setup.memory_tau),
                       airspeed_input=airspeed_input(airframe.kind, setup.layout.inputs))
    stab = StabilityTargets.at(setup, penalty_trims(gates, cfg.stability_trims))
    twin = (CompiledTwin(model, setup.horizon, dt, scales.state, scales.growth)
            if cfg.compiled and find_compiler() is not None else None)
    fitted = fitter = None
    if span:  # each candidate scored from the starts it fits itself (with a twin of its own
        # where training runs in torch)
        fitter = twin or CompiledTwin(model, setup.horizon, dt, scales.state, scales.growth)
        fitted = FittedStartPredictor(fitter, val_noise, span)
    train = window_tensors(tr, scales)  # the records' starts: refits start from them too
    data = TrainingData(train, window_tensors(va, scales),
                        fixed_windows(cfg, len(tr.z0), len(va.z0)),
                        WindowLoss.of(scales, cfg, dt),
                        validation_reference(va, val_sorties, setup.horizon_sel), twin,
                        torch.as_tensor(tr.inputs, dtype=model.in_mean.dtype), fitted,
                        _refitted_starts(cfg, span, fitter, train, train_noise))
    loop = screened_start(model, network, data, stab, cfg, rng, start, airframe.name)
    loop.advance(cfg.epochs)
    model, run = loop.model, loop.result()
    if steady is not None:
        layout = _with_steady_box(model, layout, steady)
    ref, horizon_s = data.reference, setup.selection_horizon_s
    checks = Checks(model, layout, model.out_scale.clone(), airframe, setup, gates.all,
                    gates.skipped, data.val, ref,
                    FreeRunGuard(setup.physics, val_sorties, airframe, setup.sample_dt,
                                 sortie_noise, cfg.free_run_ratio),
                    RunFacts(cfg, airframe.name, ref.physics_rmse, horizon_s,
                             len(run.history) - 1, len(train_sorties), len(val_sorties),
                             [t.describe() for t in gates.all], gates.skipped,
                             setup.memory_tau,
                             start, run.screened,
                             fits), data.predict)
    if cfg.seen_guard:
        checks = replace(checks, seen=_seen_sorties(tr, train_sorties, train_noise, setup,
                                                    physics_sim, scales, fitter, twin))
    found = search(checks, run)
    if cfg.stability_trims == "repair":
        found, run, _ = stability_repair(checks, run, found, data, gates.all, loop.rng, start,
                                         airframe.name)
    chosen, tried = found.chosen, found.tried
    if chosen is None:
        report = fallback(checks, run.best, tried, found.report)
        alpha, channels = cfg.shrink[0], np.ones(len(layout.bound))
        final, epoch = run.best.selection, run.best.epoch
    else:
        report, alpha, channels, final, epoch = (chosen.report, chosen.scale, chosen.channels,
                                                 chosen.selection, chosen.epoch)
    validation = validation_summary(final, ref, alpha, channels, tried, horizon_s)
    seconds = time.perf_counter() - start
    if chosen is not None:
        reason = kept_reason(final, ref.physics_rmse, alpha, channels, chosen.row, report,
                             horizon_s)
        return SafeResult(chosen.net, True, reason, run.history, cfg, epoch, seconds,
                          validation, report, run.stopped, run.screened,
                          fits, steady_note)
    reason = refusal_reason(tried, cfg, ref.physics_rmse, run.best.selection, report,
                            horizon_s)
    return SafeResult(None, False, reason, run.history, cfg, epoch, seconds, validation,
                      report, run.stopped, run.screened,
                      fits, steady_note)
