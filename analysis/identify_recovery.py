"""Recovery of known parameters by ``uavdyn identify`` with the truth known: emulated sorties of
an airframe (default the non-preset ``examples/trainer.toml``, flown closed loop by the
emulator's autopilot, sensor noise on, a share of turbulent sorties), identified with the
pipeline's parameter list, each estimate compared with the value the emulator flew (the
airframe file's, and the truth model's own alpha-dot derivatives and lags from the dataset's
manifest). Prints JSON and a table: estimate, Cramer-Rao and corrected standard errors, truth,
the distance to the truth in corrected standard errors, and the flags. The truth model is
richer than the identified structure (dynamic stall, actuator rate limits), so a parameter
may be biased; the test of honesty is that it is then flagged or its corrected interval is
wide enough.

Usage: ``python analysis/identify_recovery.py [--airframe FILE] [--sorties 30]
[--duration 30] [--params a,b,c] [--max-windows 120] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# the truth model's names for the terms the baseline model calls otherwise
TRUTH_KEYS = {"C_m_alpha_dot": "C_m_alphadot", "C_L_alpha_dot": "C_L_alphadot",
              "tau_elevator": "tau_elevator", "tau_throttle": "tau_throttle",
              "tau_rotor": "tau_rotor"}
# the model's slew time is 1 / the truth model's actuator rate limit
SLEW_KEYS = {"slew_elevator": "rate_elevator", "slew_throttle": "rate_throttle"}


def truth_of(name: str, airframe, truth: dict) -> float:
    """The value the emulator flew for parameter ``name``."""
    if SLEW_KEYS.get(name) in truth:
        return 1.0 / float(truth[SLEW_KEYS[name]])
    key = TRUTH_KEYS.get(name)
    if key is not None and key in truth:
        return float(truth[key])
    return float(getattr(airframe.params, name))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--airframe", default=str(REPO / "examples" / "trainer.toml"))
    ap.add_argument("--sorties", type=int, default=30, help="sorties generated")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--params", help="comma-separated (default: the pipeline's list)")
    ap.add_argument("--data", help="dataset folder to use (default: generate a new one)")
    ap.add_argument("--max-windows", type=int, default=120,
                    help="windows the fit uses at most (0: all)")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args()

    from uavdyn.airframes import load_airframe
    from uavdyn.emulation import Recipe, generate_dataset
    from uavdyn.experiments.common import IDENTIFY_PARAMS
    from uavdyn.flightdata import load_dataset
    from uavdyn.identify import identify

    airframe = load_airframe(args.airframe)
    names = args.params.split(",") if args.params else list(IDENTIFY_PARAMS[airframe.kind])
    with tempfile.TemporaryDirectory(prefix="uavdyn-recovery-") as tmp:
        data = Path(args.data) if args.data else Path(tmp) / "data"
        if not args.data:
            generate_dataset(Recipe(airframe=args.airframe, sorties=args.sorties,
                                    duration_s=args.duration, seed=0), data, progress=False)
        ds = load_dataset(data)
        truth = json.loads((data / "manifest.json").read_text()).get("truth", {})
        t0 = time.perf_counter()
        result = identify(airframe, ds.train, ds.validation, names, progress=False,
                          max_windows=args.max_windows or None)
        wall = time.perf_counter() - t0
    rows = []
    for e in result.estimates:
        true = truth_of(e.name, airframe, truth)
        se = e.std_error_corrected
        rows.append({"name": e.name, "value": e.value, "truth": true, "nominal": e.nominal,
                     "std_error_cramer_rao": e.std_error, "std_error_corrected": se,
                     "error_in_corrected_se": abs(e.value - true) / se if se > 0 else math.inf,
                     "error_in_cramer_rao_se": (abs(e.value - true) / e.std_error
                                                if e.std_error > 0 else math.inf),
                     "determined": e.determined, "flags": e.flags()})
    out = {"airframe": airframe.name, "train_sorties": len(ds.train),
           "duration_s": args.duration, "parameters": names, "wall_s": wall,
           "estimates": rows, "diagnostics": result.diagnostics,
           "confident_and_wrong": [r["name"] for r in rows
                                   if r["determined"] and r["error_in_corrected_se"] > 3],
           "max_windows": args.max_windows or None,
           "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                       "load_1min": os.getloadavg()[0]},
           "command": " ".join(["python analysis/identify_recovery.py", *sys.argv[1:]])}
    print(f"{'name':>14} {'value':>10} {'truth':>10} {'CR s.e.':>9} {'corr. s.e.':>10} "
          f"{'|err|/s.e.':>10}  flags")
    for r in rows:
        print(f"{r['name']:>14} {r['value']:10.4g} {r['truth']:10.4g} "
              f"{r['std_error_cramer_rao']:9.2g} {r['std_error_corrected']:10.2g} "
              f"{r['error_in_corrected_se']:10.2f}  {'; '.join(r['flags']) or '-'}")
    print(json.dumps(out, indent=2))
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
