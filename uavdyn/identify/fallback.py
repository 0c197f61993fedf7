"""What an identification writes for a parameter the data do not determine: the airframe file's
value, not the fit's, or, for a group the data determine only in part, the fit with just the
undetermined combination held at the file's values.

A parameter whose corrected interval spans zero or that ended on a bound (a sign bound
included) is reset to its file value, and the others, fitted jointly with it, are refitted
with it fixed (the rule applied again), so the written model is consistent.

A collinear group (Belsley's near-dependency) is different: its members' intervals may be
narrow, the data determining every combination of them but one. Resetting the whole group
throws that information away (the emulated Aerosonde, 24 x 30 s: ``C_m_alpha``,
``C_m_delta_e`` and ``tau_elevator`` collinear at r = 0.99, each data-only interval narrow
around the truth; reset, the file's ``tau_elevator = 0`` made a held-out sortie 41 % worse
than the file's own model). So the group is refitted with only the near-dependency's direction,
the combination the data cannot determine, held at the file's values (principal-components
regression, the biased estimator Klein and Morelli give for collinear data; a member whose
interval also spans zero, or that sits on a bound, is reset to its file value and its group's
row dropped, and a parameter outside every group that does so is reset in the same refit,
the groups held): the file decides
the common scale that closed-loop data can get wrong (narrow intervals around a common scale
twice the truth in the trainer recovery of ``analysis/identify_recovery.py``), the data the
rest. Such an estimate says so in ``held`` with the unconstrained value as ``data_value``; it
still counts as not determined by the data alone, and its standard errors are the constrained
ones (they take the held combination as exact).

Halves of the data disagreeing is a flag on the model structure, not a sign that the data
cannot determine the value: such an estimate stays, flagged. ``identify(...,
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
    """Whether a continuous estimate is not to be written as fitted: on a bound, or (without
    a ``prior``, or with one but a file value of 0, which has none) its corrected interval
    spanning zero or in a collinear group (names)."""
    if estimate.searched:
        return False
    if estimate.at_bound or (prior and estimate.nominal != 0):
        return bool(estimate.at_bound)
    return bool(zero_spanned(estimate.value, estimate.std_error_corrected)
                or any(estimate.name in g for g in groups))


def only_collinear(estimate: Estimate) -> bool:
    """Whether an undetermined estimate is so only for its collinear group (its interval
    clear of zero, not on a bound): a member whose group is held, not reset."""
    return not estimate.at_bound and not zero_spanned(estimate.value,
                                                      estimate.std_error_corrected)


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
    if not prior:
        reset = {n: e for n, e in kept.items() if not only_collinear(e)}
        # a group keeps its held row unless one of its members is reset (that breaks it)
        weak = [(g, row) for g, row in zip(groups, result.diagnostics.get("weak_directions", []))
                if not set(g) & set(reset)]
        held = {n for g, _ in weak for n in g}
        # every collinear-only estimate must be in a held group, else the rule sees a refit
        if weak and all(n in held for n in kept if n not in reset):
            return hold_weak_combinations(identify, result, nominal, train, validation, names,
                                          options, reset, weak)
        kept = reset or kept
    rest = [n for n in names if n not in kept]
    if rest:
        refit = identify(nominal, train, validation, rest, keep_undetermined=False,
                         free_run=False, **options)
    else:
        refit = _nothing_fitted(result, nominal, train, validation)
    return _with_kept(refit, result, kept, names)


def _with_kept(refit: IdentificationResult, result: IdentificationResult,
               kept: dict[str, Estimate], names: list[str]) -> IdentificationResult:
    """``refit`` with the ``kept`` estimates (of the first fit ``result``) at the file's
    value, in the order of ``names``."""
    by_name = {e.name: e for e in refit.estimates}
    refit.estimates = [dataclasses.replace(kept[n], value=kept[n].nominal,
                                           data_value=kept[n].value, kept=kept_reason(kept[n]))
                       if n in kept else by_name[n] for n in names]
    refit.diagnostics["first_fit"] = result.to_dict()["estimates"]
    refit.seconds += result.seconds
    return refit


def hold_weak_combinations(identify: Callable[..., IdentificationResult],
                           result: IdentificationResult, nominal: Airframe, train: list[Sortie],
                           validation: list[Sortie], names: list[str], options: dict,
                           reset: dict[str, Estimate],
                           weak: list[tuple[list[str], dict[str, float]]]
                           ) -> IdentificationResult:
    """``result`` refitted with the ``reset`` estimates at the file's value and each
    collinear group's undetermined combination (``weak``: the group and its
    ``diagnostics["weak_directions"]`` row) held at the file's values (module docstring);
    the other arguments as :func:`keep_file_values`."""
    members = {n for g, _ in weak for n in g}
    reset = dict(reset)
    for _ in range(len(names)):  # one the refit leaves undetermined is reset too
        rest = [n for n in names if n not in reset]
        rows = [{n: c for n, c in row.items() if n in rest} for _, row in weak]
        refit = identify(nominal, train, validation, rest, keep_undetermined=True,
                         free_run=False, hold=rows, **{**options, "check_halves": False})
        again = refit.diagnostics.get("collinear_groups", [])
        newly = {e.name: e for e in refit.estimates if e.name not in members
                 and not_determined(e, again) and not e.searched}
        if not newly:
            break
        reset.update(newly)
    first = {e.name: e for e in result.estimates}
    estimates = []
    for e in refit.estimates:
        group = next((g for g, _ in weak if e.name in g), None)
        if group is None or e.searched:
            estimates.append(e)
            continue
        data = first[e.name]
        halves = tuple(w for w in data.undetermined if "halves" in w
                       and w not in e.undetermined)
        estimates.append(dataclasses.replace(
            e, undetermined=e.undetermined + halves, data_value=data.value,
            held=(f"with {', '.join(g for g in group if g != e.name)}, the one combination "
                  f"these data cannot determine held at the file's values, the rest fitted "
                  f"(unconstrained: {data.value:.6g} +- {data.std_error_corrected:.2g})")))
    refit.estimates = estimates
    refit.diagnostics["collinear_groups"] = [g for g, _ in weak]
    return _with_kept(refit, result, reset, names)


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
