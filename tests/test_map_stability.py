"""Stability of the discrete step map: with a zero correction the hybrid map is the RK4 map,
whose eigenvalues are the RK4 stability polynomial of A dt and, to RK4 truncation, exp(A dt)."""

import numpy as np
import pytest

from uavdyn.learned import CorrectionNet, hybrid_step
from uavdyn.linear import discrete_map_modes, linearise


def zero_correction(airframe, formulation="improved"):
    rng = np.random.default_rng(0)
    n_in, n_out = (6, 3) if formulation == "improved" else (5, 4)
    sizes = [n_in, 8, 8, 8, n_out]
    weights = [rng.standard_normal((sizes[i + 1], sizes[i])) for i in range(3)]
    weights.append(np.zeros((n_out, 8)))
    biases = [rng.standard_normal(sizes[i + 1]) for i in range(3)] + [np.zeros(n_out)]
    return CorrectionNet(formulation=formulation, activation="relu", kind=airframe.kind,
                         airframe_hash=airframe.param_hash(), dt=0.002,
                         weights=tuple(weights), biases=tuple(biases),
                         in_mean=np.zeros(n_in), in_scale=np.ones(n_in),
                         out_mean=np.zeros(n_out), out_scale=np.ones(n_out))


@pytest.mark.parametrize("name, trim_name", [("aerosonde", "aerosonde_trim"),
                                             ("f450", "f450_hover")])
def test_zero_correction_map_equals_exp_A_dt(name, trim_name, request):
    af, point = request.getfixturevalue(name), request.getfixturevalue(trim_name)
    dt = 0.002
    step = hybrid_step(zero_correction(af), af, compile=False)
    comp = discrete_map_modes(step, point, dt)
    # RK4 stability polynomial R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24 of the continuous poles
    A, _ = linearise(af, point)
    z = np.linalg.eigvals(A) * dt
    rk4_poly = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    for lam in comp.map_eigenvalues:
        assert np.min(np.abs(rk4_poly - lam)) < 1e-12
    # and exp(A dt) to 1e-9 (the difference is RK4's (lambda dt)^5/120 truncation)
    assert np.abs(comp.map_eigenvalues - comp.exact_eigenvalues).max() < 1e-9
    assert comp.made_unstable == []
    assert "exp(A dt) eigenvalue" in comp.table()
    # the map's continuous-equivalent modes are the physics model's
    phys = sorted(m.natural_frequency for m in comp.physics_modes)
    mapped = sorted(m.natural_frequency for m in comp.map_modes)
    np.testing.assert_allclose(mapped, phys, rtol=1e-6, atol=1e-9)


def test_destabilising_map_is_flagged(aerosonde, aerosonde_trim):
    """A step map that amplifies w each step is reported as made unstable by the correction."""
    import casadi as ca

    base = hybrid_step(zero_correction(aerosonde), aerosonde, compile=False)
    x, u, p, dt = ca.SX.sym("x", 4), ca.SX.sym("u", 2), ca.SX.sym("p", len(aerosonde.p)), \
        ca.SX.sym("dt")
    bump = ca.vertcat(0, 0.5 * (x[1] - aerosonde_trim.x[1]), 0, 0)
    bad = ca.Function("bad", [x, u, p, dt], [base(x, u, p, dt) + bump])
    comp = discrete_map_modes(base.with_function(bad), aerosonde_trim, 0.005)
    assert comp.made_unstable, comp.table()
    assert "UNSTABLE" in comp.table()
