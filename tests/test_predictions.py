"""One prediction per model, step size, sortie and target in a run: ``uavdyn evaluate`` reads
Table 1, Table 4, the per-sortie comparison and the ladder from one
:class:`~uavdyn.experiments.predictions.PredictionStore`, so no prediction is computed twice,
whatever the tables call its row. The calls are counted where the work is done (the
evaluation functions the store calls), keyed by what a prediction is computed from."""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from uavdyn.experiments import predictions


def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a, float)).tobytes())
    return h.hexdigest()[:16]


def _content_key(solver, time, states, controls, p) -> tuple:
    """What a prediction is computed from, whatever the row it is made for is called."""
    model = solver.model
    return (model.name, model.description, model.nx, solver.dt, _digest(p),
            _digest(time, states, controls))


def count_predictions(monkeypatch) -> dict[str, Counter]:
    """Count the trajectory and horizon predictions the store makes, by content."""
    counts = {"trajectory": Counter(), "horizons": Counter()}
    trajectory, horizons = predictions.evaluate_trajectory, predictions.horizon_predictions

    def counted_trajectory(solver, time, states, controls, p, *args, **kwargs):
        counts["trajectory"][_content_key(solver, time, states, controls, p)] += 1
        return trajectory(solver, time, states, controls, p, *args, **kwargs)

    def counted_horizons(solver, time, states, controls, p, horizons_s):
        counts["horizons"][(*_content_key(solver, time, states, controls, p),
                            tuple(horizons_s))] += 1
        return horizons(solver, time, states, controls, p, horizons_s)

    monkeypatch.setattr(predictions, "evaluate_trajectory", counted_trajectory)
    monkeypatch.setattr(predictions, "horizon_predictions", counted_horizons)
    return counts


def test_evaluate_computes_each_prediction_once(tmp_path, monkeypatch):
    from test_reproduce import write_hand_dataset

    from uavdyn.airframes import load_airframe
    from uavdyn.experiments.evaluate import evaluate_dataset
    from uavdyn.learned import shipped_correction, shipped_identified, shipped_weights

    folder = write_hand_dataset(tmp_path / "hand", n_sorties=6, duration=6.0)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["sorties"][4]["split"] = "test"  # two test sorties
    (folder / "manifest.json").write_text(json.dumps(manifest))
    counts = count_predictions(monkeypatch)
    nominal = load_airframe("aerosonde")
    weights = [shipped_correction("aerosonde")[0], shipped_weights("aerosonde", "paper")]
    result = evaluate_dataset(nominal, folder, weights,
                              identified=shipped_identified("aerosonde"))

    assert len(result["sorties"]) == 2
    rows = [r for t in result["table1"].values() for r in t["rows"]]
    assert rows and result["table4"] and result["ladder"]["per_sortie"]
    assert [e["correction"].split(" (")[0] for e in result["per_sortie"]] == [
        "hybrid improved", "hybrid paper"]
    # every prediction computed exactly once ...
    for kind, counter in counts.items():
        assert counter, kind
        twice = {k: n for k, n in counter.items() if n > 1}
        assert not twice, (kind, twice)
    # ... and no more than Table 1's models (one per model, step size, sortie and target)
    # and the ladder's at its own step (the log interval, 0.01 s or its float neighbour):
    # the per-sortie comparison and Table 4 read Table 1's
    n = len(result["sorties"])
    table1 = result["table1"]
    models = len(table1["flight data"]["rows"]) + len(
        table1["baseline fine-step reference"]["rows"])
    rungs = len(result["ladder"]["models"])
    shared = rungs if result["ladder"]["dt"] in (0.005, 0.01, 0.02) else 0
    assert sum(counts["trajectory"].values()) == (models + rungs - shared) * n
    assert sum(counts["horizons"].values()) == rungs * n


def test_store_shares_a_model_across_row_names_and_keeps_targets_apart(aerosonde,
                                                                      aerosonde_trim):
    from uavdyn.evaluation import Solver
    from uavdyn.experiments.predictions import Candidate, PredictionStore
    from uavdyn.flightdata import Sortie
    from uavdyn.integrate import free_run, physics_step

    dt = 0.01
    controls = np.tile(aerosonde_trim.u, (301, 1))
    controls[50:100, 0] += 0.02
    step = physics_step(aerosonde)
    states = free_run(step, aerosonde_trim.x, controls[:-1], aerosonde.p, dt)
    sortie = Sortie("s", "fixed_wing", np.arange(301) * dt, states, controls, "doublet",
                    {"condition": "calm"}, true_states=states)
    a = Candidate(Solver("nominal physics", step, dt), aerosonde)
    b = a.named("nominal physics @ 0.01 s")
    c = Candidate(Solver("nominal physics", step, 0.005), aerosonde)
    store = PredictionStore(aerosonde)
    assert store.trajectory(a, sortie) is store.trajectory(b, sortie)
    assert store.trajectory(c, sortie) is not store.trajectory(a, sortie)
    assert store.trajectory(a, sortie, "reference") is not store.trajectory(a, sortie)
    assert store.horizons(a, sortie, (0.1, 1.0)) is store.horizons(b, sortie, [0.1, 1])
    assert set(store.keys()) == {("nominal physics", 0.01, "s", "data"),
                                 ("nominal physics", 0.005, "s", "data"),
                                 ("reference", "s"),
                                 ("nominal physics", 0.01, "s", "reference"),
                                 ("nominal physics", 0.01, "s", ("horizons", (0.1, 1.0)))}
    with pytest.raises(ValueError, match="target"):
        store.trajectory(a, sortie, "truth")


def test_two_weight_files_of_one_name_stay_apart_in_the_rows(tmp_path):
    """`uavdyn evaluate --weights old/f.npz new/f.npz` (an old and a re-trained file): the
    rows name each file by its path, not by the one name they share."""
    import shutil

    from test_reproduce import write_hand_dataset

    from uavdyn.airframes import load_airframe
    from uavdyn.experiments.evaluate import evaluate_dataset
    from uavdyn.learned import shipped_correction, shipped_identified

    folder = write_hand_dataset(tmp_path / "hand", n_sorties=6, duration=4.0)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["sorties"][4]["split"] = "test"
    (folder / "manifest.json").write_text(json.dumps(manifest))
    shipped = shipped_correction("aerosonde")[0]
    copies = []
    for sub in ("old", "new"):
        (tmp_path / sub).mkdir()
        copies.append(Path(shutil.copy(shipped, tmp_path / sub / "f.npz")))
    result = evaluate_dataset(load_airframe("aerosonde"), folder, copies,
                              identified=shipped_identified("aerosonde"))
    labels = [e["correction"] for e in result["per_sortie"]]
    assert len(set(labels)) == 2
    assert all(str(p) in label for p, label in zip(copies, labels))
