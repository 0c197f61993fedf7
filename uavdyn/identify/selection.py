"""Structure from the data: which model terms beyond the ones asked for the flight data
support (``uavdyn identify --structure auto``).

Candidate terms are the model's own optional terms and a breakpoint table of the pitching
moment over angle of attack (:func:`candidates_for`). Selection is greedy and forward: each
round fits every remaining candidate added to the current structure by output error on the
training sorties and scores it on the validation sorties (1 s pitch RMSE, windows restarted
from recorded states: data the candidate was not fitted on); the best candidate is kept when
it lowers that error by at least :data:`MIN_GAIN`, and the search stops when none does. Every
candidate's effect is reported, kept or not.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.airframes.tables import Table
from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.output_error import identify
from uavdyn.identify.result import IdentificationResult

MIN_GAIN = 0.02      # a kept term lowers the validation error by at least 2 %
MAX_ROUNDS = 4
TABLE_POINTS = 5     # breakpoints of a candidate C_m(alpha) table

# Optional linear terms per kind: (parameter, what it is)
LINEAR_TERMS: dict[str, tuple[tuple[str, str], ...]] = {
    "fixed_wing": (
        ("C_L_alpha2", "lift quadratic in angle of attack"),
        ("C_L_q", "lift from pitch rate"),
        ("C_L_delta_e", "lift from the elevator"),
        ("C_D_delta_e", "drag from the elevator"),
        ("C_L_alpha_dot", "lift from the rate of angle of attack"),
        ("C_m_alpha_dot", "pitching moment from the rate of angle of attack"),
        ("tau_elevator", "elevator actuator lag"),
        ("slew_elevator", "elevator servo rate limit"),
        ("slew_throttle", "throttle (engine) rate limit"),
    ),
    "multirotor": (
        ("M_u", "speed-stability pitching moment"),
        ("M_0", "constant pitching moment"),
        ("k_inflow", "thrust loss with axial inflow"),
        ("tau_rotor", "rotor-speed lag"),
        ("CdA_z", "vertical drag"),
        ("drag_linear", "linear rotor drag"),
    ),
}


@dataclass(frozen=True)
class Candidate:
    """A term the data may support: the parameters it adds to the fit, those it replaces, and
    the structure change it needs (e.g. a table in the airframe)."""

    name: str
    what: str
    adds: tuple[str, ...]
    replaces: tuple[str, ...] = ()
    change: Callable[[Airframe], Airframe] | None = None

    def apply(self, airframe: Airframe, names: list[str]) -> tuple[Airframe, list[str]]:
        """The airframe and parameter list with this term in."""
        af = self.change(airframe) if self.change is not None else airframe
        kept = [n for n in names if n not in self.replaces]
        return af, kept + [n for n in self.adds if n not in kept]


def candidates_for(airframe: Airframe, names: list[str], sorties: list[Sortie]
                   ) -> list[Candidate]:
    """The candidate terms for ``airframe`` not already fitted: its kind's optional linear
    terms, and for a fixed wing without a pitching-moment table a ``C_m(alpha)`` table of
    :data:`TABLE_POINTS` breakpoints over the angles of attack flown below stall (replacing
    ``C_m_0 + C_m_alpha alpha``, started from that line)."""
    out = [Candidate(p, what, (p,)) for p, what in LINEAR_TERMS[airframe.kind]
           if p not in names and p in airframe.param_names]
    if airframe.kind == "fixed_wing" and "C_m" not in airframe.tables:
        alpha = np.concatenate([np.arctan2(s.states[:, 1], s.states[:, 0]) for s in sorties])
        alpha = alpha[np.abs(alpha) < airframe.params.alpha0]
        if alpha.size and np.ptp(alpha) > 1e-3:  # the whole range flown: held beyond it
            points = tuple(float(a) for a in np.linspace(alpha.min(), alpha.max(),
                                                         TABLE_POINTS))
            out.append(_moment_table(airframe, points))
    return out


def _moment_table(airframe: Airframe, points: tuple[float, ...]) -> Candidate:
    P = airframe.params
    values = tuple(float(P.C_m_0 + P.C_m_alpha * a) for a in points)
    table = Table("C_m", (("alpha", points),), values)

    def change(af: Airframe) -> Airframe:
        return dataclasses.replace(af, tables={**af.tables, "C_m": table})

    return Candidate(f"C_m(alpha) table, {len(points)} points",
                     "pitching moment as a breakpoint table over angle of attack "
                     f"({np.degrees(points[0]):.1f} to {np.degrees(points[-1]):.1f} deg)",
                     table.value_names(), ("C_m_0", "C_m_alpha"), change)


def validation_error(result: IdentificationResult) -> float:
    """The criterion: pooled 1 s pitch RMSE of the fitted model on the validation sorties."""
    return float(result.fit["validation"]["theta_rmse"]["identified"])


def select_structure(airframe: Airframe, train: list[Sortie], validation: list[Sortie],
                     names: list[str], say: Callable[[str], None] | None = None,
                     **options) -> tuple[IdentificationResult, Airframe, list[dict]]:
    """Fit ``names``, then add candidate terms greedily while one lowers the validation error
    by :data:`MIN_GAIN` or more (module docstring). ``say(message)`` is told each fit;
    ``options`` go to :func:`uavdyn.identify.identify`.

    Returns
    -------
    result : IdentificationResult
        The final fit (of the chosen structure).
    start : Airframe
        The airframe it started from (the nominal one with the chosen structure changes).
    log : list of dict
        Every fit: the terms in it, its validation error, whether it was kept.

    Raises
    ------
    IdentifyError
        Without validation sorties (the criterion needs data the terms were not fitted on).
    """
    if not validation:
        raise IdentifyError("structure selection needs validation sorties (manifest split "
                            "'validation'): terms are kept only if they predict data they "
                            "were not fitted on")
    say = say or (lambda _msg: None)
    halves = options.pop("check_halves", True)
    options["check_halves"] = False  # the candidates are compared on validation data
    say(f"structure: fitting the base ({', '.join(names)})")
    best = identify(airframe, train, validation, names, **options)
    start, current, score = airframe, list(names), validation_error(best)
    log = [{"step": "base", "terms": list(names), "validation_theta_rmse": score,
            "kept": True}]
    remaining = candidates_for(airframe, names, train)
    for _ in range(MAX_ROUNDS):
        trials = []
        for cand in remaining:
            af, trial_names = cand.apply(start, current)
            say(f"structure: trying {cand.name}")
            try:
                res = identify(af, train, validation, trial_names, **options)
            except IdentifyError as exc:  # e.g. not excited by these data
                log.append({"step": cand.name, "what": cand.what, "refused": str(exc),
                            "kept": False})
                continue
            trials.append((validation_error(res), cand, res, af, trial_names))
            log.append({"step": cand.name, "what": cand.what,
                        "validation_theta_rmse": trials[-1][0], "against": score,
                        "kept": False})
        if not trials:
            break
        value, cand, res, af, trial_names = min(trials, key=lambda t: t[0])
        if not value <= (1.0 - MIN_GAIN) * score:
            break
        next(e for e in reversed(log) if e["step"] == cand.name)["kept"] = True
        start, current, score, best = af, trial_names, value, res
        remaining = [c for c in remaining if c is not cand]
        say(f"structure: kept {cand.name} (validation 1 s pitch RMSE {value:.4g} rad)")
    if halves:  # the chosen structure's final fit, with the consistency check
        say("structure: final fit of the chosen structure")
        best = identify(start, train, validation, current, **{**options, "check_halves": True})
    return best, start, log
