"""The :class:`Airframe`: a named kind, typed parameters with sources, limits and structure."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

from uavdyn.airframes.bounds import _as_number, _check_values
from uavdyn.airframes.errors import AirframeError
from uavdyn.airframes.limits import CONTROL_RANGES, RATE_SUFFIX, _parse_delays
from uavdyn.airframes.params import (
    LATERAL_PARAMS,
    OPTIONAL_PARAMS,
    PARAM_CLASSES,
    ParamsType,
    param_names,
)
from uavdyn.airframes.tables import VALUE_LIMITS, Table


@dataclass(frozen=True)
class Airframe:
    """A named airframe: its kind, typed parameters, and the source of every number."""

    name: str
    kind: str
    params: ParamsType
    sources: dict[str, str]
    description: str = ""
    nominal_airspeed: float = 0.0
    origin: str = ""
    # The file's [limits] as parsed: control -> (low, high), '<control>_rate' -> rate (1/s).
    limits: dict[str, tuple[float, float] | float] = field(default_factory=dict)
    # Integer transport delay per control, in samples of the discrete step (absent: 0).
    delays: dict[str, int] = field(default_factory=dict)
    # "constant": rho as given; "isa": rho is the sea-level density, scaled by the standard
    # atmosphere at the sortie's altitude (manifest 'altitude_m') or at the h state.
    atmosphere: str = "constant"
    tables: dict[str, Table] = field(default_factory=dict)
    # The file declares the airframe statically unstable by design (C_m_alpha may be >= 0 in a
    # fit); a constraint of identification, not of the model (not in param_hash).
    relaxed_stability: bool = False
    # The model takes the recorded lateral channels (phi, p, r, beta) as inputs (turning
    # flight; :meth:`with_lateral`). Not a file key: set from the data the model is fed.
    lateral: bool = False

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of ``p``: the kind's parameters, then the values of each table (sorted by
        table name, row-major), then with lateral inputs ``Jx, Jz, Jxz``."""
        return param_names(self.kind) + tuple(
            n for name in sorted(self.tables) for n in self.tables[name].value_names()) + (
            LATERAL_PARAMS if self.lateral else ())

    @property
    def p(self) -> np.ndarray:
        """The numeric parameter vector in model order."""
        core = [getattr(self.params, n) for n in param_names(self.kind)]
        table_values = [v for name in sorted(self.tables) for v in self.tables[name].values]
        lateral = [getattr(self.params, n) for n in LATERAL_PARAMS] if self.lateral else []
        return np.array(core + table_values + lateral, dtype=float)

    def for_inputs(self, lateral: bool) -> Airframe:
        """This airframe with (or without) the lateral inputs the data carry: ``self`` when
        it already matches (see :meth:`with_lateral`)."""
        return self if bool(lateral) == self.lateral else self.with_lateral(bool(lateral))

    def with_lateral(self, on: bool = True) -> Airframe:
        """A copy whose model takes (``on``) or not the lateral inputs of turning flight. On
        needs the roll and yaw inertias ``Jx``, ``Jz`` (kg m^2) in the file's ``[params]``."""
        if on and not (self.params.Jx > 0.0 and self.params.Jz > 0.0):
            raise AirframeError(
                f"airframe '{self.name}': turning flight (lateral inputs phi, p, r, beta) needs "
                "the roll and yaw inertias Jx and Jz (kg m^2, and Jxz if not 0) in [params]")
        return dataclasses.replace(self, lateral=bool(on))

    def delay_samples(self) -> tuple[int, ...]:
        """The transport delay of each control in model order (samples of the step)."""
        return tuple(int(self.delays.get(n, 0)) for n, _ in CONTROL_RANGES[self.kind])

    def control_bounds(self) -> tuple[tuple[float, float], ...]:
        """The (low, high) of each control in model order: the file's ``[limits]`` where set,
        else the kind's physical range (so trim, MPC and simulate respect the real actuator)."""
        return tuple(tuple(map(float, self.limits.get(n, b)))  # type: ignore[arg-type]
                     for n, b in CONTROL_RANGES[self.kind])

    def rate_limits(self) -> tuple[float | None, ...] | None:
        """Per-control rate limits (per second) from ``[limits]``, None for a control without
        one; None if the file sets no rate at all (the caller keeps its own defaults)."""
        rates = tuple(self.limits.get(n + RATE_SUFFIX) for n, _ in CONTROL_RANGES[self.kind])
        if all(r is None for r in rates):
            return None
        return tuple(None if r is None else float(r) for r in rates)  # type: ignore[arg-type]

    def param_hash(self) -> str:
        """Short hash of kind + parameter values, used to tie trained weights to an airframe.

        Hashed: every core parameter, and an optional parameter only where it differs from its
        default, so adding an optional key to the schema leaves existing hashes (and the weight
        files tied to them) valid while any value that changes the model changes the hash."""
        optional = OPTIONAL_PARAMS[self.kind]
        core = [repr(float(getattr(self.params, n))) for n in param_names(self.kind)
                if n not in optional]
        doc: dict = {"kind": self.kind, "p": core}
        changed = {n: repr(float(getattr(self.params, n))) for n, default in optional.items()
                   if getattr(self.params, n) != default}
        if changed:
            doc["optional"] = changed
        # model structure beyond p, hashed only where set (existing hashes stay valid)
        delays = {k: v for k, v in sorted(self.delays.items()) if v}
        if delays:
            doc["delays"] = delays
        if self.atmosphere != "constant":
            doc["atmosphere"] = self.atmosphere
        if self.lateral:
            doc["lateral"] = [repr(float(getattr(self.params, n))) for n in LATERAL_PARAMS]
        if self.tables:
            doc["tables"] = {n: [list(map(list, (b for _, b in t.axes))),
                                 [a for a, _ in t.axes], [repr(v) for v in t.values]]
                             for n, t in sorted(self.tables.items())}
        return hashlib.sha256(json.dumps(doc).encode()).hexdigest()[:16]

    def replace(self, **changes: float) -> Airframe:
        """A copy with some parameter values changed (typed and range-checked like a file)."""
        origin = self.origin or self.name
        unknown = set(changes) - set(self.param_names)
        if unknown:
            raise AirframeError(f"unknown parameter(s) {sorted(unknown)} for kind '{self.kind}'")
        numbers = {k: _as_number(v, k, origin) for k, v in changes.items()}
        values = {f.name: getattr(self.params, f.name) for f in dataclasses.fields(self.params)}
        values.update({k: v for k, v in numbers.items() if k in values})
        _check_values(values, self.kind, origin)
        tables = dict(self.tables)
        for name, table in self.tables.items():
            names = table.value_names()
            if any(n in numbers for n in names):
                new = [numbers.get(n, v) for n, v in zip(names, table.values)]
                bad = [n for n, v in zip(names, new)
                       if not (math.isfinite(v) and abs(v) < VALUE_LIMITS[name])]
                if bad:
                    raise AirframeError(f"{origin}: table value '{bad[0]}' must be finite and "
                                        f"within +-{VALUE_LIMITS[name]:g}")
                tables[name] = table.with_values(new)
        return dataclasses.replace(self, params=PARAM_CLASSES[self.kind](**values),
                                   tables=tables)

    def with_delays(self, **delays: int) -> Airframe:
        """A copy with some controls' transport delays (samples) changed."""
        checked = _parse_delays({**self.delays, **delays}, self.kind, self.origin or self.name)
        return dataclasses.replace(self, delays=checked)
