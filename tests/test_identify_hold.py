"""A collinear group is refitted with only the combination the data cannot determine held at
the file's values (principal-components regression): the direction Belsley's diagnostics
name, the constrained covariance, the exact constrained least squares, the fallback's choice
between holding a group and resetting a parameter, and a held fit through the real solver."""

import math

import numpy as np
import pytest
from test_identify import _sorties

from uavdyn.airframes import load_airframe
from uavdyn.identify import identify
from uavdyn.identify.fallback import keep_file_values
from uavdyn.identify.result import Estimate, IdentificationResult
from uavdyn.identify.uncertainty import constrained, near_dependencies, physical_combination


def _collinear_design(seed=4, n=500):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal(n)
    return np.column_stack([a, 2.0 * a + 1e-3 * rng.standard_normal(n),
                            rng.standard_normal(n)])


def test_the_weak_direction_is_the_combination_the_data_do_not_see():
    X = _collinear_design()
    _, _, groups, rows = near_dependencies(X.T @ X)
    assert groups == [[0, 1]] and rows.shape == (1, 3)
    a = rows[0]
    # columns x and 2x: unit-length columns (Belsley's scaling) make both x, the weak
    # eigenvector there is (1, -1) / sqrt 2, so in the parameters the held combination is
    # t0 - 2 t1 (the change from the file lies in the data's subspace in that scaling)
    np.testing.assert_allclose(abs(a @ np.array([1.0, -2.0, 0.0])) / math.sqrt(5), 1.0,
                               atol=1e-4)
    # and it does pin the direction the data cannot see, (2, -1): a . (2, -1) != 0
    assert abs(a @ np.array([2.0, -1.0, 0.0])) > 0.5
    assert np.linalg.norm(X @ np.array([2.0, -1.0, 0.0])) < 1e-2 * np.linalg.norm(X[:, 2])


def test_held_least_squares_is_the_constrained_solution_and_its_covariance():
    X = _collinear_design()
    rng = np.random.default_rng(0)
    truth = np.array([0.5, -0.3, 1.2])
    y = X @ truth + 0.01 * rng.standard_normal(len(X))
    _, _, _, rows = near_dependencies(X.T @ X)
    # the held fit as the library makes it: the rows far above the data in the least squares
    big = 1e6 * np.linalg.norm(X)
    held = np.linalg.lstsq(np.vstack([X, big * rows]),
                           np.concatenate([y, np.zeros(len(rows))]), rcond=None)[0]
    # the exact solution: minimise |X t - y| subject to rows @ t = 0 (KKT system)
    K = np.block([[X.T @ X, rows.T], [rows, np.zeros((1, 1))]])
    exact = np.linalg.solve(K, np.concatenate([X.T @ y, [0.0]]))[:3]
    np.testing.assert_allclose(held, exact, rtol=1e-6, atol=1e-9)
    assert abs(rows[0] @ held) < 1e-9
    assert abs(held[2] - truth[2]) < 0.01  # the independent parameter: the data's
    cov = np.linalg.inv(X.T @ X)
    cc = constrained(cov, rows)
    assert abs(rows[0] @ cc @ rows[0]) < 1e-12 * np.trace(cov)
    assert cc[2, 2] == pytest.approx(cov[2, 2], rel=1e-3)
    assert np.all(np.diag(cc) <= np.diag(cov) * (1 + 1e-12))


def test_a_combination_round_trips_through_physical_units():
    row = np.array([0.6, -0.8, 1e-6])
    scale = np.array([2.0, 0.5, 1.0])
    c = physical_combination(row, ["a", "b", "c"], scale)
    assert set(c) == {"a", "b"}  # a negligible coefficient left out
    back = np.array([c.get(n, 0.0) * s for n, s in zip("abc", scale)])
    np.testing.assert_allclose(back / np.linalg.norm(back), row / np.linalg.norm(row),
                               atol=1e-5)


def _result(estimates, groups, weak):
    return IdentificationResult(
        airframe=load_airframe("aerosonde"), estimates=estimates,
        correlation=np.eye(len(estimates)),
        flagged_pairs=[], state_sigma=np.ones(4), cost_initial=1.0, cost_final=1.0,
        iterations=1, seconds=1.0, window_s=1.0, dt=0.005,
        diagnostics={"collinear_groups": groups, "weak_directions": weak})


def _recording_identify(group: bool):
    """A stand-in for ``identify`` that records each call's names and options and returns
    every parameter at -1.1 +- 0.01 (flagged collinear when ``group``)."""
    calls = []

    def stub(nominal, train, validation, names, **options):
        calls.append((list(names), options))
        return _result([_estimate(n, -1.0, -1.1, 0.01, group=group) for n in names], [], [])

    return calls, stub


def _estimate(name, nominal, value, std_c, group=True):
    why = ("collinear with the others (these data cannot separate them)",) if group else ()
    return Estimate(name, nominal, value, std_c / 4, std_error_corrected=std_c,
                    undetermined=why)


def test_a_group_with_narrow_intervals_is_held_not_reset():
    calls, stub = _recording_identify(group=True)

    weak = [{"C_m_alpha": 1.0, "C_m_delta_e": -0.5}]
    first = _result([_estimate("C_m_alpha", -2.7, -2.6, 0.05),
                     _estimate("C_m_delta_e", -1.0, -0.95, 0.03),
                     _estimate("C_L_alpha", 5.6, 5.7, 0.01, group=False)],
                    [["C_m_alpha", "C_m_delta_e"]], weak)
    out = keep_file_values(stub, first, None, [], [], ["C_m_alpha", "C_m_delta_e",
                                                       "C_L_alpha"], {"check_halves": True})
    (names, options), = calls
    assert names == ["C_m_alpha", "C_m_delta_e", "C_L_alpha"]
    assert options["hold"] == weak and options["keep_undetermined"] is True
    assert options["check_halves"] is False
    held = {e.name: e for e in out.estimates}
    assert held["C_m_alpha"].held and held["C_m_alpha"].data_value == -2.6
    assert not held["C_m_alpha"].kept and not held["C_L_alpha"].held
    assert "C_m_delta_e" in held["C_m_alpha"].held


def test_a_member_spanning_zero_is_reset_first_and_the_rest_refitted_by_the_rule():
    calls, stub = _recording_identify(group=False)

    first = _result([_estimate("C_m_alpha", -2.7, -2.6, 0.05),
                     _estimate("C_m_alpha_dot", 0.0, -3.0, 4.0),
                     _estimate("C_m_q", -38.0, -40.0, 1.0)],
                    [["C_m_alpha", "C_m_alpha_dot", "C_m_q"]], [{"C_m_alpha": 1.0}])
    out = keep_file_values(stub, first, load_airframe("aerosonde"), [], [],
                           ["C_m_alpha", "C_m_alpha_dot", "C_m_q"], {})
    (names, options), = calls
    assert names == ["C_m_alpha", "C_m_q"] and options["keep_undetermined"] is False
    assert "hold" not in options
    kept = {e.name: e for e in out.estimates}
    assert kept["C_m_alpha_dot"].kept and kept["C_m_alpha_dot"].value == 0.0


@pytest.mark.slow
def test_a_held_fit_keeps_the_combination_at_the_file_and_fits_the_rest(aerosonde):
    truth = aerosonde.replace(C_m_alpha=aerosonde.params.C_m_alpha * 1.1,
                              C_m_delta_e=aerosonde.params.C_m_delta_e * 0.9)
    train = _sorties(truth, 2, 5, duration=8.0)
    names = ["C_m_alpha", "C_m_delta_e", "C_m_q"]
    free = identify(aerosonde, train, [], names, progress=False, keep_undetermined=True,
                    free_run=False)
    hold = [{"C_m_alpha": 1.0, "C_m_delta_e": 2.0}]
    result = identify(aerosonde, train, [], names, progress=False, keep_undetermined=True,
                      free_run=False, hold=hold)
    p, nominal = result.airframe.params, aerosonde.params
    held = (p.C_m_alpha - nominal.C_m_alpha) + 2.0 * (p.C_m_delta_e - nominal.C_m_delta_e)
    assert abs(held) < 1e-6 * abs(nominal.C_m_alpha)
    assert result.cost_final >= free.cost_final * (1 - 1e-9)  # a constraint costs fit
    assert result.diagnostics["held_at_file_values"]
    e = {x.name: x for x in result.estimates}
    # along the held combination no variance is left: the two errors are tied
    s_a, s_d = e["C_m_alpha"].std_error_corrected, e["C_m_delta_e"].std_error_corrected
    assert s_a == pytest.approx(2.0 * s_d, rel=1e-3)


def test_a_parameter_outside_the_group_spanning_zero_is_reset_in_the_held_refit():
    calls, stub = _recording_identify(group=True)

    first = _result([_estimate("C_m_alpha", -2.7, -2.6, 0.05),
                     _estimate("C_m_delta_e", -1.0, -0.95, 0.03),
                     _estimate("C_m_alpha_dot", 0.0, -0.1, 0.8, group=False)],
                    [["C_m_alpha", "C_m_delta_e"]],
                    [{"C_m_alpha": 1.0, "C_m_delta_e": -0.5, "C_m_alpha_dot": 1e-3}])
    out = keep_file_values(stub, first, load_airframe("aerosonde"), [], [],
                           ["C_m_alpha", "C_m_delta_e", "C_m_alpha_dot"], {})
    (names, options), = calls  # one refit: the group held, the other reset
    assert names == ["C_m_alpha", "C_m_delta_e"]
    assert options["hold"] == [{"C_m_alpha": 1.0, "C_m_delta_e": -0.5}]
    by = {e.name: e for e in out.estimates}
    assert by["C_m_alpha_dot"].kept and by["C_m_alpha_dot"].value == 0.0
    assert by["C_m_alpha"].held and by["C_m_delta_e"].held
    assert [e.name for e in out.estimates] == ["C_m_alpha", "C_m_delta_e", "C_m_alpha_dot"]


def test_a_collinear_member_whose_group_is_broken_is_not_written_unheld():
    calls, stub = _recording_identify(group=False)

    # group 1 holds; group 2 loses its row (C_m_alpha_dot spans zero), leaving C_m_q in it
    first = _result([_estimate("C_m_alpha", -2.7, -2.6, 0.05),
                     _estimate("C_m_delta_e", -1.0, -0.95, 0.03),
                     _estimate("C_m_q", -38.0, -40.0, 1.0),
                     _estimate("C_m_alpha_dot", 0.0, -3.0, 4.0)],
                    [["C_m_alpha", "C_m_delta_e"], ["C_m_q", "C_m_alpha_dot"]],
                    [{"C_m_alpha": 1.0, "C_m_delta_e": -0.5}, {"C_m_q": 1.0}])
    keep_file_values(stub, first, load_airframe("aerosonde"), [], [],
                     ["C_m_alpha", "C_m_delta_e", "C_m_q", "C_m_alpha_dot"], {})
    (names, options), = calls  # reset, and the rule applied again to the refit
    assert names == ["C_m_alpha", "C_m_delta_e", "C_m_q"]
    assert "hold" not in options and options["keep_undetermined"] is False


def test_a_parameter_the_held_refit_leaves_spanning_zero_is_reset_and_refitted():
    calls = []

    def stub(nominal, train, validation, names, **options):
        calls.append(list(names))
        spans = len(calls) == 1  # the first held refit leaves C_m_alpha_dot spanning zero
        return _result([_estimate(n, 0.0 if n == "C_m_alpha_dot" else -1.0,
                                  -0.1 if n == "C_m_alpha_dot" else -1.1,
                                  0.8 if (n == "C_m_alpha_dot" and spans) else 0.01,
                                  group=False) for n in names], [], [])

    first = _result([_estimate("C_m_alpha", -2.7, -2.6, 0.05),
                     _estimate("C_m_delta_e", -1.0, -0.95, 0.03),
                     _estimate("C_m_alpha_dot", 0.0, -3.0, 0.5, group=False)],
                    [["C_m_alpha", "C_m_delta_e"]], [{"C_m_alpha": 1.0, "C_m_delta_e": -0.5}])
    out = keep_file_values(stub, first, load_airframe("aerosonde"), [], [],
                           ["C_m_alpha", "C_m_delta_e", "C_m_alpha_dot"], {})
    assert calls == [["C_m_alpha", "C_m_delta_e", "C_m_alpha_dot"],
                     ["C_m_alpha", "C_m_delta_e"]]
    by = {e.name: e for e in out.estimates}
    assert by["C_m_alpha_dot"].kept and by["C_m_alpha_dot"].value == 0.0
    assert by["C_m_alpha"].held


def test_a_parameter_the_held_refit_finds_collinear_outside_the_held_groups_is_reset():
    calls = []

    def stub(nominal, train, validation, names, **options):
        calls.append(list(names))
        groups = [["C_m_alpha", "C_m_q"]] if len(calls) == 1 else []
        return _result([_estimate(n, -1.0, -1.1, 0.01, group=bool(groups) and n == "C_m_q")
                        for n in names], groups, [])

    first = _result([_estimate("C_m_alpha", -2.7, -2.6, 0.05),
                     _estimate("C_m_delta_e", -1.0, -0.95, 0.03),
                     _estimate("C_m_q", -38.0, -40.0, 1.0, group=False)],
                    [["C_m_alpha", "C_m_delta_e"]], [{"C_m_alpha": 1.0, "C_m_delta_e": -0.5}])
    out = keep_file_values(stub, first, load_airframe("aerosonde"), [], [],
                           ["C_m_alpha", "C_m_delta_e", "C_m_q"], {})
    assert calls[-1] == ["C_m_alpha", "C_m_delta_e"]
    by = {e.name: e for e in out.estimates}
    assert by["C_m_q"].kept and by["C_m_q"].value == by["C_m_q"].nominal
