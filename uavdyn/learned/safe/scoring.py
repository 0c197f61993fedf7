"""How the safe trainer scores a network: the training loss over windows (the physics scores
1), and the validation figures that select and guard it (pooled pitch RMSE at the selection
horizon, per-sortie and per-state ratios against the physics with each sortie's measurement
noise taken off, :mod:`uavdyn.learned.rules`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from uavdyn.flightdata import Sortie
from uavdyn.learned.rules import (
    noise_resolution,
    pooled_state_errors,
    sortie_ratio,
    summarise_ratios,
)
from uavdyn.learned.rules import state_noise as sortie_state_noise
from uavdyn.learned.safe.config import THETA, SafeConfig
from uavdyn.learned.safe.data import LossScales, TrainingWindows, WindowTensors, as_tensor
from uavdyn.learned.torch_model import TorchCorrection

# the model's free run through windows as NumPy (W, H, 4): the compiled twin's ``predict``
Predictor = Callable[[TorchCorrection, WindowTensors], np.ndarray]


def torch_rollout(model: TorchCorrection, z0, u, p, dt: float) -> torch.Tensor:
    """Free run of the torch hybrid step through each window: body states (W, H, 4)."""
    z, out = z0, []
    for k in range(u.shape[1]):
        z = model.step(z, u[:, k], p, dt)
        out.append(z[:, :4])
    return torch.stack(out, dim=1)


@dataclass(frozen=True)
class WindowLoss:
    """The training loss. It mixes two views, each scoring the physics-only step as 1: per
    window, relative to the physics' error on that window (a calm window weighs as much as a
    gusty one, so the correction may not buy turbulent accuracy with calm-air errors), and
    pooled (the windows where the physics is worst count by their size, as in the pooled RMSE
    users quote)."""

    state_scale: torch.Tensor
    growth: torch.Tensor
    pooled_weight: float
    dt: float

    @classmethod
    def of(cls, scales: LossScales, cfg: SafeConfig, dt: float) -> WindowLoss:
        return cls(as_tensor(scales.state), as_tensor(scales.growth), cfg.pooled_weight, dt)

    def __call__(self, model: TorchCorrection, D: WindowTensors) -> torch.Tensor:
        return self.of_prediction(torch_rollout(model, D.z0, D.u, D.p.T, self.dt), D)

    def of_prediction(self, pred: torch.Tensor, D: WindowTensors) -> torch.Tensor:
        """The loss of the predicted body states ``pred`` (W, H, 4) of the windows ``D``."""
        e = torch.mean(torch.mean(((pred - D.y) / self.state_scale) ** 2, dim=2) / self.growth,
                       dim=1)
        return ((1.0 - self.pooled_weight) * torch.mean(e * D.weight)
                + self.pooled_weight * torch.mean(e))


def fixed_windows(cfg: SafeConfig, n_train: int, n_val: int) -> tuple[torch.Tensor, ...]:
    """The training and validation windows scored after every epoch: one definition for the
    loss columns of Table 2 (the running mini-batch mean mixes changing weights)."""
    pick = np.random.default_rng([cfg.seed, 1])  # not the batches' generator
    return tuple(torch.as_tensor(np.sort(pick.choice(n, min(cfg.eval_windows, n),
                                                     replace=False)))
                 for n in (n_train, n_val))


STRETCH_S = 60.0  # validation sorties longer than this are scored in stretches about this long
MIN_UNITS = 3  # fewer units than this: stretches cut shorter (the gain's t needs a spread) ...
MIN_STRETCH_S = 5.0  # ... but not below this (five 1 s windows side by side)


@dataclass(frozen=True)
class Stretches:
    """The units the per-sortie rules score: every validation sortie cut into
    ``round(duration / L)`` (at least 1) equal stretches by its windows' start times, ``L``
    :data:`STRETCH_S` (:func:`stretch_length`). An emulated 30 s sortie is one stretch; a
    6-minute log of a campaign is six, so the rule that no sortie may get worse looks at each
    minute of it, and the gain's significance (a paired t over the units) has more than one
    unit to measure a spread on. Where that would leave fewer than :data:`MIN_UNITS` (a log's
    one 13 s validation segment), the stretches are cut shorter, down to
    :data:`MIN_STRETCH_S`: with one unit a gain's t cannot be measured and any gain would
    pass the significance rule."""

    index: np.ndarray         # (W,) the stretch of each window
    sortie: np.ndarray        # (n_units,) the sortie of each stretch
    names: tuple[str, ...]    # the sortie's name, with the stretch's span where cut


def stretches(va: TrainingWindows, val_sorties: list[Sortie]) -> Stretches:
    """:class:`Stretches` of the validation windows ``va``."""
    starts = np.asarray(va.windows.starts, int).reshape(-1, 2)
    index = np.zeros(len(starts), int)
    owner, names = [], []
    stretch_s = stretch_length([s.duration for s in val_sorties])
    for i, s in enumerate(val_sorties):
        n = max(1, int(round(s.duration / stretch_s)))
        length = s.duration / n
        mine = starts[:, 0] == i
        t0 = s.time[starts[mine, 1]] - s.time[0]
        index[mine] = len(owner) + np.minimum((t0 // length).astype(int), n - 1)
        owner += [i] * n
        names += [s.name] if n == 1 else [f"{s.name} [{k * length:.0f}-{(k + 1) * length:.0f} s]"
                                          for k in range(n)]
    return Stretches(index, np.array(owner, int), tuple(names))


def stretch_length(durations: list[float]) -> float:
    """The stretch length of :func:`stretches` for sorties of these ``durations`` (s):
    :data:`STRETCH_S`, or shorter (not below :data:`MIN_STRETCH_S`) so that there are at
    least :data:`MIN_UNITS` stretches where the flight allows."""
    units = sum(max(1, int(round(d / STRETCH_S))) for d in durations)
    if units >= MIN_UNITS:
        return STRETCH_S
    return max(MIN_STRETCH_S, float(sum(durations)) / MIN_UNITS)


def _sortie_rmse(err: np.ndarray, sortie: np.ndarray, i: int) -> float | None:
    """Sortie ``i``'s pitch RMSE over its windows (None: no window)."""
    mine = err[sortie == i]
    return math.sqrt(float(np.mean(mine))) if len(mine) else None


@dataclass(frozen=True)
class ValidationReference:
    """The validation windows' records and the physics' figures a network is compared with.
    Per-sortie and per-state ratios compare errors against the truth: each sortie's state
    noise (estimated from its own records) is taken off; the pooled pitch RMSE stays as
    measured."""

    y: np.ndarray                       # (W, H, 4) recorded body states
    sortie: np.ndarray                  # (W,) the stretch (Stretches) of each window
    horizon: int                        # samples of the selection horizon
    state_noise: np.ndarray             # (n_units, 4) per stretch: its sortie's noise
    physics_sortie: list[float | None]  # per stretch pitch RMSE of the physics
    physics_states: np.ndarray          # (4,) pooled errors of the physics (inf where 0)
    physics_rmse: float                 # pooled pitch RMSE of the physics
    names: tuple[str, ...] = ()         # per stretch: its sortie's name (and span where cut)

    @property
    def noise(self) -> list[float]:
        """Per sortie pitch noise (rad)."""
        return [float(n) for n in self.state_noise[:, THETA]]

    @property
    def resolution(self) -> list[float]:
        """Per sortie, the smallest pitch error above the noise its scored samples resolve
        (:func:`uavdyn.learned.rules.noise_resolution`)."""
        counts = np.bincount(self.sortie, minlength=len(self.state_noise)) * self.horizon
        return [noise_resolution(n, c) for n, c in zip(self.noise, counts)]

    def state_errors(self, pred: np.ndarray) -> np.ndarray:
        """Pooled errors of each body state of ``pred`` (W, horizon, 4), noise taken off."""
        return pooled_state_errors(pred, self.y[:, :self.horizon, :4],
                                   self.state_noise[self.sortie])


def validation_reference(va: TrainingWindows, val_sorties: list[Sortie], horizon: int
                         ) -> ValidationReference:
    """The :class:`ValidationReference` of the validation windows ``va``, scored per
    :func:`stretches`."""
    units = stretches(va, val_sorties)
    state_noise = np.array([sortie_state_noise(s) for s in val_sorties])[units.sortie]
    err_val = (va.physics[:, :horizon, THETA] - va.y[:, :horizon, THETA]) ** 2
    phys_states = pooled_state_errors(va.physics[:, :horizon], va.y[:, :horizon, :4],
                                      state_noise[units.index])
    return ValidationReference(
        va.y, units.index, horizon, state_noise,
        [_sortie_rmse(err_val, units.index, i) for i in range(len(units.names))],
        np.where(phys_states > 0, phys_states, np.inf),
        float(np.sqrt(np.mean(err_val))), units.names)


def score(model: TorchCorrection, V: WindowTensors, ref: ValidationReference, dt: float,
          predict: Predictor | None = None) -> dict:
    """Validation pitch RMSE at the selection horizon (pooled), per validation sortie the
    ratio corrected / physics of the pitch errors with the sortie's measurement noise taken
    off (their geometric mean selects, the worst one guards) and per body state the ratio of
    pooled errors, noise taken off too (guards: a correction may not buy pitch accuracy with
    airspeed or climb-rate errors, which a speed or altitude controller would pay for)."""
    H = ref.horizon
    if predict is not None:
        pred = predict(model, V)[:, :H]
    else:
        with torch.no_grad():
            pred = torch_rollout(model, V.z0, V.u[:, :H], V.p.T, dt).numpy()
    err = (pred[:, :, THETA] - ref.y[:, :H, THETA]) ** 2
    noise, resolution = ref.noise, ref.resolution
    with np.errstate(over="ignore", invalid="ignore"):
        state_ratios = ref.state_errors(pred) / ref.physics_states
        ratios = [sortie_ratio(ref.physics_sortie[i], _sortie_rmse(err, ref.sortie, i),
                               noise[i], resolution[i]) for i in range(len(noise))]
    summary = summarise_ratios(ratios)
    worst_state = float(np.max(state_ratios))
    return {"val_theta_rmse": float(np.sqrt(np.mean(err))),
            "val_state_ratios": [float(v) for v in state_ratios],
            "val_state_ratio_worst": worst_state if math.isfinite(worst_state) else math.inf,
            "val_ratio_geomean": summary.geomean,
            "val_ratio_worst": summary.worst,
            "val_gain_t": summary.gain_t,
            "val_sortie_ratios": [None if v is None or not math.isfinite(v) else float(v)
                                  for v in ratios]}


def rank(sel: dict, cfg: SafeConfig) -> tuple:
    """Epochs where no validation sortie got worse come first, then the geometric mean
    (epoch 0, the untrained network, is the physics itself and never a candidate)."""
    return (sel["val_ratio_worst"] > cfg.worst_sortie_ratio, sel["val_ratio_geomean"])


def gain_large_enough(sel: dict, cfg: SafeConfig) -> bool:
    """The validation sorties' gain stands out of their spread (``cfg.gain_significance``)
    and is at least ``cfg.min_gain`` (geometric mean of the per-sortie ratios)."""
    return (sel.get("val_gain_t", math.inf) >= cfg.gain_significance
            and sel["val_ratio_geomean"] <= 1.0 - cfg.min_gain)


def beats_physics_in_pitch(sel: dict, cfg: SafeConfig, physics_rmse: float,
                           gain_checked: bool = True) -> bool:
    """Pooled and on every validation sortie (within the tolerance) at the selection
    horizon, by a gain large enough (:func:`gain_large_enough`; ``gain_checked=False``: any
    gain)."""
    return (sel["val_ratio_worst"] <= cfg.worst_sortie_ratio
            and sel["val_ratio_geomean"] < 1.0 and sel["val_theta_rmse"] < physics_rmse
            and (not gain_checked or gain_large_enough(sel, cfg)))
