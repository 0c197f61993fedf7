"""Turning flight used (issue 41 item 2): the lateral inputs phi, p, r, beta of the longitudinal
model, checked against independent truths (a level coordinated turn's load factor, the Euler
kinematics of a rotation, finite differences), the wings-level model unchanged, identification
through turns, and the import that keeps turning flight."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import fsolve

from uavdyn.airframes import AirframeError, load_airframe
from uavdyn.cli import main
from uavdyn.flightdata import Sortie, load_dataset, read_csv
from uavdyn.flightdata.attitude import body_from_euler
from uavdyn.flightdata.csvio import write_csv
from uavdyn.identify import identify
from uavdyn.integrate import free_run, rk4_step
from uavdyn.integrate.augmented import physics_function
from uavdyn.integrate.inputs import chirp, multistep_3211
from uavdyn.linear import trim
from uavdyn.model import LATERAL_INPUT_NAMES, build_model, structure_of

ROOT = Path(__file__).resolve().parents[1]
TRAINER = ROOT / "examples" / "trainer.toml"
G = 9.80665


@pytest.fixture(scope="module")
def trainer():
    return load_airframe(str(TRAINER))


@pytest.fixture(scope="module")
def aerosonde_j(aerosonde):
    """The Aerosonde with Beard & McLain's roll/yaw inertias (their Table E.2)."""
    return dataclasses.replace(aerosonde, params=dataclasses.replace(
        aerosonde.params, Jx=0.8244, Jz=1.759, Jxz=0.1204))


def _level_turn(airframe, phi: float, V: float):
    """Trim a level coordinated turn: velocity horizontal (``tan(theta) = tan(alpha)
    cos(phi)``), turning at ``omega`` about the vertical (body rates ``p = -omega sin(theta)``,
    ``q = omega sin(phi) cos(theta)``, ``r = omega cos(phi) cos(theta)``), no sideslip and no
    side force (the side equation ``g sin(phi) cos(theta) = r u - p w``, which makes
    ``omega = g tan(phi) / V`` at alpha 0); solved for (alpha, elevator, throttle, omega) that
    also zero u_dot, w_dot, q_dot. Returns the lateral airframe, x, u and omega."""
    al = airframe.with_lateral()
    f = build_model(al).f
    g = al.params.gravity

    def point(z):
        alpha, elevator, throttle, omega = z
        theta = math.atan(math.tan(alpha) * math.cos(phi))
        x = np.array([V * math.cos(alpha), V * math.sin(alpha), omega * math.sin(phi)
                      * math.cos(theta), theta])
        lat = [phi, -omega * math.sin(theta), omega * math.cos(phi) * math.cos(theta), 0.0]
        return x, np.array([elevator, throttle, *lat])

    def residual(z):
        x, u = point(z)
        side = g * math.sin(phi) * math.cos(x[3]) - (u[4] * x[0] - u[3] * x[1])
        return [*np.asarray(f(x, u, al.p)).ravel()[:3], side]

    level = trim(airframe, V)
    z = fsolve(residual, [math.atan2(level.x[1], level.x[0]), *level.u,
                          g * math.tan(phi) / V], xtol=1e-13)
    x, u = point(z)
    return al, x, u, z[3]


@pytest.mark.parametrize("bank_deg", [0.0, 20.0, 45.0])
def test_a_level_coordinated_turn_is_an_equilibrium_with_load_factor_one_over_cos_phi(
        trainer, bank_deg):
    phi = math.radians(bank_deg)
    al, x, u, omega = _level_turn(trainer, phi, 15.0)
    xdot = np.asarray(build_model(al).f(x, u, al.p)).ravel()
    assert np.max(np.abs(xdot)) < 1e-9  # u, w, q and theta all steady
    X, Z = (float(v) for v in build_model(al).forces(x, u, al.p)[:2])
    alpha = math.atan2(x[1], x[0])
    normal = X * math.sin(alpha) - Z * math.cos(alpha)  # force normal to the path, up
    along = X * math.cos(alpha) + Z * math.sin(alpha)
    weight = al.params.mass * al.params.gravity
    # the force balances weight and the centripetal V omega: m sqrt(g^2 + (V omega)^2)
    assert normal / weight == pytest.approx(math.hypot(1.0, 15.0 * omega / al.params.gravity),
                                            rel=1e-9)
    assert normal / weight == pytest.approx(1.0 / math.cos(phi), rel=2e-3)  # n = 1/cos(phi)
    assert omega == pytest.approx(al.params.gravity * math.tan(phi) / 15.0, rel=2e-3)
    assert abs(along) < 1e-9 * weight  # steady speed: thrust balances drag
    if bank_deg:  # the turn needs more lift than wings level: a larger alpha
        _, x0, _, _ = _level_turn(trainer, 0.0, 15.0)
        assert x[1] / x[0] > x0[1] / x0[0]


def test_theta_dot_is_the_euler_pitch_rate_of_the_rotation(trainer):
    """theta_dot = q cos(phi) - r sin(phi) against a finite difference of Euler angles whose
    body rates come from the rotation matrix alone."""
    al = trainer.with_lateral()
    f = build_model(al).f

    def euler(t):
        return 0.6 * math.sin(0.7 * t) + 0.2, 0.3 * math.sin(0.5 * t + 0.4), 0.9 * t

    for t in (0.3, 1.7, 4.2):
        h = 1e-5
        C = [body_from_euler(*map(np.atleast_1d, euler(s)))[0] for s in (t - h, t, t + h)]
        W = -(C[2] - C[0]) / (2 * h) @ C[1].T   # skew(omega) = -C_dot C^T (C: NED -> body)
        p, q, r = W[2, 1], W[0, 2], W[1, 0]
        phi, theta, _ = euler(t)
        theta_dot = (euler(t + h)[1] - euler(t - h)[1]) / (2 * h)
        x = np.array([15.0, 0.8, q, theta])
        u = np.array([-0.02, 0.5, phi, p, r, 0.03])
        assert float(f(x, u, al.p)[3]) == pytest.approx(theta_dot, abs=1e-8)


@pytest.mark.parametrize("name", ["trainer", "x500"])
def test_zero_lateral_inputs_give_the_wings_level_step_exactly(name):
    af = load_airframe(str(ROOT / "examples" / f"{name}.toml"))
    al = af.with_lateral()
    rng = np.random.default_rng(3)
    s0, s1 = structure_of(af), structure_of(al)
    assert not s0.lateral and s1.lateral
    assert s1.control_names == s0.control_names + LATERAL_INPUT_NAMES
    assert al.p[:len(af.p)].tolist() == af.p.tolist()
    step0, step1 = physics_function(af, substeps=2), physics_function(al, substeps=2)
    f0, f1 = build_model(af).f, build_model(al).f
    nz = step0.size1_in(0)
    for _ in range(5):
        base = np.array([14.0, 0.5, 0.1, 0.05]) if af.kind == "fixed_wing" else np.array(
            [2.0, 0.3, 0.1, -0.05])
        x = base + rng.normal(0, 0.1, 4)
        u = np.array([0.02, 0.55]) + rng.normal(0, 0.02, 2)
        z = np.concatenate([x, np.tile(u, 2)[:nz - 4]])
        u1 = np.concatenate([u, np.zeros(4)])
        assert np.array_equal(np.asarray(f0(x, u, af.p)), np.asarray(f1(x, u1, al.p)))
        assert np.array_equal(np.asarray(step0(z, u, af.p, 0.02)),
                              np.asarray(step1(z, u1, al.p, 0.02)))


def test_a_model_without_lateral_inputs_is_unchanged_by_the_inertia_keys(trainer, tmp_path):
    """Jx, Jz, Jxz in a file change nothing without lateral inputs: same p, hash, graph."""
    text = TRAINER.read_text()
    start = text.index("[params.Jx]")
    stop = text.index("[params.S_wing]")
    bare = tmp_path / "bare.toml"
    bare.write_text(text[:start] + text[stop:])
    plain = load_airframe(str(bare))
    assert plain.params.Jx == 0.0 and trainer.params.Jx == 0.14
    assert plain.param_names == trainer.param_names
    assert plain.p.tolist() == trainer.p.tolist()
    assert plain.param_hash() == trainer.param_hash()
    assert structure_of(plain) == structure_of(trainer)
    assert trainer.with_lateral().param_hash() != trainer.param_hash()
    with pytest.raises(AirframeError, match="needs the roll and yaw inertias Jx and Jz"):
        plain.with_lateral()


def test_jacobians_match_finite_differences_with_the_lateral_inputs(trainer):
    al, x, u, _ = _level_turn(trainer, math.radians(30.0), 15.0)
    u = u + np.array([0.01, 0.02, 0.05, 0.1, -0.05, 0.04])
    m = build_model(al)
    A, B, _ = (np.asarray(J) for J in m.jacobians(x, u, al.p))
    h = 1e-6

    def f(xx, uu):
        return np.asarray(m.f(xx, uu, al.p)).ravel()

    A_fd = np.column_stack([(f(x + h * e, u) - f(x - h * e, u)) / (2 * h) for e in np.eye(4)])
    B_fd = np.column_stack([(f(x, u + h * e) - f(x, u - h * e)) / (2 * h) for e in np.eye(6)])
    assert np.allclose(A, A_fd, rtol=1e-6, atol=1e-6)
    assert np.allclose(B, B_fd, rtol=1e-6, atol=1e-6)
    assert np.all(np.abs(B[:, 2:]).max(axis=0) > 1e-3)  # every lateral input acts


SCALED = {"C_m_alpha": 1.15, "C_m_q": 0.90, "C_L_alpha": 1.20}


def _turning_sorties(truth, n, seed, duration=12.0):
    """Sysid flights of ``truth`` through a coordinated turn (bank to 20-30 deg and back),
    elevator 3-2-1-1 and chirp, throttle wiggle; noise-free."""
    rng = np.random.default_rng(seed)
    step = rk4_step(build_model(truth).f)
    out = []
    for i in range(n):
        point = trim(truth, 21.0 + 2.0 * i)
        t = np.arange(int(round(duration / 0.01)) + 1) * 0.01
        bank = math.radians(rng.uniform(20.0, 30.0)) * rng.choice([-1.0, 1.0])
        phi = bank * np.clip(np.minimum(t - 2.0, 9.0 - t), 0.0, 1.0)
        psi_dot = G * np.tan(phi) / 21.0
        lat = np.column_stack([phi, np.gradient(phi, t), psi_dot * np.cos(phi),
                               np.full_like(t, 0.01)])
        u = np.tile(point.u, (len(t), 1))
        u[:, 0] += multistep_3211(t, np.radians(2.0), start=1.0 + 0.2 * i)
        u[:, 0] += chirp(t, np.radians(1.0), start=5.0, duration=duration - 5.0)
        u[:, 1] += 0.05 * np.sin(0.6 * t + i)
        u = np.column_stack([u, lat])
        x = free_run(step, point.x, u[:-1], truth.p, 0.005, 2)
        out.append(Sortie(f"s{seed}_{i}", "fixed_wing", t, x, u, "sysid"))
    return out


@pytest.mark.slow
def test_identification_through_turns_recovers_the_parameters(aerosonde_j):
    truth = aerosonde_j.with_lateral().replace(
        **{k: getattr(aerosonde_j.params, k) * f for k, f in SCALED.items()})
    train = _turning_sorties(truth, 3, 0)
    assert all(s.lateral for s in train)
    assert max(np.abs(s.controls[:, 2]).max() for s in train) > math.radians(19.0)
    result = identify(aerosonde_j, train, _turning_sorties(truth, 1, 1), list(SCALED),
                      progress=False)
    assert result.airframe.lateral
    for e in result.estimates:
        true = getattr(truth.params, e.name)
        assert abs(e.value - true) <= 5e-3 * abs(true), (e.name, e.value, true)
        assert abs(e.value - e.nominal) > 0.05 * abs(true)
    assert result.fit["validation"]["theta_rmse"]["identified"] < 1e-6
    assert result.fit["validation"]["theta_rmse"]["nominal"] > 1e-3


def test_lateral_columns_round_trip_through_the_csv(tmp_path, trainer):
    t = np.arange(50) * 0.02
    states = np.column_stack([np.full(50, 15.0), np.full(50, 0.5), np.full(50, 0.1),
                              0.05 + np.cumsum(np.full(50, 0.1 * math.cos(0.3) - 0.2
                                                       * math.sin(0.3))) * 0.02 - 0.002])
    controls = np.column_stack([np.full(50, -0.02), np.full(50, 0.5), np.full(50, 0.3),
                                np.zeros(50), np.full(50, 0.2), np.full(50, 0.01)])
    path = write_csv(Sortie("turn", "fixed_wing", t, states, controls), tmp_path / "turn.csv")
    assert path.read_text().splitlines()[0] == \
        "time,u,w,q,theta,elevator,throttle,phi,p,r,beta"
    back = read_csv(path)
    assert back.lateral and np.array_equal(back.controls, controls)


def test_import_keeps_turning_flight_and_the_model_takes_it(tmp_path, trainer):
    """import-log --turns keeps the turns (cut only beyond --max-bank), records the channels
    it fed, and the dataset's sorties carry phi, p, r, beta."""
    from tests.campaign_flights import write_campaign
    from tests.turning_flights import turning_flight

    flight = turning_flight(5, duration_s=80.0, rate_hz=20.0)
    assert flight.turns and flight.bank_time(15.0) > 5.0
    logs = write_campaign(tmp_path / "logs", [flight])
    assert main(["import-log", str(logs[0]), "--kind", "fixed_wing", "--out",
                 str(tmp_path / "level")]) == 0
    assert main(["import-log", str(logs[0]), "--kind", "fixed_wing", "--turns", "--out",
                 str(tmp_path / "turn")]) == 0
    level, turn = load_dataset(tmp_path / "level"), load_dataset(tmp_path / "turn")
    assert not level.lateral and turn.lateral
    kept = {name: sum(s.duration for s in ds.sorties) for name, ds in
            (("level", level), ("turn", turn))}
    assert kept["turn"] == pytest.approx(flight.duration, abs=0.1)
    assert kept["level"] < flight.duration - flight.bank_time(15.0)
    manifest = json.loads((tmp_path / "turn" / "manifest.json").read_text())
    assert manifest["logs"][0]["lateral_inputs"]["phi"] == "roll"
    assert manifest["logs"][0]["segmentation"]["rules"]["turns"] is True
    phi = np.concatenate([s.controls[:, 2] for s in turn.sorties])
    assert np.degrees(np.abs(phi)).max() > 19.0
    # the bank limit cuts: below the flight's bank, the turns are dropped again
    assert main(["import-log", str(logs[0]), "--kind", "fixed_wing", "--turns", "--max-bank",
                 "10", "--out", str(tmp_path / "limited")]) == 0
    limited = load_dataset(tmp_path / "limited")
    assert sum(s.duration for s in limited.sorties) < kept["turn"] - 5.0
    assert (tmp_path / "limited" / "import_summary.txt").read_text().count(
        "banked above 10 deg (the turning-flight limit)") >= 1


def test_mixed_lateral_and_wings_level_sorties_are_refused(tmp_path, trainer):
    from uavdyn.flightdata import FlightDataError

    t = np.arange(300) * 0.02
    states = np.column_stack([np.full(300, 15.0), np.full(300, 0.5), np.zeros(300),
                              np.full(300, 0.03)])
    a = Sortie("a", "fixed_wing", t, states, np.tile([-0.02, 0.5], (300, 1)))
    b = Sortie("b", "fixed_wing", t, states, np.tile([-0.02, 0.5, 0, 0, 0, 0], (300, 1)))
    from uavdyn.flightdata.manifest import write_manifest

    for s in (a, b):
        write_csv(s, tmp_path / f"{s.name}.csv")
    write_manifest(tmp_path, airframe="", kind="fixed_wing", sample_rate_hz=50.0,
                   source="test", sorties=[{"file": f"{s.name}.csv", "mission": "",
                                            "duration_s": s.duration, "split": "train"}
                                           for s in (a, b)])
    with pytest.raises(FlightDataError, match="all have them or none"):
        load_dataset(tmp_path)


def test_export_c_with_the_lateral_inputs(tmp_path):
    out = tmp_path / "bundle"
    assert main(["export-c", "--airframe", str(TRAINER), "--model", "rk4", "--lateral",
                 "--out", str(out)]) == 0
    header = (out / "uav_step.h").read_text()
    assert "#define UAV_STEP_NU 6" in header
    assert "u = [elevator, throttle, phi, p, r, beta]" in header


def test_a_weight_file_records_the_lateral_inputs(tmp_path, trainer):
    """n_controls = 6 survives the file; a network for 6 inputs refuses a wings-level step."""
    from uavdyn.learned.weights import CorrectionNet, WeightFileError, load_weights, save_weights
    from uavdyn.model import structure_of as structure

    al = trainer.with_lateral()
    n_state = structure(al).nx()
    n_in = n_state + 6
    rng = np.random.default_rng(0)
    widths = [n_in, 8, 8, 8, 3]
    net = CorrectionNet(
        formulation="improved", activation="tanh", kind="fixed_wing",
        airframe_hash=al.param_hash(), dt=0.05, n_state=n_state, n_controls=6,
        weights=tuple(rng.normal(size=(widths[i + 1], widths[i])) for i in range(4)),
        biases=tuple(np.zeros(widths[i + 1]) for i in range(4)),
        in_mean=np.zeros(n_in), in_scale=np.ones(n_in), out_mean=np.zeros(3),
        out_scale=np.ones(3))
    path = save_weights(net, tmp_path / "w.npz")
    back = load_weights(path)
    assert back.n_controls == 6 and back.n_in == n_in
    assert back.layout(structure(al)).nu == 6
    with pytest.raises(WeightFileError, match="n_controls"):
        back.layout(structure(trainer))


def test_the_emulator_with_zero_lateral_inputs_flies_the_wings_level_truth(trainer):
    """The truth's turning terms vanish with the lateral inputs at zero, and a bank makes the
    truth need more lift (it sinks without more elevator)."""
    from uavdyn.emulation.autopilot import open_loop_references
    from uavdyn.emulation.emulator import Emulator

    point = trim(trainer, 15.0)
    emulator = Emulator(trainer, sample_rate_hz=50.0, internal_dt=0.005, compiled=False)
    n = 101
    ref = open_loop_references(np.tile(point.u, (n, 1)))
    x0 = emulator.initial_state(point.x, point.u, 100.0)
    plain = emulator.fly(x0, ref)
    zero = emulator.fly(x0, ref, lateral=np.zeros((n, 4)))
    assert np.array_equal(plain.true_states, zero.true_states)
    bank = np.tile([math.radians(30.0), 0.0, G * math.tan(math.radians(30.0)) / 15.0
                    * math.cos(math.radians(30.0)), 0.0], (n, 1))
    turned = emulator.fly(x0, ref, lateral=bank)
    assert turned.aux["h"][-1] < plain.aux["h"][-1] - 0.5
