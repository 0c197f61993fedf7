"""The exact recipe of the shipped safe corrections (``uavdyn/learned/shipped/<preset>_safe.npz``
and the identified airframe each was trained on, ``<preset>_identified.toml``).

It runs the functions ``uavdyn reproduce --retrain`` runs, with the same data and settings: the
dataset of the shipped recipe, identification of the physics on its calm train sorties
(:func:`uavdyn.experiments.reproduce.identify_physics`), then the safe correction with the
default :class:`uavdyn.learned.safe.SafeConfig` on top of the identified airframe
(:func:`uavdyn.experiments.reproduce.obtain_weights`). Training ends by epochs and patience,
not by wall-clock time, so a re-run gives the same weights up to the last floating-point digits
of another CPU.

``python -m training.ship_safe --out DIR`` writes, per preset, ``DIR/<preset>_safe.npz``,
``<preset>_safe_history.json``/``.png`` and ``<preset>_identified.toml``; copy them into
``uavdyn/learned/shipped/`` to re-ship.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from uavdyn.airframes import load_airframe
from uavdyn.experiments.reproduce import (
    ReproduceConfig,
    dataset_for,
    identify_physics,
    obtain_weights,
)
from uavdyn.integrate import cache_dir

PRESETS = {"fixed_wing": "aerosonde", "quadrotor": "f450"}


def ship(out: Path, kinds: list[str], progress: bool = True, quick: bool = False
         ) -> list[Path]:
    """Identify and train every preset of ``kinds``; returns the files written into ``out``
    (``quick``: the small datasets and short training of the test pipeline, a smoke run)."""
    config = ReproduceConfig(out=str(out), retrain=True, progress=progress, quick=quick)
    written = []
    for kind in kinds:
        nominal = load_airframe(PRESETS[kind])
        ds = dataset_for(kind, config)
        identified, summary = identify_physics(nominal, ds, config, print)
        if identified is None:
            raise SystemExit(f"{nominal.name}: {summary['missing']}")
        weights = obtain_weights(identified, ds, "improved", config, print)
        history = out / "weights" / f"{identified.name}_improved_history.json"
        pairs = [(out / "identified" / f"{nominal.name}.toml",
                  out / f"{nominal.name}_identified.toml"),
                 (history, out / f"{nominal.name}_safe_history.json"),
                 (history.with_suffix(".png"), out / f"{nominal.name}_safe_history.png")]
        if weights is not None:
            pairs.append((weights, out / f"{nominal.name}_safe.npz"))
        else:
            print(f"{nominal.name}: the correction was not kept (see {history}); the physics "
                  "ships alone")
        for src, dst in pairs:
            if src.exists():
                shutil.copyfile(src, dst)
                written.append(dst)
        _drop_machine_paths(out / f"{nominal.name}_identified.toml")
    return written


def _drop_machine_paths(path: Path) -> None:
    """The shipped airframe file names its dataset by cache key, not by this machine's path."""
    if path.exists():
        text = path.read_text().replace(str(cache_dir()).rstrip("/") + "/", "<uavdyn cache>/")
        path.write_text(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for the shipped files")
    parser.add_argument("--kinds", nargs="+", default=list(PRESETS), choices=list(PRESETS))
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run on the small test datasets (not the shipped recipe)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    for path in ship(Path(args.out), args.kinds, progress=not args.quiet, quick=args.quick):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
