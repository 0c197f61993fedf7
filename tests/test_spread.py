"""Per-sortie spread: pooled RMSE from per-sortie sums equals the RMSE of the concatenated
errors, the bootstrap interval behaves (contains the estimate, collapses for identical
sorties, is reproducible), diverged sorties are counted not pooled, paired comparisons flag
the right sorties, and error-against-horizon windows agree with the 1 s mode."""

import math

import numpy as np
import pytest

from tests.test_alignment import doublets
from uavdyn.airframes import load_airframe
from uavdyn.evaluation import (
    Solver,
    SortieError,
    compare_paired,
    evaluate_trajectory,
    horizon_predictions,
    pooled_rmse,
    pooled_with_interval,
    squared_error,
)
from uavdyn.integrate import physics_step


def test_pooled_rmse_equals_rmse_of_concatenated_errors():
    rng = np.random.default_rng(0)
    errs = [rng.normal(0, s, size=n) for s, n in ((0.1, 50), (0.3, 200), (0.05, 10))]
    sortie_errors = []
    for i, e in enumerate(errs):
        pred = np.zeros((len(e), 4))
        pred[:, 3] = e
        sse, n = squared_error(pred, np.zeros_like(pred))
        sortie_errors.append(SortieError(f"s{i}", sse, n))
    assert pooled_rmse(sortie_errors) == pytest.approx(
        float(np.sqrt(np.mean(np.concatenate(errs) ** 2))), rel=1e-12)
    assert sortie_errors[1].rmse == pytest.approx(float(np.sqrt(np.mean(errs[1] ** 2))))


def test_bootstrap_interval_contains_estimate_and_collapses_for_identical_sorties():
    varied = [SortieError(f"s{i}", sse, 100) for i, sse in enumerate([1.0, 4.0, 0.25, 9.0, 2.0])]
    a = pooled_with_interval(varied)
    assert a.low <= a.rmse <= a.high and a.low < a.high
    assert pooled_with_interval(varied) == a  # fixed seed: reproducible
    same = [SortieError(f"s{i}", 1.0, 100) for i in range(5)]
    b = pooled_with_interval(same)
    assert b.low == pytest.approx(b.rmse) and b.high == pytest.approx(b.rmse)
    assert b.rmse == pytest.approx(0.1)


def test_diverged_sorties_are_counted_not_pooled():
    pred = np.zeros((5, 4))
    pred[2, 3] = np.nan
    sse, n = squared_error(pred, np.zeros((5, 4)))
    assert math.isinf(sse) and n == 5
    errors = [SortieError("a", 1.0, 100), SortieError("b", sse, n)]
    pooled = pooled_with_interval(errors)
    assert pooled.diverged == 1 and pooled.sorties == 2
    assert pooled.rmse == pytest.approx(0.1)


def test_paired_comparison_flags_worse_sorties_and_new_divergence():
    a = [SortieError("x", 1.0, 100), SortieError("y", 1.0, 100), SortieError("z", 1.0, 100)]
    b = [SortieError("x", 0.81, 100), SortieError("y", 1.44, 100),
         SortieError("z", math.inf, 100)]
    cmp = compare_paired(a, b, tolerance=0.1)
    assert cmp.ratios["x"] == pytest.approx(0.9) and cmp.ratios["y"] == pytest.approx(1.2)
    assert cmp.worse == ("y",) and cmp.worse_beyond_tolerance == ("y",)
    assert cmp.new_divergence == ("z",)
    with pytest.raises(ValueError, match="same sorties"):
        compare_paired(a, b[::-1])


def test_horizon_windows_agree_with_the_one_second_mode():
    af = load_airframe("aerosonde")
    t, x0, U = doublets(af, duration=8.0)
    states = np.zeros((len(t), 4)) + x0  # any target: both paths must compare the same samples
    solver = Solver("rk4", physics_step(af), 0.01)
    curve = horizon_predictions(solver, t, states, U, af.p, (0.002, 0.5, 1.0, 20.0))
    res = evaluate_trajectory(solver, t, states, U, af.p)
    np.testing.assert_array_equal(curve[1.0][0], res["horizon_1s"][0])
    np.testing.assert_array_equal(curve[1.0][1], res["horizon_1s"][1])
    assert 0.002 not in curve and 20.0 not in curve  # below one step / beyond the sortie
    assert curve[0.5][0].shape == (len(range(0, len(t) - 50, 50)) * 50, 4)


def test_error_share_is_the_pooled_gap_removed_with_a_sortie_bootstrap():
    from uavdyn.evaluation import error_share

    def errs(rmse):  # 100 samples per sortie: sse = 100 rmse^2
        return [SortieError(f"s{i}", 100.0 * r**2, 100) for i, r in enumerate(rmse)]

    a, b, c = errs([0.02, 0.01, 0.03]), errs([0.01, 0.01, 0.02]), errs([0.005, 0.01, 0.01])
    pooled = [math.sqrt(sum(r**2 for r in x) / 3) for x in
              ([0.02, 0.01, 0.03], [0.01, 0.01, 0.02], [0.005, 0.01, 0.01])]
    removed = error_share(a, b)
    assert removed.share == pytest.approx(1 - pooled[1] / pooled[0], rel=1e-12)
    assert removed.low <= removed.share <= removed.high and removed.sorties == 3
    recovered = error_share(a, b, c)
    assert recovered.share == pytest.approx((pooled[0] - pooled[1]) / (pooled[0] - pooled[2]),
                                            rel=1e-12)
    # a diverged sortie in any model is left out of every model's pool
    d = errs([0.02, 0.01, 0.03])
    d[2] = SortieError("s2", math.inf, 100)
    assert error_share(a, d).sorties == 2
    # a gap within noise (below min_gap of A) has no share
    near = errs([0.0199, 0.0099, 0.0299])
    within = error_share(a, b, near, min_gap=0.03)
    assert within.share is None and within.left_out > 0
    with pytest.raises(ValueError, match="same sorties"):
        error_share(a, errs([0.01, 0.02]))
