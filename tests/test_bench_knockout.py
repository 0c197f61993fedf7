"""The knockout benchmark's arithmetic and bookkeeping (``analysis/bench_knockout.py``): the
recovered and removed shares with their bootstrap over sorties, the "not measurable" rule, the
made-worse count, the ``--safe-config`` parser and the resume of finished cases."""

import importlib.util
import json
import math
from pathlib import Path

import pytest

from uavdyn.evaluation import SortieError

SCRIPT = Path(__file__).resolve().parent.parent / "analysis" / "bench_knockout.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_knockout", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def errors_of(rmse: list[float], n: int = 100) -> list[SortieError]:
    return [SortieError(f"s{i}", r * r * n, n) for i, r in enumerate(rmse)]


def test_shares_pooled_from_per_sortie_errors(bench):
    a = [0.020, 0.030, 0.010, 0.040]
    b = [0.010, 0.015, 0.006, 0.020]
    c = [0.014, 0.021, 0.0102, 0.026]   # third sortie 2 % worse than a: not "> 2 %"
    stats = bench.share_statistics({"a": errors_of(a), "corrected": errors_of(c),
                                    "b": errors_of(b)}, resamples=500)

    def pooled(x):
        return math.sqrt(sum(v * v for v in x) / len(x))

    ea, ec, eb = pooled(a), pooled(c), pooled(b)
    assert stats["err"]["a"] == pytest.approx(ea)
    assert stats["recovered_share"] == pytest.approx((ea - ec) / (ea - eb))
    assert stats["removed_share"] == pytest.approx((ea - ec) / ea)
    low, high = stats["recovered_share_interval"]
    assert low <= stats["recovered_share"] <= high
    assert 0.0 < low and high < 1.0
    assert stats["n_sorties_worse"] == 0
    assert stats["corrected_over_a"]["s2"] == pytest.approx(1.02)


def test_bootstrap_collapses_when_every_sortie_agrees(bench):
    # Every sortie the same errors: every resample gives the same share.
    stats = bench.share_statistics({"a": errors_of([0.02] * 5),
                                    "corrected": errors_of([0.014] * 5),
                                    "b": errors_of([0.01] * 5)}, resamples=200)
    assert stats["recovered_share"] == pytest.approx(0.6)
    assert stats["recovered_share_interval"] == pytest.approx([0.6, 0.6])


def test_share_not_measurable_within_noise_and_worse_sorties_counted(bench):
    stats = bench.share_statistics({"a": errors_of([0.020, 0.020, 0.020]),
                                    "corrected": errors_of([0.019, 0.0205, 0.0210]),
                                    "b": errors_of([0.0199, 0.0198, 0.0197])})
    assert stats["recovered_share"] is None
    assert "not measurable" in stats["recovered_share_note"]
    assert stats["sorties_worse"] == ["s1", "s2"]    # 1.025 and 1.05 times a; 0.95 is not
    # both also worse than b by more than 2 % (1.035 and 1.066 times b)
    assert stats["sorties_worse_than_term"] == ["s1", "s2"]
    stats2 = bench.share_statistics({"a": errors_of([0.02]), "corrected": errors_of([0.0203])})
    assert stats2["n_sorties_worse"] == 0 and "recovered_share" not in stats2


def test_divergence_is_left_out_of_the_pool_and_counted_worse(bench):
    a = errors_of([0.02, 0.03])
    c = [SortieError("s0", math.inf, 100), errors_of([0.03, 0.015])[1]]
    stats = bench.share_statistics({"a": a, "corrected": c})
    assert stats["diverged"]["corrected"] == ["s0"]
    assert stats["pooled_over"] == 1
    assert stats["sorties_worse"] == ["s0"]
    assert stats["removed_share"] == pytest.approx(0.5)


def test_safe_config_parsing(bench):
    values = bench.parse_key_values('inputs="physical",horizon_s=3.0,memory_tau=[0.05,0.2],'
                                    'output=coefficient')
    assert values == {"inputs": "physical", "horizon_s": 3.0, "memory_tau": [0.05, 0.2],
                      "output": "coefficient"}
    cfg = bench.safe_config(values, quick=False)
    assert cfg.horizon_s == 3.0 and cfg.memory_tau == (0.05, 0.2) and not cfg.progress
    with pytest.raises(ValueError, match="unknown SafeConfig field"):
        bench.safe_config({"feature": 1}, quick=False)
    with pytest.raises(ValueError, match="KEY=VALUE"):
        bench.parse_key_values("horizon_s")


def test_truth_overrides_are_checked_against_the_truth_model(bench, capsys):
    assert bench.parse_key_values("C_D_Re=0.3,C_m_Re=-0.3", "--truth") == {
        "C_D_Re": 0.3, "C_m_Re": -0.3}
    with pytest.raises(ValueError, match="^--truth: 'C_D_Re' is not KEY=VALUE"):
        bench.parse_key_values("C_D_Re", "--truth")
    with pytest.raises(SystemExit):
        bench.main(["--airframes", "aerosonde", "--truth", "C_X=1", "--out", "unused.json"])
    assert "--truth: no airframe's truth model has C_X" in capsys.readouterr().err


def test_finished_case_is_resumed_without_any_work(bench, tmp_path, monkeypatch):
    """A case whose definition is unchanged is kept from the result file: no dataset is
    generated and the entry stays as it was; --force would rerun it."""
    args = bench.argparse.Namespace(quick=True, sorties=None, duration=None, seed=0,
                                    noise_scale=1.0, identify_on="train",
                                    noise_share=bench.NOISE_SHARE, force=False,
                                    balance_conditions=True)
    cfg = bench.safe_config({}, quick=True)
    ref, file_hash = bench.airframe_ref("aerosonde")
    af = bench.load_airframe(ref)
    flown = [t for t in bench.TERMS if bench.TERMS[t]["kind"] == af.kind
             and bench.term_status(t, af) is None]
    truth = {k: v for t in flown for k, v in bench.TERMS[t]["truth"].items()}
    recipe = bench.recipe_for(ref, af.kind, args, truth)
    key = bench.case_key("aerosonde", "alpha_dot", recipe, file_hash, cfg, args)
    out = tmp_path / "k.json"
    marker = {"airframe": "aerosonde", "term": "alpha_dot", "case_key": key, "status": "done",
              "marker": 1}
    out.write_text(json.dumps({"cases": {"aerosonde/alpha_dot": marker}}))

    def no_generation(*_a, **_k):
        raise AssertionError("a finished case generated data")

    monkeypatch.setattr(bench, "dataset", no_generation)
    cache = tmp_path / "cache"
    assert bench.main(["--quick", "--airframes", "aerosonde", "--terms", "alpha_dot",
                       "--out", str(out), "--cache", str(cache)]) == 0
    doc = json.loads(out.read_text())
    assert doc["cases"]["aerosonde/alpha_dot"]["marker"] == 1
    assert doc["machine"]["cpu_count"] >= 1 and "wall_s" in doc
    with pytest.raises(AssertionError, match="generated data"):
        bench.main(["--quick", "--airframes", "aerosonde", "--terms", "alpha_dot",
                    "--out", str(out), "--cache", str(cache), "--force"])


def test_the_benchmarks_dealing_gives_both_splits_both_conditions(bench):
    """The recipe's split at equal per-mission counts puts every test sortie in turbulence;
    the re-deal keeps each mission's counts and mixes the conditions."""
    from types import SimpleNamespace

    sorties = []
    for m in ("m0", "m1", "m2", "m3"):
        for i, (split, cond) in enumerate([("train", "calm"), ("train", "turbulent"),
                                           ("validation", "calm"), ("test", "turbulent")]):
            sorties.append(SimpleNamespace(name=f"{m}_{i}", mission=m,
                                           meta={"split": split, "condition": cond}))
    ds = SimpleNamespace(sorties=sorties)

    def split_of(s):
        return s.meta["split"]

    moved = bench.deal_conditions_by_mission(ds)
    assert moved  # the test sorties of the even missions moved
    for m in ("m0", "m1", "m2", "m3"):
        mine = [split_of(s) for s in ds.sorties if s.mission == m]
        assert sorted(mine) == ["test", "train", "train", "validation"]
    test = [s.meta["condition"] for s in sorties if split_of(s) == "test"]
    val = [s.meta["condition"] for s in sorties if split_of(s) == "validation"]
    assert sorted(test) == ["calm", "calm", "turbulent", "turbulent"]
    assert sorted(val) == ["calm", "calm", "turbulent", "turbulent"]


def test_markdown_names_the_split_shares_only_when_scored(bench):
    """``--score-splits``: the table gains a column with the recovered share on the training
    and validation sorties ("n.m." where not measurable); without it the table is as before."""
    a, b, c = [0.02, 0.03], [0.01, 0.015], [0.012, 0.018]
    score = bench.share_statistics({"a": errors_of(a), "corrected": errors_of(c),
                                    "b": errors_of(b)}, resamples=50)
    case = {"status": "done", "airframe_name": "f450", "term": "inflow", "score": score,
            "correction": {"kept": True}}
    plain = bench.markdown_table({"cases": {"f450/inflow": case}})
    assert "train / validation" not in plain and plain.splitlines()[2].count("|") == 12
    split = {**case, "score_on": {"train": {"recovered_share": 1.04},
                                  "validation": {"recovered_share": None}}}
    table = bench.markdown_table({"cases": {"f450/inflow": split}})
    header, _, row = table.splitlines()
    assert header.endswith("recovered on train / validation sorties |")
    assert row.endswith("| 1.04 / n.m. |") and row.count("|") == 13


def test_a_merged_older_case_gets_the_worse_than_the_term_count_from_its_sorties(bench, tmp_path):
    """A run written before the figure existed: the merge derives it from the per-sortie
    errors (the same rule as the scoring), and names it in the definitions."""
    case = {"airframe": "x", "score": {"sorties_worse": ["s0", "s1"], "n_sorties_worse": 2,
                                       "worse_by_more_than": 0.02},
            "per_sortie": [{"sortie": "s0", "rmse_1s_a": 0.020, "rmse_1s_corrected": 0.0208,
                            "rmse_1s_b": 0.0210},
                           {"sortie": "s1", "rmse_1s_a": 0.010, "rmse_1s_corrected": 0.012,
                            "rmse_1s_b": 0.005},
                           {"sortie": "s2", "rmse_1s_a": 0.010, "rmse_1s_corrected": 0.008,
                            "rmse_1s_b": 0.007}]}
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"command": "c", "cases": {"x/t": case}}))
    doc = bench.merged([path])
    score = doc["cases"]["x/t"]["score"]
    assert score["sorties_worse_than_term"] == ["s1"] and score["n_sorties_worse_than_term"] == 1
    assert "n_sorties_worse_than_term" in doc["definitions"]


def test_merge_keeps_every_airframe_of_its_files_unless_told(bench, tmp_path, capsys):
    """``--merge`` without ``--airframes`` keeps an airframe file's cases (a T-28 run was
    silently dropped when the default list of four filtered the merge); with it, only those;
    a merge that keeps nothing is refused in one line and writes nothing."""
    case = {"airframe": "examples/alfa_t28.toml", "score": {}, "per_sortie": []}
    run = tmp_path / "t28.json"
    run.write_text(json.dumps({"command": "c", "cases": {"alfa_t28/power": case}}))
    out = tmp_path / "merged.json"
    assert bench.main(["--merge", str(run), "--out", str(out)]) == 0
    assert list(json.loads(out.read_text())["cases"]) == ["alfa_t28/power"]
    empty = tmp_path / "empty.json"
    with pytest.raises(SystemExit):
        bench.main(["--merge", str(run), "--airframes", "aerosonde", "--out", str(empty)])
    assert "no case of aerosonde" in capsys.readouterr().err and not empty.exists()
