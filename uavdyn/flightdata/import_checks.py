"""Checks shared by the log importers (ULog, ALFA): their options and the imported arrays.

Options are checked before any file is read; the imported arrays go through the same
:func:`check_values` as CSV data, with its row restated as a row of the resampled grid.
"""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path

import numpy as np

from uavdyn.flightdata.checks import check_values
from uavdyn.flightdata.errors import FlightDataError

MAX_RATE_HZ = 10_000.0              # grid rates above this are refused (no such log rates)


def _as_path(path: object, option: str) -> Path:
    """``path`` as a Path; anything but a non-empty str or os.PathLike is refused up front."""
    if isinstance(path, (str, os.PathLike)) and str(path) != "":
        try:
            return Path(path)
        except TypeError:  # a PathLike giving bytes
            pass
    raise FlightDataError(f"option {option} must be a non-empty path (str or os.PathLike), "
                          f"got {path!r}")


def _finite_real(value: object) -> bool:
    """A finite real number (numpy scalars included), not a boolean."""
    return (isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
            and math.isfinite(float(value)))


def _check_rate(rate_hz: object, path: Path, allow_none: bool) -> None:
    """Option ``rate_hz``: a finite number in (0, MAX_RATE_HZ] (or None if ``allow_none``)."""
    if rate_hz is None and allow_none:
        return
    if not _finite_real(rate_hz) or not 0 < float(rate_hz) <= MAX_RATE_HZ:
        raise FlightDataError(f"option rate_hz must be a finite number in (0, {MAX_RATE_HZ:g}] "
                              f"Hz{' or None' if allow_none else ''}, got {rate_hz!r}", path)


def _check_bool(value: object, option: str, path: Path) -> None:
    """A True/False option (a numpy boolean counts)."""
    if not isinstance(value, (bool, np.bool_)):
        raise FlightDataError(f"option {option} must be True or False, got {value!r}", path)


def _check_name(name: object, path: Path) -> None:
    """Option ``name``: a non-empty string or None."""
    if name is not None and (not isinstance(name, str) or not name):
        raise FlightDataError(f"option name must be a non-empty string or None, got {name!r}",
                              path)


def _checked(path: Path, kind: str, time: np.ndarray, states: np.ndarray,
             controls: np.ndarray, rate_hz: float, kinematic: bool) -> None:
    """:func:`check_values` on imported arrays; its row (of the resampled grid, not of any
    file) is restated as a grid row and time so that nobody looks for it in a CSV."""
    try:
        check_values(path, kind, time, states, controls, sample_rate_hz=rate_hz,
                     kinematic=kinematic)
    except FlightDataError as exc:
        if exc.row is None:
            raise
        k = min(max(exc.row - 1, 0), len(time) - 1)
        raise FlightDataError(f"imported grid row {exc.row} (t = {time[k]:.3f} s): "
                              f"{exc.reason}", path, column=exc.column) from None


def check_reader_options(path: Path, kind: object, rate_hz: object, control_maps: object,
                         name: object, kind_required: bool = False) -> None:
    """The options every six-degree-of-freedom reader takes, refused before the file is read:
    the airframe kind (None allowed unless ``kind_required``), the grid rate, the name and the
    control maps."""
    from uavdyn.flightdata.control_map import ChannelMap
    from uavdyn.model import CONTROL_NAMES

    if (kind is not None or kind_required) and (not isinstance(kind, str)
                                                or kind not in CONTROL_NAMES):
        raise FlightDataError(f"unknown kind {kind!r} (option kind must be one of "
                              f"{tuple(CONTROL_NAMES)}{'' if kind_required else ' or None'})",
                              path)
    _check_rate(rate_hz, path, allow_none=True)
    _check_name(name, path)
    if control_maps is not None and (not isinstance(control_maps, (list, tuple)) or not all(
            isinstance(m, ChannelMap) for m in control_maps)):
        raise FlightDataError("option control_maps must be a list of ChannelMap or None, got "
                              f"{type(control_maps).__name__}", path)
