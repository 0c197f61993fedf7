"""Consistency of an identification across its data: the same parameters fitted on each half
of the training sorties. Residual statistics cannot see a structure error that biases every
window alike; two halves flown differently can."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.excitation import excitation_for
from uavdyn.identify.result import IdentificationResult
from uavdyn.identify.uncertainty import zero_spanned

# Halves closer than this share of the value agree for any purpose a model is put to: on
# noise-free data their standard errors shrink to 1e-7 and less, and the integrator's own
# truncation error (the data's step against the fit's) would otherwise flag a recovered value.
HALVES_AGREE_RELATIVE = 1e-3


def compare_halves(identify: Callable[..., IdentificationResult], result: IdentificationResult,
                 train: list[Sortie], continuous: list[str], windows: int, options: dict
                 ) -> None:
    """Fit the continuous parameters on each half of the training sorties (alternate ones,
    from the fitted values) and compare: a difference beyond twice the halves' combined
    corrected standard error (and beyond :data:`HALVES_AGREE_RELATIVE` of the value) means
    the data disagree with the model structure (something the
    halves excite differently), whatever the residual statistics say. Such a parameter is
    flagged, and its corrected standard error raised to at least half the difference (the
    spread of a mean of two halves). Every corrected standard error is also at least that of
    the two halves' estimates combined (inverse-variance): the whole data are no more
    certain than their two independent halves together."""
    halves = []
    for part in (train[0::2], train[1::2]):
        try:
            res = identify(result.airframe, part, [], continuous, max_windows=windows,
                           **options)
        except IdentifyError as exc:  # a half that does not excite a parameter
            result.diagnostics["halves"] = {"not compared": str(exc)}
            return
        halves.append({e.name: e for e in res.estimates})
    out = {}
    for k, e in enumerate(result.estimates):
        if e.name not in continuous:
            continue
        a, b = halves[0][e.name], halves[1][e.name]
        sa, sb = a.std_error_corrected, b.std_error_corrected
        out[e.name] = {"first": [a.value, sa], "second": [b.value, sb]}
        # the whole data are no more certain than its two independent halves combined
        floor = 1.0 / math.sqrt(1.0 / max(sa, 1e-300) ** 2 + 1.0 / max(sb, 1e-300) ** 2)
        changes: dict = {"std_error_corrected": max(e.std_error_corrected, floor)}
        if abs(a.value - b.value) > max(2.0 * math.hypot(sa, sb),
                                        HALVES_AGREE_RELATIVE * abs(e.value)):
            why = (f"the two halves of the training sorties disagree ({a.value:.4g} +- "
                   f"{sa:.2g} against {b.value:.4g} +- {sb:.2g}): the model structure misses "
                   "something they excite differently")
            changes = {"std_error_corrected": max(changes["std_error_corrected"],
                                                  abs(a.value - b.value) / 2),
                       "undetermined": (*e.undetermined, why),
                       "excitation": e.excitation or excitation_for(e.name, [])}
        new = dataclasses.replace(e, **changes)
        spans = zero_spanned(new.value, new.std_error_corrected)
        if spans and spans not in new.undetermined:  # wider now: the interval may reach 0
            new = dataclasses.replace(new, undetermined=(*new.undetermined, spans),
                                      excitation=new.excitation or excitation_for(e.name, []))
        result.estimates[k] = new
    result.diagnostics["halves"] = out
