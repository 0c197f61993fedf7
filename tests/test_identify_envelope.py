"""The identification's envelope: a fixed wing's windows are fitted only where the model's
quasi-steady stall blend is not yet acting (below the angle where it reaches 1 %), because
there real separation lags and overshoots and would bias the attached-flow derivatives."""

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from uavdyn.airframes import load_airframe
from uavdyn.flightdata import Sortie, make_windows
from uavdyn.identify.windows import inside_envelope, stall_onset
from uavdyn.model import NUMPY_OPS
from uavdyn.model.equations import stall_blend

TRAINER = Path(__file__).resolve().parents[1] / "examples" / "trainer.toml"


@pytest.mark.parametrize("name", ["aerosonde", "trainer"])
def test_stall_onset_is_where_the_blend_reaches_one_percent(name, aerosonde):
    af = aerosonde if name == "aerosonde" else load_airframe(TRAINER)
    P = af.params
    root = brentq(lambda a: stall_blend(a, P.M_blend, P.alpha0, NUMPY_OPS) - 0.01,
                  0.0, P.alpha0)
    assert stall_onset(af) == pytest.approx(root, abs=1e-6)
    assert 0.0 < stall_onset(af) < P.alpha0


def test_windows_reaching_the_onset_are_left_out(aerosonde):
    onset = stall_onset(aerosonde)
    t = np.arange(0, 6.0, 0.01)
    # alpha steps through: well below, just below, between onset and alpha0, past alpha0
    levels = [0.5 * onset, onset - 0.01, 0.5 * (onset + aerosonde.params.alpha0),
              aerosonde.params.alpha0 + 0.05, 0.2 * onset, onset - 0.002]
    alpha = np.repeat(levels, len(t) // len(levels))
    V = 20.0
    states = np.column_stack([V * np.cos(alpha), V * np.sin(alpha), 0 * alpha, alpha])
    sortie = Sortie("s", "fixed_wing", t[:len(alpha)], states, np.zeros((len(alpha), 2)))
    windows = make_windows([sortie], 50, every=100)  # one window inside each level
    assert windows.count == len(levels)
    assert inside_envelope(aerosonde, windows).tolist() == [True, True, False, False, True,
                                                             True]


def test_the_fit_summary_also_pools_the_windows_short_of_the_onset(aerosonde):
    """Where windows reach past the stall onset (left out of the fit), ``fit_summary`` adds
    the pitch RMSE over the others: the same per-window errors, the outside ones masked."""
    from uavdyn.identify.windows import fit_summary, physics_windows

    onset = stall_onset(aerosonde)
    t = np.arange(0, 4.0, 0.01)
    levels = [0.5 * onset, aerosonde.params.alpha0 + 0.05, 0.2 * onset, onset - 0.01]
    alpha = np.repeat(levels, len(t) // len(levels))
    V = 20.0
    states = np.column_stack([V * np.cos(alpha), V * np.sin(alpha), 0 * alpha, alpha])
    sortie = Sortie("s", "fixed_wing", t[:len(alpha)], states, np.zeros((len(alpha), 2)))
    fitted = aerosonde.replace(C_m_alpha=0.9 * aerosonde.params.C_m_alpha)
    out = fit_summary(aerosonde, fitted, [sortie], 0.01, 1, 50, 1)
    # 0.5 s windows back to back (each with its start sample), 1 s per level: the second
    # level lies in three (the one ending on its first sample too)
    assert out["windows_past_stall_onset"] == 3
    windows = make_windows([sortie], 50)
    inside = inside_envelope(aerosonde, windows)
    for label, af in (("nominal", aerosonde), ("identified", fitted)):
        err = physics_windows(af, windows, 0.01, 1)[..., 3] - windows.y[..., 3]
        assert out["theta_rmse_inside"][label] == pytest.approx(
            np.sqrt(np.mean(err[inside] ** 2)), rel=1e-12)
        assert out["theta_rmse"][label] == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
    calm = Sortie("c", "fixed_wing", sortie.time, np.tile(states[0], (len(alpha), 1)),
                  sortie.controls)
    assert "theta_rmse_inside" not in fit_summary(aerosonde, fitted, [calm], 0.01, 1, 50, 1)
