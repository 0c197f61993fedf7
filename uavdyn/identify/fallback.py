"""What an identification writes for a parameter the data do not determine: the airframe file's
value, not the fit's. A parameter whose corrected interval spans zero, that is collinear with
others or that ended on a bound (a sign bound included) is reset to its file value, and the
others, fitted jointly with it, are refitted with it fixed, so the written model is
consistent. Collinearity stays a reason: a closed-loop flight makes the elevator a copy of the
pitch states, and a group of moment derivatives can then come out with narrow intervals around
a common scale twice the truth, the halves agreeing (the trainer recovery of
``analysis/identify_recovery.py`` with each sortie weighted by its noise: ``C_m_alpha`` -1.64
+- 0.18 against -0.78). Halves of the data disagreeing is a flag on the model structure, not
a sign that the data cannot determine the value: such an estimate stays, flagged. The
estimate keeps the fit's value as ``data_value`` and says why in ``kept``; ``identify(...,
keep_undetermined=True)`` (``uavdyn identify --keep-undetermined``) writes the raw fit
instead. Under a prior, only an estimate still on a bound (or one without a prior, its file
value 0) keeps the file's value (the prior decides the others)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.identify.result import Estimate, IdentificationResult
from uavdyn.identify.uncertainty import zero_spanned
from uavdyn.identify.windows import fit_summary


def not_determined(estimate: Estimate, groups: list[list[str]], prior: bool = False) -> bool:
    """Whether a continuous estimate is not to be written: on a bound, or (without a
    ``prior``, or with one but a file value of 0, which has none) its corrected interval
    spanning zero or in a collinear group (names)."""
    if estimate.searched:
        return False
    if estimate.at_bound or (prior and estimate.nominal != 0):
        return bool(estimate.at_bound)
    return bool(zero_spanned(estimate.value, estimate.std_error_corrected)
                or any(estimate.name in g for g in groups))


def kept_reason(estimate: Estimate) -> str:
    """Why an estimate keeps the file's value (its flags)."""
    # an open sign bound at 0 is held just inside it (a denormal): say 0
    value = "0" if abs(estimate.value) < 1e-300 else f"{estimate.value:.6g}"
    return ("kept the airframe file's value: " + "; ".join(estimate.flags())
            + f" (the fit gave {value} +- {estimate.std_error_corrected:.2g})")


def keep_file_values(identify: Callable[..., IdentificationResult],
                     result: IdentificationResult, nominal: Airframe, train: list[Sortie],
                     validation: list[Sortie], names: list[str], options: dict
                     ) -> IdentificationResult:
    """``result`` with every undetermined continuous parameter at the file's value and the
    others refitted with them fixed (module docstring).

    Parameters
    ----------
    identify : callable
        :func:`uavdyn.identify.identify` (the refit applies this rule again, so a parameter
        the refit leaves undetermined keeps its file value too).
    result : IdentificationResult
        The fit of all ``names``.
    nominal : Airframe
        The airframe file's model.
    train, validation : list of Sortie
        The data of the fit.
    names : list of str
        The parameters of the fit, in order.
    options : dict
        The other keyword arguments of the fit.

    Returns
    -------
    IdentificationResult
        ``result`` itself when every parameter is determined.
    """
    groups = result.diagnostics.get("collinear_groups", [])
    prior = options.get("prior_sd") is not None
    kept = {e.name: e for e in result.estimates if not_determined(e, groups, prior)}
    if not kept:
        return result
    rest = [n for n in names if n not in kept]
    if rest:
        refit = identify(nominal, train, validation, rest, keep_undetermined=False,
                         free_run=False, **options)
    else:
        refit = _nothing_fitted(result, nominal, train, validation)
    by_name = {e.name: e for e in refit.estimates}
    refit.estimates = [dataclasses.replace(kept[n], value=kept[n].nominal,
                                           data_value=kept[n].value, kept=kept_reason(kept[n]))
                       if n in kept else by_name[n] for n in names]
    refit.diagnostics["first_fit"] = result.to_dict()["estimates"]
    refit.seconds += result.seconds
    return refit


def _nothing_fitted(result: IdentificationResult, nominal: Airframe, train: list[Sortie],
                    validation: list[Sortie]) -> IdentificationResult:
    """The result when no parameter is left to fit: the file's airframe, scored as both."""
    interval = result.dt * result.substeps
    stride = max(1, int(round(interval / float(np.median(np.diff(train[0].time))))))
    L = int(result.fit["window_samples"])
    fit = dict(result.fit)
    for split, sorties in (("train", train), ("validation", validation)):
        if fit.get(split):
            fit[split] = fit_summary(nominal, nominal, sorties, interval, result.substeps, L,
                                     stride)
    return dataclasses.replace(result, airframe=nominal, correlation=np.zeros((0, 0)),
                               flagged_pairs=[], fit=fit, diagnostics={})
