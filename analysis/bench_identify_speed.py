"""Speed of one output-error identification, the cold compile included: the fixed-wing case of
the identification issue (11 training sorties of 30 s at 100 Hz, the pipeline's 9 fixed-wing
parameters), on emulated data of a non-preset airframe (``examples/trainer.toml``: a ~2 m
trainer). Prints JSON: wall time with a cold compile cache (nothing reused) and again with
the libraries cached, the CPU time of this process (the compiler's is not in it), the solver's
iterations, the largest library the fit compiled, the machine and its load, and
each estimate with its standard errors so a change of method can be checked for equal results.

Usage: ``python analysis/bench_identify_speed.py [--airframe FILE] [--sorties 11]
[--duration 30] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from uavdyn.evaluation.emit import emit_json

REPO = Path(__file__).resolve().parents[1]


def _largest_library(folder: Path) -> dict:
    libs = [p for p in folder.rglob("*") if p.is_file() and p.suffix in (".so", ".dylib", ".dll")]
    if not libs:
        return {"name": None, "bytes": 0, "count": 0}
    big = max(libs, key=lambda p: p.stat().st_size)
    return {"name": big.name, "bytes": big.stat().st_size, "count": len(libs),
            "total_bytes": sum(p.stat().st_size for p in libs)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--airframe", default=str(REPO / "examples" / "trainer.toml"))
    ap.add_argument("--sorties", type=int, default=11, help="training sorties")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per sortie")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="uavdyn-bench-id-") as tmp:
        os.environ["UAVDYN_CACHE"] = str(Path(tmp) / "cache")  # cold: before uavdyn loads
        from uavdyn.airframes import load_airframe
        from uavdyn.emulation import Recipe, generate_dataset
        from uavdyn.experiments.common import IDENTIFY_PARAMS
        from uavdyn.flightdata import load_dataset
        from uavdyn.identify import identify

        airframe = load_airframe(args.airframe)
        names = list(IDENTIFY_PARAMS[airframe.kind])
        data = Path(tmp) / "data"
        # more sorties than needed so the train split holds args.sorties of them
        recipe = Recipe(airframe=args.airframe, sorties=int(args.sorties * 1.5) + 2,
                        duration_s=args.duration, seed=0)
        generate_dataset(recipe, data, progress=False)
        ds = load_dataset(data)
        train = ds.split("train")[:args.sorties]
        validation = ds.split("validation")
        load = os.getloadavg()[0]
        wall0, cpu0 = time.perf_counter(), time.process_time()
        result = identify(airframe, train, validation, names, progress=False)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        library = _largest_library(Path(tmp) / "cache")
        wall0 = time.perf_counter()  # again: every library is in the disk cache now
        again = identify(airframe, train, validation, names, progress=False)
        wall_warm = time.perf_counter() - wall0
    out = {
        "airframe": airframe.name, "train_sorties": len(train), "duration_s": args.duration,
        "parameters": names, "wall_s": wall, "cpu_s_this_process": cpu,
        "wall_s_warm_cache": wall_warm,
        "warm_equals_cold": [e.value for e in again.estimates] == [e.value for e in
                                                                   result.estimates],
        "iterations": result.iterations, "windows": result.fit.get("windows"),
        "largest_library": library,
        "estimates": [{"name": e.name, "value": e.value, "std_error": e.std_error,
                       **({"std_error_corrected": e.std_error_corrected}
                          if hasattr(e, "std_error_corrected") else {})}
                      for e in result.estimates],
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "load_1min_before": load, "load_1min_after": os.getloadavg()[0]},
        "command": "python analysis/bench_identify_speed.py",
    }
    emit_json(out, args.out)


if __name__ == "__main__":
    main()
