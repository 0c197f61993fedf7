"""Uncertainty of the output-error estimates against independent truths: the corrected
covariance equals the Cramer-Rao bound for white residuals and matches the Monte-Carlo spread
of least-squares estimates under coloured (AR(1)) residuals, where the Cramer-Rao bound is far
too small; profiling the start states out equals inverting the whole information matrix;
Belsley's diagnostics name a collinear pair and leave an independent parameter alone; an
estimate is projected onto its physical bounds before it is written."""

import math

import numpy as np
import pytest
import scipy.sparse as sp

from uavdyn.identify.uncertainty import collinearity, estimate_uncertainty


def _regressors(W: int, L: int) -> np.ndarray:
    """Smooth regressors, one record of L samples per window, 4 'states' per sample: the
    sensitivities of a linear model y = A theta (``(W * L * 4) x 2``)."""
    t = np.arange(L) / L
    A = np.zeros((W, L, 4, 2))
    for w in range(W):
        A[w, :, :, 0] = np.sin(2 * np.pi * (t[:, None] + 0.1 * w) + np.arange(4))
        A[w, :, :, 1] = (t[:, None] - 0.5) * (1 + 0.2 * np.arange(4)) + 0.05 * w
    return A.reshape(-1, 2)


def _ar1(rng, W: int, L: int, phi: float) -> np.ndarray:
    e = rng.standard_normal((W, L, 4))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0] / math.sqrt(1 - phi**2)
    for i in range(1, L):
        x[:, i] = phi * x[:, i - 1] + e[:, i]
    return x.reshape(-1)


def test_white_residuals_give_the_cramer_rao_bound():
    rng = np.random.default_rng(1)
    W, L = 40, 50
    A = _regressors(W, L)
    r = 0.3 * rng.standard_normal(A.shape[0])
    unc = estimate_uncertainty(sp.csr_matrix(A), r, 2, W, L, False, 0.01)
    sigma = unc.residual_sigma
    cr = np.linalg.inv((A / np.tile(sigma, W * L)[:, None]).T
                       @ (A / np.tile(sigma, W * L)[:, None]))
    np.testing.assert_allclose(unc.cramer_rao, cr, rtol=1e-10, atol=1e-12 * cr.max())
    ratio = np.sqrt(np.diag(unc.corrected) / np.diag(unc.cramer_rao))
    assert np.all(np.abs(ratio - 1) < 0.25), ratio  # sampling noise of the lag sums only
    assert np.all(unc.correlation_time_s <= 0.011)  # one lag at most


def test_coloured_residuals_corrected_error_matches_the_monte_carlo_spread():
    """Least squares on data with AR(1) noise (phi 0.9, correlation time ~10 samples):
    the spread of the estimates over 200 noise draws against both standard errors."""
    rng = np.random.default_rng(2)
    W, L, phi = 20, 100, 0.9
    A = _regressors(W, L)
    pinv = np.linalg.pinv(A)
    estimates, cr, corrected = [], [], []
    for _ in range(200):
        noise = 0.1 * _ar1(rng, W, L, phi)
        theta = pinv @ noise  # the LS estimate's deviation from the truth
        r = noise - A @ theta
        estimates.append(theta)
        unc = estimate_uncertainty(sp.csr_matrix(A), r, 2, W, L, False, 0.01)
        cr.append(np.sqrt(np.diag(unc.cramer_rao)))
        corrected.append(np.sqrt(np.diag(unc.corrected)))
    spread = np.std(estimates, axis=0)
    cr, corrected = np.mean(cr, axis=0), np.mean(corrected, axis=0)
    assert np.all(cr < 0.5 * spread), (cr, spread)  # the white bound is far too small
    np.testing.assert_allclose(corrected, spread, rtol=0.3)


def test_profiling_the_start_states_equals_inverting_the_whole_information():
    """theta block of inv(J^T J) with per-window start-state columns and their prior rows."""
    rng = np.random.default_rng(3)
    W, L, n_theta = 6, 30, 3
    rows = 4 * L
    theta_cols = rng.standard_normal((W * rows, n_theta))
    x0_blocks = [rng.standard_normal((rows, 4)) * np.exp(-np.arange(L))[:, None].repeat(4, 0)[:rows]
                 for _ in range(W)]
    J = sp.vstack([sp.hstack([sp.csr_matrix(theta_cols), sp.block_diag(x0_blocks)]),
                   sp.hstack([sp.csr_matrix((4 * W, n_theta)), sp.identity(4 * W)])]).tocsr()
    r = np.concatenate([rng.standard_normal(W * rows), rng.standard_normal(4 * W)])
    unc = estimate_uncertainty(J, r, n_theta, W, L, True, 0.01)
    sigma = unc.residual_sigma
    scale = np.concatenate([np.tile(1 / sigma, W * L), np.ones(4 * W)])
    Js = J.multiply(scale[:, None]).toarray()
    full = np.linalg.inv(Js.T @ Js)[:n_theta, :n_theta]
    np.testing.assert_allclose(unc.cramer_rao, full, rtol=1e-8)


def test_collinearity_names_the_pair_the_data_cannot_separate():
    rng = np.random.default_rng(4)
    a = rng.standard_normal(500)
    X = np.column_stack([a, a + 1e-3 * rng.standard_normal(500), rng.standard_normal(500)])
    index, proportions, groups = collinearity(X.T @ X)
    assert groups == [[0, 1]]
    assert index[-1] > 100 and index[1] < 3
    np.testing.assert_allclose(proportions.sum(axis=0), 1.0)


@pytest.mark.parametrize("value, expected", [(1.0000000089, 1.0), (-1e-12, 0.0), (0.4, 0.4)])
def test_an_estimate_is_projected_onto_its_physical_bounds(f450, value, expected):
    from uavdyn.identify.unknowns import project_inside as _inside

    assert _inside(f450, "pitch_mix", value) == expected  # a share: [0, 1], both closed


def test_an_open_bound_is_projected_just_inside(f450):
    from uavdyn.identify.unknowns import project_inside as _inside

    inside = _inside(f450, "c_T", 0.0)  # a thrust coefficient: > 0
    assert 0.0 < inside < 1e-300


def _result_with(estimates):
    from uavdyn.identify.result import IdentificationResult

    return IdentificationResult(airframe=None, estimates=list(estimates),
                                correlation=np.eye(len(estimates)), flagged_pairs=[],
                                state_sigma=np.ones(4), cost_initial=1.0, cost_final=1.0,
                                iterations=1, seconds=0.0, window_s=1.0, dt=0.005)


def test_halves_that_disagree_flag_the_parameter_and_widen_its_error():
    """Two halves whose estimates differ by more than twice their combined errors: flagged
    as a structure error, the corrected error at least half the difference; halves that
    agree only floor the error at their inverse-variance combination."""
    from uavdyn.identify.consistency import compare_halves
    from uavdyn.identify.result import Estimate

    full = [Estimate("a", 1.0, 2.0, 0.01, std_error_corrected=0.02),
            Estimate("b", 1.0, 3.0, 0.01, std_error_corrected=0.02)]
    halves = iter([[Estimate("a", 0, 1.0, 0.01, std_error_corrected=0.1),
                    Estimate("b", 0, 3.0, 0.01, std_error_corrected=0.3)],
                   [Estimate("a", 0, 3.0, 0.01, std_error_corrected=0.1),
                    Estimate("b", 0, 3.1, 0.01, std_error_corrected=0.4)]])

    def fake_identify(airframe, sorties, validation, names, **options):
        return _result_with(next(halves))

    result = _result_with(full)
    compare_halves(fake_identify, result, list(range(6)), ["a", "b"], 10, {})
    a, b = result.estimates
    assert not a.determined and "disagree" in a.flags()[0]
    assert a.std_error_corrected == pytest.approx(1.0)  # half of |1 - 3|
    assert b.determined
    assert b.std_error_corrected == pytest.approx(1 / math.sqrt(1 / 0.3**2 + 1 / 0.4**2))
    assert result.diagnostics["halves"]["b"] == {"first": [3.0, 0.3], "second": [3.1, 0.4]}
