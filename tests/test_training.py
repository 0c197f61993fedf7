"""Training: a short run on a small emulated dataset really learns (validation loss down >= 10x,
held-out free-run pitch error below physics-only RK4 at the same step); the CLI writes weights,
history JSON and PNG, and refuses to train without a dataset; datasets are built by sortie
with clear errors."""

import json
from dataclasses import asdict, replace

import numpy as np
import pytest

torch = pytest.importorskip("torch")


from emulated_data import emulated_dataset  # noqa: E402

from uavdyn.airframes import perturb  # noqa: E402
from uavdyn.evaluation import pitch_rmse  # noqa: E402
from uavdyn.flightdata import load_dataset  # noqa: E402
from uavdyn.integrate import EvalGrid, GridError, physics_step  # noqa: E402
from uavdyn.learned import hybrid_step, load_weights, save_weights  # noqa: E402
from uavdyn.learned.data import (  # noqa: E402
    DatasetError,
    one_step_pairs,
    rollout_windows,
    target_trajectories,
    window_times,
)
from uavdyn.learned.train import TrainConfig, train  # noqa: E402

pytestmark = pytest.mark.slow  # trains networks or runs whole pipelines


@pytest.fixture(scope="module")
def emulated(aerosonde, tmp_path_factory):
    """Ten calm, noise-free 5 s sorties of an Aerosonde whose stability derivatives and mass
    terms are 15 % off the model (the paper's robustness case), with train and validation
    splits."""
    return emulated_dataset(tmp_path_factory.mktemp("emulated") / "data",
                            perturb(aerosonde, 1.15), 10, 5.0)


@pytest.fixture(scope="module")
def small_data(emulated):
    sorties = load_dataset(emulated).sorties
    return sorties[:6], sorties[6:8], sorties[8:]


def test_short_training_learns_the_discrepancy(small_data, aerosonde, tmp_path):
    train_s, val_s, test_s = small_data
    cfg = TrainConfig(epochs=20, warmup_epochs=2, hidden=16, rollout_horizon=10,
                      rollout_batch=32, rollout_batches_per_epoch=3, batch_size=256, lr=1e-2,
                      patience=10, max_seconds=90, progress=False, seed=0)
    result = train(train_s, val_s, aerosonde, cfg, history_path=tmp_path / "hist.json")
    hist = result.history
    initial, best = hist[0]["val_total"], hist[result.best_epoch]["val_total"]
    assert initial / best >= 10, f"validation loss {initial:.3g} -> {best:.3g}"
    doc = json.loads((tmp_path / "hist.json").read_text())
    assert len(doc["history"]) == len(hist) and (tmp_path / "hist.png").stat().st_size > 1000
    assert all("train_total" in h and "val_total" in h for h in doc["history"])

    path = save_weights(result.net, tmp_path / "w.npz")
    step = hybrid_step(load_weights(path, aerosonde), aerosonde, compile=False)
    rk4 = physics_step(aerosonde)
    e_hybrid = pitch_rmse(step, test_s, aerosonde.p, 0.005)
    e_physics = pitch_rmse(rk4, test_s, aerosonde.p, 0.005)
    assert e_hybrid < e_physics, (e_hybrid, e_physics)


def test_cli_train_writes_weights_history_and_plot(tmp_path, emulated, capsys):
    """The files written, and what is printed: the verdict in words (the kept reason the
    history records, the network, the files), not the summary's JSON."""
    from uavdyn.cli import main

    out = tmp_path / "w.npz"
    code = main(["train", "--airframe", "aerosonde", "--dataset", str(emulated),
                 "--epochs", "1", "--hidden", "4", "--horizon", "0.3", "--quiet",
                 "--min-gain", "0", "--out", str(out)])
    # short rollouts and one epoch, any gain kept: the files written are what is checked
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    history = json.loads((tmp_path / "w_history.json").read_text())
    assert lines[0] == f"kept: {history['reason']}"
    assert "improved MLP" in lines[1] and "validation sorties" in lines[1]
    assert lines[-1] == f"wrote {out}, {tmp_path / 'w_history.json'} and " \
        f"{tmp_path / 'w_history.png'}"
    net = load_weights(out)
    assert net.hidden == (4, 4, 4) and net.formulation == "improved"
    assert net.info["data_source"] == f"dataset {emulated}"
    assert (tmp_path / "w_history.json").exists() and (tmp_path / "w_history.png").exists()


def _assert_refused_in_one_line(tmp_path, emulated, capsys, option: str, cases) -> None:
    """Each argument list in ``cases`` makes ``uavdyn train`` exit 2 with one line naming
    ``option``, and no weight file is written."""
    from uavdyn.cli import main

    for bad in cases:
        assert main(["train", "--airframe", "aerosonde", "--dataset", str(emulated),
                     "--out", str(tmp_path / "x.npz"), *bad]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and option in err
    assert not (tmp_path / "x.npz").exists()


def test_cli_train_restarts_screens_the_starts_and_refuses_bad_counts(tmp_path, emulated,
                                                                      capsys):
    """``--restarts 2``: both starts are screened and one is carried on (the summary and the
    history say which, with their training losses); 0 starts, or starts for a legacy
    formulation, are refused in one line naming the option."""
    import json

    from uavdyn.cli import main

    out = tmp_path / "w.npz"
    code = main(["train", "--airframe", "aerosonde", "--dataset", str(emulated),
                 "--epochs", "2", "--hidden", "4", "--horizon", "0.3", "--quiet",
                 "--restarts", "2", "--min-gain", "0", "--json", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 0
    screened = json.loads(printed)["screened"]
    assert len(screened) == 2 and sum(s["chosen"] for s in screened) == 1
    history = json.loads((tmp_path / "w_history.json").read_text())
    assert history["screened"] == screened
    _assert_refused_in_one_line(tmp_path, emulated, capsys, "--restarts",
                                (["--restarts", "0"],
                                 ["--restarts", "2", "--formulation", "paper"]))


def test_cli_train_start_fit_is_recorded_and_refused_out_of_range(tmp_path, emulated, capsys):
    """``--start-fit``: by default (0.2 s) the summary and the history record how many
    validation starts the physics fitted over 21 samples; ``--start-fit 0`` fits none (the
    records are the starts) and records nothing; a span beyond 2 s, a negative one, or one
    for a legacy formulation is refused in one line naming the option."""
    import json

    from uavdyn.cli import main

    base = ["train", "--airframe", "aerosonde", "--dataset", str(emulated), "--epochs", "2",
            "--hidden", "4", "--horizon", "0.3", "--quiet", "--min-gain", "0", "--json"]
    assert main([*base, "--out", str(tmp_path / "fit.npz")]) == 0
    fits = json.loads(capsys.readouterr().out)["start_fits"]
    assert fits["validation"]["span_samples"] == 21
    assert 0.0 <= fits["validation"]["share_fitted"] <= 1.0
    history = json.loads((tmp_path / "fit_history.json").read_text())
    assert history["start_fits"] == fits and history["config"]["start_fit_s"] == 0.2
    assert main([*base, "--start-fit", "0", "--out", str(tmp_path / "raw.npz")]) == 0
    assert json.loads(capsys.readouterr().out)["start_fits"] == {}
    _assert_refused_in_one_line(tmp_path, emulated, capsys, "--start-fit",
                                (["--start-fit", "3"], ["--start-fit", "-0.1"],
                                 ["--start-fit", "0.2", "--formulation", "paper"]))


def test_cli_train_envelope_fade_reaches_the_weight_file_and_is_refused_out_of_range(
        tmp_path, emulated, capsys):
    """``--envelope-fade``: the run's configuration records it, and a kept correction's gate
    fades over that share of each input's training range (where the range is not a
    floor-width constant); out of range, or for a legacy formulation, one line naming the
    option."""
    import json

    import numpy as np

    from uavdyn.airframes import load_airframe
    from uavdyn.cli import main
    from uavdyn.learned import load_weights

    out = tmp_path / "fade.npz"
    assert main(["train", "--airframe", "aerosonde", "--dataset", str(emulated), "--epochs",
                 "2", "--hidden", "4", "--horizon", "0.3", "--quiet", "--min-gain", "0",
                 "--envelope-fade", "0.5", "--out", str(out)]) == 0
    capsys.readouterr()
    history = json.loads((tmp_path / "fade_history.json").read_text())
    assert history["config"]["envelope_fade"] == 0.5
    env = load_weights(out, load_airframe("aerosonde")).envelope
    width = env.high - env.low
    wide = width > 1e-3
    assert wide.sum() >= 4
    np.testing.assert_allclose(env.fade[wide] / width[wide], 0.5, rtol=1e-12)
    _assert_refused_in_one_line(tmp_path, emulated, capsys, "--envelope-fade",
                                (["--envelope-fade", "0"], ["--envelope-fade", "5"],
                                 ["--envelope-fade", "1", "--formulation", "paper"]))


def test_cli_train_needs_a_dataset(tmp_path, capsys):
    """No stand-in data: without --dataset, one line naming the option and how to make one;
    nothing is written."""
    from uavdyn.cli import build_parser, main

    assert main(["train", "--airframe", "aerosonde", "--out", str(tmp_path / "w.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "--dataset DIR is required" in err and "uavdyn generate-data" in err
    assert list(tmp_path.iterdir()) == []
    for gone in ("--sorties", "--duration"):  # the stand-in's options
        with pytest.raises(SystemExit):
            build_parser().parse_args(["train", gone, "3"])


def test_cli_defaults_match_train_config():
    from uavdyn.cli import build_parser
    from uavdyn.learned.safe import SafeConfig

    args = build_parser().parse_args(["train"])
    d = asdict(TrainConfig())
    for key in ("formulation", "target", "activation", "lr", "seed", "threads"):
        assert getattr(args, key) == d[key], key
    # options whose default differs between the trainers, or that apply to one trainer only
    # (given for the other, they are refused), are left to each trainer's config
    safe = asdict(SafeConfig())
    assert safe["hidden"] != d["hidden"]
    for key in ("epochs", "patience", "max_seconds", "stability_weight", "hidden", "dt",
                "rollout_horizon", "rollout_weight", "stability_margin", "horizon",
                "memory_tau"):
        assert getattr(args, key) is None, key
    for key in ("lr", "seed", "threads"):
        assert getattr(args, key) == safe[key], key


def test_dataset_building(small_data, aerosonde, f450):
    train_s = small_data[0]
    g, coarse = EvalGrid(0.01, 0.005), EvalGrid(0.01, 0.05)
    assert (g.stride, g.substeps) == (1, 2) and (coarse.stride, coarse.substeps) == (5, 1)
    with pytest.raises(GridError, match="must divide"):
        EvalGrid(0.01, 0.003)
    bad_rate = [replace(train_s[0], time=train_s[0].time * 0.3)]
    with pytest.raises(DatasetError, match="must divide"):
        target_trajectories(bad_rate, aerosonde, "data", 0.005)
    trajs = target_trajectories(train_s, aerosonde, "data", 0.005)
    pairs = one_step_pairs(trajs)
    assert len(pairs.t) == sum(len(s.time) - 1 for s in train_s)
    assert len(trajs) == len(train_s) and trajs[0].substeps == 2
    np.testing.assert_array_equal(pairs.x1[0], train_s[0].states[1])
    win = rollout_windows(trajs, 10)
    assert win.length == 10 and win.y.shape[1:] == (10, 4) and win.u.shape[1:] == (10, 2)
    i, k = win.starts[1]
    np.testing.assert_array_equal(win.x0[1], trajs[i].states[k])
    np.testing.assert_array_equal(win.y[1], trajs[i].states[k + 1:k + 11])
    np.testing.assert_array_equal(win.u[1], trajs[i].controls[k:k + 10])
    np.testing.assert_array_equal(window_times(win)[1], trajs[i].time[k:k + 10])
    assert k == 5 and win.count == sum((len(t.time) - 10 + 4) // 5 for t in trajs)
    with pytest.raises(DatasetError, match="longer than the rollout horizon"):
        rollout_windows(trajs, 10_000)
    # reference target: the baseline's own fine-step trajectory (differs from the data)
    ref = target_trajectories(train_s[:1], aerosonde, "reference", 0.05)
    assert ref[0].substeps == 1 and len(ref[0].time) == len(train_s[0].time[::5])
    assert np.abs(ref[0].states - train_s[0].states[::5]).max() > 1e-3
    with pytest.raises(DatasetError, match="kind 'fixed_wing'"):
        target_trajectories(train_s, f450, "data", 0.005)
    with pytest.raises(DatasetError, match="unknown target"):
        target_trajectories(train_s, aerosonde, "truth", 0.005)


def test_cli_train_damping_weight_is_recorded_and_refused_out_of_range(tmp_path, emulated,
                                                                       capsys):
    """``--damping-weight``: the default (10) and a given weight reach the history's config,
    the history records the damping penalty of every trained epoch; a negative weight, or one
    for a legacy formulation, is refused in one line naming the option."""
    import json

    from uavdyn.cli import main

    for given, expected in (([], 10.0), (["--damping-weight", "0"], 0.0)):
        out = tmp_path / f"d{expected:g}.npz"
        assert main(["train", "--airframe", "aerosonde", "--dataset", str(emulated),
                     "--epochs", "2", "--hidden", "4", "--horizon", "0.3", "--quiet",
                     "--min-gain", "0", *given, "--out", str(out)]) == 0
        capsys.readouterr()
        history = json.loads((tmp_path / f"d{expected:g}_history.json").read_text())
        assert history["config"]["damping_weight"] == expected
        trained = [h for h in history["history"] if h["epoch"] > 0]
        assert trained and all(h["damping_penalty"] >= 0.0 for h in trained)
        if expected == 0.0:  # not computed at all
            assert all(h["damping_penalty"] == 0.0 for h in trained)
    _assert_refused_in_one_line(tmp_path, emulated, capsys, "--damping-weight",
                                (["--damping-weight", "-1"],
                                 ["--damping-weight", "1", "--formulation", "paper"]))
