"""Window starts fitted by the model being scored (``SafeConfig.start_fit_s``,
:mod:`uavdyn.integrate.start_fit`), checked against records the physics itself flew (its own
trajectory is the exact answer), the same records with white noise of known size, a gust the
physics cannot know, and the hybrid twin with an untrained network (it is the physics)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.integrate import StateLayout, physics_step, rollout
from uavdyn.integrate.start_fit import fit_starts, start_fit_function
from uavdyn.linear import trim
from uavdyn.model import structure_of

DT = 0.01
SPAN = 21
NOISE = np.array([0.05, 0.05, 0.005, 0.002])  # u, w (m/s), q (rad/s), theta (rad)


def _flown_by_the_physics(name: str = "aerosonde", seconds: float = 12.0):
    """The physics' own trajectory from trim under elevator doublets (the records an exact
    model explains to round-off), cut into windows of 1 s every 0.37 s."""
    airframe = load_airframe(name)
    structure = structure_of(airframe)
    phys = physics_step(structure)
    t0 = trim(airframe)
    n = int(round(seconds / DT))
    t = np.arange(n) * DT
    controls = np.tile(np.asarray(t0.u, float), (n, 1))
    controls[:, 0] += 0.03 * np.sign(np.sin(2 * np.pi * 0.7 * t))
    layout = StateLayout(structure, ())
    z_first = layout.states(np.asarray(t0.x, float)[None, :4], controls[:1], airframe.p, DT)[0]
    path = np.array(rollout(phys, n - 1)(z_first, controls[:-1].T, airframe.p, DT)).T
    z = np.vstack([z_first, path])
    return airframe, phys, z, controls


def _windows(z, records, controls, H=100, every=37):
    starts = np.arange(0, len(z) - H, every)
    z0 = np.array(z[starts], float)
    z0[:, :4] = records[starts]
    u = np.array([controls[k:k + H] for k in starts])
    y = np.array([records[k + 1:k + 1 + H] for k in starts])
    return starts, z0, u, y


def _fit(phys, airframe, z0, u, y, noise=NOISE, span=SPAN):
    fit = start_fit_function(phys.function, span)
    p = np.repeat(airframe.p[:, None], len(z0), axis=1)
    return fit_starts(fit, z0, u, y, p, DT, np.tile(noise, (len(z0), 1)), span)


def test_records_the_physics_flew_are_their_own_estimate():
    """Noise-free records of the physics' own flight: the fit returns them to round-off and
    finds every window consistent (zero residual)."""
    airframe, phys, z, controls = _flown_by_the_physics()
    starts, z0, u, y = _windows(z, z[:, :4], controls)
    fits = _fit(phys, airframe, z0, u, y)
    np.testing.assert_allclose(fits.body, z[starts, :4], rtol=0, atol=1e-9)
    assert np.all(fits.chi2 < 1e-12) and np.all(fits.consistent)


def test_white_noise_is_averaged_out_of_the_start():
    """The same flight with white noise of known size on every record: the fitted starts'
    error against the noise-free flight is well under the noise (21 samples of each state
    through the physics), and the fit's residual per degree of freedom is about 1."""
    airframe, phys, z, controls = _flown_by_the_physics()
    rng = np.random.default_rng(7)
    records = z[:, :4] + rng.normal(size=(len(z), 4)) * NOISE
    starts, z0, u, y = _windows(z, records, controls)
    fits = _fit(phys, airframe, z0, u, y)
    err = np.sqrt(np.mean((fits.body - z[starts, :4]) ** 2, axis=0)) / NOISE
    raw = np.sqrt(np.mean((records[starts] - z[starts, :4]) ** 2, axis=0)) / NOISE
    assert np.all(err < 0.75), err
    assert np.all(raw > 0.6), raw             # the records themselves are off by the noise
    assert 0.7 < np.median(fits.chi2) < 1.3 and np.mean(fits.consistent) > 0.9


def test_a_gust_the_physics_cannot_know_keeps_the_record():
    """A 0.1 s pulse in the recorded w (a gust of 20 noise standard deviations the physics
    does not fly) inside a window's fitted span: that window keeps its record; windows whose span is
    clear of it are fitted."""
    airframe, phys, z, controls = _flown_by_the_physics()
    rng = np.random.default_rng(3)
    records = z[:, :4] + rng.normal(size=(len(z), 4)) * NOISE
    records[300:310, 1] += 20 * NOISE[1]
    starts, z0, u, y = _windows(z, records, controls)
    fits = _fit(phys, airframe, z0, u, y)
    hit = (starts < 310) & (starts + SPAN > 300)
    assert hit.any() and not fits.consistent[hit].any()
    np.testing.assert_array_equal(fits.body[hit], records[starts[hit]])
    clear = (starts + SPAN < 300) | (starts >= 310)
    assert np.mean(fits.consistent[clear]) > 0.9


@pytest.mark.parametrize("name", ["aerosonde", "examples/x500.toml"])
def test_an_untrained_hybrid_fits_the_starts_the_physics_fits(name, tmp_path):
    """The twin's hybrid step with an untrained network (its output is exactly zero) is the
    physics: it fits the same starts as the physics step (two independent builds of the
    step), on noisy records with the step's actuator and memory states."""
    import torch

    from uavdyn.learned.safe.data import WindowTensors
    from uavdyn.learned.safe.twin import CompiledTwin
    from uavdyn.learned.torch_model import TorchCorrection

    airframe, phys, z, controls = _flown_by_the_physics(name, 6.0)
    structure = structure_of(airframe)
    rng = np.random.default_rng(1)
    records = z[:, :4] + rng.normal(size=(len(z), 4)) * NOISE
    memory = (0.1,)
    lay = StateLayout(structure, memory)
    z_full = lay.states(z[:, :4], controls, airframe.p, DT)
    np.testing.assert_allclose(z_full[:, :z.shape[1]], z, atol=1e-9)
    starts, z0, u, y = _windows(z_full, records, controls, H=40)
    from uavdyn.learned.formulations import CorrectionLayout, network_inputs

    layout = CorrectionLayout(structure, memory)
    inputs, _ = network_inputs(layout, z_full, controls, airframe.p)
    model = TorchCorrection(airframe.kind, "improved", 4, "relu", inputs.mean(axis=0),
                            inputs.std(axis=0) + 1e-9, np.ones(3), DT, seed=0,
                            structure=structure, layout=layout)
    twin = CompiledTwin(model, 40, DT, np.ones(4), np.ones(40))
    p = np.repeat(airframe.p[None, :], len(z0), axis=0)
    D = WindowTensors(*(torch.as_tensor(a) for a in (z0, u, y, p)),
                      torch.ones(len(z0), dtype=torch.float64))
    noise = np.tile(NOISE, (len(z0), 1))
    hybrid = twin.fit_starts(model, D, noise, SPAN)
    physics = _fit(phys, airframe, z0[:, :z.shape[1]], u, y)
    np.testing.assert_allclose(hybrid.body, physics.body, rtol=0, atol=1e-9)
    np.testing.assert_allclose(hybrid.chi2, physics.chi2, rtol=1e-9)


def test_noise_resolution_bounds_the_excess_error_of_a_perfect_prediction():
    """A prediction equal to the truth scored against records with white noise: its excess
    RMSE (the noise taken off) is below :func:`noise_resolution` in about 98 % of draws (the
    floor is two standard deviations of the noise's share of the mean square error), and a
    ratio of two errors both under it is exactly 1."""
    from uavdyn.flightdata import excess_rmse
    from uavdyn.learned.rules import noise_resolution, sortie_ratio

    rng = np.random.default_rng(4)
    sigma, n = 0.002, 3000
    floor = noise_resolution(sigma, n)
    assert floor == pytest.approx(sigma * (8 / n) ** 0.25)
    excess = [excess_rmse(float(np.sqrt(np.mean(rng.normal(0, sigma, n) ** 2))), sigma)
              for _ in range(2000)]
    assert 0.95 < np.mean(np.array(excess) < floor) < 0.995
    # both within the resolution: neither a gain nor a loss; above it: the plain ratio
    assert sortie_ratio(sigma * 1.0001, sigma * 1.00001, sigma, floor) == 1.0
    e_p, e_c = 3 * floor, 1.5 * floor
    ratio = sortie_ratio(np.hypot(e_p, sigma), np.hypot(e_c, sigma), sigma, floor)
    assert ratio == pytest.approx(0.5)
    assert sortie_ratio(sigma, np.hypot(2 * floor, sigma), sigma, floor) == pytest.approx(2.0)


def test_training_scores_the_physics_from_fitted_starts_with_less_start_noise(tmp_path):
    """``train_safe`` with ``start_fit_s`` (the default) against 0: the physics' validation
    error it compares with is lower than from the raw records (the
    start's noise fitted out: emulated flights plus white noise), the run records how many
    starts the physics fitted, and the kept-or-not rules still run to a verdict."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe

    airframe = load_airframe("aerosonde")
    clean = load_dataset(emulated_dataset(tmp_path / "data", airframe, 5, 8.0)).sorties
    rng = np.random.default_rng(2)
    sorties = [dataclasses.replace(s, states=s.true_states + rng.normal(
        size=s.true_states.shape) * NOISE) for s in clean]
    base = dict(epochs=2, batches_per_epoch=2, batch_windows=6, horizon_s=1.0,
                progress=False, memory_tau=(0.1,), patience=100)
    raw = train_safe(sorties[:3], sorties[3:], airframe, SafeConfig(**base, start_fit_s=0))
    fit = train_safe(sorties[:3], sorties[3:], airframe, SafeConfig(**base))
    assert raw.start_fits == {}
    summary = fit.start_fits["validation"]
    assert summary["span_samples"] == 21 and summary["share_fitted"] > 0.5
    physics_raw = raw.history[0]["physics_val_theta_rmse"]
    physics_fit = fit.history[0]["physics_val_theta_rmse"]
    assert physics_fit < 0.9 * physics_raw, (physics_fit, physics_raw)
    assert fit.reason and len(fit.history) == 3
