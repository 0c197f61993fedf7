"""The validation pipeline end to end on a tiny configuration: every table has its rows and
finite numbers, every figure is a valid PNG, and the accuracy metrics recomputed independently
from the saved trajectories equal the reported ones. Then ``uavdyn train`` + ``uavdyn evaluate``
on a dataset folder written by hand (not by the generator)."""

import json
import math
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from uavdyn.airframes import load_airframe, perturb
from uavdyn.cli import main
from uavdyn.experiments.reproduce import ReproduceConfig, run
from uavdyn.integrate import rk4_step, simulate
from uavdyn.linear import trim
from uavdyn.model import build_model

pytestmark = pytest.mark.slow  # trains networks or runs whole pipelines

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """The quick pipeline, its output folder, its dataset cache and the predictions it made
    (counted by content: :func:`test_predictions.count_predictions`)."""
    from test_predictions import count_predictions

    out = tmp_path_factory.mktemp("results")
    cache = tmp_path_factory.mktemp("datasets")
    with pytest.MonkeyPatch.context() as mp:
        counts = count_predictions(mp)
        results = run(ReproduceConfig(out=str(out), quick=True, cache=str(cache),
                                      cost_repeats=2, cost_segment_s=2.0, progress=False,
                                      save_trajectories=True))
    return out, results, cache, counts


def finite(x):
    return x is not None and math.isfinite(x)


LADDER_ROWS = ("nominal physics @ 0.01 s", "identified physics @ 0.01 s", "corrected @ 0.01 s")


def ships(name: str) -> bool:
    """Whether the package ships a kept correction for the preset (its training history says
    kept, and the weights are there)."""
    from uavdyn.learned.hybrid import shipped_corrections

    return name in shipped_corrections()


def test_tables_have_rows_and_finite_numbers(quick_run):
    out, results, _, _ = quick_run
    assert [a["airframe"] for a in results["airframes"]] == ["f450", "aerosonde"]
    for af in results["airframes"]:
        groups = af["table1"]
        assert "baseline fine-step reference" in groups
        for label, table in groups.items():
            names = [r["solver"] for r in table["rows"]]
            assert "nominal physics @ 0.005 s" in names and "nominal physics @ 0.02 s" in names
            if label.startswith("flight data"):  # the ladder, corrected where one ships
                ladder = LADDER_ROWS if ships(af["airframe"]) else LADDER_ROWS[:2]
                assert all(name in names for name in ladder)
            for row in table["rows"]:
                assert finite(row["one_step"]["theta_rmse"])
                assert finite(row["horizon_1s"]["theta_rmse"])
        ident = af["identification"]  # the shipped identified airframe, its values reported
        assert ident["estimates"] and all(finite(e["value"]) for e in ident["estimates"])
        table2 = af["table2"]  # the shipped training run, kept or not
        assert table2 and table2[0]["model"] == "corrected"
        assert finite(table2[0]["first_train_loss"]) and finite(table2[0]["best_val"])
        assert "validation split" in table2[0]["val_metric"]
        assert table2[0]["kept"] == ships(af["airframe"])
        if not ships(af["airframe"]):  # the missing rung says why
            why = af["ladder"]["missing"]["corrected"]
            assert "did not keep" in why or "physics is kept" in why or "candidates" in why
        families = {p["family"] for p in af["cost"]["points"]}
        needed = ["nominal physics", "nominal physics (CasADi VM)", "identified physics",
                  "CVODES", "scipy RK45", "emulator (truth model)"]
        for name in needed + (["corrected"] if ships(af["airframe"]) else []):
            assert name in families, name
        assert all(finite(p["median_ms"]) and p["min_ms"] <= p["median_ms"]
                   for p in af["cost"]["points"])
        scenarios = {r["scenario"] for r in af["table4"]}
        assert any("nominal" in s for s in scenarios) and any("+15 %" in s for s in scenarios)
        assert any("alpha > 20" in s for s in scenarios) == (af["kind"] == "fixed_wing")
        assert all(finite(r["max_error_rad"]) for r in af["table4"] if r.get("sorties"))


def test_figures_are_valid_pngs(quick_run):
    out, results, _, _ = quick_run
    for af in results["airframes"]:
        figs = af["figures"]
        for name in ("error_vs_horizon", "fig2", "fig3", "fig4", "fig5", "fig6",
                     "work_precision"):
            path = figs[name]
            with open(path, "rb") as fh:
                assert fh.read(8) == PNG_MAGIC
            image = matplotlib.image.imread(path)
            assert image.shape[0] > 100 and image.shape[1] > 100


def test_each_prediction_is_made_once(quick_run):
    """The ladder, Table 1, Table 4 and the figures read one store: no (model, step size,
    sortie, target) prediction is computed twice, and Table 1 pools the ladder's."""
    _, results, _, counts = quick_run
    for kind, counter in counts.items():
        assert counter, kind
        assert max(counter.values()) == 1, (kind, [k for k, n in counter.items() if n > 1])
    # Table 1 computes one per model and test sortie against each target (its flight-data
    # rows are the ladder's and the nominal physics at the other step sizes); Table 4 adds
    # the perturbed sorties only; the ladder's horizon curves are one per rung and sortie
    expected = {"trajectory": 0, "horizons": 0}
    for af in results["airframes"]:
        n = len(af["dataset"]["test_sorties"])
        groups = list(af["table1"].values())
        data = next(t for t in groups if t["target"] == "data")["rows"]
        reference = next(t for t in groups if t["target"] == "reference")["rows"]
        perturbed = [r for r in af["table4"] if r["scenario"].startswith("+15 %")]
        assert perturbed and not any("missing" in r for r in perturbed)
        expected["trajectory"] += (len(data) + len(reference)) * n + sum(
            r["sorties"] for r in perturbed)
        expected["horizons"] += len(af["ladder"]["models"]) * n
    assert {k: sum(c.values()) for k, c in counts.items()} == expected


def _report_tables(report: str):
    """(header line, rows) of every Markdown table of the report."""
    tables, current = [], None
    for line in report.splitlines():
        if line.startswith("|"):
            if current is None:
                current = (line, [])
                tables.append(current)
            elif not line.startswith("|---"):
                current[1].append(line)
        else:
            current = None
    return tables


def test_report_never_places_a_paper_figure_in_a_measured_row(quick_run):
    out, results, _, _ = quick_run
    report = (out / "report.md").read_text()
    paper = ("1.82e-3", "0.00182", "1.47e-3", "0.00147", "2.31e-3", "0.00231", "148 ms",
             "287 ms", "92 ms")
    tables = _report_tables(report)
    assert any("paper" in header for header, _ in tables)  # the paper's own column exists
    for header, rows in tables:
        for row in rows:
            if any(value in row for value in paper):
                assert "the paper's" in header, row
    headline = report.split("## f450")[0]
    assert not any(value in headline for value in paper)


def test_no_table_scores_training_or_validation_sorties(quick_run):
    from uavdyn.flightdata import load_dataset

    out, results, cache, _ = quick_run
    for af in results["airframes"]:
        folder = next(p for p in cache.iterdir() if p.name.startswith(
            "quadrotor" if af["kind"] == "multirotor" else "fixed_wing"))
        split = {s.name: s.meta.get("split") for s in load_dataset(folder).sorties}
        test = {name for name, sp in split.items() if sp == "test"}
        assert set(af["dataset"]["test_sorties"]) == test and test
        for table in af["table1"].values():
            assert set(table["sorties"]) <= test
        assert {r["sortie"] for r in af["ladder"]["per_sortie"]} == test
        assert af["cost"]["sortie"] in test
        for row in af["table4"]:
            for name in row.get("sortie_names", []):
                assert name in test or name.startswith("perturbed_"), name


def test_headline_recomputed_from_the_per_sortie_table(quick_run):
    from uavdyn.evaluation import SortieError, pooled_with_interval
    from uavdyn.experiments.report import fmt

    out, results, _, _ = quick_run
    metrics = json.loads((out / "metrics.json").read_text())
    report = (out / "report.md").read_text()
    headline = report.split("## f450")[0]
    checked = 0
    for af in metrics["airframes"]:
        rows = af["ladder"]["per_sortie"]
        for cond in ("calm", "turbulent"):
            for mode, label in (("horizon_1s", "1 s"), ("free_run", "free run")):
                for model in ("nominal physics", "identified physics", "corrected"):
                    cells = [(r["sortie"], r[mode]) for r in rows if r["condition"] == cond
                             and r["model"] == model and mode in r]
                    if not cells:
                        continue
                    sse = np.array([float(c["sse"]) for _, c in cells])
                    n = np.array([c["n"] for _, c in cells], float)
                    ok = np.isfinite(sse)
                    pooled = float(np.sqrt(sse[ok].sum() / n[ok].sum()))  # by hand
                    interval = pooled_with_interval([SortieError(s, float(c["sse"]), c["n"])
                                                     for s, c in cells])
                    assert interval.rmse == pytest.approx(pooled, rel=1e-12)
                    text = (f"{model} {fmt(pooled)} [{fmt(interval.low)}, "
                            f"{fmt(interval.high)}]")
                    line = next(ln for ln in headline.splitlines() if ln.startswith(
                        f"- **{af['airframe']}, {cond}, {label}**"))
                    assert text in line, (text, line)
                    checked += 1
    assert checked >= 6


def test_metrics_recomputed_from_saved_trajectories(quick_run):
    out, results, _, _ = quick_run
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
    assert checked >= 40


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
    # two epochs of 0.3 s rollouts: what is checked is the evaluation of whatever the trainer
    # wrote, not its fit
    assert main(["train", "--airframe", "aerosonde", "--dataset", str(folder), "--epochs", "2",
                 "--hidden", "8", "--max-seconds", "30", "--horizon", "0.3", "--out",
                 str(weights), "--quiet"]) == 0
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
    # two RMSEs with the pitch noise estimated from the records taken off (these records are
    # noise-free: about nothing to take off), every worse sortie flagged
    safety = metrics["per_sortie"]
    assert len(safety) == 1
    for r in safety[0]["sorties"]:
        sigma = r["pitch_noise_std"]
        assert 0.0 <= sigma < 1e-6
        for mode in ("horizon_1s", "free_run"):
            ratio = (math.sqrt(r[f"{mode}_corrected"] ** 2 - sigma**2)
                     / math.sqrt(r[f"{mode}_physics"] ** 2 - sigma**2))
            assert r[f"{mode}_ratio"] == pytest.approx(ratio, rel=1e-12)
            assert (mode in r["worse"]) == (ratio > 1.0)
        assert 0.0 <= r["outside_envelope"] <= 1.0
        assert 0.0 <= r["damping_reversed"] <= 1.0
    assert safety[0]["worse_at_1s"] == sum("horizon_1s" in r["worse"]
                                           for r in safety[0]["sorties"])
    assert "Per sortie" in out.with_suffix(".md").read_text()
    # the report's ladder on the user's data: the headline from the per-sortie rows
    ladder = metrics["ladder"]
    assert ladder["models"] == ["nominal physics", "corrected"]
    assert ladder["missing"]["identified physics"].startswith("no --identified")
    assert {r["sortie"] for r in ladder["per_sortie"]} == {"flight_5"}
    entry = next(e for e in ladder["headline"] if e.get("mode") == "horizon_1s")
    assert entry["condition"] == "unknown" and entry["sorties"] == 1
    assert set(entry["models"]) == {"nominal physics", "corrected"}
    md = out.with_suffix(".md").read_text()
    assert "## Headline" in md and "- **aerosonde, unknown, 1 s** (1 test sortie)" in md
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


def test_evaluate_all_sorties_scores_every_split_not_only_test(tmp_path):
    """Issue 41: on a dataset that has a test split, ``--all-sorties`` used to score only the
    test sorties; it scores every one, and says how many of each split."""
    folder = write_hand_dataset(tmp_path / "hand", n_sorties=3, duration=4.0)
    manifest = json.loads((folder / "manifest.json").read_text())
    for entry, split in zip(manifest["sorties"], ("train", "validation", "test")):
        entry["split"] = split
    (folder / "manifest.json").write_text(json.dumps(manifest))
    names = [Path(e["file"]).stem for e in manifest["sorties"]]
    out = tmp_path / "m.json"
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(folder),
                 "--all-sorties", "--out", str(out)]) == 0
    metrics = json.loads(out.read_text())
    assert sorted(metrics["sorties"]) == sorted(names)
    assert {row["sortie"] for row in metrics["ladder"]["per_sortie"]} == set(names)
    assert "1 train, 1 validation, 1 test" in metrics["split"]
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(folder),
                 "--out", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["sorties"] == [names[2]]   # without it: test only


def test_free_run_runner_starts_an_augmented_step_from_its_own_start_state():
    """Table 3 / work-precision time a safe correction (command-memory states) from the state
    :meth:`DiscreteModel.initial_state` builds: the body states it returns equal a hand-built
    rollout from ``[x0, u0, u0]``."""
    from test_safe_correction import _pitch_feedback_net

    from uavdyn.experiments.common import free_run_runner
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


def test_dataset_cache_key_follows_recipe_version_and_generator_code(monkeypatch):
    import uavdyn
    from uavdyn.emulation import datagen
    from uavdyn.emulation.datagen import shipped_recipe
    from uavdyn.experiments import data

    recipe = shipped_recipe("datagen_fixed_wing")
    key = data.dataset_cache_key(recipe)
    assert data.dataset_cache_key(shipped_recipe("datagen_fixed_wing")) == key
    recipe.sorties += 1
    assert data.dataset_cache_key(recipe) != key
    recipe.sorties -= 1
    monkeypatch.setattr(uavdyn, "__version__", uavdyn.__version__ + ".post1")
    assert data.dataset_cache_key(recipe) != key
    monkeypatch.undo()
    monkeypatch.setattr(data, "generator_code_hash", lambda: "other emulator code")
    assert data.dataset_cache_key(recipe) != key
    assert datagen.generator_code_hash() != "other emulator code"


def test_a_recipe_too_small_per_mission_is_split_over_the_whole_dataset():
    """20 sorties over 7 missions: split per mission, every mission's 2-3 sorties would all
    train. Split as ``uavdyn split --by mission`` instead (one warning saying so): the same
    missions and conditions per sortie (the flights do not depend on the split), the counts
    of that rule, no mission twice outside train, calm and turbulent in validation and test.
    Two sorties cannot fill three parts: the warning says to give more."""
    import warnings

    from uavdyn.emulation.datagen import assign_sorties, shipped_recipe
    from uavdyn.flightdata.split import assign_split

    recipe = shipped_recipe("datagen_fixed_wing")
    recipe.sorties = 20  # too few for train/validation/test in every mission
    with pytest.warns(UserWarning, match="'test' split empty when each mission is split "
                                         "alone; split over the whole dataset by mission"):
        plan = assign_sorties(recipe, "fixed_wing")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recipe.split = {"train": 1.0, "validation": 0.0, "test": 0.0}
        alone = assign_sorties(recipe, "fixed_wing")  # the per-mission rule's conditions
    assert [(p["mission"], p["condition"]) for p in plan] == \
        [(p["mission"], p["condition"]) for p in alone]
    fractions = tuple(shipped_recipe("datagen_fixed_wing").split.values())
    assert [p["split"] for p in plan] == assign_split(plan, "mission", fractions, recipe.seed)
    assert all(p["split_by"] == "mission" for p in plan)
    for part in ("validation", "test"):
        members = [p for p in plan if p["split"] == part]
        assert members and len({p["mission"] for p in members}) == len(members)
        assert {p["condition"] for p in members} == {"calm", "turbulent"}
    recipe.split, recipe.sorties = dict(zip(("train", "validation", "test"), fractions)), 2
    with pytest.warns(UserWarning, match="and so does splitting them all .*give more"):
        tiny = assign_sorties(recipe, "fixed_wing")
    assert "split_by" not in tiny[0]


def test_retrain_trains_the_earlier_formulations_on_the_nominal_airframe(monkeypatch, tmp_path):
    """``reproduce --retrain`` on an identified airframe with actuator lags (the shipped
    identified airframes have them) must not hand the ``paper`` formulation, which steps the
    4 body states only, an airframe it refuses: every earlier formulation sits on the nominal
    airframe, as its shipped weights do."""
    from uavdyn.experiments import data
    from uavdyn.learned import hybrid_step, shipped_identified
    from uavdyn.model import structure_of

    nominal = load_airframe("f450")
    identified = shipped_identified("f450")
    assert structure_of(identified).augmented  # the case that used to fail
    calls = []

    def fake_obtain(airframe, ds, formulation, config, log):
        calls.append((airframe.name, formulation))
        path = data.weights_path(airframe, formulation, ReproduceConfig(out=str(tmp_path)))
        return path if path.exists() else None  # the shipped paper weights stand in

    monkeypatch.setattr(data, "obtain_weights", fake_obtain)
    config = ReproduceConfig(out=str(tmp_path), retrain=True, progress=False)
    models = data.legacy_models(nominal, None, config, lambda *a: None)
    assert sorted(calls) == sorted((nominal.name, f) for f in data.LEGACY)
    assert models and all(owner is nominal for _, owner, _ in models.values())
    # and the refusal this avoids is real: the paper weights on the identified airframe
    with pytest.raises(ValueError, match="paper"):
        hybrid_step(data.weights_path(nominal, "paper", config), identified)


def test_headline_counts_sorties_where_identification_is_worse(quick_run):
    """The headline's identified-vs-nominal sentence, recounted by hand from the per-sortie
    table (issue: a pooled gain must not hide sorties the identification made worse)."""
    out, _, _, _ = quick_run
    metrics = json.loads((out / "metrics.json").read_text())
    report = (out / "report.md").read_text()
    checked = 0
    for af in metrics["airframes"]:
        rows = af["ladder"]["per_sortie"]
        for cond in ("calm", "turbulent"):
            for mode, label in (("horizon_1s", "1 s"), ("free_run", "free run")):
                nominal, identified = ({r["sortie"]: np.sqrt(float(r[mode]["sse"]) / r[mode]["n"])
                                        for r in rows if r["condition"] == cond
                                        and r["model"] == model and mode in r}
                                       for model in ("nominal physics", "identified physics"))
                if not nominal or set(nominal) != set(identified):
                    continue
                worse = sum(identified[s] > nominal[s] for s in nominal)
                line = next(ln for ln in report.splitlines() if ln.startswith(
                    f"- **{af['airframe']}, {cond}, {label}**"))
                assert (f"Against the nominal physics, identification is worse on {worse} of "
                        f"{len(nominal)} sorties") in line, line
                checked += 1
    assert checked >= 2
