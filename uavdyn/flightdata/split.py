"""Assigning a dataset's sorties to train, validation and test, whole sorties at a time.

Samples of one flight are correlated: a split by sample would let the model see, in training,
the seconds either side of every test sample. So each sortie (an imported segment) goes whole
to one part. The rules:

* ``by="sortie"``: a seeded random permutation of the sorties, cut into counts rounded from
  ``fractions x n`` by the largest remainder (every part with a nonzero fraction gets at least
  one sortie);
* ``by="time-block"``: the sorties in flight order (``source_start_s``, else manifest order),
  cut into consecutive blocks at the cumulative-duration fractions: train first, then
  validation, then test, so the later flight is held out (no look-ahead);
* ``by="log"``: whole logs of a campaign (the sorties' ``log``), in the order the logs were
  imported, cut into consecutive blocks the same way: every segment of a log goes to one
  part, the later flights held out;
* ``by="mission"``: seeded random sorties, stratified by ``mission`` (and, within a mission,
  by ``condition`` where the entries have one): the same counts as ``sortie``, but every part
  gets each kind of flight in proportion where the counts allow (:func:`stratified_order`),
  so validation does not miss a kind of flight that train and test have.

Without stated fractions (``fractions=None``) the default 0.7/0.15/0.15 applies when there
are at least three sorties (or logs); two give train and test, one gives train
(:func:`default_fractions`), and the choice is said, not refused.

:func:`split_dataset` records the parts in ``manifest.json`` (``split`` per sortie and the
``split_rule`` used), rewritten atomically; nothing else in the folder changes.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.manifest import read_manifest
from uavdyn.flightdata.sortie import SPLIT_NAMES
from uavdyn.outputs import write_text_atomic

SPLIT_RULES = ("sortie", "time-block", "log", "mission")
DEFAULT_FRACTIONS = (0.7, 0.15, 0.15)
FEW_UNITS_FRACTIONS = {1: (1.0, 0.0, 0.0), 2: (0.5, 0.0, 0.5)}  # default for 1 or 2 sorties
FRACTION_TOLERANCE = 1e-6


class SplitError(FlightDataError):
    """A split that cannot be made as asked; the one-line message says why and what to do."""


def check_fractions(fractions: object) -> tuple[float, float, float]:
    """The train, validation and test fractions as three floats, or a one-line refusal.

    Parameters
    ----------
    fractions : sequence of three numbers
        Each finite and >= 0, summing to 1 (within :data:`FRACTION_TOLERANCE`).

    Returns
    -------
    tuple of float

    Raises
    ------
    SplitError
        If they are not three such numbers.
    """
    try:
        values = tuple(fractions)  # type: ignore[arg-type]
    except TypeError:
        raise SplitError(f"fractions must be three numbers (train, validation, test), got "
                         f"{type(fractions).__name__}") from None
    if len(values) != 3 or any(isinstance(v, bool) or not isinstance(v, (int, float))
                               for v in values):
        raise SplitError(f"fractions must be three numbers (train, validation, test), got "
                         f"{values!r}"[:200])
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) and v >= 0 for v in out):
        raise SplitError(f"fractions must be finite and >= 0, got {_parts_text(out)}")
    if abs(sum(out) - 1.0) > FRACTION_TOLERANCE:
        raise SplitError(f"fractions must sum to 1, got {_parts_text(out)} "
                         f"(sum {sum(out):.6g})")
    return out  # type: ignore[return-value]


def _parts_text(fractions: tuple[float, ...]) -> str:
    return ", ".join(f"{name} {f:g}" for name, f in zip(SPLIT_NAMES, fractions))


def _check_enough(n: int, fractions: tuple[float, float, float], noun: str = "sortie"
                  ) -> None:
    """Refuse, naming them, the parts with a nonzero fraction that ``n`` sorties leave empty
    (the smallest fractions go without first)."""
    wanted = [i for i in sorted(range(3), key=lambda i: (-fractions[i], i)) if fractions[i] > 0]
    if n >= len(wanted):
        return
    empty = [SPLIT_NAMES[i] for i in sorted(wanted[n:])]
    names = " and ".join(f"'{name}'" for name in empty)
    zeros = " and ".join(empty)
    what = "segments" if noun == "sortie" else "logs"
    noun = noun if n == 1 else noun + "s"
    raise SplitError(f"{n} {noun} cannot fill {_parts_text(fractions)}: {names} would be "
                     f"empty; import more {what} or give --fractions with 0 for {zeros}")


def _counts(n: int, fractions: tuple[float, float, float]) -> list[int]:
    """Sorties per part: largest-remainder rounding of ``fractions x n``, then one sortie for
    every part with a nonzero fraction that got none (taken from the largest part)."""
    _check_enough(n, fractions)
    total = sum(fractions)
    raw = [f / total * n for f in fractions]
    counts = [min(math.floor(r + 1e-9), n) for r in raw]
    while sum(counts) > n:  # only if rounding pushed a floor up
        counts[max(range(3), key=lambda i: counts[i] - raw[i])] -= 1
    order = sorted(range(3), key=lambda i: (-(raw[i] - counts[i]), i))
    for i in order[: n - sum(counts)]:
        counts[i] += 1
    for i in range(3):
        if fractions[i] > 0 and counts[i] == 0:
            donor = max(range(3), key=lambda j: (counts[j], -j))
            counts[donor] -= 1
            counts[i] += 1
    return counts


def _flight_order(entries: list[dict]) -> list[int]:
    """Entry indices in flight order: by ``source_start_s`` if every entry has one, manifest
    order if none has (a mix is ambiguous and refused)."""
    has = [i for i, e in enumerate(entries) if e.get("source_start_s") is not None]
    if not has:
        return list(range(len(entries)))
    if len(has) != len(entries):
        missing = next(i for i, e in enumerate(entries) if e.get("source_start_s") is None)
        raise SplitError(f"sorties[{missing}] has no source_start_s but others have: the "
                         "flight order is ambiguous for --by time-block")
    starts = [_finite(e["source_start_s"], f"sorties[{i}].source_start_s")
              for i, e in enumerate(entries)]
    return sorted(range(len(entries)), key=lambda i: (starts[i], i))


def _finite(value: object, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(float(value)):
        raise SplitError(f"{key}: expected a finite number, got {value!r}"[:200])
    return float(value)


def _nearest_cut(cumulative: np.ndarray, target: float, low: int, high: int) -> int:
    """The number of leading sorties, in ``low .. high``, whose total duration is nearest
    ``target`` (a tie goes to the earlier part, as the largest-remainder rule does)."""
    ks = np.arange(low, high + 1)
    errors = np.abs(cumulative[ks] - target)
    best = np.flatnonzero(errors <= errors.min() + 1e-9 * max(1.0, abs(target)))
    return int(ks[best[-1]])


def _time_block_counts(durations: list[float], fractions: tuple[float, float, float],
                       noun: str = "sortie") -> list[int]:
    """Sorties per consecutive block, cut where the cumulative duration is nearest the
    fractions' boundaries; a zero fraction's block is empty, a nonzero one's never."""
    n = len(durations)
    need = [1 if f > 0 else 0 for f in fractions]
    _check_enough(n, fractions, noun)
    cumulative = np.concatenate([[0.0], np.cumsum(durations)])
    total = cumulative[-1]
    if fractions[0] == 0:
        k1 = 0
    else:
        k1 = _nearest_cut(cumulative, fractions[0] * total, 1, n - need[1] - need[2])
    if fractions[2] == 0:
        k2 = n
    elif fractions[1] == 0:
        k2 = k1
    else:
        k2 = _nearest_cut(cumulative, (fractions[0] + fractions[1]) * total, k1 + 1, n - 1)
    return [k1, k2 - k1, n - k2]


def default_fractions(units: int, by: str = "sortie") -> tuple[tuple[float, float, float],
                                                              str]:
    """The fractions used when none are stated, and the sentence saying so.

    Parameters
    ----------
    units : int
        The sorties (or, for ``by="log"``, the logs) to split.
    by : str
        The rule (only for the sentence).

    Returns
    -------
    fractions : tuple of float
        :data:`DEFAULT_FRACTIONS` for three or more units; two units give train and test
        (0.5, 0, 0.5), one gives train (1, 0, 0).
    note : str
        Empty for the default; else why the part(s) stayed empty.
    """
    if units >= 3 or units < 1:
        return DEFAULT_FRACTIONS, ""
    noun = "log" if by == "log" else "sortie"
    got = "train and test" if units == 2 else "train only"
    return FEW_UNITS_FRACTIONS[units], (
        f"{units} {noun}{'s' if units > 1 else ''}: {got} (the default "
        f"{','.join(f'{f:g}' for f in DEFAULT_FRACTIONS)} needs 3; --fractions chooses)")


def _log_units(entries: list[dict]) -> tuple[list[int], list[list[int]]]:
    """For ``by="log"``: the entries grouped by their ``log``, logs in order of first
    appearance (the order they were imported)."""
    groups: dict[str, list[int]] = {}
    for i, e in enumerate(entries):
        log = e.get("log")
        if not isinstance(log, str) or not log:
            raise SplitError(f"sorties[{i}] has no 'log' (the log it was cut from): split "
                             "--by log needs a dataset made by import-log")
        groups.setdefault(log, []).append(i)
    return list(range(len(groups))), list(groups.values())


def _by_log(entries: list[dict], fractions: tuple[float, float, float] | None) -> list[str]:
    """``by="log"``: consecutive blocks of whole logs (import order) at the cumulative
    duration of their segments."""
    _, groups = _log_units(entries)
    if fractions is None:
        fractions = default_fractions(len(groups), "log")[0]
    fractions = check_fractions(fractions)
    durations = [sum(_finite(entries[i].get("duration_s"), f"sorties[{i}].duration_s")
                     for i in g) for g in groups]
    counts = _time_block_counts(durations, fractions, noun="log")
    parts = [name for name, c in zip(SPLIT_NAMES, counts) for _ in range(c)]
    out = [""] * len(entries)
    for group, part in zip(groups, parts):
        for i in group:
            out[i] = part
    return out


def _spread(groups: list[list[int]], rng: np.random.Generator) -> dict[int, float]:
    """Each member of ``groups`` (lists of indices) at a position in [0, 1): a group's members
    in random order at ``(rank + offset) / size``, one random offset per group, so every
    group is spread evenly over [0, 1)."""
    out: dict[int, float] = {}
    for group in groups:
        offset = rng.random()
        for rank, j in enumerate(rng.permutation(len(group))):
            out[group[int(j)]] = (rank + offset) / len(group)
    return out


def stratified_order(entries: list[dict], seed: int) -> list[int]:
    """The entries in an order whose consecutive blocks give every stratum its share: each
    mission's sorties spread evenly over [0, 1) (:func:`_spread`; within a mission the
    ``condition`` groups are spread first and interleaved the same way), all sorted by
    position. Cutting it at the fractions' counts, train first, hands each mission (and
    condition) to each part in proportion, up to one sortie, where the counts allow;
    :func:`balance_conditions` then gives validation and test every condition where a swap
    within a mission can."""
    rng = np.random.default_rng([int(seed), 1])
    missions: dict[str, list[int]] = {}
    for i, e in enumerate(entries):
        missions.setdefault(str(e.get("mission", "")), []).append(i)
    position: dict[int, float] = {}
    for members in missions.values():
        conditions: dict[str, list[int]] = {}
        for i in members:
            conditions.setdefault(str(entries[i].get("condition", "")), []).append(i)
        within = _spread(list(conditions.values()), rng)  # conditions interleaved
        ranked = sorted(members, key=lambda i: (within[i], i))
        offset = rng.random()
        for rank, i in enumerate(ranked):
            position[i] = (rank + offset) / len(members)
    ties = rng.random(len(entries))
    return sorted(range(len(entries)), key=lambda i: (position[i], ties[i]))


def balance_conditions(entries: list[dict], names: list[str], seed: int) -> list[str]:
    """``names`` with validation and test each given every ``condition`` the dataset has
    where a swap can do it: a sortie of a part that lacks a condition trades places with a
    train sortie of the same mission in that condition (counts and mission shares kept)."""
    rng = np.random.default_rng([int(seed), 2])
    names = list(names)
    conditions = sorted({str(e["condition"]) for e in entries if e.get("condition")})
    for part in ("validation", "test"):
        for wanted in conditions:
            members = [i for i, n in enumerate(names) if n == part]
            if len(members) < 2 or any(entries[i].get("condition") == wanted
                                       for i in members):
                continue
            pairs = [(i, j) for i in members for j in range(len(entries))
                     if names[j] == "train" and entries[j].get("condition") == wanted
                     and entries[j].get("mission") == entries[i].get("mission")]
            if pairs:
                i, j = pairs[int(rng.integers(len(pairs)))]
                names[i], names[j] = "train", part
    return names


def assign_split(entries: list[dict], by: str = "sortie",
                 fractions: tuple[float, float, float] | None = DEFAULT_FRACTIONS,
                 seed: int = 0) -> list[str]:
    """One split name per manifest entry, whole sorties only (never by sample).

    Parameters
    ----------
    entries : list of dict
        Manifest ``sorties`` entries; ``by="time-block"`` reads ``duration_s`` and, if every
        entry has one, ``source_start_s``; ``by="log"`` reads ``log`` and ``duration_s``.
    by : {"sortie", "time-block", "log", "mission"}
        Seeded random sorties, consecutive blocks in flight order (the later flight held
        out as test), consecutive blocks of whole logs in import order, or seeded random
        sorties stratified by mission and condition (:func:`stratified_order`).
    fractions : tuple of float or None
        Train, validation and test shares (counts for ``sortie`` and ``mission``, duration for
        ``time-block`` and ``log``); each >= 0, summing to 1. A zero share leaves its part
        empty. None: :func:`default_fractions` for the number of sorties (or logs).
    seed : int
        Seed of the ``sortie`` and ``mission`` orders (>= 0); the same seed gives the same
        split.

    Returns
    -------
    list of str
        ``train``/``validation``/``test`` for each entry, in the entries' order.

    Raises
    ------
    SplitError
        On one line: a bad rule, fractions or seed, or too few sorties to give every part
        with a nonzero fraction at least one (naming the part that would be empty).
    """
    if by not in SPLIT_RULES:
        raise SplitError(f"split rule {by!r} is not one of {SPLIT_RULES}"[:200])
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SplitError(f"seed must be a whole number >= 0, got {seed!r}"[:200])
    if by == "log":
        return _by_log(entries, fractions)
    if fractions is None:
        fractions = default_fractions(len(entries), by)[0]
    fractions = check_fractions(fractions)
    n = len(entries)
    if by == "sortie":
        order = [int(i) for i in np.random.default_rng(int(seed)).permutation(n)]
        counts = _counts(n, fractions)
    elif by == "mission":
        order = stratified_order(entries, int(seed))
        counts = _counts(n, fractions)
    else:
        order = _flight_order(entries)
        durations = [_finite(entries[i].get("duration_s"), f"sorties[{i}].duration_s")
                     for i in order]
        counts = _time_block_counts(durations, fractions)
    names = [name for name, c in zip(SPLIT_NAMES, counts) for _ in range(c)]
    out = [""] * n
    for i, name in zip(order, names):
        out[i] = name
    return balance_conditions(entries, out, int(seed)) if by == "mission" else out


def split_rule(entries: list[dict], by: str = "sortie",
               fractions: tuple[float, float, float] | None = DEFAULT_FRACTIONS,
               seed: int = 0) -> dict:
    """The rule as a manifest records it (``split_rule``): ``by``, the ``fractions`` used
    (the default for the number of sorties or logs when None), ``seed``, and a ``note`` when
    the default left a part empty.

    Parameters
    ----------
    entries : list of dict
        The manifest's sorties (counted, and grouped by ``log`` for ``by="log"``).
    by, fractions, seed
        As for :func:`assign_split`.

    Returns
    -------
    dict
    """
    note = ""
    if fractions is None:
        units = len(_log_units(entries)[1]) if by == "log" else len(entries)
        fractions, note = default_fractions(units, by)
    rule = {"by": by, "fractions": list(check_fractions(fractions)), "seed": int(seed)}
    return {**rule, "note": note} if note else rule


def split_dataset(folder: str | Path, by: str = "sortie",
                  fractions: tuple[float, float, float] | None = DEFAULT_FRACTIONS,
                  seed: int = 0) -> dict[str, list[str]]:
    """Assign every sortie of a dataset folder to a split and record it in its manifest.

    ``manifest.json`` is validated, then rewritten through a temporary sibling renamed into
    place (an interrupted or failed write leaves the old manifest intact); it records each
    entry's ``split`` and the rule as ``split_rule``. No other file is touched.

    Parameters
    ----------
    folder : str or Path
        The dataset folder.
    by, fractions, seed
        As for :func:`assign_split`.

    Returns
    -------
    dict of str to list of str
        ``train``, ``validation`` and ``test`` (always all three) to the sortie file names
        (the manifest's ``file``), in manifest order.

    Raises
    ------
    FlightDataError
        If the manifest is invalid, or (:class:`SplitError`) the split cannot be made.
    """
    path = Path(folder) / "manifest.json"
    manifest = read_manifest(path)
    rule = split_rule(manifest["sorties"], by, fractions, seed)
    names = assign_split(manifest["sorties"], by, rule["fractions"], seed)
    sorties = [dict(entry, split=name) for entry, name in zip(manifest["sorties"], names)]
    updated = dict(manifest, sorties=sorties, split_rule=rule)
    write_text_atomic(path, json.dumps(updated, indent=2) + "\n")
    out: dict[str, list[str]] = {name: [] for name in SPLIT_NAMES}
    for entry in sorties:
        out[entry["split"]].append(entry["file"])
    return out
