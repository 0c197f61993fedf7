"""Parameters a flight-test engineer would sign: the fit keeps the signs physics gives the
derivatives (a sign-reversed truth is never called determined, and by default the written
value is the file's, the others refitted); the prior's limits (a vanishing prior: the file's
values; an infinite one: the data-only fit) and its posterior standard errors (below both the
prior's and the data's); the free-run check flags a model that departs; bad options are
refused in one line."""

import dataclasses

import numpy as np
import pytest
from test_identify import _sorties

from uavdyn.airframes import load_airframe
from uavdyn.cli import main
from uavdyn.identify import IdentifyError, identify, write_outputs
from uavdyn.identify.freerun import departure_line, free_run_check
from uavdyn.identify.report import airframe_toml
from uavdyn.identify.unknowns import _bound_of


def test_fit_bounds_follow_the_sign_convention_and_relaxed_stability(aerosonde):
    assert _bound_of(aerosonde, "C_m_q")[1:4:2] == (0.0, True)       # < 0, open
    assert _bound_of(aerosonde, "C_m_delta_e")[1:4:2] == (0.0, True)
    assert _bound_of(aerosonde, "C_L_alpha")[0:3:2] == (0.0, True)   # > 0, open
    assert _bound_of(aerosonde, "C_m_alpha")[1] == 0.0
    assert _bound_of(aerosonde, "C_m_0")[:2] == (-1e3, 1e3)          # either sign
    relaxed = dataclasses.replace(aerosonde, relaxed_stability=True)
    assert _bound_of(relaxed, "C_m_alpha")[1] == 1e3
    unstable = aerosonde.replace(C_m_alpha=0.3)
    with pytest.raises(IdentifyError, match="wrong sign.*relaxed_stability = true"):
        identify(unstable, _sorties(aerosonde, 1, 0, duration=3.0), [], ["C_m_alpha"],
                 progress=False)


def test_relaxed_stability_is_read_and_written(tmp_path, aerosonde):
    path = tmp_path / "relaxed.toml"
    path.write_text(airframe_toml(dataclasses.replace(aerosonde, relaxed_stability=True), []))
    assert load_airframe(path).relaxed_stability
    assert not load_airframe("aerosonde").relaxed_stability
    path.write_text(path.read_text().replace("relaxed_stability = true",
                                             'relaxed_stability = "yes"'))
    with pytest.raises(Exception, match="relaxed_stability' must be true or false"):
        load_airframe(path)


@pytest.mark.slow
def test_reversed_elevator_is_never_determined_and_keeps_the_file_value(tmp_path, aerosonde):
    reversed_truth = aerosonde.replace(C_m_delta_e=0.5)  # elevator pitches the nose UP
    train = _sorties(reversed_truth, 2, 3, duration=8.0)
    names = ["C_m_delta_e", "C_D_0"]
    raw = identify(aerosonde, train, [], names, progress=False, keep_undetermined=True,
                   free_run=False)
    e = raw.estimates[0]
    assert e.at_bound == "upper" and not e.determined and e.value <= 0.0
    result = identify(aerosonde, train, [], names, progress=False)
    kept, other = result.estimates
    assert kept.kept and kept.value == aerosonde.params.C_m_delta_e  # the file's value
    assert kept.data_value == e.value and not kept.determined
    assert result.airframe.params.C_m_delta_e == aerosonde.params.C_m_delta_e
    assert other.value != raw.estimates[1].value  # refitted with C_m_delta_e fixed
    assert other.kept or other.determined  # never written undetermined
    paths = write_outputs(result, aerosonde, "data", "uavdyn identify ...",
                          tmp_path / "fit.toml", tmp_path / "report")
    written = load_airframe(paths["airframe"])
    assert written.params.C_m_delta_e == aerosonde.params.C_m_delta_e
    assert "kept the airframe file's value" in written.sources["C_m_delta_e"]
    assert "kept the file's value" in paths["airframe"].read_text()


@pytest.mark.slow
def test_prior_limits_and_posterior_standard_errors(aerosonde):
    truth = aerosonde.replace(C_m_alpha=-3.2, C_m_q=-33.0)
    train = _sorties(truth, 2, 4, duration=8.0, noise=1.0)
    names = ["C_m_alpha", "C_m_q"]
    common = {"progress": False, "check_halves": False, "free_run": False,
              "keep_undetermined": True}
    data = identify(aerosonde, train, [], names, **common)
    wide = identify(aerosonde, train, [], names, prior_sd=1e6, **common)
    tight = identify(aerosonde, train, [], names, prior_sd=1e-6, **common)
    # a prior as informative as the data on one parameter, more so on the other
    rel_sd = min(e.std_error_corrected / abs(e.nominal) for e in data.estimates)
    mid = identify(aerosonde, train, [], names, prior_sd=rel_sd, **common)
    for d, w, t, m in zip(data.estimates, wide.estimates, tight.estimates, mid.estimates):
        assert abs(w.value - d.value) < 1e-3 * d.std_error_corrected, d.name
        assert w.prior_share < 1e-6 and w.data_value == d.value
        assert abs(t.value - t.nominal) < 1e-4 * abs(t.nominal), d.name
        assert t.prior_share > 0.999
        prior_sd = rel_sd * abs(m.nominal)
        assert m.std_error_corrected < min(prior_sd, d.std_error_corrected), d.name
        assert 0.0 < m.prior_share < 1.0
        assert "prior" in m.pull() and not d.pull()
    # the maximum a posteriori is nearer the prior's centre than the data-only fit (in the
    # prior's own metric: it trades data misfit for prior misfit)
    weights = np.array(next(s["weights"] for s in mid.search if s.get("step") == "prior"))

    def prior_misfit(result):
        theta = np.array([(e.value - e.nominal) / abs(e.nominal) for e in result.estimates])
        return float(np.sum((weights * theta) ** 2))

    assert prior_misfit(mid) < prior_misfit(data)


@pytest.mark.slow
def test_free_run_check_flags_a_model_that_departs(aerosonde):
    train = _sorties(aerosonde, 2, 5, duration=10.0)
    unstable = dataclasses.replace(aerosonde.replace(C_m_alpha=1.5, C_m_q=-5.0),
                                   relaxed_stability=True)
    check = free_run_check(aerosonde, unstable, train, 2)
    assert check["nominal_departed"] == []
    assert check["identified_departed"] == [s.name for s in train]
    assert "free run departs" in departure_line({"free_run": check}, 2)
    assert departure_line({"free_run": free_run_check(aerosonde, aerosonde, train, 2)}, 2) == ""
    windows = {"train": {"per_sortie": [{"sortie": "s", "theta_rmse_nominal": 0.1,
                                         "theta_rmse_identified": float("inf")}]}}
    assert "diverges within the fit's windows on 1 of 2" in departure_line(windows, 2)


@pytest.mark.parametrize("value", ["nominal:-1", "foo", "nominal:0", "nominal:nan",
                                   "nominal:"])
def test_bad_prior_is_refused_in_one_line(value, capsys):
    code = main(["identify", "--prior", value, "--airframe", "aerosonde", "--dataset", ".",
                 "--params", "C_m_q", "--out", "x.toml"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --prior" in err[0] and "REL_SD" in err[0]


def test_posterior_is_tighter_than_the_prior_and_the_data_and_a_zero_file_value_has_none():
    from uavdyn.identify.prior import posterior, prior_precision

    rng = np.random.default_rng(0)
    a = rng.normal(size=(4, 4))
    cov = a @ a.T + 0.1 * np.eye(4)
    precision = prior_precision(np.array([-2.7, 0.0, 5.6, -38.0]), 0.3)
    assert precision[1] == 0.0 and precision[0] == pytest.approx(1 / 0.09)
    post = posterior(cov, precision)
    assert np.all(np.diag(post) < np.diag(cov))
    assert np.all(np.diag(post)[precision > 0] < 1 / precision[precision > 0])
    assert np.allclose(posterior(cov, np.zeros(4)), cov)
