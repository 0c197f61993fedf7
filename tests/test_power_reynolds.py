"""Power effects (``eta_slipstream``: the elevator sees ``qbar + eta T / A_disk``) and Reynolds
effects (``C_D_Re``, ``C_m_Re``: ``Delta C = C_Re / sqrt(V)``), optional fixed-wing keys of the
baseline model and truth extras of the emulator: absent they change nothing (forces recorded
from the code before they existed), present they add exactly the textbook increments in every
ops namespace, their CasADi Jacobian is right, and the emulator can fly them."""

import math

import casadi as ca
import numpy as np
import pytest

from uavdyn.airframes import AirframeError, load_airframe, param_names
from uavdyn.emulation.datagen import Recipe
from uavdyn.emulation.emulator import Emulator, emulator_rhs, truth_param_names
from uavdyn.linear import trim
from uavdyn.model import NUMPY_OPS, fixed_wing_forces, propeller_thrust, symbolic_params
from uavdyn.model.equations import V_RE_FLOOR

TRAINER = "examples/trainer.toml"
NEW_KEYS = ("eta_slipstream", "C_D_Re", "C_m_Re")
STATES = [([14.0, 0.8, 0.1, 0.05], [-0.05, 0.6]), ([20.0, -1.0, -0.3, 0.1], [0.1, 1.0]),
          ([9.0, 2.5, 0.4, 0.2], [-0.2, 0.2]), ([0.3, 0.2, 0.0, 0.0], [0.0, 0.5])]
# X, Z, M of examples/trainer.toml at STATES, recorded with the code before the keys existed
# (git 371fee8, NumPy ops).
RECORDED = [
    (1.5781555712207624, -35.503495321934906, 0.07196641346547861),
    (3.428948929436192, -6.918306824043864, 0.04419417121921168),
    (-1.295898432997491, -5.176775820643088, -0.6384355780713117),
    (4.598869682538788, -0.025383360676083093, -0.004365858962478821),
]
VALUES = {"eta_slipstream": 0.8, "C_D_Re": 0.05, "C_m_Re": -0.05}


@pytest.fixture(scope="module")
def trainer():
    return load_airframe(TRAINER)


def _with_zero_keys(tmp_path):
    """The trainer file with the three keys written out explicitly at 0."""
    text = open(TRAINER).read()
    text += "".join(f"\n[params.{k}]\nvalue = 0.0\nsource = \"explicit zero\"\n"
                    for k in NEW_KEYS)
    path = tmp_path / "trainer_zero.toml"
    path.write_text(text)
    return load_airframe(str(path))


def test_keys_appended_optional_and_hash_unchanged(trainer, tmp_path):
    assert param_names("fixed_wing")[-3:] == NEW_KEYS
    explicit = _with_zero_keys(tmp_path)
    assert explicit.param_hash() == trainer.param_hash() == "b683b28803bc4bda"
    assert trainer.replace(eta_slipstream=0.5).param_hash() != trainer.param_hash()
    for key, bad in (("eta_slipstream", -0.1), ("eta_slipstream", 3.5), ("C_D_Re", -0.01),
                     ("C_m_Re", 2.5)):
        with pytest.raises(AirframeError, match=key):
            trainer.replace(**{key: bad})


def test_absent_keys_change_nothing(trainer, tmp_path):
    explicit = _with_zero_keys(tmp_path)
    for (x, u), recorded in zip(STATES, RECORDED):
        for af in (trainer, explicit):
            got = fixed_wing_forces(np.array(x), np.array(u), af.p, NUMPY_OPS)[:3]
            np.testing.assert_allclose(got, recorded, rtol=0, atol=1e-15)
        # the CasADi graph gives the same numbers
        got = fixed_wing_forces(ca.DM(x), ca.DM(u), ca.DM(explicit.p))[:3]
        np.testing.assert_allclose([float(v) for v in got], recorded, rtol=1e-14, atol=1e-15)


def _expected_increments(af, x, u):
    """dX, dZ, dM of the three keys at VALUES, from the formulas (NumPy, written here)."""
    P = af.params
    ub, wb = x[0], x[1]
    V = math.hypot(ub, wb)
    alpha = math.atan2(wb, ub)
    qbar = 0.5 * P.rho * V**2
    T = float(propeller_thrust(symbolic_params("fixed_wing", af.p), V, u[1], NUMPY_OPS))
    dq_tail = VALUES["eta_slipstream"] * T / (math.pi * P.D_prop**2 / 4)
    root = math.sqrt(max(V, V_RE_FLOOR))
    d_lift = dq_tail * P.S_wing * P.C_L_delta_e * u[0]
    d_drag = qbar * P.S_wing * VALUES["C_D_Re"] / root
    d_m = (dq_tail * P.S_wing * P.c * P.C_m_delta_e * u[0]
           + qbar * P.S_wing * P.c * VALUES["C_m_Re"] / root)
    return (-d_drag * math.cos(alpha) + d_lift * math.sin(alpha),
            -d_drag * math.sin(alpha) - d_lift * math.cos(alpha), d_m)


def test_increments_match_the_formulas_in_every_namespace(trainer):
    torch = pytest.importorskip("torch")
    from uavdyn.model.ops import torch_ops

    on = trainer.replace(**VALUES)
    for x, u in STATES:
        x, u = np.array(x), np.array(u)
        base = np.array(fixed_wing_forces(x, u, trainer.p, NUMPY_OPS, alpha_dot=False)[:3])
        got = np.array(fixed_wing_forces(x, u, on.p, NUMPY_OPS, alpha_dot=False)[:3])
        np.testing.assert_allclose(got - base, _expected_increments(trainer, x, u),
                                   rtol=1e-9, atol=1e-12)
        casadi = fixed_wing_forces(ca.DM(x), ca.DM(u), ca.DM(on.p), alpha_dot=False)[:3]
        np.testing.assert_allclose([float(v) for v in casadi], got, rtol=1e-12, atol=1e-13)
        t = fixed_wing_forces(torch.tensor(x), torch.tensor(u), torch.tensor(on.p),
                              torch_ops(), alpha_dot=False)[:3]
        np.testing.assert_allclose([float(v) for v in t], got, rtol=1e-12, atol=1e-13)
    # finite as V -> 0 (the floor inside the root)
    x0 = np.array([0.0, 0.0, 0.0, 0.0])
    assert np.all(np.isfinite(fixed_wing_forces(x0 + [1e-9, 0, 0, 0], [0.0, 0.5], on.p,
                                                NUMPY_OPS, alpha_dot=False)[:3]))


def test_jacobian_wrt_new_parameters_matches_finite_differences(trainer):
    on = trainer.replace(**VALUES)
    names = param_names("fixed_wing")
    idx = [names.index(k) for k in NEW_KEYS]
    x, u, p = ca.SX.sym("x", 4), ca.SX.sym("u", 2), ca.SX.sym("p", len(on.p))
    X, Z, M = fixed_wing_forces(x, u, p)[:3]
    out = ca.vertcat(X, Z, M)
    f = ca.Function("f", [x, u, p], [out])
    jac = ca.Function("j", [x, u, p], [ca.jacobian(out, p[idx])])
    for xs, us in STATES[:3]:
        J = np.array(jac(xs, us, on.p))
        fd = np.zeros_like(J)
        for j, i in enumerate(idx):
            h = 1e-6
            hi, lo = on.p.copy(), on.p.copy()
            hi[i] += h
            lo[i] -= h
            fd[:, j] = (np.array(f(xs, us, hi)) - np.array(f(xs, us, lo))).ravel() / (2 * h)
        np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-7)
        # eta moves X, Z (elevator lift) and M; C_D_Re moves X, Z only; C_m_Re M only
        assert np.all(np.abs(J[:, 0]) > 0) and np.all(np.abs(J[:2, 1]) > 0)
        assert J[2, 1] == 0 and np.all(J[:2, 2] == 0) and abs(J[2, 2]) > 0


def _doublet_q(emulator, point, seconds=1.0, dt=1e-3):
    """Pitch rate of the emulator's truth on an elevator doublet at full throttle (RK4)."""
    f = emulator_rhs("fixed_wing")
    pe = emulator.pe
    x = emulator.initial_state(point.x, point.u, 100.0)
    n = int(round(seconds / dt))
    q = []
    for k in range(n):
        t = k * dt
        elevator = point.u[0] + (-0.08 if 0.1 <= t < 0.35 else 0.08 if 0.35 <= t < 0.6 else 0)
        v = np.array([elevator, 1.0, 0.0, 0.0, 0.0])
        k1 = np.array(f(x, v, pe)).ravel()
        k2 = np.array(f(x + dt / 2 * k1, v, pe)).ravel()
        k3 = np.array(f(x + dt / 2 * k2, v, pe)).ravel()
        k4 = np.array(f(x + dt * k3, v, pe)).ravel()
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        q.append(x[2])
    return np.array(q)


def test_emulator_flies_the_slipstream(trainer):
    assert truth_param_names("fixed_wing")[-3:] == NEW_KEYS
    plain = Emulator(trainer)
    assert all(plain.truth[k] == 0.0 for k in NEW_KEYS)
    point = trim(trainer.replace(C_L_alpha_dot=0.0), 14.0)
    point.u[1] = 1.0  # high throttle: a strong slipstream
    q_plain = _doublet_q(plain, point)
    q_slip = _doublet_q(Emulator(trainer, truth={"eta_slipstream": 0.8}), point)
    # the elevator is stronger in the slipstream: a larger pitch-rate response
    assert np.max(np.abs(q_slip)) > 1.2 * np.max(np.abs(q_plain)), (
        np.max(np.abs(q_slip)), np.max(np.abs(q_plain)))
    # the truth flies the file's value plus the extra
    q_sum = _doublet_q(Emulator(trainer.replace(eta_slipstream=0.5),
                                truth={"eta_slipstream": 0.3}), point)
    np.testing.assert_allclose(q_sum, q_slip, rtol=1e-9, atol=1e-12)


def test_recipe_truth_is_optional_and_checked(trainer):
    recipe = Recipe(airframe=TRAINER)
    assert "truth" not in recipe.to_dict()
    with_truth = Recipe(airframe=TRAINER, truth={"eta_slipstream": 0.8})
    assert with_truth.to_dict()["truth"] == {"eta_slipstream": 0.8}
    with_truth.validate(trainer)
    with pytest.raises(ValueError, match="eta_slip'.*known"):
        Recipe(airframe=TRAINER, truth={"eta_slip": 0.8}).validate(trainer)
    with pytest.raises(ValueError, match="finite"):
        Recipe(airframe=TRAINER, truth={"C_D_Re": float("nan")}).validate(trainer)


def test_cli_truth_option_refuses_unknown_keys_and_non_finite_values(capsys):
    from uavdyn.cli import main

    for text, expected in (("eta_slip=0.8", "unknown truth parameter 'eta_slip'; known:"),
                           ("C_D_Re=inf", "must be a finite number"),
                           ("C_D_Re", "KEY=VALUE")):
        assert main(["generate-data", "--airframe", TRAINER, "--truth", text, "--out",
                     "/tmp/never_written_power_reynolds"]) != 0
        assert expected in capsys.readouterr().err


def test_identify_recovers_slipstream_and_reynolds_drag_from_emulated_data(trainer, tmp_path):
    """Four 20 s sysid sorties of the emulator flying eta 0.8, C_D_Re 0.05 (calm, with sensor
    noise; the truth also has its alpha-dot and actuator extras the baseline lacks): the fit
    from 0 lands near both (measured: 0.725 and 0.0506, ~15 s)."""
    from uavdyn.emulation.datagen import generate_dataset
    from uavdyn.flightdata import load_dataset
    from uavdyn.identify import identify

    recipe = Recipe(airframe=TRAINER, sorties=4, duration_s=20.0,
                    missions=["sysid_3211", "sysid_chirp"], turbulent_fraction=0.0,
                    truth={"eta_slipstream": 0.8, "C_D_Re": 0.05},
                    split={"train": 1.0, "validation": 0.0, "test": 0.0})
    generate_dataset(recipe, tmp_path / "data", workers=1, progress=False)
    sorties = list(load_dataset(tmp_path / "data").sorties)
    result = identify(trainer, sorties, [], ["eta_slipstream", "C_D_Re"], progress=False,
                      check_halves=False)
    got = {e.name: e.value for e in result.estimates}
    assert got["eta_slipstream"] == pytest.approx(0.8, abs=0.15), got
    assert got["C_D_Re"] == pytest.approx(0.05, abs=0.01), got
