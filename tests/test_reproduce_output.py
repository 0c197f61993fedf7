"""What ``uavdyn reproduce`` prints at the end, on a small hand-made result (no pipeline run):
the headline table carries the result's own numbers, and the cache lines name existing folders
with their sizes."""

import re
from pathlib import Path

from uavdyn.cli.pipeline_commands import reproduce_summary
from uavdyn.experiments.report import fmt


def _entry(condition, sorties, rmse, worse):
    """One 1 s headline entry as :func:`uavdyn.experiments.ladder.headline` writes it."""
    names = [f"sortie_{k:03d}" for k in range(sorties)]

    def paired(n_worse):
        return {"ratios": {}, "worse": names[:n_worse], "worse_beyond_tolerance": [],
                "new_divergence": [], "tolerance": 0.1}

    return {"condition": condition, "mode": "horizon_1s", "label": "1 s", "sorties": sorties,
            "models": {m: {"rmse": r, "ci_low": r / 2, "ci_high": 2 * r, "sorties": sorties,
                           "diverged": 0, "level": 0.95}
                       for m, r in zip(("nominal physics", "identified physics", "corrected"),
                                       rmse)},
            "identified_vs_nominal": paired(worse[0]),
            "corrected_vs_identified": paired(worse[1])}


def _free_run(entry):
    """The free-run entry beside it, with other numbers (must not reach the table)."""
    return {**entry, "mode": "free_run", "label": "free run",
            "models": {m: {**v, "rmse": 99.0} for m, v in entry["models"].items()}}


def _result():
    calm = _entry("calm", 4, (0.0213, 0.0118, 0.00943), (1, 3))
    turb = _entry("turbulent", 3, (0.0532, 0.0411, 0.0387), (0, 2))
    return {"wall_s": 12.0, "size_bytes": 2_500_000,
            "airframes": [{"airframe": "aerosonde", "ladder": {"headline": [
                calm, _free_run(calm), turb, _free_run(turb)]}},
                {"airframe": "f450", "ladder": {"headline": [
                    {"condition": "calm", "missing": "no calm test sortie"}]}}]}


def test_the_table_carries_the_results_numbers(tmp_path, monkeypatch):
    monkeypatch.setenv("UAVDYN_CACHE", str(tmp_path / "compiled"))
    result = _result()
    text = reproduce_summary(result, tmp_path / "results", None)
    rows = {tuple(line.split()[:2]): line.split() for line in text.splitlines()
            if line.startswith(("aerosonde", "f450"))}
    for entry in result["airframes"][0]["ladder"]["headline"]:
        if entry["mode"] != "horizon_1s":
            continue
        row = rows[("aerosonde", entry["condition"])]
        assert row[2] == str(entry["sorties"])
        assert row[3:6] == [fmt(v["rmse"]) for v in entry["models"].values()]
        assert [float(row[k]) for k in (3, 4, 5)] == [
            float(f"{v['rmse']:.3g}") for v in entry["models"].values()]
        n = entry["sorties"]
        assert row[6:8] == [f"{len(entry['identified_vs_nominal']['worse'])}/{n}",
                            f"{len(entry['corrected_vs_identified']['worse'])}/{n}"]
    assert "99" not in " ".join(" ".join(r) for r in rows.values())  # free run kept out
    assert "missing: no calm test sortie" in " ".join(rows[("f450", "calm")])
    assert f"report: {tmp_path / 'results' / 'report.md'} (12 s, 2.5 MB written" in text


def test_the_cache_lines_name_existing_folders_with_their_sizes(tmp_path, monkeypatch):
    compiled, datasets = tmp_path / "compiled", tmp_path / "datasets"
    compiled.mkdir()
    (compiled / "lib.so").write_bytes(b"x" * 1_200_000)
    (datasets / "f450_abc").mkdir(parents=True)
    (datasets / "f450_abc" / "sortie_000.csv").write_bytes(b"x" * 3_400_000)
    monkeypatch.setenv("UAVDYN_CACHE", str(compiled))
    text = reproduce_summary(_result(), tmp_path / "results", str(datasets))
    found = {}
    for line in text.splitlines():
        m = re.match(r"\s+(compiled steps|datasets): (\S+) \((\d+\.\d) MB", line)
        if m:
            found[m[1]] = (m[2], float(m[3]))
    assert found == {"compiled steps": (str(compiled), 1.2), "datasets": (str(datasets), 3.4)}
    assert all(Path(p).is_dir() for p, _ in found.values())


def test_the_default_dataset_cache_is_inside_the_compile_cache(tmp_path, monkeypatch):
    compiled = tmp_path / "compiled"
    (compiled / "datasets").mkdir(parents=True)
    (compiled / "lib.so").write_bytes(b"x" * 1_000_000)
    (compiled / "datasets" / "a.csv").write_bytes(b"x" * 2_000_000)
    monkeypatch.setenv("UAVDYN_CACHE", str(compiled))
    text = reproduce_summary(_result(), tmp_path / "results", None)
    assert f"compiled steps: {compiled} (1.0 MB without the datasets in it" in text
    assert f"datasets: {compiled / 'datasets'} (2.0 MB" in text


def test_evaluate_writes_the_figure_its_report_refers_to(tmp_path, capsys):
    """``uavdyn evaluate`` writes ``<out>.png`` (1 s pitch RMSE per sortie and rung) beside
    its JSON and Markdown, and the Markdown links it."""
    from test_reproduce import PNG_MAGIC, write_hand_dataset

    from uavdyn.cli import main

    folder = write_hand_dataset(tmp_path / "hand", n_sorties=6, duration=4.0)
    out = tmp_path / "metrics.json"
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(folder),
                 "--out", str(out)]) == 0
    png = out.with_suffix(".png")
    assert png.read_bytes().startswith(PNG_MAGIC)
    assert "![1 s pitch RMSE per sortie](metrics.png)" in out.with_suffix(".md").read_text()
    assert str(png) in capsys.readouterr().out
    from uavdyn.outputs import REGISTRY  # the record of the single files uavdyn wrote here

    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([
        "hand", "metrics.json", "metrics.md", "metrics.png", REGISTRY])  # no temporary left


def test_a_headline_over_one_sortie_gives_no_interval():
    """A bootstrap over one sortie is that sortie again: its "interval" has no width and would
    read as certainty, so a one-sortie group states each figure alone and says why; a group
    of three keeps its intervals."""
    from uavdyn.experiments.report import headline_lines

    one, three = _entry("calm", 1, (0.03, 0.02, 0.01), (0, 0)), \
        _entry("turbulent", 3, (0.06, 0.05, 0.04), (1, 0))
    for entry in (one, three):
        entry["corrected_vs_identified"]["share_removed"] = {
            "share": 0.5, "ci_low": 0.5 if entry is one else 0.2,
            "ci_high": 0.5 if entry is one else 0.7}
    lines = headline_lines({"airframe": "trainer", "ladder": {"headline": [one, three]}})
    calm = next(line for line in lines if "calm" in line)
    turbulent = next(line for line in lines if "turbulent" in line)
    assert "one sortie, so no interval" in calm and "[" not in calm
    assert f"corrected {fmt(0.01)}." in calm and "share removed +0.50)" in calm
    assert "[95 % bootstrap over sorties]" in turbulent
    assert f"corrected {fmt(0.04)} [{fmt(0.02)}, {fmt(0.08)}]" in turbulent
    assert "95 % bootstrap [+0.20, +0.70]" in turbulent
