"""Measure a flight-test campaign imported in one call (issue 41 items 1 and 6) and write the
page ``docs/benchmarks/campaign_import.md``.

The campaign is synthetic (``tests/campaign_flights.py``): six-degree-of-freedom flights of the
example trainer (``examples/trainer.toml``, not a preset; the truth's pitch-moment and lift
derivatives changed) with 20-45 deg coordinated turns, climbs, wind, turbulence and noise,
written as the generic CSV at 50 Hz and 20 Hz. The commands a user would type are run:

    uavdyn import-log FLIGHTS/ --kind fixed_wing --split-by log --out DS
    uavdyn identify --airframe examples/trainer.toml --dataset DS --params ... --out ID.toml
    uavdyn evaluate --airframe examples/trainer.toml --identified ID.toml --dataset DS ...
    uavdyn evaluate ... --all-sorties

and the share of flight time used, the per-segment and pooled 1 s pitch RMSE (nominal ->
identified) on the later flight held out, and the one-segment import are reported::

    PYTHONPATH=. python analysis/campaign_acceptance.py --out docs/benchmarks
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
AIRFRAME = ROOT / "examples/trainer.toml"
# the trim terms and the moment and lift derivatives the truth changes (tests/campaign_flights)
PARAMS = "C_m_0,C_m_alpha,C_m_q,C_m_delta_e,C_L_0,C_L_alpha,C_D_0"
RATES = (50.0, 20.0, 50.0, 20.0)


def run(argv: list[str]) -> tuple[int, str]:
    """One ``uavdyn`` command in this process: its exit code and everything it printed."""
    from uavdyn.cli.app import main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        code = main([str(a) for a in argv])
    if code != 0:
        raise SystemExit(f"uavdyn {' '.join(map(str, argv))} failed:\n{buffer.getvalue()}")
    return code, buffer.getvalue()


def overlap(a: list, b: list) -> float:
    """Seconds two interval lists share."""
    return sum(max(0.0, min(y, d) - max(x, c)) for x, y in a for c, d in b)


def shares(flights: list, manifest: dict) -> list[dict]:
    """Per log: flight time, kept, truly wings-level kept, kept beyond |bank| <= 10 deg."""
    rows = []
    for flight, log in zip(flights, manifest["logs"]):
        kept = [e["flight_time_s"] for e in manifest["sorties"] if e["log"] == log["name"]]
        level = flight.level
        rows.append({"log": log["name"], "rate": log["own_rate_hz"], "duration": flight.duration,
                     "kept": sum(b - a for a, b in kept), "segments": len(kept),
                     "level": sum(b - a for a, b in level), "level_kept": overlap(kept, level),
                     "beyond_10deg": sum(b - a for a, b in kept)
                     - overlap(kept, flight.within_bank(10.0))})
    return rows


def per_segment(result: dict) -> list[tuple[str, float, float]]:
    """(segment, nominal, identified) 1 s pitch RMSE of each scored sortie."""
    cells: dict[str, dict[str, float]] = {}
    for row in result["ladder"]["per_sortie"]:
        h = row["horizon_1s"]
        cells.setdefault(row["sortie"], {})[row["model"]] = float(np.sqrt(h["sse"] / h["n"]))
    return [(s, c["nominal physics"], c["identified physics"]) for s, c in sorted(cells.items())]


def pooled(result: dict) -> tuple[float, float]:
    head = next(h for h in result["ladder"]["headline"] if h["mode"] == "horizon_1s")
    return (head["models"]["nominal physics"]["rmse"],
            head["models"]["identified physics"]["rmse"])


def page(rows, seg, pool, all_scored, one_line, import_out, took) -> str:
    total = sum(r["duration"] for r in rows)
    kept = sum(r["kept"] for r in rows)
    level = sum(r["level"] for r in rows)
    level_kept = sum(r["level_kept"] for r in rows)
    lines = ["# A flight-test campaign in one import", "",
             "Produced by `PYTHONPATH=. python analysis/campaign_acceptance.py "
             "--out docs/benchmarks` "
             f"({took:.0f} s). Synthetic six-degree-of-freedom flights of the example trainer "
             "(`tests/campaign_flights.py`: 20-45 deg coordinated turns, survey climbs and "
             "descents, 3-2-1-1 elevator inputs, a 3.6 m/s wind, Dryden turbulence, sensor "
             "noise), written as the generic CSV at 50 Hz and 20 Hz and imported by one "
             "`uavdyn import-log FLIGHTS/ --kind fixed_wing --split-by log` call. The flights' "
             "turns do not act on the pitch plane (see the generator's docstring), so the "
             "turning flight is cut, as `import-log` does today.", "",
             "## Share of flight time used", "",
             "| log | logged at | flight (s) | segments | kept (s) | kept share | truly wings "
             "level (s) | of it kept | kept, not truly level (s) | kept beyond 10 deg bank "
             "(s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows + [None]:
        r = r or {"log": "**all**", "rate": "resampled to 20", "duration": total,
                  "segments": sum(x["segments"] for x in rows), "kept": kept, "level": level,
                  "level_kept": level_kept,
                  "beyond_10deg": sum(x["beyond_10deg"] for x in rows)}
        lines.append(f"| {r['log']} | {r['rate']:g} Hz | {r['duration']:.0f} | "
                     f"{r['segments']} | {r['kept']:.1f} | "
                     f"{100 * r['kept'] / r['duration']:.1f} % | {r['level']:.1f} | "
                     f"{100 * r['level_kept'] / r['level']:.2f} % | "
                     f"{r['kept'] - r['level_kept']:.1f} | {r['beyond_10deg']:.2f} |"
                     if isinstance(r["rate"], float) else
                     f"| {r['log']} | {r['rate']} Hz | {r['duration']:.0f} | {r['segments']} | "
                     f"{r['kept']:.1f} | {100 * r['kept'] / r['duration']:.1f} % | "
                     f"{r['level']:.1f} | {100 * r['level_kept'] / r['level']:.2f} % | "
                     f"{r['kept'] - r['level_kept']:.1f} | {r['beyond_10deg']:.2f} |")
    lines += ["", "Kept but not truly wings level is the roll ramp in and out of each turn "
              "below the 10 deg threshold (30 deg/s roll rate: 0.33 s each side); nothing was "
              "kept beyond it but the roll noise's hundredths of a second.", "",
              "## 1 s pitch RMSE on the later flight held out (`--split-by log`)", "",
              f"`uavdyn identify --airframe examples/trainer.toml --params {PARAMS}` on the "
              "train logs, then `uavdyn evaluate --identified` on the test log "
              "(validation: the third log).", "",
              "| test segment | nominal (rad) | identified (rad) | ratio |", "|---|---|---|---|"]
    for name, nom, ident in seg:
        lines.append(f"| {name} | {nom:.4f} | {ident:.4f} | {ident / nom:.2f} |")
    lines += [f"| **pooled** | {pool[0]:.4f} | {pool[1]:.4f} | {pool[1] / pool[0]:.2f} |", "",
              "## Other checks", "",
              f"- `evaluate --all-sorties` scored {all_scored}.",
              f"- A one-segment log (18 s, no turn) imports without `--fractions`: "
              f"`{one_line}`.", "", "The import's own summary:", "", "```",
              *import_out.strip().splitlines()[-3:-1], "```", ""]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="folder for the page")
    parser.add_argument("--duration", type=float, default=360.0, help="s per flight")
    args = parser.parse_args()
    from tests.campaign_flights import campaign_flight, write_campaign

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        flights = [campaign_flight(k, args.duration, rate)
                   for k, rate in enumerate(RATES, start=1)]
        write_campaign(work / "flights", flights)
        data = work / "campaign"
        _, import_out = run(["import-log", work / "flights", "--kind", "fixed_wing",
                             "--split-by", "log", "--out", data])
        manifest = json.loads((data / "manifest.json").read_text())
        rows = shares(flights, manifest)
        fitted = work / "trainer_id.toml"
        _, identify_out = run(["identify", "--airframe", AIRFRAME, "--dataset", data,
                               "--params", PARAMS, "--out", fitted, "--quiet"])
        print(identify_out)
        run(["evaluate", "--airframe", AIRFRAME, "--identified", fitted, "--dataset", data,
             "--out", work / "eval.json"])
        result = json.loads((work / "eval.json").read_text())
        run(["evaluate", "--airframe", AIRFRAME, "--dataset", data, "--all-sorties",
             "--out", work / "all.json"])
        every = json.loads((work / "all.json").read_text())
        all_scored = (f"{len(every['sorties'])} of {len(manifest['sorties'])} sorties "
                      f"({every['split']})")
        one = write_campaign(work / "one", [campaign_flight(7, 18.0, 50.0)])[0]
        _, one_out = run(["import-log", one, "--kind", "fixed_wing", "--out", work / "one_ds"])
        one_line = next(line for line in one_out.splitlines() if line.startswith("split:"))
        text = page(rows, per_segment(result), pooled(result), all_scored, one_line,
                    import_out, time.perf_counter() - start)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "campaign_import.md").write_text(text)
        print(f"wrote {args.out / 'campaign_import.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
