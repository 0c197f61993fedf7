"""Breakpoint tables (``[tables]`` of an airframe file): the interpolation, the model with
tables, and the file.

Truths used, each independent of the code under test: CasADi's own
``interpolant(..., 'linear')``; central finite differences; the polynomial model a table is
sampled from (a piecewise-linear table of a linear function is that function; of the quadratic
drag polar it is off by exactly ``(a - b_i)(b_{i+1} - a) f''/2``); the propeller model at the
breakpoints of a thrust table, and the trim that follows in closed form from a table that is
linear in throttle inside a cell; the file an airframe was written to; the preset hashes
recorded before tables existed. The malformed-file cases are in ``tests/fuzz_airframe.py``
(``KEYED_CASES``, run by ``tests/test_fuzz.py``: one line naming the file and the key).
"""

from __future__ import annotations

import json
import math

import casadi as ca
import numpy as np
import pytest
from fuzz_airframe import toml_text
from test_alpha_dot import PRESET_HASH

from uavdyn.airframes import AirframeError, load_airframe, param_names, to_toml_dict
from uavdyn.airframes.tables import TABLE_MAX_POINTS
from uavdyn.integrate import free_run, physics_step
from uavdyn.linear import trim
from uavdyn.model import (
    NUMPY_OPS,
    build_model,
    interp1,
    interp2,
    propeller_thrust,
    structure_of,
    symbolic_params,
)

FULL_ALPHA = np.linspace(-math.pi, math.pi, 41)  # the whole range of atan2: no clamping


def _grid(rng, n: int) -> np.ndarray:
    """``n`` strictly increasing breakpoints with spacings spread over four decades (close and
    far breakpoints side by side: steep and flat segments)."""
    widths = np.exp(rng.uniform(math.log(1e-4), 0.0, n - 1))
    return rng.uniform(-2.0, 0.0) + np.concatenate([[0.0], np.cumsum(widths)])


def _inside(rng, breaks: np.ndarray, n: int) -> np.ndarray:
    """Random points inside the grid, the breakpoints themselves and interval midpoints."""
    mids = 0.5 * (breaks[1:] + breaks[:-1])
    return np.concatenate([rng.uniform(breaks[0], breaks[-1], n), breaks, mids])


def _away_from_breaks(rng, breaks: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points at 10..90 % of random intervals, and each one's interval width."""
    k = rng.integers(0, len(breaks) - 1, n)
    width = breaks[k + 1] - breaks[k]
    return breaks[k] + rng.uniform(0.1, 0.9, n) * width, width


# ------------------------------------------------------------------ interpolation


@pytest.mark.parametrize("n", [2, 3, 17, TABLE_MAX_POINTS])
def test_interp1_equals_casadi_interpolant_inside_the_grid(n):
    rng = np.random.default_rng(n)
    for scale in (1.0, 1e3, 1e7):  # coefficients ... thrust in N
        breaks = _grid(rng, n)
        values = rng.normal(size=n) * scale
        x = _inside(rng, breaks, 2000)
        truth = np.array(ca.interpolant("truth", "linear", [breaks], values)(x)).ravel()
        xs, vs = ca.SX.sym("x"), ca.SX.sym("v", n)
        sym = ca.Function("t", [xs, vs], [interp1(breaks, [vs[i] for i in range(n)], xs)])
        got_ca = np.array(sym.map(len(x))(x, values)).ravel()
        got_np = interp1(breaks, values, x, NUMPY_OPS)
        tol = 1e-12 * np.abs(values).max()
        assert np.abs(got_np - truth).max() <= tol
        assert np.abs(got_ca - truth).max() <= tol
        # at a breakpoint the table value itself, bit for bit
        assert np.array_equal(interp1(breaks, values, breaks, NUMPY_OPS), values)
        assert np.array_equal(np.array(sym.map(n)(breaks, values)).ravel(), values)


@pytest.mark.parametrize("n0, n1", [(2, 2), (3, 5), (40, 7), (TABLE_MAX_POINTS, 3)])
def test_interp2_equals_casadi_interpolant_inside_the_grid(n0, n1):
    rng = np.random.default_rng(100 * n0 + n1)
    b0, b1 = _grid(rng, n0), _grid(rng, n1)
    table = rng.normal(size=(n0, n1)) * 50.0
    x0 = np.concatenate([_inside(rng, b0, 500), rng.choice(b0, 300)])
    x1 = np.concatenate([_inside(rng, b1, 500), rng.choice(b1, 300)])
    m = min(len(x0), len(x1))
    x0, x1 = x0[:m], x1[:m]
    # CasADi's grid values are column-major (first axis fastest); ours row-major
    truth = np.array(ca.interpolant("truth", "linear", [b0, b1], table.ravel(order="F"))(
        np.vstack([x0, x1]))).ravel()
    got_np = interp2(b0, b1, table.ravel(), x0, x1, NUMPY_OPS)
    a0, a1, vs = ca.SX.sym("a0"), ca.SX.sym("a1"), ca.SX.sym("v", n0 * n1)
    sym = ca.Function("t", [a0, a1, vs], [interp2(b0, b1, [vs[i] for i in range(n0 * n1)],
                                                  a0, a1)])
    got_ca = np.array(sym.map(m)(x0, x1, table.ravel())).ravel()
    tol = 1e-12 * np.abs(table).max()
    assert np.abs(got_np - truth).max() <= tol
    assert np.abs(got_ca - truth).max() <= tol
    i, j = rng.integers(0, n0, 50), rng.integers(0, n1, 50)
    assert np.array_equal(interp2(b0, b1, table.ravel(), b0[i], b1[j], NUMPY_OPS), table[i, j])


def test_interpolation_is_held_constant_outside_the_grid():
    rng = np.random.default_rng(5)
    breaks = _grid(rng, 9)
    values = rng.normal(size=9)
    below = breaks[0] - rng.uniform(0, 10, 50)
    above = breaks[-1] + rng.uniform(0, 10, 50)
    assert np.all(interp1(breaks, values, below, NUMPY_OPS) == values[0])
    assert np.all(interp1(breaks, values, above, NUMPY_OPS) == values[-1])
    # 2-D: outside on one axis or both is the value at the nearest point of the grid
    b0, b1 = _grid(rng, 6), _grid(rng, 4)
    table = rng.normal(size=(6, 4))
    x0 = rng.uniform(b0[0] - 3, b0[-1] + 3, 500)
    x1 = rng.uniform(b1[0] - 3, b1[-1] + 3, 500)
    clipped = np.vstack([np.clip(x0, b0[0], b0[-1]), np.clip(x1, b1[0], b1[-1])])
    truth = np.array(ca.interpolant("t", "linear", [b0, b1], table.ravel(order="F"))(
        clipped)).ravel()
    got = interp2(b0, b1, table.ravel(), x0, x1, NUMPY_OPS)
    assert np.mean((x0 < b0[0]) | (x0 > b0[-1])) > 0.3  # many points really are outside
    assert np.abs(got - truth).max() <= 1e-14 * np.abs(table).max()
    # and the slope there is zero
    xs = ca.SX.sym("x")
    slope = ca.Function("s", [xs], [ca.jacobian(interp1(breaks, values, xs), xs)])
    assert np.all(np.array(slope.map(100)(np.concatenate([below, above]))) == 0.0)


def test_numpy_torch_casadi_interpolation_agree():
    torch = pytest.importorskip("torch")
    from uavdyn.model import torch_ops

    rng = np.random.default_rng(8)
    b0, b1 = _grid(rng, 30), _grid(rng, 5)
    values = rng.normal(size=30 * 5) * 10
    x0 = rng.uniform(b0[0] - 0.5, b0[-1] + 0.5, 3000)  # inside and outside
    x1 = rng.uniform(b1[0] - 0.5, b1[-1] + 0.5, 3000)
    T = torch.as_tensor
    one_np = interp1(b0, values[:30], x0, NUMPY_OPS)
    one_t = interp1(b0, T(values[:30]), T(x0), torch_ops()).numpy()
    two_np = interp2(b0, b1, values, x0, x1, NUMPY_OPS)
    two_t = interp2(b0, b1, T(values), T(x0), T(x1), torch_ops()).numpy()
    a0, a1 = ca.SX.sym("a0"), ca.SX.sym("a1")
    f = ca.Function("f", [a0, a1], [interp1(b0, values[:30], a0),
                                    interp2(b0, b1, values, a0, a1)])
    one_ca, two_ca = (np.array(r).ravel() for r in f.map(len(x0))(x0, x1))
    scale = np.abs(values).max()
    for a, b in ((one_t, one_np), (one_ca, one_np), (two_t, two_np), (two_ca, two_np)):
        assert np.abs(a - b).max() <= 1e-13 * scale


def test_interpolation_derivatives_match_finite_differences():
    """d/dx and d/dvalues of the CasADi graph and of torch autograd equal central differences
    (exact for a piecewise-linear function, up to rounding) away from the breakpoints."""
    torch = pytest.importorskip("torch")
    from uavdyn.model import torch_ops

    rng = np.random.default_rng(13)
    b0, b1 = _grid(rng, 12), _grid(rng, 4)
    n = len(b0) * len(b1)
    values = rng.normal(size=n)
    x0, w0 = _away_from_breaks(rng, b0, 200)
    x1, w1 = _away_from_breaks(rng, b1, 200)
    a0, a1, vs = ca.SX.sym("a0"), ca.SX.sym("a1"), ca.SX.sym("v", n)
    y = interp2(b0, b1, [vs[i] for i in range(n)], a0, a1)
    y1 = interp1(b0, [vs[i] for i in range(len(b0))], a0)
    jac = ca.Function("j", [a0, a1, vs], [ca.jacobian(y, ca.vertcat(a0, a1)),
                                          ca.jacobian(y, vs), ca.jacobian(y1, a0)])

    def table(p, q, v):
        return interp2(b0, b1, v, p, q, NUMPY_OPS)

    for k in range(len(x0)):
        dx, dv, dx1 = (np.array(m).ravel() for m in jac(x0[k], x1[k], values))
        h0, h1 = 1e-3 * w0[k], 1e-3 * w1[k]  # stays inside the interval
        fd0 = (table(x0[k] + h0, x1[k], values) - table(x0[k] - h0, x1[k], values)) / (2 * h0)
        fd1 = (table(x0[k], x1[k] + h1, values) - table(x0[k], x1[k] - h1, values)) / (2 * h1)
        fd1d = (interp1(b0, values[:len(b0)], x0[k] + h0, NUMPY_OPS)
                - interp1(b0, values[:len(b0)], x0[k] - h0, NUMPY_OPS)) / (2 * h0)
        # rounding of a difference over h: eps |v| / h
        assert abs(dx[0] - fd0) <= 1e-9 * max(1.0, abs(fd0)) + 1e-15 / h0
        assert abs(dx[1] - fd1) <= 1e-9 * max(1.0, abs(fd1)) + 1e-15 / h1
        assert abs(dx1[0] - fd1d) <= 1e-9 * max(1.0, abs(fd1d)) + 1e-15 / h0
        eye = np.eye(n)
        fdv = np.array([(table(x0[k], x1[k], values + 1e-3 * e)
                         - table(x0[k], x1[k], values - 1e-3 * e)) / 2e-3 for e in eye])
        assert np.abs(dv - fdv).max() <= 1e-12
        assert np.count_nonzero(dv) == 4 and dv.sum() == pytest.approx(1.0, abs=1e-14)
    # torch autograd (the training path) gives the same derivatives
    tx0 = torch.tensor(x0, requires_grad=True)
    tx1 = torch.tensor(x1, requires_grad=True)
    tv = torch.tensor(values, requires_grad=True)
    interp2(b0, b1, tv, tx0, tx1, torch_ops()).sum().backward()
    dxs = np.array([np.array(jac(x0[k], x1[k], values)[0]).ravel() for k in range(len(x0))])
    dvs = sum(np.array(jac(x0[k], x1[k], values)[1]).ravel() for k in range(len(x0)))
    assert np.abs(tx0.grad.numpy() - dxs[:, 0]).max() <= 1e-9 * np.abs(dxs[:, 0]).max()
    assert np.abs(tx1.grad.numpy() - dxs[:, 1]).max() <= 1e-9 * np.abs(dxs[:, 1]).max()
    assert np.abs(tv.grad.numpy() - dvs).max() <= 1e-12 * len(x0)


def test_interpolation_refuses_malformed_grids():
    with pytest.raises(ValueError, match="at least 2"):
        interp1([0.0], [1.0], 0.5, NUMPY_OPS)
    with pytest.raises(ValueError, match="strictly increasing"):
        interp1([0.0, 0.0, 1.0], [1.0, 2.0, 3.0], 0.5, NUMPY_OPS)
    with pytest.raises(ValueError, match="2 values for 3"):
        interp1([0.0, 0.5, 1.0], [1.0, 2.0], 0.5, NUMPY_OPS)
    with pytest.raises(ValueError, match="5 values for a 2 x 3"):
        interp2([0.0, 1.0], [0.0, 1.0, 2.0], [1.0] * 5, 0.5, 0.5, NUMPY_OPS)


# ------------------------------------------------------------------ the model with tables


def airframe_file(folder, name: str, base: str = "aerosonde", tables: dict | None = None,
              params: dict | None = None, **top) -> object:
    """The preset written as a JSON file with tables / changed parameters / top-level keys,
    loaded back (the loader checks everything a user's file gets checked for)."""
    data = to_toml_dict(load_airframe(base))
    data["name"] = name
    for key, value in (params or {}).items():
        data["params"][key] = {"value": value, "source": "test"}
    if tables:
        data["tables"] = tables
    data.update(top)
    path = folder / f"{name}.json"
    path.write_text(json.dumps(data))
    return load_airframe(path)


def _polynomials(P):
    """The preset's attached-flow polynomials (SPEC section 2) and the polar's curvature."""
    aspect = P.b**2 / P.S_wing
    k_polar = 1.0 / (math.pi * P.e * aspect)

    def cl(a):
        return P.C_L_0 + P.C_L_alpha * a + P.C_L_alpha2 * a**2

    def cd(a):
        return P.C_D_0 + cl(a) ** 2 * k_polar

    def cm(a):
        return P.C_m_0 + P.C_m_alpha * a

    return cl, cd, cm, 2.0 * P.C_L_alpha**2 * k_polar  # f'' of the polar (linear lift)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("tables")


@pytest.fixture(scope="module")
def polys(aerosonde):
    P = aerosonde.params
    # The preset's lift is linear in alpha (no quadratic term), so a piecewise-linear C_L
    # table is exact and the comparisons below hold to rounding; with a quadratic term the
    # table would be off by up to h^2/8 |2 C_L_alpha2|.
    assert P.C_L_alpha2 == 0.0, "the exact-table tests assume the preset's linear lift"
    return _polynomials(P)


@pytest.fixture(scope="module")
def lift_moment_tables(aerosonde, polys, folder):
    cl, _, cm, _ = polys
    return airframe_file(folder, "lift_moment", tables={
        "C_L": {"alpha": FULL_ALPHA.tolist(), "values": cl(FULL_ALPHA).tolist()},
        "C_m": {"alpha": FULL_ALPHA.tolist(), "values": cm(FULL_ALPHA).tolist()}})


def _random_states(aerosonde_trim, n: int, seed: int, wide: bool = False):
    rng = np.random.default_rng(seed)
    spread = np.array([[3.0, 2.0, 0.5, 0.2]]).T
    x = aerosonde_trim.x[:, None] + rng.normal(size=(4, n)) * spread
    if wide:  # every angle of attack, post-stall and backwards included
        speed = rng.uniform(5.0, 40.0, n)
        alpha = rng.uniform(-math.pi, math.pi, n)
        x[0], x[1] = speed * np.cos(alpha), speed * np.sin(alpha)
    u = np.vstack([rng.uniform(-0.5, 0.5, n), rng.uniform(0.0, 1.0, n)])
    return x, u


def _f(model, x, u, p):
    return np.array(model.f.map(x.shape[1])(x, u, p))


@pytest.mark.parametrize("wide", [False, True])
def test_lift_and_moment_tables_of_the_polynomials_reproduce_the_preset(
        wide, aerosonde, aerosonde_trim, lift_moment_tables):
    x, u = _random_states(aerosonde_trim, 2000, 1, wide)
    preset = _f(build_model(aerosonde), x, u, aerosonde.p)
    tabled = _f(build_model(lift_moment_tables), x, u, lift_moment_tables.p)
    assert build_model(lift_moment_tables).np == len(aerosonde.p) + 2 * len(FULL_ALPHA)
    assert np.abs(tabled - preset).max() <= 1e-12 * np.abs(preset).max()


def test_drag_table_is_off_by_exactly_the_interpolation_error_of_the_polar(
        aerosonde, aerosonde_trim, polys, folder):
    """The polar is quadratic in alpha (``f'' = 2 C_L_alpha^2 / (pi e AR)``), so its
    piecewise-linear table is above it by exactly ``(a - b_i)(b_{i+1} - a) f''/2``; the model's
    drag changes by that times ``qbar S (1 - sigma)``, in X and Z, and nothing else moves."""
    _, cd, _, curvature = polys
    airframe = airframe_file(folder, "drag", tables={
        "C_D": {"alpha": FULL_ALPHA.tolist(), "values": cd(FULL_ALPHA).tolist()}})
    x, u = _random_states(aerosonde_trim, 2000, 2, wide=True)
    forces_p = build_model(aerosonde).forces.map(x.shape[1])
    forces_t = build_model(airframe).forces.map(x.shape[1])
    X0, Z0, M0 = (np.array(r).ravel() for r in forces_p(x, u, aerosonde.p)[:3])
    X1, Z1, M1 = (np.array(r).ravel() for r in forces_t(x, u, airframe.p)[:3])
    P = aerosonde.params
    alpha = np.arctan2(x[1], x[0])
    k = np.clip(np.searchsorted(FULL_ALPHA, alpha) - 1, 0, len(FULL_ALPHA) - 2)
    delta_cd = (alpha - FULL_ALPHA[k]) * (FULL_ALPHA[k + 1] - alpha) * curvature / 2
    e_minus = np.exp(-P.M_blend * (alpha - P.alpha0))  # Beard & McLain eq. 4.10
    e_plus = np.exp(P.M_blend * (alpha + P.alpha0))
    sigma = (1 + e_minus + e_plus) / ((1 + e_minus) * (1 + e_plus))
    qbar_s = 0.5 * P.rho * (x[0] ** 2 + x[1] ** 2) * P.S_wing
    extra_drag = qbar_s * (1 - sigma) * delta_cd
    assert extra_drag.max() > 1e-3  # N: a real difference on this coarse grid
    scale = 1e-12 * max(np.abs(X0).max(), np.abs(Z0).max())
    assert np.abs((X1 - X0) + extra_drag * np.cos(alpha)).max() <= scale
    assert np.abs((Z1 - Z0) + extra_drag * np.sin(alpha)).max() <= scale
    assert np.array_equal(M1, M0)


def _doublet_controls(trim_u, n: int, dt: float) -> np.ndarray:
    t = np.arange(n) * dt
    elevator = trim_u[0] + 0.08 * ((t >= 0.5) & (t < 1.0)) - 0.08 * ((t >= 1.0) & (t < 1.5))
    throttle = np.where(t >= 2.5, trim_u[1] - 0.2, trim_u[1])
    return np.column_stack([elevator, throttle])


def test_sampled_tables_reproduce_a_rollout_of_the_preset(aerosonde, aerosonde_trim, polys,
                                                          folder):
    """C_L, C_D and C_m tables sampled from the preset (C_D on a grid made dense where the
    flight goes, so the polar's interpolation error ``h^2/8 f''`` is below 1e-7) fly a 5 s
    elevator doublet and throttle step like the preset to 1e-6."""
    cl, cd, cm, curvature = polys
    dt, n = 0.01, 500
    controls = _doublet_controls(aerosonde_trim.u, n, dt)
    preset = free_run(physics_step(aerosonde), aerosonde_trim.x, controls, aerosonde.p, dt,
                      compile=False)
    alpha = np.arctan2(preset[:, 1], preset[:, 0])
    low, high = alpha.min() - 0.02, alpha.max() + 0.02  # RK stages go a little further
    dense = np.linspace(low, high, TABLE_MAX_POINTS - 4)
    h = dense[1] - dense[0]
    assert h**2 / 8 * curvature < 1e-7  # C_D error bound on the dense part
    cd_grid = np.concatenate([[-math.pi, -1.0], dense, [1.0, math.pi]])
    airframe = airframe_file(folder, "all_tables", tables={
        "C_L": {"alpha": FULL_ALPHA.tolist(), "values": cl(FULL_ALPHA).tolist()},
        "C_D": {"alpha": cd_grid.tolist(), "values": cd(cd_grid).tolist()},
        "C_m": {"alpha": FULL_ALPHA.tolist(), "values": cm(FULL_ALPHA).tolist()}})
    tabled = free_run(physics_step(airframe), aerosonde_trim.x, controls, airframe.p, dt,
                      compile=False)
    assert np.ptp(alpha) > 0.05 and np.ptp(preset[:, 0]) > 0.5  # a real manoeuvre
    assert np.abs(tabled - preset).max() <= 1e-6 * np.abs(preset).max()
    # the lift and moment tables alone (exact) give the preset to rounding
    exact = airframe_file(folder, "lift_moment_rollout", tables={
        "C_L": {"alpha": FULL_ALPHA.tolist(), "values": cl(FULL_ALPHA).tolist()},
        "C_m": {"alpha": FULL_ALPHA.tolist(), "values": cm(FULL_ALPHA).tolist()}})
    rolled = free_run(physics_step(exact), aerosonde_trim.x, controls, exact.p, dt,
                      compile=False)
    assert np.abs(rolled - preset).max() <= 1e-10 * np.abs(preset).max()


def _central(fun, v: np.ndarray, rel: float = 1e-6) -> np.ndarray:
    cols = []
    for j in range(len(v)):
        h = rel * max(1.0, abs(v[j]))
        e = np.zeros(len(v))
        e[j] = h
        cols.append((fun(v + e) - fun(v - e)) / (2 * h))
    return np.array(cols).T


def check_jacobians(model, x, u, p) -> np.ndarray:
    """Assert the model's df/dx, df/du, df/dp equal central differences; return df/dp.

    Rounding of a central difference is ~eps |f| / h ~ 1e-8 absolute (|f| ~ 100, h ~ 1e-6),
    truncation ~h^2 relative: 1e-6 of each column's size plus 1e-9 of |f| covers both."""
    x, u, p = (np.asarray(v, float) for v in (x, u, p))
    A, B, dfdp = (np.array(m) for m in model.jacobians(x, u, p))

    def f(xx, uu, pp):
        return np.array(model.f(xx, uu, pp)).ravel()

    f_scale = np.abs(f(x, u, p)).max()
    for exact, approx in ((A, _central(lambda v: f(v, u, p), x)),
                          (B, _central(lambda v: f(x, v, p), u)),
                          (dfdp, _central(lambda v: f(x, u, v), p))):
        col_scale = np.abs(exact).max(axis=0, keepdims=True)
        assert np.all(np.abs(exact - approx) <= 1e-6 * col_scale + 1e-9 * f_scale)
    return dfdp


def test_table_model_jacobians_match_finite_differences(aerosonde, aerosonde_trim, polys,
                                                        folder):
    cl, cd, cm, _ = polys
    grid = np.linspace(-0.6, 0.8, 15)
    airframe = airframe_file(folder, "jacobians", tables={
        "C_L": {"alpha": grid.tolist(), "values": cl(grid).tolist()},
        "C_D": {"alpha": grid.tolist(), "values": cd(grid).tolist()},
        "C_m": {"alpha": grid.tolist(), "values": cm(grid).tolist()}})
    model = build_model(airframe)
    names = airframe.param_names
    table_columns = [i for i, n in enumerate(names) if "_table_" in n]
    assert len(table_columns) == 3 * len(grid)
    rng = np.random.default_rng(4)
    checked = 0
    while checked < 6:
        x = aerosonde_trim.x + rng.normal(size=4) * [3.0, 3.0, 0.5, 0.2]
        alpha = math.atan2(x[1], x[0])
        if np.abs(grid - alpha).min() < 2e-3:  # a central difference must not cross a kink
            continue
        u = aerosonde_trim.u + rng.normal(size=2) * [0.05, 0.1]
        dfdp = check_jacobians(model, x, u, airframe.p)
        # only the two values around alpha act, on each of the three tables
        assert np.count_nonzero(np.abs(dfdp[:, table_columns]).max(axis=0)) == 6
        checked += 1


def test_table_value_sensitivities_sum_to_the_polynomial_coefficients(
        aerosonde, aerosonde_trim, lift_moment_tables):
    """Adding c to every C_L value adds c to C_L (= a change of C_L_0), adding c b_i adds
    c alpha (= a change of C_L_alpha): the table's df/dp columns, summed with those weights,
    are the preset's df/dC_L_0 and df/dC_L_alpha (likewise C_m)."""
    x, u = _random_states(aerosonde_trim, 1, 6)
    x, u = x[:, 0], u[:, 0]
    d_table = np.array(build_model(lift_moment_tables).jacobians(x, u, lift_moment_tables.p)[2])
    d_preset = np.array(build_model(aerosonde).jacobians(x, u, aerosonde.p)[2])
    names, core = lift_moment_tables.param_names, param_names("fixed_wing")
    for table, const, slope in (("C_L", "C_L_0", "C_L_alpha"), ("C_m", "C_m_0", "C_m_alpha")):
        cols = [names.index(f"{table}_table_{i}") for i in range(len(FULL_ALPHA))]
        for weights, key in ((np.ones(len(FULL_ALPHA)), const), (FULL_ALPHA, slope)):
            expected = d_preset[:, core.index(key)]
            assert np.abs(expected).max() > 1e-3
            assert np.abs(d_table[:, cols] @ weights - expected).max() <= \
                1e-10 * np.abs(expected).max()
            # the polynomial coefficient no longer acts in the table model
            assert np.all(d_table[:, core.index(key)] == 0.0)


# ------------------------------------------------------------------ thrust table


def _thrust_grid(aerosonde):
    speeds = np.arange(0.0, 45.0, 5.0)  # 25 m/s (the trim speed) is a breakpoint
    throttles = np.linspace(0.0, 1.0, 11)
    P = symbolic_params("fixed_wing", aerosonde.p)
    values = np.array([[float(propeller_thrust(P, v, t, NUMPY_OPS)) for t in throttles]
                       for v in speeds])
    return speeds, throttles, values


def test_thrust_table_of_the_propeller_model_gives_its_thrust_at_breakpoints_and_trim(
        aerosonde, aerosonde_trim, folder):
    speeds, throttles, values = _thrust_grid(aerosonde)
    assert np.all(np.isfinite(values)) and values.max() > 50.0
    airframe = airframe_file(folder, "thrust_table", tables={"thrust": {
        "airspeed": speeds.tolist(), "throttle": throttles.tolist(),
        "values": values.tolist()}})
    forces_t = build_model(airframe).forces
    forces_p = build_model(aerosonde).forces
    for i, v in enumerate(speeds[1:], start=1):  # V = 0 leaves q c / 2V undefined
        for j, t in enumerate(throttles):
            x, u = [v, 0.0, 0.0, 0.0], [0.0, t]
            assert float(forces_t(x, u, airframe.p)[5]) == values[i, j]
            assert float(forces_p(x, u, aerosonde.p)[5]) == pytest.approx(values[i, j],
                                                                          rel=1e-12, abs=1e-12)
    # Trim: thrust acts along the body x axis through the centre of mass, so w_dot = q_dot = 0
    # fix alpha and elevator whatever the thrust model; u_dot = 0 asks for the same thrust
    # T_req, which the table (linear in throttle inside a cell at the 25 m/s breakpoint)
    # gives at a throttle known in closed form.
    point = trim(airframe, 25.0)
    x0, u0 = aerosonde_trim.x, aerosonde_trim.u
    required = float(forces_p(x0, u0, aerosonde.p)[5])
    row = values[list(speeds).index(25.0)]
    j = int(np.searchsorted(throttles, u0[1])) - 1
    step = throttles[j + 1] - throttles[j]
    predicted = throttles[j] + (required - row[j]) / (row[j + 1] - row[j]) * step
    assert throttles[j] <= predicted <= throttles[j + 1]  # the same cell
    np.testing.assert_allclose(point.x, x0, rtol=0, atol=1e-9)
    assert point.u[0] == pytest.approx(u0[0], abs=1e-9)
    assert point.u[1] == pytest.approx(predicted, abs=1e-9)
    # stated tolerance: the chord's error over the cell, over the slope (T'' sampled finely)
    fine = np.linspace(throttles[j], throttles[j + 1], 201)
    P = symbolic_params("fixed_wing", aerosonde.p)
    thrust = np.array([float(propeller_thrust(P, 25.0, t, NUMPY_OPS)) for t in fine])
    second = np.abs(np.diff(thrust, 2)).max() / (fine[1] - fine[0]) ** 2
    slope = (row[j + 1] - row[j]) / step
    bound = step**2 / 8 * second / slope
    assert 0 < abs(point.u[1] - u0[1]) <= 1.05 * bound + 1e-9
    assert bound < 5e-3


# ------------------------------------------------------------------ 2-D tables


def test_moment_table_over_alpha_and_elevator_reproduces_the_preset(
        aerosonde, aerosonde_trim, folder):
    """``C_m_0 + C_m_alpha a + C_m_delta_e d`` is bilinear, so its bilinear table is exact; with
    ``C_m_delta_e = 0`` in the params the table carries the elevator's moment alone."""
    P = aerosonde.params
    elevator = np.linspace(-0.6, 0.6, 5)
    table = (P.C_m_0 + P.C_m_alpha * FULL_ALPHA[:, None] + P.C_m_delta_e * elevator[None, :])
    airframe = airframe_file(folder, "moment_2d", params={"C_m_delta_e": 0.0}, tables={
        "C_m": {"alpha": FULL_ALPHA.tolist(), "elevator": elevator.tolist(),
                "values": table.tolist()}})
    assert airframe.params.C_m_delta_e == 0.0
    assert airframe.param_names[-1] == f"C_m_table_{len(FULL_ALPHA) - 1}_4"
    x, u = _random_states(aerosonde_trim, 2000, 9, wide=True)
    preset = _f(build_model(aerosonde), x, u, aerosonde.p)
    tabled = _f(build_model(airframe), x, u, airframe.p)
    assert np.abs(tabled - preset).max() <= 1e-10 * np.abs(preset).max()
    # and the elevator derivative (B) is the preset's, between elevator breakpoints
    xk, uk = aerosonde_trim.x, aerosonde_trim.u + [0.05, 0.0]
    B_p = np.array(build_model(aerosonde).jacobians(xk, uk, aerosonde.p)[1])
    B_t = np.array(build_model(airframe).jacobians(xk, uk, airframe.p)[1])
    assert np.abs(B_t - B_p).max() <= 1e-10 * np.abs(B_p).max()
    # without the params change the elevator's moment would be counted twice
    twice = airframe_file(folder, "moment_2d_twice", tables={"C_m": {
        "alpha": FULL_ALPHA.tolist(), "elevator": elevator.tolist(), "values": table.tolist()}})
    assert np.abs(_f(build_model(twice), x, u, twice.p) - preset).max() > 1.0


def test_lift_table_over_alpha_and_airspeed_reproduces_the_preset(
        aerosonde, aerosonde_trim, polys, folder):
    cl, _, _, _ = polys
    speeds = [0.0, 10.0, 20.0, 45.0]
    table = np.repeat(cl(FULL_ALPHA)[:, None], len(speeds), axis=1)
    airframe = airframe_file(folder, "lift_2d", tables={"C_L": {
        "alpha": FULL_ALPHA.tolist(), "airspeed": speeds, "values": table.tolist()}})
    x, u = _random_states(aerosonde_trim, 1000, 10, wide=True)
    preset = _f(build_model(aerosonde), x, u, aerosonde.p)
    assert np.abs(_f(build_model(airframe), x, u, airframe.p) - preset).max() <= \
        1e-12 * np.abs(preset).max()
    # a lift that depends on airspeed: 10 % more above 45 m/s shows in w_dot only there
    faster = table.copy()
    faster[:, -1] *= 1.1
    changed = airframe.replace(**{f"C_L_table_{i}_3": v for i, v in enumerate(faster[:, -1])})
    fast = np.array([[50.0], [2.0], [0.0], [0.0]])
    slow = np.array([[19.0], [2.0], [0.0], [0.0]])
    ctrl = np.array([[0.0], [0.5]])
    model = build_model(airframe)
    assert np.abs(_f(model, slow, ctrl, changed.p) - _f(model, slow, ctrl, airframe.p)).max() \
        == 0.0
    assert np.abs(_f(model, fast, ctrl, changed.p) - _f(model, fast, ctrl, airframe.p)).max() \
        > 1.0


# ------------------------------------------------------------------ files


def test_tables_load_into_p_row_major(folder):
    table = [[0.01, 0.02], [0.03, 0.04], [0.05, 0.06]]
    airframe = airframe_file(folder, "layout", tables={
        "C_m": {"alpha": [-0.1, 0.0, 0.1], "airspeed": [10.0, 30.0], "values": table},
        "C_L": {"alpha": [-0.1, 0.1], "values": [-0.3, 0.8]}})
    names, p = airframe.param_names, airframe.p
    core = len(param_names("fixed_wing"))
    # tables sorted by name, values row-major (first axis slowest)
    assert names[core:] == ("C_L_table_0", "C_L_table_1", "C_m_table_0_0", "C_m_table_0_1",
                            "C_m_table_1_0", "C_m_table_1_1", "C_m_table_2_0",
                            "C_m_table_2_1")
    assert p[core:].tolist() == [-0.3, 0.8, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
    structure = structure_of(airframe)
    assert structure.param_names == names
    assert dict(structure.tables)["C_m"] == (("alpha", (-0.1, 0.0, 0.1)),
                                             ("airspeed", (10.0, 30.0)))
    changed = airframe.replace(C_m_table_2_1=-0.5)
    assert changed.p[names.index("C_m_table_2_1")] == -0.5
    assert np.count_nonzero(changed.p != p) == 1
    assert changed.tables["C_m"].values[-1] == -0.5 and airframe.tables["C_m"].values[-1] == 0.06
    for bad in (math.nan, 1e3, True, "0.1"):
        with pytest.raises(AirframeError, match="C_m_table_2_1"):
            airframe.replace(C_m_table_2_1=bad)
    with pytest.raises(AirframeError, match="C_m_table_3_0"):
        airframe.replace(C_m_table_3_0=0.1)


def _rich_airframe(folder, kind: str):
    """An airframe with every optional key of its kind set."""
    if kind == "multirotor":
        return airframe_file(folder, "rich_quad", base="f450",
                         params={"tau_rotor": 0.04, "k_inflow": 2e-4},
                         delays={"collective": 2, "pitch_cmd": 1}, atmosphere="isa",
                         limits={"collective": [0.1, 0.9], "pitch_cmd_rate": 3.0})
    speeds, throttles, values = _thrust_grid(load_airframe("aerosonde"))
    return airframe_file(
        folder, "rich_plane", params={"tau_elevator": 0.05, "tau_throttle": 0.3,
                                      "C_m_alpha_dot": -8.0},
        delays={"elevator": 2, "throttle": 0}, atmosphere="isa",
        limits={"elevator": [-0.14, 0.14], "elevator_rate": 1.5, "throttle": [0.0, 0.95]},
        tables={
            "C_L": {"alpha": [-0.3, 0.0, 0.15, 0.3], "values": [-1.45, 0.23, 1.07, 1.2]},
            "C_m": {"alpha": [-0.2, 0.0, 0.2], "elevator": [-0.3, 0.0, 0.3],
                    "values": [[0.83, 0.56, 0.26], [0.31, 0.0135, -0.28],
                               [-0.26, -0.53, -0.83]]},
            "C_D": {"alpha": [-0.2, 0.0, 0.2], "airspeed": [10.0, 30.0],
                    "values": [[0.08, 0.07], [0.045, 0.043], [0.1, 0.09]]},
            "thrust": {"airspeed": speeds.tolist(), "throttle": throttles.tolist(),
                       "values": values.tolist()}})


def _same(a, b) -> None:
    assert a.param_names == b.param_names
    assert np.array_equal(a.p, b.p)
    assert a.params == b.params and a.tables == b.tables
    assert a.delay_samples() == b.delay_samples()  # (a delay of 0 is not written)
    assert a.atmosphere == b.atmosphere and a.limits == b.limits
    assert a.param_hash() == b.param_hash()
    assert structure_of(a) == structure_of(b)


@pytest.mark.parametrize("kind", ["fixed_wing", "multirotor"])
@pytest.mark.parametrize("fmt", ["toml", "json"])
def test_airframe_with_every_optional_key_round_trips(kind, fmt, folder, tmp_path):
    airframe = _rich_airframe(folder, kind)
    assert airframe.atmosphere == "isa" and airframe.delays and airframe.limits
    path = tmp_path / f"again.{fmt}"
    data = to_toml_dict(airframe)
    path.write_text(toml_text(data) if fmt == "toml" else json.dumps(data))
    _same(load_airframe(path), airframe)


@pytest.mark.parametrize("kind", ["fixed_wing", "multirotor"])
def test_identify_writer_keeps_every_optional_key(kind, folder, tmp_path):
    """``uavdyn identify`` writes the fitted airframe with the project's own TOML writer: the
    tables, delays, atmosphere and limits must survive it."""
    from uavdyn.identify import airframe_toml

    airframe = _rich_airframe(folder, kind)
    path = tmp_path / "fitted.toml"
    path.write_text(airframe_toml(airframe, ["a header line"]))
    _same(load_airframe(path), airframe)


def test_param_hash_sees_every_structure_key_and_presets_keep_theirs(folder, tmp_path):
    for name, expected in PRESET_HASH.items():
        preset = load_airframe(name)
        assert preset.param_hash() == expected
        path = tmp_path / f"{name}.toml"
        path.write_text(toml_text(to_toml_dict(preset)))
        assert load_airframe(path).param_hash() == expected
        # keys at their no-effect value are the preset
        zero = airframe_file(folder, f"{name}_zero", base=name, delays={}, atmosphere="constant",
                         tables={})
        assert zero.param_hash() == expected
    plane = load_airframe("aerosonde")
    base = airframe_file(folder, "hashed", tables={"C_L": {"alpha": [-0.2, 0.0, 0.2],
                                                       "values": [-0.9, 0.23, 1.35]}})
    variants = [
        base.replace(C_L_table_1=0.24),
        airframe_file(folder, "hashed_b", tables={"C_L": {"alpha": [-0.2, 0.01, 0.2],
                                                      "values": [-0.9, 0.23, 1.35]}}),
        airframe_file(folder, "hashed_c", tables={"C_L": {"alpha": [-0.2, 0.0, 0.2],
                                                      "elevator": [-0.1, 0.1],
                                                      "values": [[-0.9, -0.9], [0.23, 0.23],
                                                                 [1.35, 1.35]]}}),
        airframe_file(folder, "hashed_d", tables={"C_m": {"alpha": [-0.2, 0.0, 0.2],
                                                      "values": [-0.9, 0.23, 1.35]}}),
        plane.with_delays(elevator=1), plane.with_delays(throttle=1),
        airframe_file(folder, "isa", atmosphere="isa"),
        plane.replace(tau_elevator=0.05), plane.replace(tau_throttle=0.05),
    ]
    hashes = [base.param_hash()] + [v.param_hash() for v in variants]
    assert len(set(hashes)) == len(hashes)
    assert PRESET_HASH["aerosonde"] not in hashes
    assert plane.with_delays(elevator=1).with_delays(elevator=0).param_hash() == \
        PRESET_HASH["aerosonde"]



def test_perturb_scales_a_table_value(lift_moment_tables):
    """perturb() reaches table values by name like any parameter (the robustness scenario)."""
    from uavdyn.airframes import perturb

    tabled = lift_moment_tables
    i = tabled.param_names.index("C_L_table_1")
    scaled = perturb(tabled, 1.1, ["C_L_table_1"])
    assert scaled.p[i] == pytest.approx(1.1 * tabled.p[i], rel=1e-15)
    others = np.delete(np.arange(len(tabled.p)), i)
    np.testing.assert_array_equal(scaled.p[others], tabled.p[others])
