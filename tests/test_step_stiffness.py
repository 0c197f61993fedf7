"""One RK4 step per log sample against a stiff fitted model (:mod:`uavdyn.linear.stiffness`):
the stability boundary against its analytic value, the verdict on a quadrotor whose fitted
pitch damping absorbed a rotor lag, and the one-line refusal of the trainer and warning of
the fit."""

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.identify.freerun import departure_line, stiffness_check
from uavdyn.linear.stiffness import largest_stable_step, rk4_amplification, step_stiffness

# RK4's stability boundary on the negative real axis: the real root of
# 1 + z + z^2/2 + z^3/6 + z^4/24 = -1 (Hairer & Wanner, Solving ODEs II, sec. IV.2)
RK4_REAL_BOUNDARY = -2.785293563405282


def test_rk4_boundary_on_the_real_axis_and_for_a_lightly_damped_mode():
    assert rk4_amplification(RK4_REAL_BOUNDARY) == pytest.approx(1.0, abs=1e-12)
    assert largest_stable_step(-100.0 + 0j) == pytest.approx(-RK4_REAL_BOUNDARY / 100, rel=1e-9)
    # a lightly damped mode: |R| is 1 at the step found, above it just beyond
    lam = -0.5 + 20.0j
    h = largest_stable_step(lam)
    assert rk4_amplification(lam * h) == pytest.approx(1.0, abs=1e-9)
    assert rk4_amplification(lam * h * 1.001) > 1.0
    assert largest_stable_step(0.3 + 0j) == float("inf")  # growing in the model itself


def test_a_fitted_damping_that_absorbed_a_lag_is_too_stiff_for_the_log_step():
    x500 = load_airframe("examples/x500.toml")
    assert not step_stiffness(x500, 0.01).too_stiff
    # q_dot = -pitch_damping q / Jy: 12 / 0.0217 = 553 1/s needs steps below 2.785 / 553 s
    stiff = x500.replace(pitch_damping=12.0)
    found = step_stiffness(stiff, 0.01)
    rate = 12.0 / x500.params.Jy
    assert found.too_stiff
    assert found.max_stable_dt == pytest.approx(-RK4_REAL_BOUNDARY / rate, rel=0.02)
    assert not step_stiffness(stiff, 0.004).too_stiff
    line = departure_line({"step_stiffness": stiffness_check(stiff, 0.01)}, 10)
    assert line.startswith("WARNING:") and "too stiff for one RK4 step" in line
    assert departure_line({"step_stiffness": stiffness_check(x500, 0.01)}, 10) == ""


def test_the_trainer_refuses_physics_that_diverges_in_its_windows_in_one_line(tmp_path):
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, SafeTrainingError, train_safe

    x500 = load_airframe("examples/x500.toml")
    sorties = load_dataset(emulated_dataset(tmp_path / "data", x500, 4, 4.0)).sorties
    stiff = x500.replace(pitch_damping=12.0)
    cfg = SafeConfig(epochs=1, horizon_s=1.0, progress=False)
    with pytest.raises(SafeTrainingError) as err:
        train_safe(sorties[:3], sorties[3:], stiff, cfg)
    text = str(err.value)
    assert "\n" not in text and "diverges within" in text
    assert "grows in one RK4 step of 0.01 s" in text
    assert np.isfinite(float(text.split("below ")[1].split(" s")[0]))
