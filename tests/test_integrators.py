"""RK4, rollouts and the reference solver against independent truths: convergence order,
CVODES, scipy DOP853, the plain NumPy loop, compiled C, and the linearised model."""

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from uavdyn.integrate import (
    compile_function,
    estimate_start,
    find_compiler,
    generate_c,
    reference_step,
    rk4_numpy,
    rk4_step,
    rollout,
    simulate,
    substepped,
)
from uavdyn.integrate.inputs import control_sequence
from uavdyn.linear import linearise
from uavdyn.model import build_model, numpy_rhs

CASES = {"aerosonde": ("aerosonde_trim", 0, math.radians(2.0)),
         "f450": ("f450_hover", 1, 0.02)}


def doublet_case(request, name, duration, dt, amplitude=None):
    trim_fixture, channel, default_amp = CASES[name]
    af = request.getfixturevalue(name)
    point = request.getfixturevalue(trim_fixture)
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    amp = default_amp if amplitude is None else amplitude
    U = control_sequence("doublet", t, point.u, amp, channel=channel, start=0.5, width=0.5)
    return af, point, U


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_rk4_global_error_falls_16x_when_dt_halves(name, request):
    """Switch times of the doublet lie on every grid used, so the error is pure truncation."""
    af = request.getfixturevalue(name)
    step = rk4_step(build_model(af).f)

    def final_state(dt):
        _, point, U = doublet_case(request, name, 3.0, dt)
        return simulate(step, point.x, U, af.p, dt)[-1]

    ref = final_state(0.02 / 64)
    errors = [np.abs(final_state(dt) - ref).max() for dt in (0.02, 0.01, 0.005)]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    print(name, "errors", errors, "ratios", ratios)
    for r in ratios:
        assert 14.0 <= r <= 18.0


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_fine_rk4_matches_cvodes_and_dop853(name, request):
    dt = 0.001
    af, point, U = doublet_case(request, name, 2.0, dt)
    model = build_model(af)
    rk4 = simulate(rk4_step(model.f), point.x, U, af.p, dt)
    # CVODES: one zero-order-held step per control interval, tolerance 1e-12
    cvodes = simulate(reference_step(model.f), point.x, U, af.p, dt)
    # scipy DOP853 integrated piece by piece over the intervals where the input is constant
    rhs = numpy_rhs(af.kind)
    breaks = np.flatnonzero(np.any(np.diff(U, axis=0) != 0, axis=1)) + 1
    edges = np.concatenate([[0], breaks, [len(U)]])
    x = point.x.copy()
    dop = [x]
    for a, b in zip(edges[:-1], edges[1:]):
        t_eval = np.arange(a, b + 1) * dt
        sol = scipy.integrate.solve_ivp(lambda t, y, u=U[a]: rhs(y, u, af.p),
                                        (t_eval[0], t_eval[-1]), x, method="DOP853",
                                        t_eval=t_eval, rtol=1e-12, atol=1e-12)
        assert sol.success
        dop.extend(sol.y.T[1:])
        x = sol.y[:, -1]
    dop = np.array(dop)
    assert rk4.shape == cvodes.shape == dop.shape
    err_cv = np.abs(rk4 - cvodes).max()
    err_dop = np.abs(rk4 - dop).max()
    print(name, "max |RK4 - CVODES|", err_cv, "max |RK4 - DOP853|", err_dop)
    assert err_cv < 1e-8
    assert err_dop < 1e-8


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler on this machine")
@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_compiled_vm_and_python_agree(name, request, tmp_path):
    dt = 0.01
    af, point, U = doublet_case(request, name, 3.0, dt)
    func = rollout(rk4_step(build_model(af).f), len(U))
    compiled = compile_function(func, directory=tmp_path)
    assert compiled.class_name() == "External"
    vm = np.array(func(point.x, U.T, af.p, dt)).T
    c = np.array(compiled(point.x, U.T, af.p, dt)).T
    py = rk4_numpy(numpy_rhs(af.kind), point.x, U, af.p, dt)[1:]
    assert np.abs(vm - c).max() <= 1e-12
    assert np.abs(vm - py).max() <= 1e-12
    assert np.abs(vm - point.x).max() > 1e-3  # the doublet really moved the aircraft


@pytest.mark.slow
def test_rollout_of_100k_steps_generates_small_c(aerosonde, tmp_path):
    func = rollout(rk4_step(build_model(aerosonde).f), 100_000)
    source = generate_c(func, tmp_path)
    size = source.stat().st_size
    print("C source bytes for a 100,000-step rollout:", size)
    assert size < 200_000


def test_substepped_equals_finer_rollout(aerosonde, aerosonde_trim):
    step = rk4_step(build_model(aerosonde).f)
    coarse = substepped(step, 4)
    U = np.tile(aerosonde_trim.u + [0.05, 0.0], (10, 1))
    a = simulate(coarse, aerosonde_trim.x, U, aerosonde.p, 0.02)
    b = simulate(step, aerosonde_trim.x, np.repeat(U, 4, axis=0), aerosonde.p, 0.005)[::4]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)
    with pytest.raises(ValueError, match="n_samples and substeps must be >= 1"):
        rollout(step, 0)


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_estimate_start_recovers_a_known_start_from_noisy_samples(request, name):
    """Records of a doublet from a known start off trim: without noise the fitted start is the
    known one to 1e-8; with white noise of known spread on every state, the fitted start is
    closer to the known one than the first noisy sample is, several times for u, w and theta
    (q, damped within a few samples by the short period, is seen by fewer of them)."""
    af, point, U = doublet_case(request, name, 1.0, 0.01)
    step = rk4_step(build_model(af).f)
    x_true = point.x + np.array([0.3, -0.2, 0.02, 0.01])
    clean = simulate(step, x_true, U, af.p, 0.01)
    sigma = np.array([0.05, 0.05, 0.005, 0.002])
    exact = estimate_start(step, clean[0] + 3 * sigma, U, clean, af.p, 0.01, sigma)
    np.testing.assert_allclose(exact, x_true, rtol=0, atol=1e-8)
    rng = np.random.default_rng(7)
    first, fitted = [], []
    for _ in range(20):
        noisy = clean + sigma * rng.standard_normal(clean.shape)
        first.append((noisy[0] - x_true) / sigma)
        fitted.append((estimate_start(step, noisy[0], U, noisy, af.p, 0.01, sigma) - x_true)
                      / sigma)
    rms_first = np.sqrt(np.mean(np.square(first), axis=0))
    rms_fitted = np.sqrt(np.mean(np.square(fitted), axis=0))
    assert np.all(rms_fitted < 0.7 * rms_first), (rms_first, rms_fitted)
    assert np.all(rms_fitted[[0, 1, 3]] < 0.35 * rms_first[[0, 1, 3]]), (rms_first, rms_fitted)


def test_small_doublet_matches_linear_model_to_second_order(request, aerosonde, aerosonde_trim):
    """Nonlinear minus linear response shrinks as amplitude^2 (ratio 4 when amplitude halves)."""
    dt, duration = 0.005, 4.0
    A, B = linearise(aerosonde, aerosonde_trim)
    # exact zero-order-hold discretisation of the linear model
    M = scipy.linalg.expm(np.block([[A, B], [np.zeros((2, 6))]]) * dt)
    Ad, Bd = M[:4, :4], M[:4, 4:]
    step = rk4_step(build_model(aerosonde).f)
    errors = []
    for amp in (math.radians(2.0), math.radians(1.0), math.radians(0.5)):
        _, point, U = doublet_case(request, "aerosonde", duration, dt, amp)
        nonlinear = simulate(step, point.x, U, aerosonde.p, dt) - point.x
        dx = np.zeros(4)
        linear = [dx]
        for u in U - point.u:
            dx = Ad @ dx + Bd @ u
            linear.append(dx)
        errors.append(np.abs(nonlinear[:, 3] - np.array(linear)[:, 3]).max())
        assert np.abs(nonlinear[:, 3]).max() > 10 * errors[-1]  # linear model is close
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    print("pitch error nonlinear vs linear", errors, "ratios", ratios)
    for r in ratios:
        assert 3.5 <= r <= 4.5


def test_simulate_output_layout(aerosonde, aerosonde_trim):
    step = rk4_step(build_model(aerosonde).f)
    traj = simulate(step, aerosonde_trim.x, np.tile(aerosonde_trim.u, (7, 1)), aerosonde.p, 0.01)
    assert traj.shape == (8, 4)
    np.testing.assert_allclose(traj, np.tile(aerosonde_trim.x, (8, 1)), atol=1e-9)
    assert Path(__file__).exists()
