"""The safe trainer's verdict: the validation figures a run reports, and the reason a
correction is kept (what it gains, at which scale, with which checks passed) or not (how every
candidate failed, then the closest failure)."""

from __future__ import annotations

import math

import numpy as np

from uavdyn.learned.rules import FREE_RUN_NOISE_FLOOR
from uavdyn.learned.safe.config import SafeConfig
from uavdyn.learned.safe.scoring import ValidationReference, beats_physics_in_pitch
from uavdyn.learned.stability import StabilityReport


def validation_summary(final: dict, ref: ValidationReference, alpha: float,
                       channels: np.ndarray, tried: list, horizon_s: float) -> dict:
    """The validation figures of the network reported (``final``: its :func:`score`)."""
    physics_val = ref.physics_rmse
    return {"selection_horizon_s": horizon_s, "physics_theta_rmse": physics_val,
            "corrected_theta_rmse": final["val_theta_rmse"],
            "ratio": (final["val_theta_rmse"] / physics_val if physics_val > 0 else math.inf),
            "sortie_ratio_geomean": final["val_ratio_geomean"],
            "sortie_ratio_worst": final["val_ratio_worst"],
            "state_ratios": dict(zip(("u", "w", "q", "theta"),
                                     final.get("val_state_ratios", []))),
            "sortie_ratios": dict(zip(ref.names, final["val_sortie_ratios"])),
            "pitch_noise_std": dict(zip(ref.names, ref.noise)),
            "state_noise_std": {name: [float(v) for v in n]
                                for name, n in zip(ref.names, ref.state_noise)},
            "output_scale": alpha, "channel_scales": [float(c) for c in channels],
            "shrink_tried": tried}


def _noise_level_text(row: dict) -> str:
    """The free-run sorties above the ratio by a noise-level difference, said (or nothing)."""
    n = row.get("free_run_noise_level", 0)
    return (f" ({n} above the ratio by less than {FREE_RUN_NOISE_FLOOR:g} x its pitch "
            "noise, a noise-level difference)") if n else ""


def _seen_text(row: dict) -> str:
    """The training sorties' worst ratio (``SafeConfig.seen_guard``), said (or nothing)."""
    worst = row.get("train_ratio_worst")
    return "" if worst is None else (f"; every training sortie's pitch error at most "
                                     f"{worst:.3g}x the physics'")


def kept_reason(final: dict, physics_val: float, alpha: float, channels: np.ndarray,
                chosen_row: dict, report: StabilityReport, horizon_s: float) -> str:
    """Why the correction is kept: its gains, scale, free runs and stability."""
    free_text = ""
    if "free_run_ok" in chosen_row:
        worst_free = chosen_row["free_run_worst"]
        free_text = (f"; free runs: worst ratio "
                     f"{'n/a' if worst_free is None else f'{worst_free:.3g}'} over "
                     f"{chosen_row['free_run_scored']} sorties the physics follows"
                     + _noise_level_text(chosen_row) + ", no new departure")
    return (f"validation pitch RMSE at {horizon_s:g} s "
            f"{physics_val:.4g} -> {final['val_theta_rmse']:.4g} rad (per-sortie "
            f"ratio geometric mean {final['val_ratio_geomean']:.3g}, worst "
            f"{final['val_ratio_worst']:.3g}, gain {final.get('val_gain_t', math.inf):.3g} "
            f"standard errors, output scale {alpha:g}"
            + ("" if np.all(channels == 1) else " x channels ("
               + ", ".join(f"{c:g}" for c in channels) + ")")
            + f"; every body state's error at most "
            f"{final['val_state_ratio_worst']:.3g}x the "
            f"physics'){_seen_text(chosen_row)}{free_text}; "
            f"{report.describe()}")


def _tally(tried: list, cfg: SafeConfig, physics_val: float, horizon_s: float) -> str:
    """How every candidate (epoch, output scales) failed."""
    beat = [r for r in tried if beats_physics_in_pitch(r, cfg, physics_val)]
    small = [r for r in tried if not beats_physics_in_pitch(r, cfg, physics_val)
             and beats_physics_in_pitch(r, cfg, physics_val, gain_checked=False)]
    states_worse = [r["val_state_ratio_worst"] for r in beat
                    if r["val_state_ratio_worst"] > cfg.state_ratio_limit]
    return (f"of {len(tried)} candidates (epoch, output scales): {len(tried) - len(beat)} do "
            f"not beat the physics in pitch on every validation sortie at {horizon_s:g} s"
            + (f" ({len(small)} of them by too small a gain: t below "
               f"{cfg.gain_significance:g} or a geometric mean ratio above "
               f"{1 - cfg.min_gain:g}; best t {max(r['val_gain_t'] for r in small):.3g}, best "
               f"mean {min(r['val_ratio_geomean'] for r in small):.3g})" if small else "")
            + f", {len(states_worse)} make a body state's error grow beyond "
            f"{cfg.state_ratio_limit:g}x"
            + (f" (least {min(states_worse):.4g}x)" if states_worse else "")
            + (f", {sum(r.get('train_ok') is False for r in tried)} make a training sortie "
               f"worse than {cfg.worst_sortie_ratio:g}x" if cfg.seen_guard else "")
            + f", {sum(r.get('free_run_ok') is False for r in tried)} fail the free-run guard, "
            f"{sum(r.get('stable') is False for r in tried)} the stability check; ")


def refusal_reason(tried: list, cfg: SafeConfig, physics_val: float, best: dict,
                   report: StabilityReport, horizon_s: float) -> str:
    """Why no correction is kept: the tally of failures, then the closest reason (``best``:
    the best epoch's validation figures)."""
    tally = _tally(tried, cfg, physics_val, horizon_s)
    if any(r.get("stable") is False for r in tried):  # beat the physics, failed the check
        return (tally + report.describe() + "; raise "
                f"--stability-weight (now {cfg.stability_weight:g}) or "
                "--stability-margin (now "
                f"{cfg.stability_margin:g}) and retrain")
    free_fails = [r for r in tried if r.get("free_run_ok") is False]
    if free_fails:  # beat the physics at the selection horizon, not over whole free runs
        r = free_fails[-1]
        why = [f"{r['free_run_new_departures']} run(s) leave the data where the physics' do "
               "not"] if r["free_run_new_departures"] else []
        if r["free_run_worst"] is not None and r["free_run_worst"] > cfg.free_run_ratio:
            why.append(f"worst free-run ratio {r['free_run_worst']:.3g} > "
                       f"{cfg.free_run_ratio:g}")
        return (tally + f"every output scale that beats the physics at "
                f"{horizon_s:g} s makes validation free runs worse (smallest, "
                f"{r['scale']:g}: {'; '.join(why)}): the physics is kept")
    seen_fails = [r for r in tried if r.get("train_ok") is False]
    if seen_fails:  # passed validation, made a sortie it was trained on worse
        r = min(seen_fails, key=lambda row: row["train_ratio_worst"])
        names = ", ".join(r["train_sorties_worse"]) or "a run that left the data"
        return (tally + f"every candidate that passes the validation rules makes a training "
                f"sortie worse than {cfg.worst_sortie_ratio:g}x the physics at "
                f"{horizon_s:g} s (closest: epoch {r['epoch']}, scale {r['scale']:g}, worst "
                f"{r['train_ratio_worst']:.3g}x: {names}): the physics is kept")
    small = [r for r in tried
             if beats_physics_in_pitch(r, cfg, physics_val, gain_checked=False)]
    if small:  # beat the physics on every sortie, by too small a gain
        r = max(small, key=lambda row: (row["val_gain_t"], -row["val_ratio_geomean"]))
        head = (tally + f"the best gain (epoch {r['epoch']}, scale {r['scale']:g}: per-sortie "
                f"ratio geometric mean {r['val_ratio_geomean']:.3g}, worst "
                f"{r['val_ratio_worst']:.3g}) is ")
        if r["val_gain_t"] < cfg.gain_significance:
            return (head + f"{r['val_gain_t']:.3g} standard errors of the sortie-to-sortie "
                    f"spread, below {cfg.gain_significance:g}: not told apart from no gain "
                    "on these validation sorties: the physics is kept")
        return (head + f"smaller than {100 * cfg.min_gain:g} % (the loss a sortie may show "
                "within noise): the physics is kept")
    closest = min(tried, key=lambda r: max(r["val_ratio_worst"] / cfg.worst_sortie_ratio,
                                           r["val_state_ratio_worst"] / cfg.state_ratio_limit))
    return (tally + f"the correction does not beat the physics on every "
            f"validation sortie at {horizon_s:g} s without a body state's error "
            f"growing (limits {cfg.worst_sortie_ratio:g}x per sortie in pitch, "
            f"{cfg.state_ratio_limit:g}x per state) at any epoch and output scale "
            f"tried ({', '.join(f'{a:g}' for a in cfg.shrink)}; closest: epoch "
            f"{closest['epoch']}, scale {closest['scale']:g}, worst sortie "
            f"{closest['val_ratio_worst']:.3g}x, worst state "
            f"{closest['val_state_ratio_worst']:.3g}x; pooled pitch "
            f"{best['val_theta_rmse']:.4g} vs {physics_val:.4g} rad): the physics "
            "is kept")
