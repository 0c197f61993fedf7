"""What defines a safe-correction training run and what it returns: the configuration, the
result, the error, and the quantities every stage derives from them (sample step, window
lengths, the physics step and the correction's state layout)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.integrate import DiscreteModel, physics_step
from uavdyn.learned.formulations import CorrectionLayout
from uavdyn.learned.hybrid import correction_structure
from uavdyn.learned.stability import DEFAULT_MARGIN, STABILITY_TRIMS, StabilityReport
from uavdyn.learned.weights import CorrectionNet
from uavdyn.model import ModelStructure

THETA = 3  # index of pitch in the body state (u, w, q, theta)
# The hidden width by airframe kind. The cost target is relative to the physics step, and a
# multirotor's physics step (no aerodynamic coefficients) costs about 0.15 us against a fixed
# wing's 0.4 us on recorded flight (analysis/bench_rollout.py --dataset): the same network
# weighs more on it. The multirotor width is the knockout's choice (docs/learned_correction.md,
# docs/benchmarks/knockout_width/): 3 x 5 costs about 1.48x the physics step where 3 x 6 cost
# 1.51-1.54x; over three training seeds it misses a 0.6 share of the inflow term as often
# (1 of 6 runs) and makes as many test sorties worse (2), recovering somewhat less on average.
DEFAULT_HIDDEN = {"fixed_wing": 8, "multirotor": 5}
# The network's input and output design by airframe kind, chosen by the knockout benchmark
# (analysis/bench_knockout.py, docs/learned_correction.md): physical inputs for both (a fixed
# wing's alpha, V, q c/2V, alpha-dot c/2V and thrust coefficient; a multirotor's u, w, q,
# thrust per weight, rotor speed times u and w and the front-rear rotor-speed difference times
# u and w), a fixed wing's output as coefficients
# scaled by dynamic pressure (a hovering multirotor has none to scale by).
DEFAULT_DESIGN = {"fixed_wing": ("physical", "coefficient"),
                  "multirotor": ("physical", "acceleration")}


class SafeTrainingError(ValueError):
    """The data cannot train a correction (the message says why)."""


@dataclass
class SafeConfig:
    """Everything that defines a safe-correction training run (saved with the weights)."""

    hidden: int | None = None         # width of the 3 ReLU layers; None: DEFAULT_HIDDEN of
                                      # the airframe's kind (the width sets the step cost)
    activation: str = "relu"
    inputs: str | None = None         # what the network sees in place of the body states:
                                      # "state" or "physical" (alpha, V, q c/2V, ...;
                                      # uavdyn.learned.formulations.correction_inputs);
                                      # None: DEFAULT_DESIGN of the airframe's kind
    output: str | None = None         # "acceleration" or "coefficient" (dC_X, dC_Z, dC_m
                                      # times dynamic pressure; a fixed wing only); None:
                                      # DEFAULT_DESIGN of the airframe's kind
    linear: bool = True               # a linear path from the inputs to the outputs beside the
                                      # hidden layers (uavdyn.learned.mlp): on the knockout
                                      # benchmark it recovered 0.45 of the trainer's alpha-dot
                                      # term against 0.15 without, 0.56 of the F450's inflow
                                      # term against 0.27
    rates_linear: bool = False        # the rate inputs (q, q c/2V, alpha_dot c/2V) reach the
                                      # outputs only through the linear path: a rate enters
                                      # as a stability derivative does, one constant per
                                      # output, not a damping the hidden layers vary with
                                      # the flight condition
    all_linear: bool = False          # every input reaches the outputs only through the
                                      # linear path (the hidden layers give a constant): the
                                      # correction is a change of the physics' coefficients
    linear_first_epochs: int = 0      # > 0: the first this many epochs train the linear path
                                      # alone (the hidden layers' output held at zero), then
                                      # the hidden layers join from their initial weights
                                      # (patience counts from the release)
    memory_tau: tuple[float, ...] | None = None  # None: (0.05, 0.2) s without actuator states
    horizon_s: float = 2.0            # rollout windows from recorded states, this long
    window_stride_s: float = 0.5
    selection_horizon_s: float = 1.0  # validation metric: pitch RMSE over this horizon
    batch_windows: int = 24
    batches_per_epoch: int = 6
    eval_windows: int = 128           # fixed train and validation windows scored after every
                                      # epoch with the same loss (Table 2, Fig. 4)
    epochs: int = 300                # a budget: patience ends a run that stops improving
    lr: float = 3e-3
    lr_final: float = 3e-4
    patience: int = 40               # epochs without a better validation rank or mean
                                     # ratio; on the knockout benchmark 20 ended runs while
                                     # the learning rate was still high (F450 inflow at epoch
                                     # 64, X500 inflow 0.84 of the term against 0.94 with 40)
    start_lowpass_hz: float = 0.0    # windows start from the records low-passed at this
                                     # cutoff (zero phase; 0: raw), the targets stay raw
    validation_start_lowpass_hz: float = 0.0  # the same for the validation windows only
                                     # (what selects and keeps a correction)
    start_fit_s: float = 0.2         # validation windows start where each model scored (the
                                     # physics, each candidate) fits its own trajectory to
                                     # the window's first records over this long (0: the
                                     # records, whose noise a network could earn a gain by
                                     # damping; uavdyn.integrate.start_fit)
    train_start_fit: bool = False    # True: the training windows start where the physics
                                     # fits the first start_fit_s of records too (so a network
                                     # gains nothing by damping a noisy start out)
    train_refit_every: int = 0       # > 0: every this many epochs the training windows
                                     # start where the network being trained fits the first
                                     # start_fit_s of records (0: from the records)
    average_decay: float = 0.0       # > 0: the epochs score and keep an exponential moving
                                     # average of the weights over the optimiser steps, with
                                     # this decay per step (epochs.WeightAverage)
    restarts: int = 1                # networks started from different seeds, each trained
                                     # restart_epochs, the best by validation rank carried on
    restart_epochs: int = 40
    pooled_weight: float = 0.0       # share of the loss on the pooled error (rest: per window)
    output_weight: float = 0.0       # weight of the output penalty (mean square output over
                                     # training samples, in output scales; epochs.py)
    damping_weight: float = 10.0     # weight of the damping prior (epochs.damping_penalty),
                                     # an exact-penalty hinge as the stability one: the
                                     # hybrid's pitch damping d(q_dot)/dq at the training
                                     # windows' starts may weaken the physics' but not turn
                                     # positive. Without it an X500 network did, on 16 % of
                                     # a gusty inspection's samples, and its pitch-rate
                                     # feedback made that flight 15 % worse (4 % with it);
                                     # 0 switches it off (docs/learned_correction.md)
    stability_weight: float = 10.0
    stability_margin: float = DEFAULT_MARGIN
    stability_trims: str = "repair"   # where the training penalty holds the hybrid's modes:
                                      # "box" (trims over the training envelope's airspeeds)
                                      # or "gate" (those and the margins' out to where the gate
                                      # reaches 0: every trim the final exact check runs at);
                                      # "repair" (default): "box", and where a candidate at
                                      # full output fails only the exact check, the best of
                                      # them trained on for repair_epochs epochs with the
                                      # penalty at every trim the check runs at, its epochs
                                      # competing in the final checks. On an imported turning
                                      # campaign "box" let the phugoid at the fast margin go
                                      # unstable at full output and the check kept the
                                      # correction at output scale 0.35; "gate" held the
                                      # knockout's networks more than its data needed
                                      # (docs/learned_correction.md, turning_correction*.json)
    repair_epochs: int = 40           # the epochs of a stability repair (stability_trims)
    envelope_quantile: float = 0.001
    steady_gate: bool = False         # in steady flight (pitch rate held near zero) the
                                      # correction acts only inside the box of the training
                                      # data's steady flight (SteadyBox): between the steady
                                      # conditions a network was trained on it has only
                                      # manoeuvres, which do not show the moment balance
                                      # (docs/learned_correction.md, knockout_residuals.py)
    envelope_fade: float | None = None  # how far beyond the training box the gate reaches
                                      # 0 (the exact stability check runs out to there).
                                      # None: per input, as far as any training or
                                      # validation sample lies beyond the box, 0.1-1 range
                                      # widths (Envelope.from_evidence): the network acts only
                                      # where data vouch for it. A number: this many range
                                      # widths for every input (1.0 let an X500 correction
                                      # act 12 % above its fastest flight and made a calm
                                      # survey 30 % worse; docs/learned_correction.md)
    bound_factor: float = 2.0
    shrink: tuple[float, ...] = (1.0, 0.75, 0.5, 0.35, 0.25)  # output scales tried at the end
    candidate_epochs: int = 5        # the best epochs (by rank) the final checks go through
    worst_sortie_ratio: float = 1.02  # every validation sortie: corrected/physics at 1 s <=
                                     # this (its measurement noise taken off both)
    gain_significance: float = 2.0   # ... and the validation sorties' mean log ratio below 0
                                     # by this many standard errors (a paired t statistic,
                                     # about one-sided 95 % on 6 sorties): a gain within the
                                     # sortie-to-sortie spread is not a gain (issue 40: a
                                     # 0.2 % gain kept at worst 1.02 made 2 test sorties
                                     # worse by more than 2 %)
    min_gain: float = 0.02           # ... and their geometric mean ratio at most 1 - this: a
                                     # gain smaller than the 2 % a sortie may lose to noise
                                     # is not worth shipping (issue 40: the Aerosonde's
                                     # Reynolds case, 0.4 % on validation with t = 2.2, made 2
                                     # test sorties worse by more than 2 %)
    state_ratio_limit: float = 1.02  # every body state (u, w, q, theta): pooled validation
                                     # error at the selection horizon, its measurement noise
                                     # taken off, corrected/physics <= this
    channel_scales: tuple[float, ...] = (0.5, 0.0)  # where an output scale beats the physics
                                     # in pitch but a state got worse: one output channel at a
                                     # time scaled by these, the others kept
    seen_guard: bool = False         # True: the training sorties held to worst_sortie_ratio
                                     # too, scored as the validation ones. Off: on the
                                     # knockout benchmark it refused what learning the term
                                     # costs, not harm (the model fitted without the term suits
                                     # its own training sorties; with the term some get worse):
                                     # the Aerosonde's power effect 0.62 -> 0.36 recovered, no
                                     # test sortie fewer worse (docs/learned_correction.md)
    free_run_ratio: float = 1.1      # every validation free run: corrected/physics <= this
    free_run_guard: bool = True      # ... and over its whole free run, where the physics' stays
                                     # within DEPARTURE_RAD of the data; no new departures
    seed: int = 0
    threads: int = 1
    compiled: bool = True             # window rollouts and their gradients in compiled CasADi
                                      # code (uavdyn.learned.safe.twin; needs a C compiler),
                                      # else in torch: the same loss to round-off
    max_seconds: float = 3600.0       # a safety net: epochs and patience end a run, so
                                      # the result does not depend on the machine's speed
    progress: bool = True


@dataclass
class SafeResult:
    """The trained network (or None when it is not kept), its history and the checks."""

    net: CorrectionNet | None
    kept: bool
    reason: str
    history: list[dict]
    config: SafeConfig
    best_epoch: int
    seconds: float
    validation: dict = field(default_factory=dict)
    stability: StabilityReport | None = None
    stopped: str = ""  # why the epochs ended (patience, epoch or wall-clock budget)
    screened: list[dict] = field(default_factory=list)  # the starts screened (restarts > 1)
    start_fits: dict = field(default_factory=dict)  # how window starts were fitted, per split
    steady_gate: str = ""  # what the steady gate found (steady_gate on), one line


@dataclass(frozen=True)
class SafeSetup:
    """What a run derives from its configuration, airframe and data before any training."""

    config: SafeConfig             # with ``hidden`` resolved
    sample_dt: float               # the log's sample step
    dt: float                      # the hybrid step: one call per log sample (delay buffers
                                   # and memory count samples)
    structure: ModelStructure      # the physics the correction sits on
    memory_tau: tuple[float, ...]
    horizon: int                   # samples per rollout window
    horizon_sel: int               # samples of the selection horizon
    stride: int                    # samples between window starts
    physics: DiscreteModel         # the physics-only step

    @property
    def layout(self) -> CorrectionLayout:
        """The correction's state layout, without gate or bound (they come from the data)."""
        return CorrectionLayout(self.structure, self.memory_tau, inputs=self.config.inputs,
                                output=self.config.output)

    @property
    def selection_horizon_s(self) -> float:
        """The selection horizon in seconds, on the sample grid."""
        return round(self.horizon_sel * self.sample_dt, 9)


def safe_setup(train_sorties: list[Sortie], val_sorties: list[Sortie], airframe: Airframe,
               config: SafeConfig | None) -> SafeSetup:
    """The run's :class:`SafeSetup`.

    Raises
    ------
    SafeTrainingError
        If a split is empty.
    ValueError
        On a ``stability_trims`` other than ``"box"``, ``"gate"`` or ``"repair"``.
    """
    cfg = config or SafeConfig()
    if cfg.stability_trims not in STABILITY_TRIMS:
        raise ValueError(f"stability_trims must be one of {', '.join(STABILITY_TRIMS)}, got "
                         f"{cfg.stability_trims!r}")
    if cfg.hidden is None:
        cfg = replace(cfg, hidden=DEFAULT_HIDDEN[airframe.kind])
    inputs, output = DEFAULT_DESIGN[airframe.kind]
    cfg = replace(cfg, inputs=cfg.inputs or inputs, output=cfg.output or output)
    if not train_sorties or not val_sorties:
        raise SafeTrainingError("training needs train and validation sorties")
    sample_dt = float(np.median(np.diff(train_sorties[0].time)))
    structure = correction_structure(airframe, airframe.kind, "improved")
    taus = cfg.memory_tau if cfg.memory_tau is not None else (
        () if structure.n_actuator else (0.05, 0.2))
    H = max(1, int(round(cfg.horizon_s / sample_dt)))
    return SafeSetup(
        config=cfg, sample_dt=sample_dt, dt=sample_dt, structure=structure,
        memory_tau=tuple(taus), horizon=H,
        horizon_sel=max(1, min(H, int(round(cfg.selection_horizon_s / sample_dt)))),
        stride=max(1, int(round(cfg.window_stride_s / sample_dt))),
        physics=physics_step(structure))
