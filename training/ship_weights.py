"""The exact recipe of the shipped weights (``uavdyn/learned/shipped/``): the datasets and the
training commands, run in order. ``python -m training.ship_weights --out DIR`` writes the
weight files into ``DIR`` (copy them into the package to re-ship).

Training stops on a wall-clock budget, so the epoch count, and the last digits of the weights,
depend on the machine's speed and load.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from uavdyn.cli import main as cli_main

DATA = {  # airframe -> generate-data options
    "aerosonde": ["--sorties", "40", "--duration", "30", "--turbulent-fraction", "0",
                  "--seed", "1"],
    "f450": ["--sorties", "40", "--duration", "30", "--turbulent-fraction", "0", "--seed", "1"],
}
RUNS = {  # weight file stem -> train options (besides airframe, dataset and output)
    "{af}_improved": ["--lowpass-hz", "10", "--rollout-weight", "5", "--rollout-horizon", "50"],
    "{af}_paper": ["--lowpass-hz", "10", "--rollout-weight", "5", "--rollout-horizon", "50",
                   "--formulation", "paper"],
    "{af}_improved_reference": ["--target", "reference"],
}


def commands(out: Path, data_root: Path) -> list[list[str]]:
    """Every ``uavdyn`` command of the recipe, in order."""
    cmds = []
    for af, opts in DATA.items():
        data = data_root / f"emu_{af}_calm"
        cmds.append(["generate-data", "--airframe", af, *opts, "--out", str(data)])
        for stem, train_opts in RUNS.items():
            name = stem.format(af=af)
            cmds.append(["train", "--airframe", af, "--dataset", str(data), *train_opts,
                         "--out", str(out / f"{name}.npz")])
    return cmds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for the weight files")
    parser.add_argument("--data", default="results/ship_data", help="folder for the datasets")
    parser.add_argument("--dry-run", action="store_true", help="print the commands only")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    for cmd in commands(Path(args.out), Path(args.data)):
        print("uavdyn " + " ".join(cmd), flush=True)
        if not args.dry_run:
            code = cli_main(cmd)
            if code:
                return code
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
