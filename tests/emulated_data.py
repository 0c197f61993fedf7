"""Small emulated datasets for the training tests: calm, noise-free sorties flown by the
emulator (:func:`uavdyn.emulation.generate_dataset`) on a 'truth' airframe whose parameters
differ from the model the correction is trained on, so there is a discrepancy to learn."""

from __future__ import annotations

import json
from pathlib import Path

from uavdyn.airframes import Airframe, to_toml_dict
from uavdyn.emulation import Recipe, generate_dataset

SYSID = ["sysid_doublet", "sysid_3211", "sysid_chirp"]


def emulated_dataset(folder: Path, truth: Airframe, sorties: int, duration_s: float,
                     seed: int = 11) -> Path:
    """Generate ``sorties`` system-identification sorties of ``truth`` into ``folder``, split
    into train and validation (the truth's airframe file is written beside it); returns
    ``folder``."""
    folder = Path(folder)
    data = to_toml_dict(truth)
    data["name"] = "truth"  # a file name: the truth airframe's own name may not be one
    path = folder.with_name(folder.name + "_truth.json")
    path.write_text(json.dumps(data))
    generate_dataset(Recipe(airframe=str(path), sorties=sorties, duration_s=duration_s,
                            seed=seed, missions=SYSID, turbulent_fraction=0.0, noise_scale=0.0,
                            split={"train": 0.7, "validation": 0.3, "test": 0.0}),
                     folder, workers=1, progress=False)
    return folder
