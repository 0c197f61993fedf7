"""What fixes the graph of an airframe's model beyond its kind: alpha-dot terms, breakpoint
tables, actuator lags, transport delays and the atmosphere. Values live in ``p``; this is the
rest, hashable, so each structure's Functions are built once.

The discrete step of a structure with actuator dynamics works on the augmented state::

    z = [x (4, or 6 with position) | actuator states (one per lagged control) |
         delay buffers (per control, most recent command first)]

A lagged control's actuator state follows the (delayed) command with a first-order lag, which
a slewed control also limits in rate (``slew_<control>`` = 1 / the rate limit); a
delay of ``k`` samples means the command given at step ``n`` acts from step ``n + k``.
"""

from __future__ import annotations

from dataclasses import dataclass

from uavdyn.airframes import CONTROL_RANGES, Airframe, param_names
from uavdyn.airframes.params import LATERAL_PARAMS
from uavdyn.airframes.tables import Table

ALPHA_DOT_KEYS = ("C_L_alpha_dot", "C_m_alpha_dot")
STATE_NAMES = ("u", "w", "q", "theta")
# The recorded lateral channels of turning flight, appended to the controls as non-actuated
# inputs (no lag, no delay): bank angle phi (rad), roll and yaw rates p, r (rad/s), sideslip
# beta (rad). All zero is wings-level flight (SPEC section 2).
LATERAL_INPUT_NAMES = ("phi", "p", "r", "beta")
POSITION_STATE_NAMES = ("x_n", "h")
# The time constant of each control's lag, per kind (the multirotor's rotor speed is linear in
# both commands, so one rotor-speed lag is the same lag on each of them).
LAG_PARAMS = {"fixed_wing": {"elevator": "tau_elevator", "throttle": "tau_throttle"},
              "multirotor": {"collective": "tau_rotor", "pitch_cmd": "tau_rotor"}}
# The slew time (1 / rate limit) of each control's actuator, per kind: a servo or an engine
# cannot follow a large command step faster than its rate limit, which no lag reproduces.
SLEW_PARAMS = {"fixed_wing": {"elevator": "slew_elevator", "throttle": "slew_throttle"},
               "multirotor": {}}


@dataclass(frozen=True)
class ModelStructure:
    """The graph-fixing description of a model (see the module docstring).

    Parameters
    ----------
    kind : str
        ``"fixed_wing"`` or ``"multirotor"``.
    alpha_dot : bool
        Carry the fixed-wing alpha-dot terms.
    lagged : tuple of str
        Controls with a first-order actuator lag (an actuator state each).
    slewed : tuple of str
        Lagged controls whose actuator is also rate limited.
    delays : tuple of int
        Transport delay of each control in samples (empty: none).
    tables : tuple
        ``(name, axes)`` of each breakpoint table, sorted by name (values are in ``p``).
    isa : bool
        Density from the standard atmosphere (at the ``h`` state when the model has it).
    lateral : bool
        The inputs end with the recorded lateral channels :data:`LATERAL_INPUT_NAMES` (turning
        flight) and ``p`` with ``Jx, Jz, Jxz``; without, the graph is the wings-level model's.
    """

    kind: str
    alpha_dot: bool = False
    lagged: tuple[str, ...] = ()
    slewed: tuple[str, ...] = ()
    delays: tuple[int, ...] = ()
    tables: tuple[tuple[str, tuple[tuple[str, tuple[float, ...]], ...]], ...] = ()
    isa: bool = False
    lateral: bool = False

    def __post_init__(self) -> None:
        names = self.actuated_names
        unknown = [c for c in self.lagged if c not in names]
        if unknown:
            raise ValueError(f"lagged control(s) {unknown} not in {names}")
        if not set(self.slewed) <= set(self.lagged):
            raise ValueError(f"slewed control(s) {self.slewed} must be lagged {self.lagged}")
        if self.delays and (len(self.delays) != len(names) or min(self.delays) < 0):
            raise ValueError(f"delays must give a whole number >= 0 per control {names}")

    @property
    def actuated_names(self) -> tuple[str, ...]:
        """The kind's controls (the actuated inputs, which may lag or be delayed)."""
        return tuple(n for n, _ in CONTROL_RANGES[self.kind])

    @property
    def control_names(self) -> tuple[str, ...]:
        """Every input of the step: the controls, then with lateral inputs
        :data:`LATERAL_INPUT_NAMES`."""
        return self.actuated_names + (LATERAL_INPUT_NAMES if self.lateral else ())

    @property
    def nu(self) -> int:
        return len(self.control_names)

    def table_objects(self) -> tuple[Table, ...]:
        return tuple(Table(name, axes, ()) for name, axes in self.tables)

    @property
    def param_names(self) -> tuple[str, ...]:
        return param_names(self.kind) + tuple(
            n for t in self.table_objects() for n in t.value_names()) + (
            LATERAL_PARAMS if self.lateral else ())

    @property
    def np(self) -> int:
        return len(self.param_names)

    def table_slices(self) -> dict[str, tuple[tuple, int, int]]:
        """``name -> (axes, start, stop)`` of each table's values in ``p``."""
        out, start = {}, len(param_names(self.kind))
        for t in self.table_objects():
            n = len(t.value_names())
            out[t.name] = (t.axes, start, start + n)
            start += n
        return out

    @property
    def lag_indices(self) -> tuple[int, ...]:
        """Control index of each actuator state."""
        return tuple(self.control_names.index(c) for c in self.lagged)

    @property
    def tau_indices(self) -> tuple[int, ...]:
        """Index in ``p`` of each actuator state's time constant."""
        names = param_names(self.kind)
        return tuple(names.index(LAG_PARAMS[self.kind][c]) for c in self.lagged)

    @property
    def slew_indices(self) -> tuple[int | None, ...]:
        """Index in ``p`` of each actuator state's slew time (None: not rate limited)."""
        names = param_names(self.kind)
        return tuple(names.index(SLEW_PARAMS[self.kind][c]) if c in self.slewed else None
                     for c in self.lagged)

    @property
    def delay_samples(self) -> tuple[int, ...]:
        """The delay of each input in samples (the lateral inputs: none)."""
        delays = self.delays or (0,) * len(self.actuated_names)
        return tuple(delays) + (0,) * (self.nu - len(delays))

    @property
    def lateral_slice(self) -> slice | None:
        """Where the lateral inputs sit in ``u`` (None: the model has none)."""
        n = len(self.actuated_names)
        return slice(n, n + len(LATERAL_INPUT_NAMES)) if self.lateral else None

    @property
    def lateral_param_indices(self) -> tuple[int, int, int] | None:
        """Indices of ``Jx, Jz, Jxz`` in ``p`` (None: the model has no lateral inputs)."""
        if not self.lateral:
            return None
        names = self.param_names
        return tuple(names.index(n) for n in LATERAL_PARAMS)  # type: ignore[return-value]

    @property
    def n_actuator(self) -> int:
        return len(self.lagged)

    @property
    def n_buffer(self) -> int:
        return sum(self.delay_samples)

    @property
    def augmented(self) -> bool:
        """Whether the discrete step carries actuator or delay states."""
        return bool(self.n_actuator or self.n_buffer)

    def body_state_names(self, with_position: bool = False) -> tuple[str, ...]:
        return STATE_NAMES + (POSITION_STATE_NAMES if with_position else ())

    def state_names(self, with_position: bool = False) -> tuple[str, ...]:
        """Names of the augmented state of the discrete step."""
        return (self.body_state_names(with_position)
                + tuple(f"{c}_actuator" for c in self.lagged)
                + tuple(f"{c}_delay_{k}" for c, d in zip(self.control_names,
                                                          self.delay_samples)
                        for k in range(1, d + 1)))

    def nx(self, with_position: bool = False) -> int:
        return len(self.state_names(with_position))


def structure_of(airframe: Airframe, fitting: tuple[str, ...] | list[str] = ()
                 ) -> ModelStructure:
    """The structure an airframe's values call for; ``fitting`` names parameters about to be
    identified, whose terms must be in the graph even where their current value is 0."""
    fitting = tuple(fitting)
    P = airframe.params
    alpha_dot = airframe.kind == "fixed_wing" and any(
        getattr(P, k) != 0.0 or k in fitting for k in ALPHA_DOT_KEYS)
    lags, slews = LAG_PARAMS[airframe.kind], SLEW_PARAMS[airframe.kind]

    def wanted(name: str | None) -> bool:
        return name is not None and (getattr(P, name) > 0.0 or name in fitting)

    slewed = tuple(c for c, _ in CONTROL_RANGES[airframe.kind] if wanted(slews.get(c)))
    lagged = tuple(c for c, _ in CONTROL_RANGES[airframe.kind]
                   if wanted(lags[c]) or c in slewed)
    delays = airframe.delay_samples()
    return ModelStructure(
        kind=airframe.kind, alpha_dot=alpha_dot, lagged=lagged, slewed=slewed,
        delays=delays if any(delays) else (),
        tables=tuple((n, airframe.tables[n].axes) for n in sorted(airframe.tables)),
        isa=airframe.atmosphere == "isa", lateral=airframe.lateral)
