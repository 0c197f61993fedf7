"""The cost study on a short synthetic sortie: every family is timed in one harness run (the
nominal RK4 compiled and in the VM, each model at the step sizes it accepts, CVODES, scipy, the
emulator), a refused step size is listed as missing with its reason, the ratios are the
quotients of the reported timings, and both figures are written as PNG files."""

import dataclasses
import json
import math

import numpy as np
import pytest

from uavdyn.airframes import load_airframe, perturb
from uavdyn.experiments.cost import (
    CVODES_TOLS,
    MODEL_DTS,
    NOMINAL,
    NOMINAL_VM,
    RK4_DTS,
    SCIPY_RUNS,
    VM_DTS,
    cost_study,
)
from uavdyn.experiments.figures import cost_figure, work_precision_figure
from uavdyn.flightdata import Sortie
from uavdyn.integrate import physics_step, rk4_step, simulate
from uavdyn.linear import trim
from uavdyn.model import build_model

pytestmark = pytest.mark.slow  # trains networks or runs whole pipelines

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
DURATION = 3.0


@pytest.fixture(scope="module")
def sortie_and_models():
    """A 3 s 'flight' of a fixed wing whose derivatives are 10 % off the model (states from
    RK4 at 1 ms), an 'identified' airframe (with an actuator lag state) and a stand-in
    correction bound to dt 0.01 s."""
    af = load_airframe("aerosonde")
    flown = perturb(af, 1.10)
    point = trim(af)
    dt = 0.01
    t = np.arange(int(round(DURATION / dt)) + 1) * dt
    U = np.tile(point.u, (len(t), 1))
    U[(t >= 0.5) & (t < 1.0), 0] += 0.03
    U[(t >= 1.0) & (t < 1.5), 0] -= 0.03
    states = simulate(rk4_step(build_model(af).f), point.x, np.repeat(U[:-1], 10, axis=0),
                      flown.p, dt / 10)[::10]
    sortie = Sortie("synthetic", "fixed_wing", t, states, U, mission="doublet",
                    meta={"condition": "calm"}, true_states=states)
    bound = dataclasses.replace(physics_step(flown), dt=0.01)  # tied to dt 0.01 s
    # identified with an elevator lag: its step runs on the augmented state (actuators at rest
    # on the first command), as an identified airframe's does
    ident = flown.replace(tau_elevator=0.005)
    models = {"identified physics": (physics_step(ident), ident), "corrected": (bound, flown)}
    return af, sortie, models


@pytest.fixture(scope="module")
def study(sortie_and_models):
    af, sortie, models = sortie_and_models
    ticks = []
    out = cost_study(af, sortie, models, repeats=3, segment_s=DURATION,
                     progress=lambda: ticks.append(1))
    return out, ticks


def test_every_family_is_timed_once_each_in_one_run(study):
    out, ticks = study
    json.dumps(out)  # JSON-able as returned
    assert out["repeats"] == 3 and out["segment_s"] == pytest.approx(DURATION)
    assert "ZOH" in out["grid"] and "interleaved" in out["harness"]
    assert len(ticks) == 3 * len(out["points"])  # one harness run: every point, every repeat
    pts = out["points"]
    labels = [p["label"] for p in pts]
    assert len(set(labels)) == len(labels)
    dts = {f: sorted(p["dt"] for p in pts if p["family"] == f)
           for f in (NOMINAL, NOMINAL_VM, "identified physics", "corrected")}
    assert dts[NOMINAL] == sorted(RK4_DTS)
    assert dts[NOMINAL_VM] == sorted(VM_DTS)
    assert dts["identified physics"] == sorted(MODEL_DTS)
    assert dts["corrected"] == [0.01]
    assert sorted(p["tol"] for p in pts if p["family"] == "CVODES") == sorted(CVODES_TOLS)
    scipy = {(p["family"], p["tol"]) for p in pts if p["family"].startswith("scipy")}
    assert scipy == {(f"scipy {m}", r) for m, r in SCIPY_RUNS}
    assert any(p["family"].startswith("emulator") for p in pts)
    assert any(p["in_table3"] for p in pts) and not all(p["in_table3"] for p in pts)
    for p in pts:
        assert 0 < p["min_ms"] <= p["median_ms"]
        assert p["flight_mode"] == "free_run"
        assert math.isfinite(p["theta_rmse_vs_flight"])
        assert math.isfinite(p["theta_rmse_vs_reference"])
    # the nominal physics converges to its own fine-step reference, the 10 %-off physics not
    fine = next(p for p in pts if p["family"] == NOMINAL and p["dt"] == 0.001)
    ident = next(p for p in pts if p["family"] == "identified physics" and p["dt"] == 0.005)
    assert fine["theta_rmse_vs_reference"] < 1e-8 < ident["theta_rmse_vs_reference"]
    assert ident["theta_rmse_vs_flight"] < fine["theta_rmse_vs_flight"]


def test_refused_step_sizes_are_reported_missing_with_the_reason(study):
    out, _ = study
    missing = {m["dt"]: m["missing"] for m in out["missing"] if m["family"] == "corrected"}
    assert sorted(missing) == sorted(dt for dt in MODEL_DTS if dt != 0.01)
    assert all("made for 0.01 s" in why for why in missing.values())


def test_ratios_are_quotients_of_the_reported_timings(study):
    out, _ = study
    by = {p["label"]: p for p in out["points"]}
    ratios = out["ratios"]
    same = ratios["vs_physics_same_dt"]
    assert {(r["model"], r["baseline"]) for r in same} >= {
        ("corrected", "nominal physics @ 0.01 s"),
        ("corrected", "identified physics @ 0.01 s"),
        ("identified physics", "nominal physics @ 0.005 s")}
    rows = [(f"{r['model']} @ {r['dt']:g} s", r) for r in same]
    rows += [(r["model"], r) for r in ratios["vs_fine_rk4"]]
    rows += [(r["label"], {**r, "baseline": ratios["vs_fastest_model"]["reference"]["label"]})
             for r in ratios["vs_fastest_model"]["points"]]
    assert {r["baseline"] for r in ratios["vs_fine_rk4"]} == {"nominal physics @ 0.001 s",
                                                             "nominal physics @ 0.0005 s"}
    for label, r in rows:
        a, b = by[label], by[r["baseline"]]
        assert r["median"] == pytest.approx(a["median_ms"] / b["median_ms"], rel=1e-12)
        assert r["min"] == pytest.approx(a["min_ms"] / b["min_ms"], rel=1e-12)
    fastest = ratios["vs_fastest_model"]["reference"]["label"]
    model_medians = [p["median_ms"] for p in out["points"]
                     if p["family"] in ("identified physics", "corrected")]
    assert by[fastest]["median_ms"] == min(model_medians)


def test_figures_are_written_as_png(study, tmp_path):
    out, _ = study
    wp = work_precision_figure("aerosonde", out, tmp_path)
    bars = cost_figure("aerosonde", out, tmp_path)
    assert wp.endswith("work_precision_aerosonde.png")
    assert bars.endswith("fig5_cost_aerosonde.png")
    for path in (wp, bars):
        with open(path, "rb") as fh:
            assert fh.read(8) == PNG_MAGIC


def test_headline_cost_ratio_is_the_one_at_the_ladders_step():
    """The report's headline cost is the corrected/identified ratio at the step the ladder
    scores the correction at, not the first step size the study happened to time."""
    from uavdyn.experiments.report import corrected_cost_ratio

    rows = [{"model": "corrected", "dt": dt, "baseline": f"identified physics @ {dt:g} s",
             "median": m, "min": m} for dt, m in ((0.02, 1.2), (0.01, 1.4), (0.005, 1.5))]
    af = {"cost": {"ratios": {"vs_physics_same_dt": rows}}, "ladder": {"dt": 0.01 - 2e-16}}
    assert corrected_cost_ratio(af)["median"] == 1.4
    af["ladder"]["dt"] = 0.0025
    assert corrected_cost_ratio(af) is None
