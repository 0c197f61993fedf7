"""Breakpoint tables of an airframe file: aerodynamic coefficients over angle of attack
(optionally a second axis) and a thrust table over airspeed and throttle.

A table's values are parameters of ``p`` (named ``<table>_table_<i>`` or ``<table>_table_<i>_<j>``),
so they can be identified like any coefficient; the breakpoints are structure (they fix the
graph). File form (TOML)::

    [tables.C_L]                     # replaces C_L_0 + C_L_alpha a + C_L_alpha2 a^2
    alpha = [-0.2, 0.0, 0.2, 0.3]    # rad, strictly increasing, 2..200 points
    values = [-0.9, 0.23, 1.35, 1.6]
    [tables.C_m]                     # replaces C_m_0 + C_m_alpha a
    alpha = [-0.2, 0.0, 0.2]
    elevator = [-0.3, 0.0, 0.3]      # optional second axis: 'elevator' (rad) or 'airspeed' (m/s)
    values = [[...], [...], [...]]   # one row per alpha, one column per second-axis point
    [tables.thrust]                  # N; replaces the electric motor/propeller model
    airspeed = [0.0, 20.0, 40.0]
    throttle = [0.0, 0.5, 1.0]
    values = [[0, 30, 80], [0, 20, 60], [0, 10, 40]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TABLE_MAX_POINTS = 200
# table -> (first axis, allowed second axes, whether the second axis is required)
TABLE_AXES: dict[str, tuple[str, tuple[str, ...], bool]] = {
    "C_L": ("alpha", ("elevator", "airspeed"), False),
    "C_D": ("alpha", ("elevator", "airspeed"), False),
    "C_m": ("alpha", ("elevator", "airspeed"), False),
    "thrust": ("airspeed", ("throttle",), True),
}
AXIS_RANGES: dict[str, tuple[float, float, str]] = {
    "alpha": (-math.pi, math.pi, "rad"), "elevator": (-math.pi / 2, math.pi / 2, "rad"),
    "airspeed": (0.0, 300.0, "m/s"), "throttle": (0.0, 1.0, ""),
}
VALUE_LIMITS = {"C_L": 1e3, "C_D": 1e3, "C_m": 1e3, "thrust": 1e7}


class TableError(ValueError):
    """A table of an airframe file is malformed (the message names ``tables.<name>.<key>``)."""


@dataclass(frozen=True)
class Table:
    """One breakpoint table: axis names with their breakpoints, values row-major
    (first axis slowest), evaluated by piecewise-linear interpolation, held constant beyond the
    end points."""

    name: str
    axes: tuple[tuple[str, tuple[float, ...]], ...]
    values: tuple[float, ...]

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(b) for _, b in self.axes)

    def value_names(self) -> tuple[str, ...]:
        """Names of the table values in ``p`` (row-major)."""
        if len(self.axes) == 1:
            return tuple(f"{self.name}_table_{i}" for i in range(self.shape[0]))
        n0, n1 = self.shape
        return tuple(f"{self.name}_table_{i}_{j}" for i in range(n0) for j in range(n1))

    def with_values(self, values) -> Table:
        return Table(self.name, self.axes, tuple(float(v) for v in values))

    def structure_key(self) -> tuple:
        """What fixes the model graph: the name and the breakpoints (not the values)."""
        return (self.name, self.axes)

    def to_file(self) -> dict:
        out: dict = {axis: list(b) for axis, b in self.axes}
        if len(self.axes) == 1:
            out["values"] = list(self.values)
        else:
            n1 = self.shape[1]
            out["values"] = [list(self.values[i * n1:(i + 1) * n1]) for i in range(self.shape[0])]
        return out


def _shown(value: object, limit: int = 40) -> str:
    """A short printable repr of a value for a message (cut with '...', never silently)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def number_value(value: object) -> float | None:
    """A file value as a float: None for anything that is not a number (a boolean is not one),
    ``inf`` for an integer too large for a float (so a finiteness check catches it)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf


def _numbers(raw: object, where: str, origin: str) -> list[float]:
    if not isinstance(raw, list) or not raw:
        raise TableError(f"{origin}: key '{where}' must be a non-empty array of numbers, got "
                         f"{_shown(raw)}")
    out = []
    for i, v in enumerate(raw):
        f = number_value(v)
        if f is None:
            raise TableError(f"{origin}: key '{where}[{i}]' must be a number, got {_shown(v)}")
        if not math.isfinite(f):
            raise TableError(f"{origin}: key '{where}[{i}]' must be finite, got {_shown(v)}")
        out.append(f)
    return out


def _breakpoints(raw: object, axis: str, where: str, origin: str) -> tuple[float, ...]:
    points = _numbers(raw, where, origin)
    if not 2 <= len(points) <= TABLE_MAX_POINTS:
        raise TableError(f"{origin}: key '{where}' needs 2..{TABLE_MAX_POINTS} breakpoints, got "
                         f"{len(points)}")
    for i in range(1, len(points)):
        if not points[i] > points[i - 1]:
            raise TableError(f"{origin}: key '{where}' must be strictly increasing "
                             f"({points[i - 1]:g} then {points[i]:g} at index {i})")
    low, high, unit = AXIS_RANGES[axis]
    if points[0] < low or points[-1] > high:
        raise TableError(f"{origin}: key '{where}' spans [{points[0]:g}, {points[-1]:g}], outside "
                         f"the {axis} range [{low:g}, {high:g}] {unit}".rstrip())
    return tuple(points)


def parse_tables(raw: object, kind: str, origin: str) -> dict[str, Table]:
    """The ``[tables]`` of an airframe file, checked (names, axes, shapes, finite values)."""
    if not isinstance(raw, dict):
        raise TableError(f"{origin}: key 'tables' must be a table, got {_shown(raw)}")
    if kind != "fixed_wing" and raw:
        raise TableError(f"{origin}: key 'tables' is for fixed wings only (kind '{kind}')")
    out: dict[str, Table] = {}
    for name in sorted(raw, key=str):
        entry = raw[name]
        if name not in TABLE_AXES:
            raise TableError(f"{origin}: unknown table 'tables.{str(name):.30}'; expected any of "
                             f"{sorted(TABLE_AXES)}")
        if not isinstance(entry, dict):
            raise TableError(f"{origin}: key 'tables.{name}' must be a table with axes and "
                             "'values'")
        first, seconds, required = TABLE_AXES[name]
        allowed = {first, "values", *seconds}
        extra = sorted(str(k) for k in entry if k not in allowed)
        if extra:
            raise TableError(f"{origin}: unknown key 'tables.{name}.{extra[0]:.30}'; expected "
                             f"{sorted(allowed)}")
        for key in (first, "values"):
            if key not in entry:
                raise TableError(f"{origin}: missing key 'tables.{name}.{key}'")
        second = [k for k in seconds if k in entry]
        if len(second) > 1:
            raise TableError(f"{origin}: table 'tables.{name}' has two second axes {second}; "
                             "give one")
        if required and not second:
            raise TableError(f"{origin}: missing key 'tables.{name}.{seconds[0]}'")
        axes = [(first, _breakpoints(entry[first], first, f"tables.{name}.{first}", origin))]
        if second:
            axes.append((second[0], _breakpoints(entry[second[0]], second[0],
                                                 f"tables.{name}.{second[0]}", origin)))
        where = f"tables.{name}.values"
        rows = entry["values"]
        if len(axes) == 1:
            values = _numbers(rows, where, origin)
            if len(values) != len(axes[0][1]):
                raise TableError(f"{origin}: key '{where}' has {len(values)} values for "
                                 f"{len(axes[0][1])} breakpoints of '{first}'")
        else:
            n0, n1 = len(axes[0][1]), len(axes[1][1])
            if not isinstance(rows, list) or len(rows) != n0:
                raise TableError(f"{origin}: key '{where}' must have {n0} rows (one per "
                                 f"'{first}' breakpoint)")
            values = []
            for i, row in enumerate(rows):
                row_values = _numbers(row, f"{where}[{i}]", origin)
                if len(row_values) != n1:
                    raise TableError(f"{origin}: key '{where}[{i}]' has {len(row_values)} values "
                                     f"for {n1} breakpoints of '{axes[1][0]}'")
                values += row_values
        limit = VALUE_LIMITS[name]
        for i, v in enumerate(values):
            if abs(v) >= limit:
                raise TableError(f"{origin}: key '{where}' value {v:g} (entry {i}) is beyond "
                                 f"+-{limit:g}")
        out[name] = Table(name, tuple(axes), tuple(values))
    return out
