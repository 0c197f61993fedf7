"""The learned correction on an imported turning-flight campaign, against the physical term the
data support (issue 40, measured the way a user meets it), written as
``docs/benchmarks/turning_correction.{json,md}``.

The campaign is :mod:`tests.turning_flights` (the example trainer, not a preset, with its
truth's moment and lift derivatives changed; 20-45 deg coordinated turns the pitch-plane
dynamics feel, climbs and descents, wind, Dryden turbulence, sensor noise; the generic
six-degree-of-freedom CSV at 50 and 20 Hz), the same four flights as
``analysis/turning_acceptance.py`` plus flights of other seeds the pipeline never sees. The
commands a user would type are run::

    uavdyn import-log FLIGHTS/ --kind fixed_wing --split-by log --turns --out DS
    uavdyn import-log UNSEEN/ --kind fixed_wing --split-by log --turns --fractions 0,0,1 ...
    uavdyn identify --airframe examples/trainer.toml --dataset DS --params P --out A.toml
    uavdyn identify ... --params P,C_m_alpha_dot --out B.toml      (the term, below)
    uavdyn train --airframe A.toml --dataset DS --seed S --out W.npz   (seeds 0, 1, 2)
    uavdyn evaluate --airframe examples/trainer.toml --identified A.toml --weights W.npz ...

``C_m_alpha_dot`` is the one term ``uavdyn identify --structure auto`` keeps on these flights
(measured on this campaign: validation 1 s pitch RMSE 0.01351 -> 0.01257 rad; every other
candidate below the 2 % it asks for; ``--structure-auto`` re-runs that search here, about
15 min). Scored like the knockout
benchmark (``analysis/bench_knockout.py``, its :func:`share_statistics`) on the held-out test
log and on the unseen flights, whole and cut into wings-level and turning stretches of at
least 3 s (``turning_acceptance.stretches``): the 1 s pitch RMSE of (a) the identified
physics, the correction on it and (b) the physics identified with the term; the share of (a)'s
error the correction removes, the share of the term's gain it recovers, both with 95 %
bootstrap intervals over stretches, and the stretches it makes more than 2 % worse::

    PYTHONPATH=. python analysis/turning_correction.py --out docs/benchmarks

``--airframe FILE`` flies the same campaign with another airframe's truth (the file needs
``Jx, Jz, Jxz`` for the turns; ``examples/alfa_t28.toml``), written as
``turning_correction[_stability_X]_<name>``; with ``--structure-auto`` (b) is what the
structure search keeps on that campaign, the term to recover unchosen by hand.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
import time
from pathlib import Path

from bench_knockout import machine, share_statistics  # the script's own folder is on the path
from turning_acceptance import AIRFRAME, PARAMS, RATES, run, stretches

from uavdyn.evaluation import SortieError
from uavdyn.learned.stability import STABILITY_TRIMS
from uavdyn.outputs import write_text_atomic

TERM = "C_m_alpha_dot"
MODELS = {"a": "identified physics", "corrected": "corrected"}
LABELS = {"test_log": "test log", "unseen_flights": "unseen flights",
          "test_log_stretches": "test log, stretches",
          "unseen_flights_stretches": "unseen flights, stretches"}


def train(work: Path, fitted: Path, data: Path, seed: int, options: list[str]) -> dict:
    """``uavdyn train`` at its defaults (but ``options``) and one seed: whether a correction
    was kept, the weight file, the wall time and the training's own verdict line."""
    from uavdyn.cli.app import main

    out = work / f"correction_seed{seed}.npz"
    buffer = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        code = main(["train", "--airframe", str(fitted), "--dataset", str(data), "--seed",
                     str(seed), *options, "--out", str(out), "--quiet"])
    seconds = time.perf_counter() - t0
    text = buffer.getvalue()
    verdict = next((line.strip() for line in text.splitlines()
                    if line.strip().startswith(("kept", "no correction", "not kept"))), "")
    run = next((line.strip() for line in text.splitlines() if "best epoch" in line), "")
    if code != 0 and out.exists():
        raise SystemExit(f"uavdyn train exited {code} but wrote {out}:\n{text}")
    return {"seed": seed, "kept": out.exists(), "weights": out if out.exists() else None,
            "train_s": seconds, "verdict": verdict or text.strip().splitlines()[-1],
            "run": run}  # the network, its best epoch and how the run ended (a repair too)


def errors(result: dict, model: str) -> list[SortieError]:
    """One model's 1 s pitch errors per scored sortie of an ``evaluate`` JSON, sorted by
    sortie (a sortie whose prediction diverged has an infinite sum)."""
    rows = sorted((r for r in result["ladder"]["per_sortie"] if r["model"] == model),
                  key=lambda r: r["sortie"])
    out = []
    for r in rows:
        h = r.get("horizon_1s") or {}
        sse = h.get("sse")
        out.append(SortieError(r["sortie"], math.inf if sse is None else float(sse),
                               int(h.get("n") or 0)))
    return out


def evaluate(work: Path, data: Path, fitted: Path, weights: Path | None, tag: str,
             airframe: str = AIRFRAME) -> dict:
    """``uavdyn evaluate`` of one identified airframe (and correction) on ``data`` against the
    nominal ``airframe``."""
    out = work / f"eval_{tag}.json"
    run(["evaluate", "--airframe", airframe, "--identified", fitted, "--dataset", data,
         *(["--weights", weights] if weights is not None else []), "--out", out])
    return json.loads(out.read_text())


def score(a_run: dict, b_run: dict) -> dict:
    """(a), the correction and (b) on every test sortie: the knockout's share statistics
    (no correction kept: (a) and (b) only)."""
    errs = {"a": errors(a_run, MODELS["a"]), "b": errors(b_run, MODELS["a"])}
    if any(r["model"] == MODELS["corrected"] for r in a_run["ladder"]["per_sortie"]):
        errs["corrected"] = errors(a_run, MODELS["corrected"])
    stats = share_statistics(errs)
    stats["per_sortie"] = [
        {"sortie": e.sortie, "rmse_1s_a": e.rmse, "rmse_1s_b": errs["b"][i].rmse,
         **({"rmse_1s_corrected": errs["corrected"][i].rmse} if "corrected" in errs else {})}
        for i, e in enumerate(errs["a"])]
    return stats


def campaign(work: Path, duration: float, unseen_seeds: list[int],
             airframe: str = AIRFRAME) -> dict:
    """Write the flights of ``airframe``'s truth and import them: the campaign's dataset, the
    unseen flights' dataset (all test) and both cut into wings-level and turning stretches."""
    from tests.campaign_flights import write_campaign
    from tests.turning_flights import turning_flight
    from uavdyn.airframes import load_airframe

    nominal = load_airframe(airframe)
    write_campaign(work / "flights", [turning_flight(k, duration, rate, nominal=nominal)
                                      for k, rate in enumerate(RATES, start=1)])
    write_campaign(work / "unseen", [turning_flight(k, duration, 50.0, nominal=nominal)
                                     for k in unseen_seeds], stem="unseen")
    ds, unseen = work / "ds", work / "ds_unseen"
    run(["import-log", work / "flights", "--kind", "fixed_wing", "--split-by", "log",
         "--turns", "--out", ds])
    run(["import-log", work / "unseen", "--kind", "fixed_wing", "--split-by", "log", "--turns",
         "--fractions", "0,0,1", "--out", unseen])
    return {"test_log": ds, "unseen_flights": unseen,
            "test_log_stretches": stretches(ds, work / "st_test")[0],
            "unseen_flights_stretches": stretches(unseen, work / "st_unseen")[0]}


def identify_both(work: Path, data: Path, structure_auto: bool, airframe: str = AIRFRAME
                  ) -> tuple[Path, Path, dict]:
    a, b = work / "a.toml", work / "b.toml"
    t0 = time.perf_counter()
    run(["identify", "--airframe", airframe, "--dataset", data, "--params", PARAMS, "--out", a,
         "--quiet"])
    seconds = {"a": time.perf_counter() - t0}
    t0 = time.perf_counter()
    extra = ["--structure", "auto"] if structure_auto else []
    params = PARAMS if structure_auto else f"{PARAMS},{TERM}"
    run(["identify", "--airframe", airframe, "--dataset", data, "--params", params, *extra,
         "--out", b, "--quiet"])
    seconds["b"] = time.perf_counter() - t0
    return a, b, seconds


def train_options(args) -> list[str]:
    """The ``uavdyn train`` options this run gives (none: train's defaults)."""
    out = [] if args.stability_trims is None else ["--stability-trims", args.stability_trims]
    return out + ([] if args.steady_gate is None else ["--steady-gate", args.steady_gate])


def out_stem(args) -> str:
    """The file name: the defaults', or the options'; another airframe's with its name."""
    stem = "turning_correction"
    if args.stability_trims is not None:
        stem += f"_stability_{args.stability_trims}"
    if args.steady_gate is not None:
        stem += f"_steady_gate_{args.steady_gate}"
    return stem if is_default(args.airframe) else f"{stem}_{Path(args.airframe).stem}"


def is_default(airframe) -> bool:
    """Whether ``airframe`` names the example trainer's file (however it is written)."""
    return Path(airframe).resolve() == Path(AIRFRAME).resolve()


def shown(airframe) -> str:
    """An airframe file as the command line names it (the default relative to the root)."""
    return "examples/trainer.toml" if is_default(airframe) else str(airframe)


def command(args) -> str:
    """The command that writes this run's files into docs/benchmarks."""
    return ("PYTHONPATH=. python analysis/turning_correction.py --out docs/benchmarks"
            + ("" if is_default(args.airframe) else f" --airframe {args.airframe}")
            + (" --structure-auto" if args.structure_auto else "")
            + "".join(f" {o}" for o in train_options(args)))


def measure(args) -> dict:
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        sets = campaign(work, args.duration, args.unseen_seeds, args.airframe)
        a, b, id_seconds = identify_both(work, sets["test_log"], args.structure_auto,
                                         args.airframe)
        from uavdyn.airframes import load_airframe
        b_value = getattr(load_airframe(b).params, TERM, None)
        b_runs = {name: evaluate(work, data, b, None, f"b{i}", args.airframe)
                  for i, (name, data) in enumerate(sets.items())}
        seeds = []
        for seed in args.seeds:
            t = train(work, a, sets["test_log"], seed, train_options(args))
            print(f"seed {seed}: {t['verdict']} ({t['train_s']:.0f} s)", flush=True)
            scored = {name: score(evaluate(work, data, a, t["weights"], f"s{seed}_{i}",
                                           args.airframe),
                                  b_runs[name])
                      for i, (name, data) in enumerate(sets.items())}
            seeds.append({k: v for k, v in t.items() if k != "weights"} | {"scores": scored})
    return {"benchmark": "turning_correction", "machine": machine(),
            "command": command(args),
            "airframe": f"{shown(args.airframe)} (truth: "
                        "tests.campaign_flights.truth_airframe)",
            "flights": {"campaign_seeds": [1, 2, 3, 4], "campaign_rates_hz": list(RATES),
                        "unseen_seeds": args.unseen_seeds, "duration_s": args.duration},
            "params_a": PARAMS, "term": TERM, "term_value_b": b_value,
            "b_from": "identify --structure auto" if args.structure_auto else
                      f"identify --params {PARAMS},{TERM} (the term --structure auto keeps)",
            "identify_s": id_seconds, "train_options": train_options(args), "seeds": seeds,
            "wall_s": time.perf_counter() - start}


def _interval(stats: dict, key: str) -> str:
    """A share with its bootstrap interval, or why it is not measurable."""
    value, interval = stats.get(key), stats.get(f"{key}_interval")
    if value is None:
        return stats.get(f"{key}_note", "n.m.")
    return f"{value:.2f} [{interval[0]:.2f}, {interval[1]:.2f}]" if interval else f"{value:.2f}"


def markdown(doc: dict) -> str:
    options = " ".join(doc["train_options"])
    name = doc["airframe"].split(" (")[0]
    other = name != shown(AIRFRAME)
    lines = ["# The correction on imported turning flights"
             + (f": {Path(name).stem}" if other else "")
             + (f" (train {options})" if options else ""), "",
             f"Written by `{doc['command']}` ({doc['wall_s'] / 60:.0f} min on a "
             f"{doc['machine']['cpu_count']}-core machine, load "
             f"{doc['machine']['load_average'][0]:.1f} at the start). "
             + (f"`{name}`'s" if other else "The example trainer's")
             + " turning campaign (`tests/turning_flights.py`: coordinated turns the pitch-plane "
             "dynamics feel, climbs, wind, turbulence, sensor noise), imported with `--turns`; "
             f"(a) identified with `{doc['params_a']}`, the correction trained on (a) at the "
             "defaults" + "".join(f" {o}" for o in doc["train_options"])
             + f", (b) identified with `{doc['term']}` too ({doc['b_from']}; "
             f"{doc['term']} = {doc['term_value_b']:.2f}). 1 s pitch RMSE (rad) on the held-out "
             "test log and on flights of other seeds the pipeline never saw, whole and in "
             "wings-level and turning stretches of at least 3 s.", "",
             "| seed | scored on | sorties | (a) | corrected | (b) with the term | removed share "
             "of (a) | recovered share of the term's gain | worse > 2 % (and than b) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for s in doc["seeds"]:
        if not s["kept"]:
            lines.append(f"| {s['seed']} | no correction kept | | | | | | | |")
        for name, st in s["scores"].items():
            err = st["err"]

            corrected = f"{err['corrected']:.5f}" if "corrected" in err else "-"
            worse = (f"{st['n_sorties_worse']} ({st.get('n_sorties_worse_than_term', '-')})"
                     if "n_sorties_worse" in st else "-")
            lines.append(f"| {s['seed']} | {LABELS[name]} | {st['sorties']} | {err['a']:.5f} | "
                         f"{corrected} | {err['b']:.5f} | {_interval(st, 'removed_share')} | "
                         f"{_interval(st, 'recovered_share')} | {worse} |")
    lines += ["", "Training: " + "; ".join(
        f"seed {s['seed']} {s['train_s']:.0f} s, {s['verdict']}"
        + (f" ({s['run']})" if s.get("run") else "") for s in doc["seeds"]), ""]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="folder for the JSON and page")
    parser.add_argument("--duration", type=float, default=360.0, help="s per flight")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2],
                        help="training seeds")
    parser.add_argument("--unseen-seeds", type=int, nargs="+", default=[11, 12],
                        help="seeds of the flights the pipeline never sees")
    parser.add_argument("--stability-trims", choices=STABILITY_TRIMS, default=None,
                        help="uavdyn train --stability-trims (default: train's own)")
    parser.add_argument("--steady-gate", choices=("on", "off"), default=None,
                        help="uavdyn train --steady-gate (default: train's own)")
    parser.add_argument("--airframe", default=AIRFRAME,
                        help="the nominal airframe whose truth flies the campaign (default "
                             "%(default)s; another needs Jx, Jz, Jxz for the turns)")
    parser.add_argument("--structure-auto", action="store_true",
                        help="(b) from identify --structure auto (about 15 min) instead of "
                             f"adding {TERM}")
    args = parser.parse_args()
    doc = measure(args)
    text = markdown(doc)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        stem = args.out / out_stem(args)
        write_text_atomic(stem.with_suffix(".json"), json.dumps(doc, indent=1, default=str)
                          + "\n")
        write_text_atomic(stem.with_suffix(".md"), text)
        print(f"wrote {stem}.json and .md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
