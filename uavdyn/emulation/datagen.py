"""Reproducible emulated flight-data sets: a recipe (airframe, sortie count, seed, missions,
turbulence, noise, split) in, a SPEC section 3 dataset folder out (manifest.json, one measured
CSV and one noise-free ``*_true.csv`` per sortie).

What the CSVs hold: ``u, w`` are air-relative body velocities (what the aerodynamics see:
inertial minus mean wind minus gust), ``q, theta`` inertial (gyro, attitude); SPEC section 3.
Turbulent sorties fly in a mean head wind, an inertial vector rotated into body axes with the
current pitch inside the emulator, plus Dryden turbulence in body axes (pitch-rate gust with
the airframe's span, :func:`uavdyn.emulation.emulator.gust_span`). The wind is not a CSV
column; each sortie's manifest entry records it (``wind_inertial_mps``, ``[W_x, W_z]``).

Every sortie draws from its own generator seeded by ``(seed, sortie index)``, so the files do not
depend on the number of worker processes or their scheduling: the same recipe gives
byte-identical files on the same platform (compiler and libm).

The missions follow the airframe's own envelope and ``[limits]`` and the truth model takes the
file's actuator lags (:mod:`uavdyn.emulation.missions`, :mod:`uavdyn.emulation.emulator`); the
manifest's ``truth`` records what the truth model used and the envelope. A mission the airframe
cannot fly (its envelope, or the sortie duration) is left out with one warning line naming it
and why, as is a mission one of whose sorties leaves the flight-data checks' ranges in every
draw; a recipe with no mission left is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.emulation.emulator import (
    Emulator,
    dryden_gusts,
    emulator_rollout,
    gust_span,
    truth_param_names,
)
from uavdyn.emulation.envelope import envelope
from uavdyn.emulation.missions import missions_for, plan_mission, unflyable_missions
from uavdyn.flightdata import (
    FlightDataError,
    Sortie,
    check_values,
    csv_columns,
    write_csv,
    write_manifest,
)
from uavdyn.flightdata.split import split_rule
from uavdyn.interrupts import CheckedBar
from uavdyn.outputs import output_folder

SPLITS = ("train", "validation", "test")


@dataclass
class Recipe:
    """Everything that determines a generated dataset."""

    airframe: str = "quadrotor"
    sorties: int = 100
    seed: int = 0
    duration_s: float = 60.0
    sample_rate_hz: float = 100.0
    internal_dt_s: float = 1e-3
    missions: list[str] = field(default_factory=list)  # empty: all missions of the kind
    turbulent_fraction: float = 0.5
    turbulence_intensity: tuple[float, float] = (0.5, 2.0)  # x light turbulence, uniform
    mean_wind_mps: tuple[float, float] = (0.0, 6.0)  # inertial head wind, turbulent sorties
    noise_scale: float = 1.0
    split: dict[str, float] = field(
        default_factory=lambda: {"train": 0.7, "validation": 0.15, "test": 0.15})
    # Truth-model overrides (keys of uavdyn.emulation.truth.TRUTH_DEFAULTS, e.g.
    # eta_slipstream): empty = the emulator's defaults, left out of to_dict (keys unchanged).
    truth: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The recipe as a plain dict (what is hashed, cached and recorded in a manifest): an
        empty ``truth`` is left out, so recipes from before it existed keep their keys."""
        out = asdict(self)
        if not out["truth"]:
            del out["truth"]
        return out

    @classmethod
    def from_json(cls, path: str | Path) -> Recipe:
        """Read a recipe file (unknown keys are an error, missing keys take defaults)."""
        data = json.loads(Path(path).read_text())
        data.pop("checksums", None)
        data.pop("comment", None)
        known = set(cls.__dataclass_fields__)
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"{path}: unknown recipe key(s) {sorted(unknown)}; expected "
                             f"{sorted(known)}")
        for key in ("turbulence_intensity", "mean_wind_mps"):
            if key in data:
                data[key] = tuple(data[key])
        return cls(**data)

    def validate(self, airframe: Airframe) -> None:
        """Reject impossible recipes with a message naming the field."""
        if self.sorties < 1:
            raise ValueError(f"sorties must be >= 1, got {self.sorties}")
        if not (self.duration_s > 0 and self.sample_rate_hz > 0):
            raise ValueError("duration_s and sample_rate_hz must be positive")
        if not 0.0 <= self.turbulent_fraction <= 1.0:
            raise ValueError(f"turbulent_fraction must be in [0, 1], got "
                             f"{self.turbulent_fraction}")
        if set(self.split) != set(SPLITS) or any(v < 0 for v in self.split.values()) \
                or abs(sum(self.split.values()) - 1.0) > 1e-9:
            raise ValueError(f"split must give non-negative fractions of {SPLITS} summing to 1, "
                             f"got {self.split}")
        if not isinstance(self.truth, dict):
            raise ValueError(f"truth must map truth-parameter names to numbers, got "
                             f"{type(self.truth).__name__}")
        known = truth_param_names(airframe.kind)
        unknown = [k for k in self.truth if k not in known]
        if unknown:
            raise ValueError(f"unknown truth parameter(s) {unknown} for {airframe.kind}; "
                             f"known: {', '.join(known)}")
        bad_values = {k: v for k, v in self.truth.items()
                      if isinstance(v, bool) or not isinstance(v, (int, float))
                      or not np.isfinite(v)}
        if bad_values:
            raise ValueError(f"truth value(s) must be finite numbers, got {bad_values}")
        allowed = missions_for(airframe.kind)
        bad = [m for m in self.missions if m not in allowed]
        if bad:
            raise ValueError(f"mission(s) {bad} do not apply to {airframe.kind}; "
                             f"choose from {allowed}")

    @property
    def split_fractions(self) -> tuple[float, float, float]:
        """The train, validation and test fractions, in :data:`SPLITS` order."""
        return tuple(self.split[s] for s in SPLITS)

    def mission_list(self, kind: str) -> list[str]:
        """The missions to cycle through (all of the kind's missions if none are named)."""
        return list(self.missions) or missions_for(kind)


GENERATOR_PACKAGES = ("uavdyn.emulation", "uavdyn.model", "uavdyn.airframes")


def generator_code_hash() -> str:
    """A hash of what decides a generated dataset besides its recipe: the package version
    and the source of the emulator, the model it builds on and the airframe presets. A cache
    keyed by the recipe alone would hand back stale data after any of them changed."""
    import uavdyn

    digest = hashlib.sha256(uavdyn.__version__.encode())
    for package in GENERATOR_PACKAGES:
        files = [f for f in resources.files(package).iterdir()
                 if f.is_file() and f.name.endswith((".py", ".toml", ".json"))]
        for f in sorted(files, key=lambda f: f.name):
            digest.update(f"{package}/{f.name}".encode())
            digest.update(f.read_bytes())
    return digest.hexdigest()[:16]


def assign_sorties(recipe: Recipe, kind: str) -> list[dict]:
    """Mission, condition (calm/turbulent) and split of every sortie. Missions cycle so each
    appears equally often; calm/turbulent and the split are stratified per mission, so every
    split holds every mission and both conditions where the counts allow."""
    rng = np.random.default_rng([recipe.seed, 0])
    missions = recipe.mission_list(kind)
    plan = [{"index": i, "mission": missions[i % len(missions)]} for i in range(recipe.sorties)]
    fractions = recipe.split_fractions
    for mission in missions:
        members = [p for p in plan if p["mission"] == mission]
        order = rng.permutation(len(members))
        n = len(members)
        n_turb = int(round(recipe.turbulent_fraction * n))
        counts = np.floor(np.array(fractions) * n).astype(int)
        for k in np.argsort(-(np.array(fractions) * n - counts))[: n - counts.sum()]:
            counts[k] += 1  # largest remainders
        bounds = np.cumsum(counts)
        for rank, j in enumerate(order):
            members[j]["split"] = SPLITS[int(np.searchsorted(bounds, rank, side="right"))]
        # Alternate calm/turbulent along the split order so each split gets both.
        for rank, j in enumerate(order):
            members[j]["condition"] = "turbulent" if (rank * n_turb) // n != \
                ((rank + 1) * n_turb) // n else "calm"
    empty = [split for split, fraction in zip(SPLITS, fractions)
             if fraction > 0 and not any(p["split"] == split for p in plan)]
    if empty:
        _split_over_the_dataset(plan, recipe, empty, len(missions))
    return plan


def _split_over_the_dataset(plan: list[dict], recipe: Recipe, empty: list[str],
                            n_missions: int) -> None:
    """Where too few sorties per mission leave a split empty, split the whole dataset by
    mission instead (the rule of ``uavdyn split --by mission``: its counts over all sorties,
    each mission spread over the parts, both conditions in validation and test where a swap
    can give them); each item then records ``split_by``. The flights do not depend on the
    split, so only the parts change. One warning line either way."""
    from uavdyn.flightdata.split import SplitError, assign_split

    per_mission = (f"{recipe.sorties} sorties over {n_missions} missions leave the "
                   f"'{empty[0]}' split empty when each mission is split alone")
    try:
        names = assign_split(plan, "mission", recipe.split_fractions, recipe.seed)
    except SplitError as exc:
        warnings.warn(f"{per_mission}, and so does splitting them all ({exc}): give more "
                      "sorties", UserWarning, stacklevel=3)
        return
    for item, name in zip(plan, names):
        item["split"], item["split_by"] = name, "mission"
    warnings.warn(f"{per_mission}; split over the whole dataset by mission instead (as "
                  "uavdyn split --by mission)", UserWarning, stacklevel=3)


MAX_ATTEMPTS = 5


def _fly_one(recipe: Recipe, airframe: Airframe, emulator: Emulator, item: dict, attempt: int):
    """Fly one sortie for draw ``attempt`` (0 keeps the original seed); the result must pass
    the loader's own checks, so a generated dataset always loads."""
    i = item["index"]
    seed = [recipe.seed, 1, i] + ([attempt] if attempt else [])
    rng = np.random.default_rng(seed)
    plan = plan_mission(item["mission"], airframe, recipe.duration_s, recipe.sample_rate_hz, rng)
    n = plan.references.shape[0]
    intensity = wind = 0.0
    gusts = wind_vector = None
    x0 = emulator.initial_state(plan.x0, plan.u0, plan.altitude)
    if item["condition"] == "turbulent":
        intensity = float(rng.uniform(*recipe.turbulence_intensity))
        wind = float(rng.uniform(*recipe.mean_wind_mps))
        wind_vector = np.array([-wind, 0.0])  # inertial head wind: the air moves towards -x
        speed_ref = plan.references[:, 3]
        # Frozen turbulence is carried by the mean wind, so the vehicle meets it at its
        # airspeed: the fixed wing's speed reference is an airspeed (pitot loop), the
        # multirotor's a ground speed (airspeed = ground speed + head wind).
        airspeed = np.abs(speed_ref) if airframe.kind == "fixed_wing" else \
            np.abs(speed_ref + wind)
        convection = max(float(airspeed.mean()), 5.0)
        gusts = dryden_gusts(rng, n, 1.0 / recipe.sample_rate_hz, convection, intensity,
                             gust_span(airframe))
        if airframe.kind == "fixed_wing":
            # The plan's trim state is air-relative: start in equilibrium with the air mass
            # (the multirotor's plan holds position over the ground and starts there).
            x0 = emulator.initial_state(plan.x0, plan.u0, plan.altitude, wind=wind_vector)
    flight = emulator.fly(x0, plan.references, gusts, rng, recipe.noise_scale,
                          wind=wind_vector)
    if not (np.all(np.isfinite(flight.true_states)) and np.all(np.isfinite(flight.controls))):
        raise RuntimeError(f"sortie {i} ({item['mission']}) produced non-finite values")
    for states in (flight.true_states, flight.measured_states):
        check_values(f"sortie {i} ({item['mission']}, draw {attempt})", airframe.kind,
                     flight.time, states, flight.controls, recipe.sample_rate_hz)
    return flight, plan, intensity, wind_vector, seed


def _generate_one(args: tuple[dict, dict, str]) -> dict:
    """Fly and write one sortie: its manifest entry, or ``{"index", "mission", "failed"}``
    if no draw of it passes the flight-data checks (the mission is then left out)."""
    recipe_dict, item, out = args
    recipe = Recipe(**recipe_dict)
    airframe = load_airframe(recipe.airframe)
    emulator = Emulator(airframe, truth=recipe.truth, sample_rate_hz=recipe.sample_rate_hz,
                        internal_dt=recipe.internal_dt_s)
    i = item["index"]
    last_error = None
    for attempt in range(MAX_ATTEMPTS):
        try:
            flight, plan, intensity, wind, seed = _fly_one(recipe, airframe, emulator, item,
                                                           attempt)
            wind = np.zeros(2) if wind is None else wind
            break
        except FlightDataError as exc:  # e.g. a gust turned a zoom climb into a loop
            last_error = exc
    else:
        return {"index": i, "mission": item["mission"],
                "failed": f"mission '{item['mission']}' left the flight-data checks' ranges "
                          f"in all {MAX_ATTEMPTS} draws of sortie {i}; last: {last_error}"}
    name = f"sortie_{i:03d}"
    meas = Sortie(name, airframe.kind, flight.time, flight.measured_states, flight.controls,
                  item["mission"])
    true = Sortie(name + "_true", airframe.kind, flight.time, flight.true_states,
                  flight.controls, item["mission"])
    write_csv(meas, Path(out) / f"{name}.csv")
    write_csv(true, Path(out) / f"{name}_true.csv")
    return {
        "file": f"{name}.csv", "true_file": f"{name}_true.csv", "mission": item["mission"],
        "duration_s": float(flight.time[-1] - flight.time[0]), "rows": int(len(flight.time)),
        "split": item["split"], "condition": item["condition"],
        "turbulence_intensity": round(intensity, 6),
        "mean_wind_mps": round(float(np.hypot(*wind)), 6),
        "wind_inertial_mps": [round(float(v), 6) + 0.0 for v in wind],
        "seed": seed, "draws": attempt + 1, "max_alpha_air_deg": round(float(np.degrees(
            np.max(flight.alpha_air))), 3) if airframe.kind == "fixed_wing" else None,
        "mission_params": plan.params,
    }


def generate_dataset(recipe: Recipe, out: str | Path, workers: int | None = None,
                     progress: bool = True, force: bool = False) -> Path:
    """Generate the dataset of ``recipe`` into folder ``out``; returns the manifest path.

    ``workers`` processes (default: all cores) share the sorties; a tqdm bar shows progress.
    The dataset is written into a temporary sibling folder and renamed into place when
    complete (manifest last), so an interrupted run leaves an earlier dataset in ``out``
    intact; a non-empty ``out`` that is not a previous dataset is refused unless ``force``.

    Raises
    ------
    uavdyn.outputs.OutputError
        If ``out`` may not be written.
    """
    airframe = load_airframe(recipe.airframe)
    recipe.validate(airframe)
    recipe, skipped = flyable_recipe(recipe, airframe)
    with output_folder(out, "generate-data", force) as tmp:
        _generate_into(recipe, airframe, tmp, workers, progress, skipped)
    return Path(out) / "manifest.json"


def flyable_recipe(recipe: Recipe, airframe: Airframe) -> tuple[Recipe, dict[str, str]]:
    """The recipe with only the missions the airframe can fly, and ``{mission: why}`` of those
    left out, each also warned about in one line. Unchanged if it can fly them all.

    Raises
    ------
    ValueError
        If the airframe can fly none of the recipe's missions (one line naming why).
    """
    missions = recipe.mission_list(airframe.kind)
    skipped = unflyable_missions(airframe, missions, recipe.duration_s, recipe.sample_rate_hz)
    if not skipped:
        return recipe, {}
    left = [m for m in missions if m not in skipped]
    if not left:
        raise ValueError(f"airframe '{airframe.name}' can fly none of the missions "
                         f"{', '.join(missions)}: " + "; ".join(skipped.values()))
    for reason in skipped.values():
        warnings.warn(f"{reason}; skipped (the other missions are generated)", UserWarning,
                      stacklevel=3)
    return Recipe(**{**recipe.to_dict(), "missions": left}), skipped


def _generate_into(recipe: Recipe, airframe: Airframe, out: Path, workers: int | None,
                   progress: bool, skipped: dict[str, str]) -> Path:
    items = assign_sorties(recipe, airframe.kind)
    # Compile the rollout once here so the workers only load the cached library.
    emulator = Emulator(airframe, truth=recipe.truth, sample_rate_hz=recipe.sample_rate_hz,
                        internal_dt=recipe.internal_dt_s)
    n_rows = int(round(recipe.duration_s * recipe.sample_rate_hz)) + 1
    emulator_rollout(airframe.kind, n_rows, emulator.substeps, True)
    workers = workers or os.cpu_count() or 1
    recipe_dict = recipe.to_dict()
    jobs = [(recipe_dict, item, str(out)) for item in items]
    bar = CheckedBar(total=len(jobs), desc=f"generating {airframe.name} sorties",
                     unit="sortie", disable=not progress)
    entries: list[dict] = []
    if workers == 1:
        for job in jobs:
            entries.append(_generate_one(job))
            bar.update()
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for entry in pool.map(_generate_one, jobs, chunksize=2):
                entries.append(entry)
                bar.update()
    bar.close()
    entries = _drop_failed_missions(entries, out, skipped)
    splits = {s: [e["file"] for e in entries if e["split"] == s] for s in SPLITS}
    rule = ({"split_rule": split_rule(entries, "mission", recipe.split_fractions, recipe.seed)}
            if items and items[0].get("split_by") == "mission" else {})
    return write_manifest(
        out, airframe=airframe.name, kind=airframe.kind, sample_rate_hz=recipe.sample_rate_hz,
        source="uavdyn flight-data emulator (uavdyn.emulator), truth model richer than the "
               "baseline; measured states with sensor noise, noise-free states in true_file",
        sorties=entries, columns=list(csv_columns(airframe.kind)), splits=splits,
        true_states="each sortie's true_file holds the noise-free states, same header",
        controls="commanded inputs, held over each log interval (zero-order hold)",
        velocities="u, w are air-relative body velocities (inertial minus mean wind minus "
                   "gust); q, theta are inertial. Each sortie's wind_inertial_mps is the mean "
                   "wind [W_x, W_z] in the inertial frame (x forward, z down; W_x < 0 is a "
                   "head wind), rotated into body axes with the pitch angle in the emulator",
        emulator={"internal_dt_s": emulator.internal_dt, "truth_params": emulator.truth,
                  "sensor_noise_std": asdict(emulator.noise.scaled(recipe.noise_scale))},
        truth=truth_record(emulator, skipped),
        recipe=recipe_dict, **rule,
    )


def _drop_failed_missions(entries: list[dict], out: Path, skipped: dict[str, str]
                          ) -> list[dict]:
    """Leave out every sortie of a mission one of whose sorties failed in every draw (its
    files deleted, one warning line naming it and why, recorded in ``skipped``).

    Raises
    ------
    ValueError
        If no mission is left.
    """
    failed = {}
    for e in entries:
        if "failed" in e:
            failed.setdefault(e["mission"], e["failed"])
    if not failed:
        return entries
    kept = [e for e in entries if e["mission"] not in failed]
    if not kept:
        raise ValueError("no mission could be flown: " + "; ".join(failed.values()))
    for e in entries:
        if e["mission"] in failed and "failed" not in e:
            for key in ("file", "true_file"):
                (Path(out) / e[key]).unlink()
    for mission, reason in failed.items():
        warnings.warn(f"{reason}; skipped (the other missions are written)", UserWarning,
                      stacklevel=4)
        skipped[mission] = reason
    return kept


def truth_record(emulator: Emulator, skipped: dict[str, str] | None = None) -> dict:
    """What the truth model of a dataset used (the manifest's ``truth``): its actuator lags
    and rates and where each came from (the airframe file or the emulator's defaults), the
    command limits the autopilot saturated at, the envelope the missions were drawn from
    (speed range, cruise, stall speed, climb rate) and the missions left out and why."""
    return {**emulator.truth, "sources": dict(emulator.truth_sources),
            **envelope(emulator.airframe).as_dict(), "missions_skipped": dict(skipped or {})}


def shipped_recipe(name: str) -> Recipe:
    """A recipe shipped with the package (``datagen_quadrotor``, ``datagen_fixed_wing``).

    Raises
    ------
    ValueError
        If no such recipe ships with the package.
    """
    res = resources.files("uavdyn.emulation.recipes").joinpath(f"{name}.json")
    if not res.is_file():
        raise ValueError(f"no shipped recipe '{name}'")
    return Recipe.from_json(Path(str(res)))
