"""Multirotor rotor thrust lost to axial inflow (optional ``k_inflow``) and the rotor-craft
pitching moments (optional ``M_u``, ``M_0``).

Per rotor ``omega = max(C_R sigma + omega_b, 0)`` and
``T = max(c_T omega^2 - k_inflow omega v_axial, 0)`` with the climb speed through the disc
``v_axial = -w`` (body z down). Truths: that formula evaluated here, the trim it implies in
closed form, the hash and trim recorded before the key existed, finite differences.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_alpha_dot import PRESET_HASH, PRESET_TRIM
from test_tables import check_jacobians

from uavdyn.linear import trim
from uavdyn.model import NUMPY_OPS, build_model, make_rhs

# About 10 % of the hover thrust of an F450 rotor (omega ~ 590 rad/s) at 2 m/s of climb.
K_INFLOW = 3e-4


def _thrusts(P, x, u, k):
    """Front and rear rotor thrust (N) from the formula."""
    v_axial = -x[1]
    out = []
    for sign in (1.0, -1.0):
        omega = np.maximum(P.C_R * (u[0] + sign * P.pitch_mix * u[1]) + P.omega_b, 0.0)
        out.append(np.maximum(P.c_T * omega**2 - k * omega * v_axial, 0.0))
    return out


def _states(n: int, seed: int):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(4, n)) * np.array([[3.0, 3.0, 0.5, 0.2]]).T
    u = np.vstack([rng.uniform(0.3, 0.9, n), rng.uniform(-0.5, 0.5, n)])
    return x, u


def test_zero_inflow_is_the_preset(f450):
    """At k_inflow = 0 (the default) the thrust is the static ``c_T omega^2`` at any climb speed,
    and the hash and trim are those recorded before the key existed."""
    assert f450.params.k_inflow == 0.0
    explicit = f450.replace(k_inflow=0.0)
    assert explicit.param_hash() == f450.param_hash() == PRESET_HASH["f450"]
    x, u = _states(1000, 1)
    thrust = np.array(build_model(explicit).forces.map(1000)(x, u, explicit.p)[5]).ravel()
    front, rear = _thrusts(f450.params, x, u, 0.0)
    assert np.abs(thrust - 2 * (front + rear)).max() <= 1e-12 * thrust.max()
    point = trim(explicit, 0.0)
    np.testing.assert_allclose(point.x, PRESET_TRIM["f450"][0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(point.u, PRESET_TRIM["f450"][1], rtol=1e-12, atol=1e-12)
    for V, gamma in ((5.0, 0.3), (5.0, -0.3)):
        a, b = trim(explicit, V, gamma), trim(f450, V, gamma)
        assert np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u)


def test_climb_loses_thrust_and_descent_gains_it(f450):
    airframe = f450.replace(k_inflow=K_INFLOW)
    P = airframe.params
    x, u = _states(2000, 2)
    forces = build_model(airframe).forces.map(2000)
    X, Z, M, _, _, thrust = (np.array(r).ravel() for r in forces(x, u, airframe.p))
    X0, Z0, M0, _, _, static = (np.array(r).ravel() for r in forces(x, u, f450.p))
    front, rear = _thrusts(P, x, u, K_INFLOW)
    assert np.abs(thrust - 2 * (front + rear)).max() <= 1e-12 * thrust.max()
    climbing, descending = x[1] < -0.1, x[1] > 0.1  # w < 0: the air comes from above
    assert np.all(thrust[climbing] < static[climbing])
    assert np.all(thrust[descending] > static[descending])
    # the loss acts along body z only, and on the moment by the front/rear difference
    assert np.array_equal(X, X0)
    assert np.abs((Z - Z0) + (thrust - static)).max() <= 1e-12 * np.abs(Z0).max()
    lever = P.arm * math.sqrt(0.5)
    front0, rear0 = _thrusts(P, x, u, 0.0)
    dM = 2 * ((front - front0) - (rear - rear0)) * lever
    assert np.abs((M - M0) - dM).max() <= 1e-12 * np.abs(M0).max()
    # at w = 0 nothing changes
    x[1] = 0.0
    assert np.array_equal(np.array(forces(x, u, airframe.p)[5]),
                          np.array(forces(x, u, f450.p)[5]))


@pytest.mark.parametrize("V, gamma", [(0.0, 0.0), (5.0, 0.3), (5.0, -0.3), (8.0, 0.0)])
def test_trim_with_inflow_needs_the_thrust_of_the_formula(f450, V, gamma):
    """Thrust is along body z, so u_dot = 0 fixes alpha whatever the rotors do, w_dot = 0 the
    total thrust and q_dot = 0 equal front and rear thrust: the same per-rotor thrust
    ``c_T omega0^2`` as without inflow, reached at
    ``omega = (k v + sqrt(k^2 v^2 + 4 c_T^2 omega0^2)) / (2 c_T)``."""
    airframe = f450.replace(k_inflow=K_INFLOW)
    P = airframe.params
    plain, lossy = trim(f450, V, gamma), trim(airframe, V, gamma)
    np.testing.assert_allclose(lossy.x, plain.x, rtol=0, atol=1e-9)
    assert plain.u[1] == pytest.approx(0.0, abs=1e-9) and lossy.u[1] == pytest.approx(0, abs=1e-9)
    omega0 = P.C_R * plain.u[0] + P.omega_b
    v = -plain.x[1]
    k, c = K_INFLOW, P.c_T
    omega = (k * v + math.sqrt(k**2 * v**2 + 4 * c**2 * omega0**2)) / (2 * c)
    assert lossy.u[0] == pytest.approx((omega - P.omega_b) / P.C_R, abs=1e-9)
    if gamma > 0:
        assert lossy.u[0] > plain.u[0] + 1e-3  # climbing needs more collective
    elif gamma < 0:
        assert lossy.u[0] < plain.u[0] - 1e-3


def test_inflow_jacobians_match_finite_differences(f450):
    airframe = f450.replace(k_inflow=K_INFLOW)
    model = build_model(airframe)
    P = airframe.params
    i_k = airframe.param_names.index("k_inflow")
    for x, u in (([2.0, -2.5, 0.3, 0.1], [0.6, 0.1]), ([-1.0, 3.0, -0.2, -0.1], [0.5, -0.2])):
        dfdp = check_jacobians(model, x, u, airframe.p)
        # d w_dot / dk = 2 (omega_f + omega_r) v / m, d q_dot / dk = 2 (omega_r - omega_f) v l / J
        v = -x[1]
        omega_f = P.C_R * (u[0] + P.pitch_mix * u[1]) + P.omega_b
        omega_r = P.C_R * (u[0] - P.pitch_mix * u[1]) + P.omega_b
        lever = P.arm * math.sqrt(0.5)
        assert dfdp[1, i_k] == pytest.approx(2 * (omega_f + omega_r) * v / P.mass, rel=1e-12)
        assert dfdp[2, i_k] == pytest.approx(2 * (omega_r - omega_f) * v * lever / P.Jy,
                                             rel=1e-12)


def test_inflow_is_the_same_in_numpy_torch_casadi(f450):
    torch = pytest.importorskip("torch")
    from uavdyn.model import torch_ops

    airframe = f450.replace(k_inflow=K_INFLOW)
    x, u = _states(1000, 4)
    f_np = make_rhs("multirotor", ops=NUMPY_OPS)(x, u, airframe.p)
    f_t = make_rhs("multirotor", ops=torch_ops())(torch.as_tensor(x), torch.as_tensor(u),
                                                  torch.as_tensor(airframe.p)).numpy()
    f_ca = np.array(build_model(airframe).f.map(1000)(x, u, airframe.p))
    scale = np.abs(f_np).max()
    assert np.abs(f_t - f_np).max() <= 1e-12 * scale
    assert np.abs(f_ca - f_np).max() <= 1e-12 * scale
    assert np.abs(f_np - make_rhs("multirotor", ops=NUMPY_OPS)(x, u, f450.p)).max() > 0.1


def test_rotor_craft_moments_add_exactly_their_pitch_acceleration(f450):
    """``M_u`` and ``M_0`` add ``(M_0 + M_u u) / J_y`` to ``q_dot`` and nothing else, in NumPy,
    torch and CasADi; at their default 0 the preset's hash is the one recorded before they
    existed."""
    torch = pytest.importorskip("torch")
    from uavdyn.model import torch_ops

    assert f450.replace(M_u=0.0, M_0=0.0).param_hash() == PRESET_HASH["f450"]
    airframe = f450.replace(M_u=0.012, M_0=-0.003)
    x, u = _states(1000, 5)
    base = make_rhs("multirotor", ops=NUMPY_OPS)(x, u, f450.p)
    expected = base.copy()
    expected[2] += (-0.003 + 0.012 * x[0]) / f450.params.Jy
    f_np = make_rhs("multirotor", ops=NUMPY_OPS)(x, u, airframe.p)
    f_t = make_rhs("multirotor", ops=torch_ops())(torch.as_tensor(x), torch.as_tensor(u),
                                                  torch.as_tensor(airframe.p)).numpy()
    f_ca = np.array(build_model(airframe).f.map(1000)(x, u, airframe.p))
    scale = np.abs(expected).max()
    for got in (f_np, f_t, f_ca):
        assert np.abs(got - expected).max() <= 1e-12 * scale
