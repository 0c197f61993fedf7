"""The validation pipeline end to end on a tiny configuration: every table has its rows and
finite numbers, every figure is a valid PNG, and the accuracy metrics recomputed independently
from the saved trajectories equal the reported ones. Then ``uavdyn train`` + ``uavdyn evaluate``
on a dataset folder written by hand (not by the generator)."""

import json
import math

import matplotlib.image
import numpy as np
import pytest

from uavdyn.airframes import load_airframe, perturb
from uavdyn.cli import main
from uavdyn.experiments.reproduce import ReproduceConfig, run
from uavdyn.integrate import rk4_step, simulate
from uavdyn.linear import trim
from uavdyn.model import build_model

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("results")
    cache = tmp_path_factory.mktemp("datasets")
    results = run(ReproduceConfig(out=str(out), quick=True, cache=str(cache), cost_repeats=1,
                                  progress=False))
    return out, results


def finite(x):
    return x is not None and math.isfinite(x)


def test_tables_have_rows_and_finite_numbers(quick_run):
    out, results = quick_run
    assert [a["airframe"] for a in results["airframes"]] == ["f450", "aerosonde"]
    for af in results["airframes"]:
        groups = af["table1"]
        assert "baseline fine-step reference" in groups
        for label, table in groups.items():
            names = [r["solver"] for r in table["rows"]]
            assert "RK4 nominal physics @ 0.005 s" in names
            assert "hybrid improved @ 0.005 s" in names
            if label != "baseline fine-step reference":  # no paper/reference weights shipped
                assert "hybrid paper @ 0.005 s" in names
            for row in table["rows"]:
                assert finite(row["one_step"]["theta_rmse"])
                assert finite(row["horizon_1s"]["theta_rmse"])
            if label.startswith("flight data"):  # the ladder: nominal -> identified physics
                assert "RK4 identified physics @ 0.005 s" in names
        # the identified airframe is a loadable file whose fitted values are the ones reported,
        # and its fit is scored on the validation split
        ident = af["identification"]
        fitted = load_airframe(out / ident["file"])
        for e in ident["estimates"]:
            assert getattr(fitted.params, e["name"]) == pytest.approx(e["value"], rel=1e-9)
        assert finite(ident["validation_theta_rmse"]["identified"])
        table2 = af["table2"]
        assert table2 and all(finite(r["initial_train_loss"]) and finite(r["best_val_loss"])
                              for r in table2)
        rows3 = af["table3"]["rows"]
        solvers3 = " ".join(r["solver"] for r in rows3)
        for needed in ("RK4 compiled", "RK4 CasADi VM", "hybrid improved compiled", "CVODES",
                       "scipy RK45", "emulator"):
            assert needed in solvers3
        assert {r["dt"] for r in rows3 if r["solver"] == "RK4 compiled"} == {0.001, 0.0005,
                                                                             0.005}
        assert all(finite(r["wall_ms"]) and r["wall_ms"] > 0 for r in rows3)
        scenarios = {r["scenario"] for r in af["table4"]}
        assert any("nominal" in s for s in scenarios) and any("+15 %" in s for s in scenarios)
        if af["kind"] == "fixed_wing":
            assert any("alpha > 20" in s for s in scenarios)
        assert all(finite(r["max_error_rad"]) for r in af["table4"] if r.get("sorties"))
        assert len(af["work_precision"]) >= 8


def test_figures_are_valid_pngs(quick_run):
    out, results = quick_run
    for af in results["airframes"]:
        figs = af["figures"]
        for name in ("fig2", "fig3", "fig4", "fig5", "fig6", "work_precision"):
            path = figs[name]
            with open(path, "rb") as fh:
                assert fh.read(8) == PNG_MAGIC
            image = matplotlib.image.imread(path)
            assert image.shape[0] > 100 and image.shape[1] > 100
    report = (out / "report.md").read_text()
    first = report.split("\n\n")[1]
    assert "1.82e-3" in first and "38 %" in first and "rad" in first


def test_metrics_recomputed_from_saved_trajectories(quick_run):
    out, results = quick_run
    text = (out / "metrics.json").read_text()
    metrics = json.loads(text)
    import uavdyn

    assert metrics["provenance"]["uavdyn"] == uavdyn.__version__
    assert "casadi" in metrics["provenance"] and "commit" in metrics["provenance"]

    def strings(obj):
        if isinstance(obj, dict):
            for v in obj.values():
                yield from strings(v)
        elif isinstance(obj, list):
            for v in obj:
                yield from strings(v)
        elif isinstance(obj, str):
            yield obj

    absolute = [s for s in strings(metrics) if s.startswith(("/", str(out)))]
    assert not absolute, absolute[:3]  # paths relative to the output, cache or package
    checked = 0
    for af in metrics["airframes"]:
        for label, table in af["table1"].items():
            slug = "".join(c if c.isalnum() else "_" for c in label).strip("_")
            for row in table["rows"]:
                solver = "".join(c if c.isalnum() else "_" for c in row["solver"]).strip("_")
                data = np.load(out / "trajectories" / f"{af['airframe']}__{slug}__{solver}.npz")
                for mode in ("one_step", "horizon_1s", "free_run"):
                    pred = np.concatenate([data[k] for k in data.files
                                           if k.endswith(f"__{mode}__predicted")])
                    targ = np.concatenate([data[k] for k in data.files
                                           if k.endswith(f"__{mode}__target")])
                    err = pred[:, 3] - targ[:, 3]
                    rmse = float(np.sqrt(np.mean(err**2)))
                    got = row[mode]["theta_rmse"]
                    if not np.isfinite(got):  # a diverged run is reported as infinite
                        assert not np.isfinite(rmse) or rmse > 1e100
                        continue
                    assert rmse == pytest.approx(got, rel=1e-12, abs=1e-15)
                    assert float(np.max(np.abs(err))) == pytest.approx(row[mode]["theta_max"],
                                                                       rel=1e-12, abs=1e-15)
                    checked += 1
    assert checked > 50


def write_hand_dataset(folder, n_sorties=6, duration=12.0):
    """A dataset written with numpy and json only: a 'real aircraft' whose stability
    derivatives are 10 % off the model, flown through 3-2-1-1 and doublet inputs."""
    af = load_airframe("aerosonde")
    truth = perturb(af, 1.10)
    point = trim(af)
    step = rk4_step(build_model(af).f)
    folder.mkdir(parents=True, exist_ok=True)
    dt = 0.01
    t = np.arange(int(duration / dt) + 1) * dt
    entries = []
    rng = np.random.default_rng(3)
    for i in range(n_sorties):
        U = np.tile(point.u, (len(t), 1))
        for start in np.arange(1.0, duration - 2, 3.0):
            amp = rng.uniform(0.01, 0.04) * rng.choice([-1, 1])
            U[(t >= start) & (t < start + 0.5), 0] += amp
            U[(t >= start + 0.5) & (t < start + 1.0), 0] -= amp
        fine = simulate(step, point.x, np.repeat(U[:-1], 10, axis=0), truth.p, dt / 10)[::10]
        name = f"flight_{i}.csv"
        table = np.column_stack([t, fine, U])
        np.savetxt(folder / name, table, delimiter=",", fmt="%.12g",
                   header="time,u,w,q,theta,elevator,throttle", comments="")
        split = "train" if i < 3 else ("validation" if i < 5 else "test")
        entries.append({"file": name, "mission": "doublets", "duration_s": duration,
                        "split": split})
    (folder / "manifest.json").write_text(json.dumps({
        "airframe": "aerosonde", "kind": "fixed_wing", "sample_rate_hz": 100.0,
        "source": "hand-written test data", "sorties": entries}))
    return folder


def test_train_and_evaluate_on_a_hand_written_dataset(tmp_path, capsys):
    pytest.importorskip("torch")
    folder = write_hand_dataset(tmp_path / "hand")
    weights = tmp_path / "w.npz"
    assert main(["train", "--airframe", "aerosonde", "--dataset", str(folder), "--epochs", "6",
                 "--hidden", "8", "--max-seconds", "60", "--out", str(weights), "--quiet"]) == 0
    assert weights.exists()
    out = tmp_path / "metrics.json"
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(folder), "--weights",
                 str(weights), "--out", str(out)]) == 0
    metrics = json.loads(out.read_text())
    assert metrics["sorties"] == ["flight_5"]
    rows = metrics["table1"]["flight data"]["rows"]
    assert len(rows) == 6
    for row in rows:
        for mode in ("one_step", "horizon_1s", "free_run"):
            assert finite(row[mode]["theta_rmse"])
    assert out.with_suffix(".md").read_text().startswith("# Evaluation of aerosonde")
    # per sortie: the correction against the physics it sits on, ratios recomputed from the
    # two RMSEs, every worse sortie flagged
    safety = metrics["per_sortie"]
    assert len(safety) == 1
    for r in safety[0]["sorties"]:
        for mode in ("horizon_1s", "free_run"):
            ratio = r[f"{mode}_corrected"] / r[f"{mode}_physics"]
            assert r[f"{mode}_ratio"] == pytest.approx(ratio, rel=1e-12)
            assert (mode in r["worse"]) == (ratio > 1.0)
        assert 0.0 <= r["outside_envelope"] <= 1.0
    assert safety[0]["worse_at_1s"] == sum("horizon_1s" in r["worse"]
                                           for r in safety[0]["sorties"])
    assert "Per sortie" in out.with_suffix(".md").read_text()
    assert metrics["table4"] and all(finite(r["max_error_rad"]) for r in metrics["table4"]
                                     if r["sorties"])


def test_evaluate_refuses_a_dataset_without_test_split_unless_asked(tmp_path, capsys):
    """No silent fallback: without test sorties ``evaluate`` says so in one line; with
    ``--all-sorties`` it scores every sortie and the result says that it did."""
    folder = write_hand_dataset(tmp_path / "hand", n_sorties=2, duration=4.0)
    manifest = json.loads((folder / "manifest.json").read_text())
    for entry in manifest["sorties"]:
        entry["split"] = "train"
    (folder / "manifest.json").write_text(json.dumps(manifest))
    out = tmp_path / "m.json"
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(folder),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no 'test' sorties" in err and "--all-sorties" in err
    assert not out.exists()
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(folder),
                 "--all-sorties", "--out", str(out)]) == 0
    metrics = json.loads(out.read_text())
    assert metrics["split"].startswith("all sorties") and len(metrics["sorties"]) == 2
    assert "all sorties" in out.with_suffix(".md").read_text()


def test_free_run_runner_starts_an_augmented_step_from_its_own_start_state():
    """Table 3 / work-precision time a safe correction (command-memory states) from the state
    its ``start_states`` builds: the body states it returns equal a hand-built rollout from
    ``[x0, u0, u0]``."""
    from test_safe_correction import _pitch_feedback_net

    from uavdyn.experiments.reproduce import free_run_runner
    from uavdyn.integrate import rollout as make_rollout
    from uavdyn.learned import hybrid_step
    from uavdyn.linear import trim as trim_point

    af = load_airframe("aerosonde")
    step = hybrid_step(_pitch_feedback_net(af, -1.0), af, compile=False)
    point = trim_point(af)
    controls = np.tile(point.u, (50, 1))
    controls[10:20, 0] += 0.02
    got = free_run_runner(step, point.x, controls, af.p, 0.01, 0.01, compiled=False)()
    z0 = np.concatenate([point.x, np.tile(controls[0], 2)])
    want = np.asarray(make_rollout(step, 50)(z0, controls.T, af.p, 0.01))[:4].T
    assert got.shape == (51, 4)
    np.testing.assert_allclose(got[0], point.x)
    np.testing.assert_allclose(got[1:], want, rtol=0, atol=1e-12)
