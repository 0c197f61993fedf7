"""The safe correction (weight formats 3-4): a hand-set destabilising network is refused by the
stability check with the trim point named; far outside the training envelope the hybrid step IS
the physics step; the gate and the bound keep the step finite and within a stated distance of
the physics from 1,000 random states in and out of the envelope; the augmented layout with
command memory round-trips through the weight file and agrees between torch and CasADi; and
a short training run on data the physics cannot reproduce ends kept or refused for a stated
reason."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from uavdyn.airframes import load_airframe
from uavdyn.integrate import StateLayout, physics_step
from uavdyn.learned import CorrectionNet, hybrid_step, load_weights, save_weights
from uavdyn.learned.envelope import Envelope, SteadyBox, smoothstep, steady_samples
from uavdyn.learned.stability import check_map_stability, envelope_trims
from uavdyn.learned.torch_model import TorchCorrection
from uavdyn.linear import trim
from uavdyn.model import build_model, structure_of

DT = 0.01
MEMORY = (0.05, 0.2)


def _pitch_feedback_net(airframe, gain: float, hidden: int = 4) -> CorrectionNet:
    """A ReLU MLP whose output is ``q_dot_residual = gain * q`` exactly (q = relu(q) -
    relu(-q) through identity-like hidden layers), zero for the other outputs: with a large
    positive gain it destabilises the short-period / pitch mode."""
    n_state = structure_of(airframe).nx() + 2 * len(MEMORY)
    n_in = n_state + 2
    W0 = np.zeros((hidden, n_in))
    W0[0, 2], W0[1, 2] = 1.0, -1.0   # q is input 2
    W1 = np.eye(hidden)
    W2 = np.eye(hidden)
    W3 = np.zeros((3, hidden))
    W3[2, 0], W3[2, 1] = gain, -gain
    zeros = [np.zeros(hidden)] * 3 + [np.zeros(3)]
    envelope = Envelope(np.full(n_in, -1e3), np.full(n_in, 1e3), np.full(n_in, 1.0))
    return CorrectionNet(
        formulation="improved", activation="relu", kind=airframe.kind,
        airframe_hash=airframe.param_hash(), dt=DT, weights=(W0, W1, W2, W3),
        biases=tuple(zeros), in_mean=np.zeros(n_in), in_scale=np.ones(n_in),
        out_mean=np.zeros(3), out_scale=np.ones(3), n_state=n_state, memory_tau=MEMORY,
        envelope=envelope, out_bound=np.full(3, 1e3))


def _trims(airframe, net):
    from uavdyn.flightdata import Sortie

    point = trim(airframe)
    x = np.tile(point.x, (50, 1))
    x[:, 0] += np.linspace(-1, 1, 50) if airframe.kind == "fixed_wing" else 0.0
    sortie = Sortie("trims", airframe.kind, np.arange(50) * DT, x, np.tile(point.u, (50, 1)),
                    "survey")
    return envelope_trims(airframe, [sortie], StateLayout(structure_of(airframe), MEMORY))


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_a_destabilising_network_is_refused_with_the_trim_named(name):
    airframe = load_airframe(name)
    phys = physics_step(airframe)
    good = _pitch_feedback_net(airframe, gain=-1.0)   # extra pitch damping: stays stable
    bad = _pitch_feedback_net(airframe, gain=60.0)    # pitch-rate positive feedback
    trims, skipped = _trims(airframe, bad)
    assert trims, skipped
    ok = check_map_stability(hybrid_step(good, airframe, compile=False), phys, trims, DT)
    assert ok.ok, ok.describe()
    report = check_map_stability(hybrid_step(bad, airframe, compile=False), phys, trims, DT)
    assert not report.ok
    message = report.describe()
    assert "trim at" in message and "m/s" in message and "eigenvalue" in message
    worst = max(report.failures, key=lambda f: f.sigma_hybrid - f.allowed)
    assert worst.sigma_hybrid > 0 > worst.sigma_physics - 1e-9 or worst.sigma_physics >= 0
    assert abs(worst.eigenvalue) > 1.0


def _random_net(airframe, seed: int, envelope: Envelope, bound: np.ndarray) -> CorrectionNet:
    rng = np.random.default_rng(seed)
    n_state = structure_of(airframe).nx() + 2 * len(MEMORY)
    n_in, h = n_state + 2, 16
    sizes = [n_in, h, h, h, 3]
    W = tuple(rng.normal(0, 3.0 / math.sqrt(a), (b, a)) for a, b in zip(sizes[:-1], sizes[1:]))
    b = tuple(rng.normal(0, 1.0, n) for n in sizes[1:])
    return CorrectionNet(
        formulation="improved", activation="relu", kind=airframe.kind,
        airframe_hash=airframe.param_hash(), dt=DT, weights=W, biases=b,
        in_mean=np.zeros(n_in), in_scale=np.ones(n_in), out_mean=np.zeros(3),
        out_scale=np.full(3, 50.0), n_state=n_state, memory_tau=MEMORY, envelope=envelope,
        out_bound=bound)


def _envelope_around(airframe, point, n_in: int) -> Envelope:
    centre = np.concatenate([point.x, np.tile(point.u, len(MEMORY)), point.u])
    width = np.concatenate([[3.0, 1.0, 0.5, 0.2], np.full(n_in - 4, 0.1)])
    return Envelope(centre - width, centre + width, 0.5 * width)


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_far_outside_the_envelope_the_hybrid_is_the_physics(name):
    airframe = load_airframe(name)
    point = trim(airframe, None if name == "aerosonde" else 0.0)
    n_in = structure_of(airframe).nx() + 2 * len(MEMORY) + 2
    net = _random_net(airframe, 1, _envelope_around(airframe, point, n_in), np.full(3, 5.0))
    hyb = hybrid_step(net, airframe, compile=False)
    phys = physics_step(airframe)
    rng = np.random.default_rng(2)
    for _ in range(50):
        x = point.x + np.array([30.0, 10.0, 3.0, 1.0]) * rng.choice([-1, 1], 4)  # far outside
        z = np.concatenate([x, np.tile(point.u, len(MEMORY))])
        got = np.array(hyb(z, point.u, airframe.p, DT)).ravel()[:4]
        want = np.array(phys(x, point.u, airframe.p, DT)).ravel()
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # inside, the same network does change the step (the test above can fail)
    z = np.concatenate([point.x, np.tile(point.u, len(MEMORY))])
    inside = np.array(hyb(z, point.u, airframe.p, DT)).ravel()[:4]
    assert np.max(np.abs(inside - np.array(phys(point.x, point.u, airframe.p, DT)).ravel())) \
        > 1e-6


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_gate_and_bound_keep_the_step_finite_and_close_to_the_physics(name):
    """1,000 random states, in and out of the envelope: a network with wild weights never
    returns a non-finite state, and never moves the step further from the physics than a
    residual acceleration of at most ``bound`` held over ``dt`` can: ``|dz| <= |bound| dt
    exp(|A| dt)`` (Gronwall, ``A`` the physics Jacobian at the start; 5 % allowance for its
    change within the step)."""
    airframe = load_airframe(name)
    point = trim(airframe, None if name == "aerosonde" else 0.0)
    n_in = structure_of(airframe).nx() + 2 * len(MEMORY) + 2
    bound = np.array([2.0, 3.0, 4.0])
    net = _random_net(airframe, 3, _envelope_around(airframe, point, n_in), bound)
    hyb = hybrid_step(net, airframe)
    phys = physics_step(airframe)
    jac = build_model(airframe).jacobians
    rng = np.random.default_rng(4)
    scale = np.array([6.0, 2.0, 1.0, 0.4])
    ratios, checked = [], 0
    for _ in range(1000):
        x = point.x + scale * rng.normal(size=4) * rng.choice([0.3, 1.0, 5.0])
        u = point.u + 0.05 * rng.normal(size=2)
        z = np.concatenate([x, np.tile(u, len(MEMORY))])
        got = np.array(hyb(z, u, airframe.p, DT)).ravel()
        want = np.array(phys(x, u, airframe.p, DT)).ravel()
        if not np.all(np.isfinite(want)):
            continue  # the physics itself is undefined there (e.g. V = 0 for a fixed wing)
        assert np.all(np.isfinite(got))
        A = np.array(jac(x, u, airframe.p)[0])
        limit = np.linalg.norm(bound) * DT * math.exp(np.linalg.norm(A, 2) * DT)
        ratios.append(np.linalg.norm(got[:4] - want) / limit)
        checked += 1
    assert checked > 900
    assert max(ratios) <= 1.05, max(ratios)
    assert max(ratios) > 0.05  # the network did act somewhere (the bound was tested)


@pytest.mark.parametrize("form", ["distance", "product"])
def test_smoothstep_and_gate_are_exactly_zero_and_one(form):
    t = np.array([-1.0, 0.0, 0.5, 1.0, 2.0])
    np.testing.assert_array_equal(smoothstep(t), [0.0, 0.0, 0.5, 1.0, 1.0])
    env = Envelope(np.array([0.0]), np.array([1.0]), np.array([0.5]))
    x = np.array([[-0.6, -0.5, 0.0, 0.5, 1.0, 1.5, 1.6]])
    np.testing.assert_array_equal(env.gate(x, form=form), [0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0])
    assert 0.0 < env.gate(np.array([[-0.25]]), form=form)[0] < 1.0


def test_the_gate_reaches_as_far_as_the_training_and_validation_data_do():
    """``Envelope.from_evidence``: the box of the training quantiles; per input the fade is the
    farthest a training or validation sample lies beyond it (a training outlier, a validation
    excursion), at least 0.1 and at most 1 range width; the gate is exactly 0 there."""
    rng = np.random.default_rng(2)
    train = rng.uniform(0.0, 1.0, size=(20_000, 4))
    train[0, 0] = 1.3                 # one trained-on sample 0.3 beyond the box
    checked = rng.uniform(0.0, 1.0, size=(500, 4))
    checked[0, 1] = -0.5              # validation reaches 0.5 below
    checked[1, 3] = 12.0              # ... and 11 widths above: capped at 1
    env = Envelope.from_evidence(train, checked)
    width = env.high - env.low
    np.testing.assert_allclose(env.low, np.quantile(train, 0.001, axis=0))
    np.testing.assert_allclose(env.fade, [1.3 - env.high[0], env.low[1] + 0.5,
                                          0.1 * width[2], width[3]])
    assert env.gate(np.array([[1.3], [0.5], [0.5], [0.5]]))[0] == 0.0
    assert env.gate(np.array([[0.5], [-0.5], [0.5], [0.5]]))[0] == 0.0
    assert env.gate(np.array([[0.5], [0.5], [env.high[2] + 0.1 * width[2]], [0.5]]))[0] == 0.0
    assert 0.0 < env.gate(np.array([[1.1], [0.5], [0.5], [0.5]]))[0] < 1.0
    same = Envelope.from_evidence(train)  # without validation data: the training's reach
    assert same.fade[1] == pytest.approx(0.1 * width[1])
    constant = Envelope.from_evidence(np.column_stack([train[:, 0], np.full(len(train), 3.0)]))
    assert constant.fade[1] > 0 and constant.gate(np.array([[0.5], [3.0]]))[0] == 1.0


@pytest.mark.parametrize("form", ["distance", "product"])
def test_the_steady_box_gates_steady_flight_only(form):
    """``SteadyBox``: inputs (x, q) with x in [0, 1] trained on, steady flight (|q| <= 0.1)
    only at x in [0, 0.5] (fading out by 0.6). Steady at x = 0.8 the gate is 0; manoeuvring
    there (|q| beyond sqrt(2) x 0.1) it is the box's 1; between, it blends smoothly; the
    rate input itself is not held to the steady range."""
    steady = SteadyBox(np.array([0.0, -0.1]), np.array([0.5, 0.1]), np.array([10.0, 0.0]),
                       np.array([0.0, 10.0]))
    env = Envelope(np.array([0.0, -1.0]), np.array([1.0, 1.0]), np.array([0.5, 0.5]), steady)
    x = np.array([[0.3, 0.8, 0.8, 0.8, 0.55], [0.0, 0.0, 0.05, 0.2, 0.0]])
    g = env.gate(x, form=form)
    np.testing.assert_array_equal(g[:4], [1.0, 0.0, 0.0, 1.0])
    assert 0.0 < g[4] < 1.0                                       # in the steady fade
    blend = env.gate(np.array([[0.8], [0.12]]), form=form)[0]     # between steady and not
    assert 0.0 < blend < 1.0
    plain = Envelope(env.low, env.high, env.fade)
    np.testing.assert_array_equal(plain.gate(x, form=form), 1.0)  # the box alone lets all act
    if form == "distance":  # evaluate's share of samples the steady box held back: 1, 2, 4
        assert env.fraction_steady_held(x.T) == pytest.approx(3 / 5)
        assert plain.fraction_steady_held(x.T) is None
    assert env.terms().shape == (7, 2) and plain.terms().shape == (3, 2)


def test_steady_samples_are_held_steady_not_passing_through_zero():
    """A held segment is steady; a manoeuvre's pitch rate crossing zero is not; the hold
    does not reach across sorties."""
    t = np.arange(0.0, 10.0, 0.1)
    rate = np.where(t < 5.0, 0.01, np.sin(2.0 * t))
    mask = steady_samples(np.concatenate([rate, rate]), (len(t), len(t)), 5, 0.05)
    first = mask[:len(t)]
    assert first[:45].all() and not first[55:].any()
    np.testing.assert_array_equal(mask[len(t):], first)  # the second sortie alike


def test_the_trainer_builds_a_steady_box_from_held_pitch_rates_only():
    """``safe.data.steady_box``: from windows' inputs (alpha, q_hat, V), the box of the
    samples whose pitch rate stays within a tenth of its spread for the hold, q_hat free;
    none where no stretch is held."""
    from uavdyn.learned.safe.data import TrainingWindows, steady_box

    n = 400
    t = np.arange(n) * 0.01
    q = np.where(t < 2.0, 0.0, 0.5 * np.sin(6.0 * t))
    alpha = np.where(t < 2.0, 0.05, 0.05 + 0.1 * np.sin(6.0 * t))
    speed = np.where(t < 2.0, 12.0, 15.0)
    rows = np.column_stack([alpha, q, speed])

    def windows(inputs):
        return TrainingWindows(None, None, None, None, None, None, inputs, None,
                               sample_counts=(len(inputs),))

    box = steady_box(windows(rows), windows(rows[:50]), ("alpha", "q_hat", "V"), 50, 0.0)
    assert box.inv_fade[1] == 0.0 and box.rate[1] > 0 and box.rate[[0, 2]].tolist() == [0, 0]
    assert box.low[2] == pytest.approx(12.0) and box.high[2] == pytest.approx(12.0)
    assert steady_box(windows(rows[200:]), windows(rows[:50]), ("alpha", "q_hat", "V"), 50,
                      0.0) is None
    # asked for where the data hold no steady flight: said, not silently dropped
    from types import SimpleNamespace

    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.trainer import _steady

    setup = SimpleNamespace(layout=SimpleNamespace(input_names=lambda: ("alpha", "q_hat", "V")),
                            sample_dt=0.02)
    with pytest.warns(UserWarning, match="no steady flight in the training data"):
        box, note = _steady(SafeConfig(steady_gate=True), setup, windows(rows[200:]),
                            windows(rows[:50]))
    assert box is None and "training box alone" in note
    assert _steady(SafeConfig(), setup, windows(rows), windows(rows)) == (None, "")


@pytest.mark.parametrize("guard", ["distance-clamp", "product-tanh"])
@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_weight_file_round_trip_and_torch_equals_casadi(name, guard, tmp_path):
    import dataclasses

    airframe = load_airframe(name)
    point = trim(airframe, None if name == "aerosonde" else 0.0)
    n_in = structure_of(airframe).nx() + 2 * len(MEMORY) + 2
    net = dataclasses.replace(
        _random_net(airframe, 5, _envelope_around(airframe, point, n_in), np.full(3, 3.0)),
        guard=guard)
    path = save_weights(net, tmp_path / "safe.npz")
    back = load_weights(path, airframe)
    assert back.n_state == net.n_state and back.memory_tau == MEMORY and back.guard == guard
    np.testing.assert_array_equal(back.envelope.low, net.envelope.low)
    np.testing.assert_array_equal(back.out_bound, net.out_bound)
    hyb = hybrid_step(back, airframe, compile=False)
    module = TorchCorrection.from_net(back, structure_of(airframe))
    rng = np.random.default_rng(6)
    Z = np.array([np.concatenate([point.x + 0.3 * rng.normal(size=4),
                                  np.tile(point.u, 2) + 0.02 * rng.normal(size=4)])
                  for _ in range(20)])
    U = np.tile(point.u, (20, 1)) + 0.02 * rng.normal(size=(20, 2))
    with torch.no_grad():
        got = module.step(torch.as_tensor(Z), torch.as_tensor(U), torch.as_tensor(airframe.p),
                          DT).numpy()
    want = np.array([np.array(hyb(z, u, airframe.p, DT)).ravel() for z, u in zip(Z, U)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # memory states follow the exact first-order filter of the command
    decay = np.exp(-DT / np.array(MEMORY))
    expect = np.concatenate([U[0] + (Z[0, 4:6] - U[0]) * decay[0],
                             U[0] + (Z[0, 6:8] - U[0]) * decay[1]])
    np.testing.assert_allclose(want[0, 4:], expect, rtol=1e-14, atol=1e-14)


def test_a_steady_box_survives_the_weight_file_and_torch_equals_casadi(tmp_path):
    import dataclasses

    airframe = load_airframe("aerosonde")
    point = trim(airframe, None)
    n_in = structure_of(airframe).nx() + 2 * len(MEMORY) + 2
    env = _envelope_around(airframe, point, n_in)
    width = env.high - env.low
    inv_fade = 1.0 / (0.1 * width)
    inv_fade[2] = 0.0
    rate = np.zeros(n_in)
    rate[2] = 1.0 / (0.05 * width[2])
    steady = SteadyBox(env.low + 0.4 * width, env.high - 0.4 * width, inv_fade, rate)
    net = _random_net(airframe, 5, dataclasses.replace(env, steady=steady), np.full(3, 3.0))
    back = load_weights(save_weights(net, tmp_path / "steady.npz"), airframe)
    for key in ("low", "high", "inv_fade", "rate"):
        np.testing.assert_array_equal(getattr(back.envelope.steady, key), getattr(steady, key))
    hyb = hybrid_step(back, airframe, compile=False)
    plain = hybrid_step(dataclasses.replace(back, envelope=env), airframe, compile=False)
    module = TorchCorrection.from_net(back, structure_of(airframe))
    rng = np.random.default_rng(3)
    Z = np.array([np.concatenate([point.x + [0.5, 0.3, 0.0, 0.0] * rng.normal(size=4),
                                  np.tile(point.u, 2)]) for _ in range(20)])
    Z[10:, 2] = 0.3 * rng.normal(size=10)  # half of them manoeuvring
    U = np.tile(point.u, (20, 1))
    with torch.no_grad():
        got = module.step(torch.as_tensor(Z), torch.as_tensor(U), torch.as_tensor(airframe.p),
                          DT).numpy()
    want = np.array([np.array(hyb(z, u, airframe.p, DT)).ravel() for z, u in zip(Z, U)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    without = np.array([np.array(plain(z, u, airframe.p, DT)).ravel() for z, u in zip(Z, U)])
    assert np.max(np.abs(want - without)) > 1e-9  # the steady box acts on these states


def test_weight_file_names_its_guard_and_a_format_3_file_keeps_the_product_tanh_guard(tmp_path):
    """A file written now says ``guard = distance-clamp`` and steps with it; the same arrays as
    a format-3 file (no guard key) step with the product gate and tanh bound it was trained
    with, which differ from the default where the gate fades or the bound bites."""
    import dataclasses

    airframe = load_airframe("aerosonde")
    point = trim(airframe)
    n_in = structure_of(airframe).nx() + 2 * len(MEMORY) + 2
    net = _random_net(airframe, 5, _envelope_around(airframe, point, n_in), np.full(3, 0.5))
    path = save_weights(net, tmp_path / "now.npz")
    back = load_weights(path, airframe)
    assert back.guard == "distance-clamp"
    with np.load(path) as content:
        arrays = {k: content[k] for k in content.files if k != "guard"}
    arrays["format_version"] = np.array(3)
    old = tmp_path / "format3.npz"
    np.savez(old, **arrays)
    legacy = load_weights(old, airframe)
    assert legacy.guard == "product-tanh"
    rng = np.random.default_rng(2)
    steps = {name: hybrid_step(n, airframe, compile=False) for name, n in
             (("now", back), ("legacy", legacy),
              ("explicit", dataclasses.replace(back, guard="product-tanh")))}
    differ = 0
    for _ in range(30):
        z = np.concatenate([point.x + rng.normal(0, 1.0, 4), np.tile(point.u, len(MEMORY))])
        out = {k: np.array(f(z, point.u, airframe.p, DT)).ravel() for k, f in steps.items()}
        np.testing.assert_array_equal(out["legacy"], out["explicit"])
        differ += not np.allclose(out["legacy"], out["now"], rtol=0, atol=1e-12)
    assert differ > 0
    arrays["format_version"] = np.array(4)
    np.savez(tmp_path / "format4.npz", **arrays)
    from uavdyn.learned import WeightFileError

    with pytest.raises(WeightFileError, match="guard"):
        load_weights(tmp_path / "format4.npz", airframe)


def test_wrong_state_size_is_refused(tmp_path):
    airframe = load_airframe("aerosonde")
    net = _pitch_feedback_net(airframe, -1.0)
    lagged = airframe.replace(tau_elevator=0.05)
    from uavdyn.learned import WeightFileError

    with pytest.raises(WeightFileError, match="n_state"):
        net.layout(structure_of(lagged))


def test_gates_and_bounds_equal_their_formulas_written_out_and_ramp_is_exact():
    """Both gate forms equal the module docstring's formulas written out independently here
    (the two-sided product of ``3c^2 - 2c^3``; one smoothstep of the squared distance to the
    box), on points spread over inside, fade and outside; both bounds are the identity well
    inside and never exceed the bound; ``ramp`` is max(x, 0) bit for bit."""
    from uavdyn.learned.envelope import bounded
    from uavdyn.model.ops import NUMPY_OPS, ramp

    rng = np.random.default_rng(3)
    low = rng.normal(0, 1, 5)
    high = low + rng.uniform(0.1, 2.0, 5)
    fade = rng.uniform(0.05, 1.0, 5)
    env = Envelope(low, high, fade)
    # each input inside its range or up to 1.3 fade widths beyond either end
    x = np.array([rng.uniform(low[i] - 1.3 * fade[i], high[i] + 1.3 * fade[i], 4000)
                  for i in range(5)])

    def s(t):
        c = np.clip(t, 0.0, 1.0)
        return 3 * c**2 - 2 * c**3

    product = np.prod([s((x[i] - low[i] + fade[i]) / fade[i])
                       * s((high[i] + fade[i] - x[i]) / fade[i]) for i in range(5)], axis=0)
    outside = np.array([np.maximum.reduce([(low[i] - x[i]) / fade[i], (x[i] - high[i]) / fade[i],
                                           np.zeros_like(x[i])]) for i in range(5)])
    distance = 1.0 - s(np.sum(outside**2, axis=0))
    for form, expected in (("product", product), ("distance", distance)):
        got = env.gate(x, form=form)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        # the sample spans the whole gate: exactly 1, exactly 0 and values in between
        assert np.any(got == 1.0) and np.any(got == 0.0) and np.any((got > 0.05) & (got < 0.95))
    raw = np.concatenate([rng.normal(0, 1, 500), rng.normal(0, 100, 500)])[None, :]
    bound = np.array([5.0])
    for form in ("clamp", "tanh"):
        y = bounded(raw, bound, NUMPY_OPS, form)
        assert np.all(np.abs(y) <= 5.0 + 1e-12)
        small = np.abs(raw) < 0.05
        np.testing.assert_allclose(y[small], raw[small], rtol=1e-4)
    np.testing.assert_array_equal(bounded(raw, bound, NUMPY_OPS, "clamp"), np.clip(raw, -5, 5))
    z = np.concatenate([rng.normal(0, 1e3, 1000), [0.0, -0.0, 5e-324, -5e-324]])
    np.testing.assert_array_equal(ramp(z, NUMPY_OPS), np.maximum(z, 0.0))


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_envelope_sweep_passes_a_damping_net_and_names_the_trim_a_feedback_net_breaks(name):
    """``envelope_check`` (what ``uavdyn modes --hybrid`` prints) trims over the airspeeds the
    weights' envelope spans and applies the rule: extra pitch damping passes, pitch-rate
    positive feedback is reported at a named trim."""
    import dataclasses

    from uavdyn.learned.stability import envelope_check, envelope_speeds

    airframe = load_airframe(name)
    point = trim(airframe)
    n_in = structure_of(airframe).nx() + 2 * len(MEMORY) + 2
    lo = np.full(n_in, -1.0)
    hi = np.full(n_in, 1.0)
    if airframe.kind == "fixed_wing":
        lo[0], hi[0] = point.x[0] - 4.0, point.x[0] + 4.0
    else:
        lo[0], hi[0] = -1.0, 4.0
    env = Envelope(lo, hi, np.full(n_in, 0.5))
    v_lo, v_hi = envelope_speeds(env)
    assert v_hi >= hi[0] and v_lo <= max(lo[0], 0.0) + 1e-12
    good = dataclasses.replace(_pitch_feedback_net(airframe, -1.0), envelope=env)
    bad = dataclasses.replace(_pitch_feedback_net(airframe, 60.0), envelope=env)
    report = envelope_check(good, airframe)
    assert report.findings and report.ok, report.describe()
    assert "| trim |" in report.table() and "ok" in report.table()
    broken = envelope_check(bad, airframe)
    assert not broken.ok and "DESTABILISED" in broken.table()
    assert "trim at" in broken.describe()


@pytest.mark.slow
def test_safe_training_keeps_a_correction_only_under_its_rules(tmp_path):
    """A short run on emulated data whose physics has a pitch-moment error the nominal model
    lacks: kept only with every validation sortie no worse than the physics at 1 s, the output
    scale one of those tried, the stability rule passed; otherwise refused with a reason."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe

    airframe = load_airframe("aerosonde")
    truth = airframe.replace(C_m_0=airframe.params.C_m_0 + 0.01,
                             C_m_q=airframe.params.C_m_q * 0.8)
    sorties = load_dataset(emulated_dataset(tmp_path / "data", truth, 6, 6.0)).sorties
    cfg = SafeConfig(epochs=3, batches_per_epoch=3, batch_windows=8, horizon_s=1.0,
                     progress=False, memory_tau=(0.1,), seen_guard=True)
    result = train_safe(sorties[:4], sorties[4:], airframe, cfg)
    assert result.reason and result.stability is not None
    # Table 2's losses: the same fixed windows after every epoch, the physics (epoch 0, zero
    # output) scoring 1 on both splits (windows below 5 % of the median weigh a little less)
    first = result.history[0]
    for key in ("train_loss_fixed", "val_loss_fixed"):
        assert 0.9 < first[key] <= 1.0 + 1e-9
        assert all(np.isfinite(h[key]) for h in result.history)
    v = result.validation
    assert set(v["sortie_ratios"]) == {s.name for s in sorties[4:]}
    assert set(v["pitch_noise_std"]) == set(v["sortie_ratios"])
    assert all(n >= 0 for n in v["pitch_noise_std"].values())
    assert v["output_scale"] in cfg.shrink and v["shrink_tried"]
    if result.kept:
        assert result.net is not None and result.stability.ok
        assert v["sortie_ratio_worst"] <= cfg.worst_sortie_ratio
        assert all(r <= cfg.worst_sortie_ratio for r in v["sortie_ratios"].values())
        assert v["corrected_theta_rmse"] < v["physics_theta_rmse"]
        assert chosen_state_ok(v, cfg)
        assert result.net.info["output_scale"] == v["output_scale"]
        chosen = v["shrink_tried"][-1]
        assert chosen["scale"] == v["output_scale"] and chosen["free_run_ok"]
        # a channel cut only after the uniform scale made a state worse, and said so
        assert len(v["channel_scales"]) == 3
        assert chosen.get("channel_scales", [1.0] * 3) == v["channel_scales"]
        if min(v["channel_scales"]) < 1.0:
            uniform = [r for r in v["shrink_tried"] if r["epoch"] == chosen["epoch"]
                       and r["scale"] == chosen["scale"] and "channel_scales" not in r]
            assert uniform and uniform[0]["val_state_ratio_worst"] > cfg.state_ratio_limit
        assert chosen["free_run_new_departures"] == 0
        # no training sortie made worse either (SafeConfig.seen_guard)
        assert chosen["train_ok"] and chosen["train_ratio_worst"] <= cfg.worst_sortie_ratio
        assert chosen["train_sorties_worse"] == []
    else:
        assert result.net is None
        assert "physics is kept" in result.reason or "destabilises" in result.reason


def test_the_steady_box_is_trained_neutral_and_put_in_for_the_final_checks(tmp_path,
                                                                           monkeypatch):
    """``SafeConfig.steady_gate``: the network trains with a neutral steady box (its gate is
    the envelope's own) and the final checks, and the exported network, have the box of the
    training data's steady flight."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe
    from uavdyn.learned.safe import trainer as trainer_module

    airframe = load_airframe("aerosonde")
    truth = airframe.replace(C_m_0=airframe.params.C_m_0 + 0.01)
    sorties = load_dataset(emulated_dataset(tmp_path / "data", truth, 6, 6.0)).sorties
    real = trainer_module.steady_box
    built, seen = [], {}

    def every_sample_steady(tr, va, names, hold, quantile):  # this short data may hold none
        box = real(tr, va, names, hold, quantile) or SteadyBox.from_steady(
            tr.inputs, None, [2, 3], 2, quantile)
        built.append(box)
        return box

    def screened(model, *args, **kwargs):
        seen["training"] = model.envelope.steady
        return screened_start(model, *args, **kwargs)

    def search(checks, run):
        seen["checks"] = checks.model.envelope.steady
        seen["layout_gate"] = checks.layout.gate
        return real_search(checks, run)

    screened_start, real_search = trainer_module.screened_start, trainer_module.search
    monkeypatch.setattr(trainer_module, "steady_box", every_sample_steady)
    monkeypatch.setattr(trainer_module, "screened_start", screened)
    monkeypatch.setattr(trainer_module, "search", search)
    cfg = SafeConfig(epochs=2, batches_per_epoch=2, batch_windows=8, horizon_s=1.0,
                     progress=False, steady_gate=True, stability_trims="box")
    result = train_safe(sorties[:4], sorties[4:], airframe, cfg)
    box = built[0]
    assert not np.any(seen["training"].inv_fade)          # neutral while training
    assert seen["checks"] is box and np.any(box.inv_fade > 0)
    assert seen["layout_gate"].__self__.steady is box     # the scaled layout gates with it
    if result.kept:
        np.testing.assert_array_equal(result.net.envelope.steady.low, box.low)


def chosen_state_ok(validation: dict, cfg) -> bool:
    """The kept scale's pooled 1 s error of every body state is within the state limit."""
    row = validation["shrink_tried"][-1]
    return (len(row["val_state_ratios"]) == 4
            and max(row["val_state_ratios"]) == row["val_state_ratio_worst"]
            and row["val_state_ratio_worst"] <= cfg.state_ratio_limit)


def test_free_run_rule_counts_new_departures_and_ratios_only_where_the_physics_follows():
    """The validation free-run rule: ratios only over sorties whose physics run stayed with the
    data, a departure of the corrected run where the physics' did not always fails."""
    from uavdyn.learned.rules import free_run_verdict

    physics = [(0.10, False), (0.20, False), (3.0, True)]
    ok = free_run_verdict(physics, [(0.105, False), (0.15, False), (math.inf, True)], 1.1)
    assert ok["free_run_ok"] and ok["free_run_scored"] == 2
    assert ok["free_run_worst"] == pytest.approx(1.05)
    worse = free_run_verdict(physics, [(0.12, False), (0.15, False), (0.1, False)], 1.1)
    assert not worse["free_run_ok"] and worse["free_run_worst"] == pytest.approx(1.2)
    left = free_run_verdict(physics, [(0.05, False), (0.9, True), (3.0, True)], 1.1)
    assert not left["free_run_ok"] and left["free_run_new_departures"] == 1
    assert left["free_run_worst"] == pytest.approx(0.5)


def test_free_run_rule_compares_errors_with_the_measurement_noise_taken_off():
    """Against records with white pitch noise sigma a prediction's expected squared error is
    its squared error against the truth plus sigma^2. Built from known errors against the truth
    (physics 1.3 mrad, corrected 2.6 mrad: 2x worse, 1.3 mrad more) and sigma = 2 mrad, the raw
    ratio is 1.29x; with the noise given the rule sees the 2x and refuses. A sortie the physics
    follows to within the noise is not scored."""
    from uavdyn.flightdata import excess_rmse
    from uavdyn.learned.rules import free_run_verdict

    sigma, truth_p, truth_c = 0.002, 0.0013, 0.0026
    physics = [(math.hypot(truth_p, sigma), False), (0.0019, False)]
    corrected = [(math.hypot(truth_c, sigma), False), (0.0021, False)]
    assert excess_rmse(physics[0][0], sigma) == pytest.approx(truth_p)
    assert excess_rmse(0.0019, sigma) == 0.0 and excess_rmse(math.inf, sigma) == math.inf
    raw = free_run_verdict(physics[:1], corrected[:1], 1.1)
    assert raw["free_run_worst"] == pytest.approx(
        math.hypot(truth_c, sigma) / math.hypot(truth_p, sigma))
    seen = free_run_verdict(physics, corrected, 1.1, [sigma, sigma])
    assert not seen["free_run_ok"] and seen["free_run_scored"] == 1
    assert seen["free_run_worst"] == pytest.approx(truth_c / truth_p)


def test_free_run_rule_does_not_refuse_a_noise_level_difference():
    """A physics free run that follows the data to a fraction of the noise makes a tiny growth
    a large ratio: 1.3 -> 1.6 mrad against the truth (1.23x) with 2 mrad of noise grows by
    0.3 mrad, under FREE_RUN_NOISE_FLOOR x sigma = 1 mrad: not worse, and said so. The same
    runs on noise-free records (no floor) are refused by the ratio."""
    from uavdyn.learned.rules import FREE_RUN_NOISE_FLOOR, free_run_verdict

    sigma, truth_p, truth_c = 0.002, 0.0013, 0.0016
    assert truth_c - truth_p < FREE_RUN_NOISE_FLOOR * sigma
    noisy = free_run_verdict([(math.hypot(truth_p, sigma), False)],
                             [(math.hypot(truth_c, sigma), False)], 1.1, [sigma])
    assert noisy["free_run_ok"] and noisy["free_run_noise_level"] == 1
    assert noisy["free_run_worst"] == pytest.approx(truth_c / truth_p)
    clean = free_run_verdict([(truth_p, False)], [(truth_c, False)], 1.1, [0.0])
    assert not clean["free_run_ok"] and clean["free_run_noise_level"] == 0


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_map_modes_of_a_memory_step_show_the_filters_exact_poles(name):
    """The command-memory filters sit at the trim command; their map eigenvalues are exactly
    ``exp(-dt/tau)`` (block triangular: driven by the command only), listed beside the same
    exact values, and the body block's modes are still reported."""
    from uavdyn.linear import discrete_map_modes

    airframe = load_airframe(name)
    point = trim(airframe)
    step = hybrid_step(_pitch_feedback_net(airframe, -1.0), airframe, compile=False)
    comp = discrete_map_modes(step, point, DT)
    lam = np.sort_complex(comp.map_eigenvalues)
    for tau in MEMORY:
        hits = np.sum(np.abs(lam - math.exp(-DT / tau)) < 1e-12)
        assert hits == 2, (tau, lam)  # one filter per command
    assert len(comp.map_eigenvalues) == step.nx == len(comp.exact_eigenvalues)
    assert step.state_names[-2 * len(MEMORY):] == tuple(
        f"{c}_memory_{tau:g}s" for tau in MEMORY for c in step.control_names)
    assert comp.map_modes and not comp.made_unstable


def test_the_stability_penalty_asks_little_of_the_physics_where_it_is_unstable():
    """With a speed-stability moment (blade flapping) the F450's hover oscillation is unstable
    at every trim; the penalty's hinge sits at most 0.01 1/s inside the physics' own abscissa
    there, so the physics-only network (zero output, what training starts from) pays at most
    that per trim: a hinge 10 % inside the physics' rate made training fight the data. For a
    stable mode the hinge sits a buffer inside the allowed value."""
    from uavdyn.learned.formulations import CorrectionLayout
    from uavdyn.learned.stability import (
        allowed_abscissa,
        body_abscissa,
        stability_penalty,
        training_target,
        trims_between,
    )

    airframe = load_airframe("f450").replace(M_u=0.011)
    structure = structure_of(airframe)
    n_in = structure.nx() + 2 * len(MEMORY) + 2
    envelope = Envelope(np.full(n_in, -1e3), np.full(n_in, 1e3), np.ones(n_in))
    layout = CorrectionLayout(structure, MEMORY, envelope.gate, np.full(3, 10.0))
    model = TorchCorrection(airframe.kind, "improved", 8, "relu", np.zeros(n_in), np.ones(n_in),
                            np.ones(3), DT, structure=structure, layout=layout,
                            envelope=envelope)
    trims, skipped = trims_between(airframe, 0.0, 8.0, StateLayout(structure, MEMORY))
    assert trims, skipped
    jp = physics_step(structure).jacobians()
    sigma = [body_abscissa(np.array(jp(t.z[:layout.n_physics], t.u, t.p, DT)[1]), DT)[0]
             for t in trims]
    assert min(sigma) > 0.1, sigma  # unstable physics at every trim
    targets = [training_target(s) for s in sigma]
    assert [allowed_abscissa(s) for s in sigma] == sigma  # may not be pushed outward
    np.testing.assert_allclose(targets, np.array(sigma) - 0.01, rtol=0, atol=1e-12)
    penalty = stability_penalty(model, trims, targets, DT).item()
    assert penalty == pytest.approx(0.01 * len(trims), abs=1e-9)
    # a stable mode: allowed -0.5 (margin 0.5), hinge 0.1 * 1 + 0.01 inside it
    assert training_target(-1.0) == pytest.approx(-0.61)
    assert training_target(0.0) == pytest.approx(-0.01)  # a neutral mode: a hair inside


def test_pooled_state_errors_recover_the_error_against_the_truth_from_noisy_records():
    """Windows from two sorties whose records carry white noise of different spread per state
    (known): the pooled RMSE with the noise taken off equals the prediction's RMSE against the
    truth (to sampling accuracy), where the raw RMSE against the records is inflated; a
    prediction that is not finite scores inf."""
    from uavdyn.learned.rules import pooled_state_errors

    rng = np.random.default_rng(3)
    W, H = 2000, 50
    truth = rng.normal(size=(W, H, 4)).cumsum(axis=1)
    offset = np.array([0.3, 0.2, 0.01, 0.003])               # the prediction's error per state
    pred = truth + offset * rng.normal(size=(W, H, 4))
    sortie_noise = np.array([[0.5, 0.3, 0.02, 0.002], [0.1, 0.6, 0.005, 0.004]])
    noise = sortie_noise[np.arange(W) % 2]                   # (W, 4): each window's sortie
    records = truth + noise[:, None, :] * rng.normal(size=(W, H, 4))
    raw = np.sqrt(np.mean((pred - records) ** 2, axis=(0, 1)))
    seen = pooled_state_errors(pred, records, noise)
    assert np.all(raw > 1.1 * offset)
    np.testing.assert_allclose(seen, offset, rtol=0.05)
    assert np.array_equal(pooled_state_errors(pred, records, 0 * noise), raw)
    bad = pred.copy()
    bad[0, 0, 1] = np.nan
    assert pooled_state_errors(bad, records, noise)[1] == math.inf


def test_a_gain_within_the_sortie_spread_is_not_a_gain():
    """The paired t statistic of the per-sortie log ratios: a 0.2 % mean gain with one sortie
    2 % worse is noise; a 9 % gain on every sortie is not; the rule refuses the first."""
    import math

    from uavdyn.learned.rules import summarise_ratios
    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.scoring import beats_physics_in_pitch

    noise = summarise_ratios([0.998, 1.02, 0.99, 0.995, 1.0, 0.985])
    gain = summarise_ratios([0.9, 0.92, 0.88, 0.91, 0.95, 0.9])
    logs = [math.log(v) for v in (0.998, 1.02, 0.99, 0.995, 1.0, 0.985)]
    mean = sum(logs) / 6
    sd = math.sqrt(sum((v - mean) ** 2 for v in logs) / 5)
    assert noise.gain_t == pytest.approx(-mean / (sd / math.sqrt(6)))
    assert noise.gain_t < 2.0 < gain.gain_t
    assert summarise_ratios([0.9]).gain_t == math.inf  # one sortie: no spread to judge by
    cfg = SafeConfig()
    for summary, kept in ((noise, False), (gain, True)):
        sel = {"val_ratio_worst": summary.worst, "val_ratio_geomean": summary.geomean,
               "val_theta_rmse": 0.5, "val_gain_t": summary.gain_t}
        assert beats_physics_in_pitch(sel, cfg, 1.0) is kept


def test_a_gain_smaller_than_the_noise_tolerance_is_not_a_gain():
    """Ratios 0.995-0.997 on six sorties: a significant (t far above 2) but 0.4 % gain, less
    than the 2 % a sortie may lose within noise; refused, and the refusal says which rule."""
    from uavdyn.learned.rules import summarise_ratios
    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.scoring import beats_physics_in_pitch
    from uavdyn.learned.safe.verdict import refusal_reason
    from uavdyn.learned.stability import StabilityReport

    tiny = summarise_ratios([0.995, 0.996, 0.997, 0.995, 0.996, 0.997])
    assert tiny.gain_t > 10 and tiny.geomean > 0.98
    row = {"epoch": 4, "scale": 0.35, "val_ratio_worst": tiny.worst,
           "val_ratio_geomean": tiny.geomean, "val_theta_rmse": 0.498,
           "val_gain_t": tiny.gain_t, "val_state_ratio_worst": 1.0}
    assert not beats_physics_in_pitch(row, SafeConfig(), 0.5)
    assert beats_physics_in_pitch(row, SafeConfig(min_gain=0.0), 0.5)
    text = refusal_reason([row], SafeConfig(), 0.5, row, StabilityReport(0.01, 0.5), 1.0)
    assert "smaller than 2 %" in text and "the physics is kept" in text


def test_a_refusal_for_a_gain_within_the_spread_says_so():
    """Every candidate beat the physics on every validation sortie, by too little: the reason
    names the significance rule and the best t, not 'does not beat the physics'."""
    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.verdict import refusal_reason
    from uavdyn.learned.stability import StabilityReport

    row = {"epoch": 3, "scale": 1.0, "val_ratio_worst": 0.999, "val_ratio_geomean": 0.978,
           "val_theta_rmse": 0.0592, "val_state_ratio_worst": 1.0, "val_gain_t": 1.03}
    text = refusal_reason([row], SafeConfig(), 0.0593, row, StabilityReport(0.01, 0.5), 1.0)
    assert "1.03 standard errors of the sortie-to-sortie spread, below 2" in text
    assert "the physics is kept" in text


def test_a_refusal_for_a_training_sortie_made_worse_names_it():
    """Candidates that pass every validation rule but make a training sortie worse
    (``SafeConfig.seen_guard``): the reason says so, with the closest one's ratio and sortie,
    and the tally counts them."""
    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.verdict import refusal_reason
    from uavdyn.learned.stability import StabilityReport

    rows = [{"epoch": e, "scale": 1.0, "val_ratio_worst": 0.95, "val_ratio_geomean": 0.8,
             "val_theta_rmse": 0.05, "val_state_ratio_worst": 1.0, "val_gain_t": 4.0,
             "train_ok": False, "train_ratio_worst": w, "train_sorties_worse": [name]}
            for e, w, name in ((3, 1.31, "sortie_005"), (7, 1.08, "sortie_024"))]
    text = refusal_reason(rows, SafeConfig(seen_guard=True), 0.06, rows[0],
                          StabilityReport(0.01, 0.5), 1.0)
    assert "2 make a training sortie worse than 1.02x" in text
    assert "closest: epoch 7, scale 1, worst 1.08x: sortie_024" in text
    assert text.endswith("the physics is kept")


def test_output_penalty_is_the_mean_square_output_in_output_scales_and_zero_at_the_start():
    """The ridge penalty in function space (``SafeConfig.output_weight``): zero for the
    untrained network (training starts at the physics), the mean square of the linear path's
    output over the rows in units of ``out_scale`` once it is set."""
    from uavdyn.learned.safe.epochs import output_penalty

    n_in, out_scale = 6, np.array([2.0, 0.5, 4.0])  # the body state and two commands
    model = TorchCorrection("fixed_wing", "improved", 4, "relu", np.zeros(n_in), np.ones(n_in),
                            out_scale, DT, linear=True)
    rows = torch.as_tensor(np.random.default_rng(3).normal(size=(40, n_in)))
    assert output_penalty(model, rows).item() == 0.0
    skip = np.random.default_rng(4).normal(size=(3, n_in))
    with torch.no_grad():
        model.skip.copy_(torch.as_tensor(skip))
    expected = np.mean((rows.numpy() @ skip.T) ** 2)  # the output is out_scale * (skip @ x)
    assert output_penalty(model, rows).item() == pytest.approx(expected, rel=1e-12)


def test_restarts_carry_on_the_start_with_the_least_training_loss(tmp_path):
    """``SafeConfig.restarts``: every start is screened for ``restart_epochs`` epochs, the
    one with the least loss on the fixed training windows is trained on (the validation
    sorties stay out of the choice), and the others are recorded; with one start the run is
    the same as before (same history to the last digit)."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe
    from uavdyn.learned.safe.epochs import restart_seed

    airframe = load_airframe("aerosonde")
    truth = airframe.replace(C_m_0=airframe.params.C_m_0 + 0.01)
    sorties = load_dataset(emulated_dataset(tmp_path / "data", truth, 5, 6.0)).sorties
    base = dict(epochs=4, batches_per_epoch=2, batch_windows=6, horizon_s=1.0,
                progress=False, memory_tau=(0.1,), patience=100)
    single = train_safe(sorties[:3], sorties[3:], airframe, SafeConfig(**base))
    again = train_safe(sorties[:3], sorties[3:], airframe, SafeConfig(**base))
    assert single.screened == [] and single.history[-1]["epoch"] == 4
    assert [h["val_theta_rmse"] for h in single.history] == \
        [h["val_theta_rmse"] for h in again.history]
    result = train_safe(sorties[:3], sorties[3:], airframe,
                        SafeConfig(**base, restarts=3, restart_epochs=2))
    screened = result.screened
    assert [s["seed"] for s in screened] == [restart_seed(0, i) for i in range(3)]
    assert sum(s["chosen"] for s in screened) == 1
    chosen = next(s for s in screened if s["chosen"])
    assert chosen["train_loss_fixed"] == min(s["train_loss_fixed"] for s in screened)
    # the chosen start's own screening epochs are the first epochs of the run's history
    assert chosen["train_loss_fixed"] == min(h["train_loss_fixed"]
                                             for h in result.history[1:3])
    assert result.history[-1]["epoch"] == 4 and len(result.history) == 5
    if chosen["seed"] == 0:  # the run's own start: the same epochs as the single run
        assert [h["val_theta_rmse"] for h in result.history] == \
            [h["val_theta_rmse"] for h in single.history]


def test_window_starts_low_passed_keep_the_signal_and_drop_most_of_the_noise():
    """``SafeConfig.start_lowpass_hz``: windows start from the zero-phase low-pass of the
    records (a 0.5 Hz pitch oscillation plus white noise of 2 mrad at 100 Hz): at 5 Hz the
    start's error against the noise-free signal is a third of the noise or less, the signal
    passes within 1 %; at 0 the starts are the records themselves."""
    from uavdyn.flightdata import Sortie
    from uavdyn.learned.safe.data import start_states

    t = np.arange(3000) * DT
    clean = np.column_stack([np.full_like(t, 20.0), np.full_like(t, 1.0),
                             0.1 * np.pi * np.cos(np.pi * t), 0.1 * np.sin(np.pi * t)])
    noisy = clean + np.random.default_rng(5).normal(size=clean.shape) * 0.002
    sortie = Sortie("s", "fixed_wing", t, noisy, np.zeros((len(t), 2)), "survey")
    assert start_states(sortie, 0.0) is sortie.states
    smooth = start_states(sortie, 5.0)
    inner = slice(200, -200)  # away from the filter's start-up at both ends
    err = np.std(smooth[inner, 3] - clean[inner, 3])
    assert err < 0.002 / 3
    gain = np.std(smooth[inner, 3]) / np.std(clean[inner, 3])
    assert abs(gain - 1.0) < 0.01


def test_low_passed_starts_change_where_windows_start_not_what_they_are_scored_against(
        tmp_path):
    """``training_windows`` with a start cutoff: the body states each window starts from are
    the low-passed records (emulated truth plus white noise of 0.05 m/s, 5 mrad/s, 2 mrad),
    closer to the noise-free truth than the raw records; the targets and the controls are
    the raw records, unchanged."""
    import dataclasses

    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.config import safe_setup
    from uavdyn.learned.safe.data import physics_rollout, training_windows

    airframe = load_airframe("aerosonde")
    clean = load_dataset(emulated_dataset(tmp_path / "data", airframe, 3, 6.0)).sorties
    rng = np.random.default_rng(2)  # the emulated records here are the truth: add the noise
    scale = np.array([0.05, 0.05, 0.005, 0.002])
    sorties = [dataclasses.replace(s, states=s.true_states + rng.normal(
        size=s.true_states.shape) * scale) for s in clean]
    setup = safe_setup(sorties[:2], sorties[2:], airframe,
                       SafeConfig(horizon_s=1.0, progress=False, memory_tau=(0.1,)))
    sim = physics_rollout(setup)
    raw = training_windows(airframe, setup, sorties[:2], sim)
    smooth = training_windows(airframe, setup, sorties[:2], sim, start_lowpass_hz=10.0)
    np.testing.assert_array_equal(raw.y, smooth.y)
    np.testing.assert_array_equal(raw.u, smooth.u)
    assert not np.allclose(raw.z0[:, :4], smooth.z0[:, :4])
    truth = np.array([sorties[i].true_states[k, :4] for i, k in raw.windows.starts])
    err_raw = np.sqrt(np.mean((raw.z0[:, :4] - truth) ** 2, axis=0))
    err_smooth = np.sqrt(np.mean((smooth.z0[:, :4] - truth) ** 2, axis=0))
    assert err_smooth[2] < err_raw[2] and err_smooth[3] < err_raw[3]  # q and theta


def test_weight_average_is_the_exponential_average_of_the_steps_written_out():
    """``SafeConfig.average_decay``: after each optimiser step the kept network's weights are
    ``keep * mean + (1 - keep) * weights`` with ``keep = min(decay, (1 + n) / (10 + n))``
    at step ``n``, checked against the recursion written out on a random walk of weights;
    the trained network itself is untouched."""
    from uavdyn.learned.safe.epochs import WeightAverage

    model = TorchCorrection("fixed_wing", "improved", 4, "relu", np.zeros(6), np.ones(6),
                            np.ones(3), DT, linear=True, seed=2)
    start = [p.detach().clone().numpy() for p in model.parameters()]
    average, decay = WeightAverage(model, 0.9), 0.9
    expected = [s.copy() for s in start]
    rng = np.random.default_rng(5)
    for n in range(1, 40):
        with torch.no_grad():
            for p in model.parameters():
                p.add_(torch.as_tensor(rng.normal(size=tuple(p.shape))))
        average.update(model)
        keep = min(decay, (1.0 + n) / (10.0 + n))
        expected = [keep * e + (1.0 - keep) * p.detach().numpy()
                    for e, p in zip(expected, model.parameters())]
    for mean, e, p in zip(average.model.parameters(), expected, model.parameters()):
        np.testing.assert_allclose(mean.detach().numpy(), e, rtol=1e-12, atol=1e-12)
        assert not np.allclose(mean.detach().numpy(), p.detach().numpy())


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_the_exact_check_runs_out_to_where_the_gate_reaches_zero(name):
    """``gate_trims``: the box's own trims (where the training penalty holds the network) and
    more in each margin the fade opens, strictly between the box's speeds and the speed where
    the gate is 0, each point once."""
    from uavdyn.learned.stability import envelope_speeds, gate_trims, reach_speeds, trims_between

    airframe = load_airframe(name)
    net = _pitch_feedback_net(airframe, 0.0)
    point = trim(airframe) if airframe.kind == "fixed_wing" else trim(airframe, 8.0, 0.0)
    speed = float(np.hypot(point.x[0], point.x[1]))
    n_in = len(net.envelope.low)
    low, high = np.full(n_in, -1e3), np.full(n_in, 1e3)
    low[:2] = [point.x[0] - 0.15 * speed, point.x[1] - 1.0]
    high[:2] = [point.x[0] + 0.05 * speed, point.x[1] + 1.0]
    envelope = Envelope(low, high, np.maximum(high - low, 1e-3))
    layout = StateLayout(structure_of(airframe), MEMORY)
    lo, hi = envelope_speeds(envelope)
    reach_lo, reach_hi = reach_speeds(envelope)
    assert reach_lo < lo < hi < reach_hi
    box, _ = trims_between(airframe, lo, hi, layout)
    gates = gate_trims(airframe, envelope, layout)
    assert [(t.airspeed, t.gamma) for t in gates.box] == [(t.airspeed, t.gamma) for t in box]
    trims = gates.all
    keys = [(t.airspeed, t.gamma) for t in trims]
    assert len(keys) == len(set(keys))
    assert set((t.airspeed, t.gamma) for t in box) <= set(keys)
    beyond = [t.airspeed for t in trims if t.airspeed > hi]
    assert beyond and all(v < reach_hi for v in beyond)
    below = [t.airspeed for t in trims if t.airspeed < lo and t.airspeed > 0]
    assert below and all(v > reach_lo for v in below)
    # the training penalty: the box's trims by default, every trim the check runs at on "gate"
    from uavdyn.learned.stability import penalty_trims
    assert penalty_trims(gates, "box") == gates.box
    assert penalty_trims(gates, "gate") == gates.all and len(gates.all) > len(gates.box)
    assert penalty_trims(gates, "repair") == gates.box  # until a repair (its own test)


def test_a_penalty_trim_choice_other_than_box_gate_or_repair_is_refused(tmp_path):
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.config import safe_setup

    airframe = load_airframe("aerosonde")
    sorties = load_dataset(emulated_dataset(tmp_path / "data", airframe, 2, 4.0)).sorties
    with pytest.raises(ValueError,
                       match="stability_trims must be one of box, gate, repair, got 'edge'"):
        safe_setup(sorties[:1], sorties[1:], airframe, SafeConfig(stability_trims="edge"))


def test_a_repair_is_made_only_for_a_stability_failure_that_beats_what_was_kept():
    """The candidate repaired: of the rows at full uniform output that failed only the exact
    check (``stable`` False), the best by mean validation ratio, and only if it beats the
    kept candidate's; channel variants, smaller scales and rows stopped earlier never."""
    from uavdyn.learned.safe.repair import repair_candidate
    from uavdyn.learned.safe.selection import Search

    rows = [{"epoch": 4, "scale": 1.0, "val_ratio_geomean": 0.7, "stable": False},
            {"epoch": 9, "scale": 1.0, "val_ratio_geomean": 0.6, "stable": False},
            {"epoch": 9, "scale": 0.75, "val_ratio_geomean": 0.5, "stable": False},
            {"epoch": 7, "scale": 1.0, "val_ratio_geomean": 0.4, "free_run_ok": False},
            {"epoch": 8, "scale": 1.0, "val_ratio_geomean": 0.3, "stable": False,
             "channel_scales": [1.0, 0.5, 1.0]},
            {"epoch": 5, "scale": 1.0, "val_ratio_geomean": 0.9}]
    assert repair_candidate(Search(None, rows, None), 1.0)["epoch"] == 9

    class Kept:
        def __init__(self, geomean):
            self.selection = {"val_ratio_geomean": geomean}

    assert repair_candidate(Search(Kept(0.65), rows, None), 1.0)["epoch"] == 9
    assert repair_candidate(Search(Kept(0.6), rows, None), 1.0) is None
    assert repair_candidate(Search(None, rows[3:], None), 1.0) is None


def test_a_stability_repair_trains_the_failed_epoch_on_with_the_penalty_at_every_trim(
        tmp_path, monkeypatch):
    """``stability_trims="repair"``: where the search reports a candidate at full output that
    failed only the exact check (made to here: the short run's candidates do not beat the
    physics), that epoch's network is trained on for ``repair_epochs`` epochs numbered after
    the run's, at the learning rate it had, with the penalty at every trim the check runs
    at; the history and the stop reason say so, and the repaired epochs go through the same
    final checks."""
    from emulated_data import emulated_dataset

    import uavdyn.learned.safe.trainer as trainer_module
    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe
    from uavdyn.learned.safe.epochs import EpochLoop
    from uavdyn.learned.safe.selection import search

    airframe = load_airframe("aerosonde")
    truth = airframe.replace(C_m_0=airframe.params.C_m_0 + 0.01)
    sorties = load_dataset(emulated_dataset(tmp_path / "data", truth, 5, 6.0)).sorties
    failed = {}

    def search_with_a_stability_failure(checks, run):
        found = search(checks, run)
        first = found.tried[0]  # a candidate's row at full output, as if only unstable
        epoch = first["epoch"]
        failed.update(epoch=epoch, lr=next(h["lr"] for h in run.history
                                           if h["epoch"] == epoch), last=run.history[-1]["epoch"])
        found.tried.append({**first, "val_ratio_geomean": 0.5, "stable": False})
        return found

    penalties = []
    original_init = EpochLoop.__init__

    def recording_init(self, model, data, stab, *args, **kwargs):
        penalties.append(len(stab.trims))
        original_init(self, model, data, stab, *args, **kwargs)

    monkeypatch.setattr(trainer_module, "search", search_with_a_stability_failure)
    monkeypatch.setattr(EpochLoop, "__init__", recording_init)
    cfg = SafeConfig(epochs=4, batches_per_epoch=2, batch_windows=6, horizon_s=1.0,
                     progress=False, memory_tau=(0.1,), patience=100,
                     stability_trims="repair", repair_epochs=3)
    result = train_safe(sorties[:3], sorties[3:], airframe, cfg)
    repaired = [h for h in result.history if h.get("phase") == "stability repair"]
    assert [h["epoch"] for h in repaired] == [failed["last"] + i for i in (1, 2, 3)]
    assert all(h["repair_of"] == failed["epoch"] for h in repaired)
    assert all(h["lr"] == pytest.approx(failed["lr"], rel=1e-12) for h in repaired)
    n_check = len(result.stability.findings)  # the exact check's trims
    assert penalties[0] < n_check and penalties[-1] == n_check
    assert (f"stability repair: epoch {failed['epoch']} trained on for 3 epochs"
            in result.stopped) and f"all {n_check} trims of the exact check" in result.stopped
    tried_after = [r for r in result.validation["shrink_tried"]
                   if r.get("repair_of") == failed["epoch"]]
    assert tried_after and {r["epoch"] for r in tried_after} <= {h["epoch"] for h in repaired}
    from uavdyn.learned.safe.history import write_safe_history
    record, png = write_safe_history(result, tmp_path / "history.json")
    written = json.loads(record.read_text())
    assert [h["epoch"] for h in written["history"] if h.get("phase")] == \
        [h["epoch"] for h in repaired] and png.stat().st_size > 0
    # without the option the same run makes no repair
    monkeypatch.setattr(EpochLoop, "__init__", original_init)
    plain = train_safe(sorties[:3], sorties[3:], airframe,
                       SafeConfig(**{**cfg.__dict__, "stability_trims": "box"}))
    assert "stability repair" not in plain.stopped
    assert not any(h.get("phase") for h in plain.history)



def test_a_fixed_wings_physical_inputs_give_the_sweep_its_airspeed_directly():
    """A fixed wing's physical inputs are angle of attack then airspeed: the sweep's speeds
    are the airspeed input's range (and its fade), not ``hypot`` of the first two inputs
    read as ``u``, ``w``; the trims of the check lie at those speeds."""
    from uavdyn.learned.formulations import airspeed_input
    from uavdyn.learned.stability import envelope_speeds, gate_trims, reach_speeds

    assert airspeed_input("fixed_wing", "physical") == 1
    assert airspeed_input("fixed_wing", "state") is None
    assert airspeed_input("multirotor", "physical") is None
    low = np.array([-0.05, 18.0, -0.1])
    high = np.array([0.25, 26.0, 0.1])
    envelope = Envelope(low, high, np.array([0.1, 2.0, 0.05]))
    assert envelope_speeds(envelope, 1) == (18.0, 26.0)
    assert reach_speeds(envelope, 1) == (16.0, 28.0)
    airframe = load_airframe("aerosonde")
    gates = gate_trims(airframe, envelope, StateLayout(structure_of(airframe)), 4, 1)
    assert gates.box and all(18.0 - 1e-9 <= t.airspeed <= 26.0 + 1e-9 for t in gates.box)
    assert gates.margins and all(16.0 < t.airspeed < 28.0 for t in gates.margins)

def test_validation_stretches_cut_long_sorties_into_minutes_and_keep_short_ones_whole():
    """``scoring.stretches``: a 30 s sortie is one unit under its own name; a 6-minute log
    is six units of 60 s and a 90 s one two of 45 s, each window in the unit its start time
    falls in (so the per-sortie rules and the gain's t statistic see every minute of a long
    campaign log)."""
    from types import SimpleNamespace

    from uavdyn.flightdata import Sortie
    from uavdyn.learned.safe.scoring import STRETCH_S, stretches

    def sortie(name, seconds):
        t = np.arange(int(seconds / DT) + 1) * DT
        return Sortie(name, "fixed_wing", t, np.zeros((len(t), 4)), np.zeros((len(t), 2)),
                      "survey")

    sorties = [sortie("short", 30.0), sortie("log", 360.0), sortie("mid", 90.0)]
    starts = [(i, k) for i, s in enumerate(sorties) for k in range(0, len(s.time) - 200, 50)]
    va = SimpleNamespace(windows=SimpleNamespace(starts=np.array(starts)))
    units = stretches(va, sorties)
    assert STRETCH_S == 60.0
    assert list(units.sortie) == [0] + [1] * 6 + [2] * 2
    assert units.names[0] == "short" and units.names[1] == "log [0-60 s]"
    assert units.names[6] == "log [300-360 s]" and units.names[8] == "mid [45-90 s]"
    for (i, k), unit in zip(starts, units.index):
        s = sorties[i]
        n = max(1, round(s.duration / STRETCH_S))
        expected = min(int(s.time[k] // (s.duration / n)), n - 1)
        assert units.sortie[unit] == i
        assert unit - list(units.sortie).index(i) == expected



def test_a_single_short_validation_sortie_is_cut_into_three_stretches():
    """Fewer than ``MIN_UNITS`` stretches (a real log's one 13.3 s validation segment) would
    leave the gain's t unmeasurable: the segment is cut into three stretches of 4.4 s (not
    below ``MIN_STRETCH_S``: a 7 s one stays whole), two 30 s sorties into two each."""
    from types import SimpleNamespace

    from uavdyn.flightdata import Sortie
    from uavdyn.learned.safe.scoring import MIN_STRETCH_S, stretch_length, stretches

    def sortie(name, seconds):
        t = np.arange(int(round(seconds / DT)) + 1) * DT
        return Sortie(name, "fixed_wing", t, np.zeros((len(t), 4)), np.zeros((len(t), 2)),
                      "survey")

    one = [sortie("segment", 13.3)]
    starts = [(0, k) for k in range(0, len(one[0].time) - 100, 50)]
    units = stretches(SimpleNamespace(windows=SimpleNamespace(starts=np.array(starts))), one)
    assert list(units.sortie) == [0, 0, 0]
    assert units.names == ("segment [0-4 s]", "segment [4-9 s]", "segment [9-13 s]")
    assert sorted(set(units.index)) == [0, 1, 2]
    assert stretch_length([7.0]) == MIN_STRETCH_S and round(7.0 / MIN_STRETCH_S) == 1
    assert stretch_length([30.0, 30.0]) == 20.0 and stretch_length([30.0] * 3) == 60.0

def test_the_training_sortie_guard_refuses_a_correction_worse_on_one_sortie_it_has_seen():
    """``SafeConfig.seen_guard``: the training windows are scored as the validation ones; a
    prediction whose pitch error on one training sortie is 1.1x the physics' (noise-free
    records) fails, with that sortie named and its ratio recorded; 1.01x passes."""
    from types import SimpleNamespace

    from uavdyn.learned.safe import SafeConfig
    from uavdyn.learned.safe.scoring import ValidationReference
    from uavdyn.learned.safe.selection import SeenSorties, _seen_sorties_kept

    W, H = 4, 10
    y = np.zeros((W, H, 4))
    sortie = np.array([0, 0, 1, 1])
    physics_err = 0.01  # the physics' pitch error on every sample

    def checks_with(factor_on_second: float):
        pred = np.zeros((W, H, 4))
        pred[:, :, 3] = physics_err * np.where(sortie == 1, factor_on_second, 0.5)[:, None]
        ref = ValidationReference(y, sortie, H, np.zeros((2, 4)), [physics_err] * 2,
                                  np.ones(4), physics_err, ("calm_survey", "chirp"))
        seen = SeenSorties(SimpleNamespace(), ref, lambda model, V: pred)
        return SimpleNamespace(seen=seen, model=None, config=SafeConfig(seen_guard=True),
                               setup=SimpleNamespace(dt=0.01))

    row: dict = {}
    assert not _seen_sorties_kept(checks_with(1.1), row)
    assert row["train_ratio_worst"] == pytest.approx(1.1)
    assert row["train_sorties_worse"] == ["chirp"] and row["train_ok"] is False
    row = {}
    assert _seen_sorties_kept(checks_with(1.01), row) and row["train_sorties_worse"] == []
    assert _seen_sorties_kept(SimpleNamespace(seen=None), {})


@pytest.mark.slow
def test_refit_training_starts_are_fitted_by_the_network_being_trained(tmp_path, monkeypatch):
    """``SafeConfig.train_refit_every``: every that many epochs the training windows start
    where the network being trained fits their first records (from the records each time,
    not from the last fit); off, the starts are never refitted."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe
    from uavdyn.learned.safe.twin import FittedStartPredictor

    airframe = load_airframe("aerosonde")
    sorties = load_dataset(emulated_dataset(tmp_path / "data", airframe, 4, 6.0)).sorties
    calls = []
    original = FittedStartPredictor.starts

    def counting(self, model, V):
        calls.append((V.count, len(self.noise), V.z0.detach().numpy().copy()))
        return original(self, model, V)

    monkeypatch.setattr(FittedStartPredictor, "starts", counting)
    base = dict(epochs=4, patience=10, batches_per_epoch=2, batch_windows=8, horizon_s=1.0,
                progress=False, memory_tau=(0.1,), free_run_guard=False)
    train_safe(sorties[:3], sorties[3:], airframe, SafeConfig(**base))
    validation_only = {c[0] for c in calls}
    calls.clear()
    train_safe(sorties[:3], sorties[3:], airframe, SafeConfig(**base, train_refit_every=2))
    refits = [c for c in calls if c[0] not in validation_only]
    assert len(refits) == 2                       # epochs 2 and 4
    assert all(n == count for count, n, _ in refits)
    np.testing.assert_array_equal(refits[0][2], refits[1][2])  # both from the records
