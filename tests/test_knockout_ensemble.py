"""The ensemble step of ``analysis/knockout_ensemble.py``: its next state is the mean of its
members' next states (checked on two physics steps of different order, whose next states
differ), and the re-scoring arithmetic it shares with ``analysis/knockout_fade.py``."""

import math
import sys

import numpy as np
import pytest
from analysis_scripts import load_script

from uavdyn.airframes import load_airframe
from uavdyn.integrate import physics_step
from uavdyn.integrate.tableau import EULER, RK4
from uavdyn.linear import trim


@pytest.fixture(scope="module")
def ensemble():
    load_script("knockout_fade")
    return load_script("knockout_ensemble")


def test_the_ensemble_step_is_the_mean_of_its_members(ensemble):
    airframe = load_airframe("aerosonde")
    members = [physics_step(airframe, RK4), physics_step(airframe, EULER)]
    step = ensemble.ensemble_step(members)
    point = trim(airframe, 25.0)
    p = np.asarray(airframe.p, float)
    x = np.asarray(members[0].initial_state(point.x, point.u, p, 0.01), float).ravel()
    x[2] += 0.3  # off the trim, where the two methods' steps differ
    u = np.asarray(point.u, float) + np.array([0.05, 0.0])
    nexts = [np.asarray(m.function(x, u, p, 0.05), float).ravel() for m in members]
    assert np.max(np.abs(nexts[0] - nexts[1])) > 1e-4
    got = np.asarray(step.function(x, u, p, 0.05), float).ravel()
    np.testing.assert_allclose(got, 0.5 * (nexts[0] + nexts[1]), rtol=0, atol=1e-13)
    assert step.state_names == members[0].state_names


def test_rescored_shares_and_worse_count(ensemble):
    a, pooled_b = [0.02, 0.01], 0.005
    pooled_a = math.sqrt((0.02**2 + 0.01**2) / 2)
    out = sys.modules["knockout_fade"].rescore_summary([0.01, 0.0103], a, pooled_a, pooled_b)
    pooled = math.sqrt((0.01**2 + 0.0103**2) / 2)
    assert out["recovered_share"] == pytest.approx((pooled_a - pooled) / (pooled_a - pooled_b))
    assert out["removed_share"] == pytest.approx((pooled_a - pooled) / pooled_a)
    no_b = sys.modules["knockout_fade"].rescore_summary([0.01, 0.0103], a, pooled_a, None)
    assert no_b["recovered_share"] is None  # no model with the term: nothing to recover
    assert out["n_sorties_worse"] == 1  # 0.0103 is 3 % above its (a)
    assert out["ratio_to_a"] == pytest.approx([0.5, 1.03])
