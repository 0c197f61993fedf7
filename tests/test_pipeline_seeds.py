"""``analysis/pipeline_seeds.py``'s summary: the geometric mean over every run's sorties, the
sorties worse by more than 2 %, and the paired t of the seeds' mean log ratios, against
figures worked by hand."""

import math

import pytest
from analysis_scripts import load_script


@pytest.fixture(scope="module")
def seeds():
    return load_script("pipeline_seeds")


def _run(seed, ratios):
    return {"seed": seed, "ratio_1s": dict(zip(("a", "b"), ratios)),
            "worse": [k for k, r in zip(("a", "b"), ratios) if r > 1.02]}


def test_summary_and_paired_difference(seeds):
    base = seeds.summarise([_run(0, (0.8, 1.0)), _run(1, (0.9, 0.9))])
    assert base["geomean_ratio"] == pytest.approx((0.8 * 1.0 * 0.9 * 0.9) ** 0.25, rel=1e-12)
    assert base["n_worse"] == 0 and base["n_sorties"] == 4
    other = seeds.summarise([_run(0, (0.8, 1.1)), _run(1, (0.9, 1.03))])
    assert other["n_worse"] == 2
    got = seeds.paired(base, other)
    d = [0.5 * math.log(1.1), 0.5 * (math.log(1.03) - math.log(0.9))]
    mean = sum(d) / 2
    se = abs(d[0] - d[1]) / 2  # the standard deviation of two values over sqrt(2)
    assert got["mean_log_difference"] == pytest.approx(mean, rel=1e-12)
    assert got["standard_error"] == pytest.approx(se, rel=1e-12)
    assert got["t"] == pytest.approx(mean / se, rel=1e-12)
    assert seeds.paired(base, base)["t"] is None  # no spread: no t (and valid JSON)
