"""Whether an identified model flies the training data: each train sortie replayed open loop
from its first recorded state (its commands, nothing restarted), by the nominal and by the
identified model. A free run whose pitch error passes :data:`uavdyn.integrate.DEPARTURE_RAD`
(or that stops being finite) has departed: a model that cannot fly the data it was fitted on
is not one to design a controller on, whatever its 1 s windows say."""

from __future__ import annotations

import math

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.evaluation.metrics import fine_reference
from uavdyn.flightdata import Sortie
from uavdyn.integrate import DEPARTURE_RAD, DivergenceError, sortie_p
from uavdyn.linear.stiffness import step_stiffness


def departure_time(airframe: Airframe, sortie: Sortie, substeps: int) -> float | None:
    """Seconds into ``sortie`` at which the free run of ``airframe`` departs (its pitch error
    first passes :data:`DEPARTURE_RAD`, or its state stops being finite), None if it never
    does."""
    try:
        traj = fine_reference(airframe, sortie.time, sortie.states[0], sortie.controls,
                              sortie_p(sortie, airframe), substeps)
    except DivergenceError:
        return float(sortie.duration)
    with np.errstate(invalid="ignore"):
        left = np.flatnonzero(~(np.abs(traj[:, 3] - sortie.states[:, 3]) <= DEPARTURE_RAD))
    return float(sortie.time[left[0]] - sortie.time[0]) if len(left) else None


def free_run_check(nominal: Airframe, identified: Airframe, sorties: list[Sortie],
                   substeps: int) -> dict:
    """The free run of every sortie by both models: per sortie the departure time of each
    (None: stayed with the data), and the sorties each departed on.

    Parameters
    ----------
    nominal, identified : Airframe
        The airframe file's model and the fitted one.
    sorties : list of Sortie
        The train sorties.
    substeps : int
        RK steps per log sample.

    Returns
    -------
    dict
        ``departure_rad``, ``per_sortie`` (``sortie``, ``nominal_s``, ``identified_s``),
        ``nominal_departed`` and ``identified_departed`` (sortie names).
    """
    rows = [{"sortie": s.name, "nominal_s": departure_time(nominal, s, substeps),
             "identified_s": departure_time(identified, s, substeps)} for s in sorties]
    return {"departure_rad": DEPARTURE_RAD, "per_sortie": rows,
            "nominal_departed": [r["sortie"] for r in rows if r["nominal_s"] is not None],
            "identified_departed": [r["sortie"] for r in rows if r["identified_s"] is not None]}


def stiffness_check(identified: Airframe, sample_dt: float) -> dict | None:
    """Whether one RK4 step per log sample carries the identified model (what ``train``,
    ``mpc`` and ``export-c`` step with, whatever sub-steps the fit used); None when it does
    not trim at its nominal airspeed."""
    found = step_stiffness(identified, sample_dt)
    if found is None:
        return None
    return {"sample_dt": sample_dt, "too_stiff": found.too_stiff,
            "max_stable_dt": found.max_stable_dt, "describe": found.describe()}


def departure_line(fit: dict, of: int) -> str:
    """The headline's flag when the identified model's free run departs on the train sorties,
    or its prediction over the fit's own windows stops being finite (empty if neither)."""
    check = fit.get("free_run") or {}
    gone = check.get("identified_departed") or []
    windows = [r["sortie"] for r in (fit.get("train") or {}).get("per_sortie", [])
               if not math.isfinite(r["theta_rmse_identified"])
               and math.isfinite(r["theta_rmse_nominal"])]
    lines = []
    if gone:
        nominal = len(check.get("nominal_departed") or [])
        lines.append(f"the identified model's free run departs (pitch error past "
                     f"{check['departure_rad']:g} rad) on {len(gone)} of {of} train sorties "
                     f"({_names(gone)}); the nominal model's on {nominal}")
    if windows:
        lines.append(f"the identified model diverges within the fit's windows on "
                     f"{len(windows)} of {of} train sorties ({_names(windows)}), where the "
                     "nominal model does not")
    stiff = fit.get("step_stiffness") or {}
    if stiff.get("too_stiff"):
        lines.append(f"the identified model is too stiff for one RK4 step per log sample: "
                     f"{stiff['describe']}; train, mpc and export-c step once per sample and "
                     "will diverge (a parameter absorbing a term the list lacks, such as a lag "
                     "or a speed-stability moment, often does this: add the term, or check the "
                     "parameters that moved most)")
    if not lines:
        return ""
    return "WARNING: " + "; ".join(lines) + ". Do not design on it without checking why."


def _names(names: list[str]) -> str:
    return ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
