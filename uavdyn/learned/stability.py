"""Stability of the hybrid discrete map over the training envelope: trim points sampled where the
data were flown, the eigenvalues of the map's Jacobian there, and the rule a correction must
keep (checked exactly in CasADi before weights are written; enforced in training by a
differentiable penalty, :func:`stability_penalty`).

The network changes only the body rows of the step (``u, w, q, theta``); actuator, delay-buffer
and command-memory states do not depend on the body state, so the map's Jacobian is block
triangular and its eigenvalues are those of the 4 x 4 body block plus constants (``exp(-dt /
tau)``, 0 for a buffer). The rule, per trim point, on the spectral abscissa
``sigma = max log|lambda| / dt`` (1/s) of the body block::

    allowed = sigma_physics + margin * |sigma_physics|   if sigma_physics < 0  (stable physics)
    allowed = sigma_physics                               otherwise (neutral or unstable)

so a stable physics map stays stable and its slowest decay rate may at most shrink by the
fraction ``margin``; a neutral mode (a nominal hovering quadrotor's pitch attitude) or a mode
the physics already has unstable (an identified quadrotor's hover oscillation) may not be
pushed outward at all. The training penalty's hinge sits a buffer inside the allowed value, so
the exact check has room, but never more than 0.01 1/s inside the physics' own abscissa: where
the allowed value IS the physics' (neutral or unstable modes) a buffer proportional to the rate
makes the penalty fight the data (it did: an identified F450, unstable at +0.74 1/s, trained to
a loss above the physics' while the penalty demanded 10 % more stability than the physics
has), while a small fixed one still leaves the exact check room at a neutral mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.integrate import DiscreteModel, StateLayout
from uavdyn.learned.envelope import Envelope
from uavdyn.learned.formulations import airspeed_input
from uavdyn.linear import TrimError, point_params, trim
from uavdyn.linear.trim import step_inputs

BODY = 4
DEFAULT_MARGIN = 0.5
TOLERANCE = 1e-9  # 1/s: round-off allowance of the exact check
HINGE_INSIDE_PHYSICS = 0.01  # 1/s: the most the training hinge asks beyond the physics' own


@dataclass(frozen=True)
class TrimSample:
    """One trim point of the envelope with the hybrid step's state and command there."""

    airspeed: float
    gamma: float
    z: np.ndarray
    u: np.ndarray
    p: np.ndarray

    def describe(self) -> str:
        return f"trim at {self.airspeed:.3g} m/s, gamma {math.degrees(self.gamma):+.3g} deg"


def envelope_trims(airframe: Airframe, sorties: list[Sortie], layout: StateLayout,
                   n_speeds: int = 4) -> tuple[list[TrimSample], list[str]]:
    """Trim points over the flown envelope: airspeeds between the 5th and 95th percentile of
    the sorties' airspeed (:func:`trims_between`). Returns the points and why others could not
    be trimmed."""
    speeds = np.concatenate([np.hypot(s.states[:, 0], s.states[:, 1]) for s in sorties])
    lo, hi = np.percentile(speeds, [5, 95])
    return trims_between(airframe, float(lo), float(hi), layout, n_speeds)


def envelope_speeds(envelope: Envelope, airspeed_input: int | None = None
                    ) -> tuple[float, float]:
    """The airspeed range a weight file's envelope spans, so the sweep of ``uavdyn modes
    --hybrid`` covers what the network was trained on: the box's range of the airspeed input
    ``airspeed_input`` where the network sees airspeed itself (a fixed wing's physical inputs,
    :func:`uavdyn.learned.formulations.airspeed_input`), else from the smallest to the largest
    ``hypot(u, w)`` over the box of its body-velocity inputs ``u``, ``w`` (the first two)."""
    if airspeed_input is not None:
        return (max(float(envelope.low[airspeed_input]), 0.0),
                max(float(envelope.high[airspeed_input]), 0.0))
    u = (float(envelope.low[0]), float(envelope.high[0]))
    w = (float(envelope.low[1]), float(envelope.high[1]))
    w_min = 0.0 if w[0] <= 0.0 <= w[1] else min(abs(w[0]), abs(w[1]))
    u_min = 0.0 if u[0] <= 0.0 <= u[1] else min(abs(u[0]), abs(u[1]))
    return math.hypot(u_min, w_min), math.hypot(max(map(abs, u)), max(map(abs, w)))


def reach_speeds(envelope: Envelope, airspeed_input: int | None = None) -> tuple[float, float]:
    """The airspeed range over which the gate lets the network act at all: the box widened
    by its fade on every side (:func:`envelope_speeds` of that box)."""
    return envelope_speeds(Envelope(envelope.low - envelope.fade,
                                    envelope.high + envelope.fade, envelope.fade),
                           airspeed_input)


@dataclass(frozen=True)
class GateTrims:
    """The trims of a correction's stability check: over the box's airspeeds (where the
    training penalty holds the network) and in the margins beyond, out to where the gate
    reaches zero; with the speeds that could not be trimmed."""

    box: list[TrimSample]
    margins: list[TrimSample]
    skipped: list[str]

    @property
    def all(self) -> list[TrimSample]:
        return self.box + self.margins


# Where the training's stability penalty holds the network (SafeConfig.stability_trims)
STABILITY_TRIMS = ("box", "gate", "repair")


def penalty_trims(gates: GateTrims, where: str) -> list[TrimSample]:
    """The trims the training penalty holds the network at (``SafeConfig.stability_trims``):
    over the envelope's box (``"box"``, and ``"repair"`` until a repair; the exact check adds
    the margins) or every trim the exact check runs at (``"gate"``)."""
    return gates.all if where == "gate" else gates.box


def gate_trims(airframe: Airframe, envelope: Envelope, layout: StateLayout,
               n_speeds: int = 4, airspeed_input: int | None = None) -> GateTrims:
    """The trims the exact stability check runs at: ``n_speeds`` over the box's airspeeds
    (:func:`envelope_speeds`) and more over the middle half of each margin out to where the
    gate reaches zero (:func:`reach_speeds`; beyond, the step is the physics), so the check
    covers trimmed flight wherever the correction acts. A margin point already in the box (a
    multirotor's hover) is not repeated. ``airspeed_input``: see :func:`envelope_speeds`."""
    lo, hi = envelope_speeds(envelope, airspeed_input)
    reach_lo, reach_hi = reach_speeds(envelope, airspeed_input)
    box, skipped = trims_between(airframe, lo, hi, layout, n_speeds)
    seen = {(round(t.airspeed, 6), round(t.gamma, 9)) for t in box}
    margins: list[TrimSample] = []
    for a, b in ((max(reach_lo, 0.0), lo), (hi, reach_hi)):
        if b <= a:
            continue
        quarter = 0.25 * (b - a)
        more, why = trims_between(airframe, a + quarter, b - quarter, layout, 3)
        skipped += why
        for t in more:
            key = (round(t.airspeed, 6), round(t.gamma, 9))
            if key not in seen:
                seen.add(key)
                margins.append(t)
    return GateTrims(box, margins, skipped)


def trims_between(airframe: Airframe, lo: float, hi: float, layout: StateLayout,
                  n_speeds: int = 4) -> tuple[list[TrimSample], list[str]]:
    """Trim points at ``n_speeds`` airspeeds spread over the part of ``[lo, hi]`` where the
    airframe can be trimmed level (found on a grid four times finer, so untrimmable ends of
    the range do not use up the points): level and +-3 deg climb for a fixed wing; hover and
    forward flight for a multirotor; each with the step's state there (``layout``: at rest
    on the trim command). Returns the points and why others could not be trimmed."""
    skipped: list[str] = []
    if airframe.kind == "fixed_wing":
        feasible = []
        for v in np.linspace(lo, hi, 4 * n_speeds + 1):
            try:
                trim(airframe, float(v), 0.0)
                feasible.append(float(v))
            except TrimError as exc:
                skipped.append(f"{v:.3g} m/s, level: {exc}")
        pick = sorted({int(round(i)) for i in np.linspace(0, len(feasible) - 1, n_speeds)}
                      ) if feasible else []
        grid = [(feasible[i], g) for i in pick
                for g in (0.0, math.radians(-3), math.radians(3))]
    else:
        forward = np.linspace(max(lo, 1.0), max(hi, 1.0), n_speeds - 1) if hi > 1.0 else []
        grid = [(0.0, 0.0)] + [(float(v), 0.0) for v in forward]
    out = []
    for v, g in grid:
        try:
            point = trim(airframe, float(v), float(g))
        except TrimError as exc:
            skipped.append(f"{v:.3g} m/s, gamma {math.degrees(g):+.3g} deg: {exc}")
            continue
        p = point_params(airframe, point)
        u = step_inputs(airframe, point.u)  # with lateral inputs: wings level, all zero
        out.append(TrimSample(float(v), float(g), layout.states(point.x, u, p, 1.0)[0], u, p))
    return out, skipped


def allowed_abscissa(sigma_physics: float, margin: float = DEFAULT_MARGIN) -> float:
    """The largest spectral abscissa (1/s) the hybrid map may have where the physics has
    ``sigma_physics`` (module docstring)."""
    if sigma_physics < 0:
        return sigma_physics + margin * abs(sigma_physics)
    return sigma_physics


def training_target(sigma_physics: float, margin: float = DEFAULT_MARGIN) -> float:
    """The abscissa (1/s) the training penalty's hinge sits at: the allowed value less a safety
    buffer (``0.1 |sigma| + 0.01``), but never more than :data:`HINGE_INSIDE_PHYSICS` inside
    the physics' own (module docstring)."""
    buffer = 0.1 * abs(sigma_physics) + 0.01
    return max(allowed_abscissa(sigma_physics, margin) - buffer,
               sigma_physics - HINGE_INSIDE_PHYSICS)


def body_abscissa(jacobian: np.ndarray, dt: float) -> tuple[float, complex]:
    """``max log|lambda| / dt`` over the body block's eigenvalues, and that eigenvalue."""
    lam = np.linalg.eigvals(np.asarray(jacobian)[:BODY, :BODY])
    i = int(np.argmax(np.abs(lam)))
    with np.errstate(divide="ignore"):
        return float(np.log(np.abs(lam[i])) / dt), complex(lam[i])


@dataclass(frozen=True)
class Finding:
    """The check at one trim point."""

    trim: str
    sigma_physics: float
    sigma_hybrid: float
    allowed: float
    eigenvalue: complex

    @property
    def ok(self) -> bool:
        return self.sigma_hybrid <= self.allowed + TOLERANCE


@dataclass
class StabilityReport:
    """The check over all trim points (``ok`` when every point keeps the rule)."""

    dt: float
    margin: float
    findings: list[Finding] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(f.ok for f in self.findings)

    @property
    def failures(self) -> list[Finding]:
        return [f for f in self.findings if not f.ok]

    def describe(self) -> str:
        """One line: the worst failure (trim, eigenvalue, rates) or the number of points."""
        if self.ok:
            return (f"the hybrid map keeps the stability rule at all {len(self.findings)} trim "
                    f"points (margin {self.margin:g})")
        worst = max(self.failures, key=lambda f: f.sigma_hybrid - f.allowed)
        lam = worst.eigenvalue
        return (f"the correction destabilises the map at {worst.trim}: eigenvalue "
                f"{lam.real:.6f}{lam.imag:+.6f}j (|lambda| = {abs(lam):.6f}, growth rate "
                f"{worst.sigma_hybrid:+.4g} 1/s) where the physics has {worst.sigma_physics:+.4g} "
                f"1/s and at most {worst.allowed:+.4g} 1/s is allowed ({len(self.failures)} of "
                f"{len(self.findings)} trim points fail)")

    def table(self) -> str:
        """Markdown table: per trim point the largest growth rate of the physics and of the
        hybrid map (log|lambda|/dt, 1/s), the allowed rate, and the verdict."""
        rows = ["| trim | physics (1/s) | hybrid (1/s) | allowed (1/s) | verdict |",
                "|---|---|---|---|---|"]
        rows += [f"| {f.trim} | {f.sigma_physics:+.4g} | {f.sigma_hybrid:+.4g} | "
                 f"{f.allowed:+.4g} | {'ok' if f.ok else 'DESTABILISED'} |"
                 for f in self.findings]
        rows += [f"| {why} | - | - | - | not trimmed |" for why in self.skipped]
        return "\n".join(rows)

    def to_dict(self) -> dict:
        return {"dt": self.dt, "margin": self.margin, "ok": self.ok, "skipped": self.skipped,
                "points": [{"trim": f.trim, "sigma_physics": f.sigma_physics,
                            "sigma_hybrid": f.sigma_hybrid, "allowed": f.allowed,
                            "eigenvalue": [f.eigenvalue.real, f.eigenvalue.imag], "ok": f.ok}
                           for f in self.findings]}


def map_pitch_damping(model: DiscreteModel, z: np.ndarray, controls: np.ndarray,
                      p: np.ndarray, dt: float, h: float = 1e-5) -> np.ndarray:
    """The step map's pitch damping ``(d q_next / d q - 1) / dt`` (1/s) at every row of the
    states ``z`` (``(N, n_state)``, the pitch rate third) with the matching ``controls``
    (central difference, one mapped call per side). A positive value is a pitch rate that
    feeds itself: the sign the trainer's damping prior keeps a correction from reversing."""
    z = np.asarray(z, float)
    up, down = z.copy(), z.copy()
    up[:, 2] += h
    down[:, 2] -= h
    slope = (model.step_rows(up, controls, p, dt)[:, 2]
             - model.step_rows(down, controls, p, dt)[:, 2]) / (2 * h)
    return (slope - 1.0) / dt


def check_map_stability(hybrid: DiscreteModel, physics: DiscreteModel, trims: list[TrimSample],
                        dt: float, margin: float = DEFAULT_MARGIN,
                        skipped: list[str] | None = None) -> StabilityReport:
    """Exact check of the rule at every trim point with CasADi Jacobians.

    Parameters
    ----------
    hybrid : DiscreteModel
        The hybrid step ``(z, u, p, dt)``.
    physics : DiscreteModel
        The physics step on its own augmented state (a prefix of ``z``).
    trims : list of TrimSample
        Points from :func:`envelope_trims`.
    dt : float
        The step size the map is used at.
    margin : float
        See the module docstring.
    """
    jh, jp = hybrid.jacobians(), physics.jacobians()
    n_phys = physics.nx
    report = StabilityReport(dt, margin, skipped=list(skipped or []))
    for t in trims:
        sigma_p, _ = body_abscissa(np.array(jp(t.z[:n_phys], t.u, t.p, dt)[1]), dt)
        sigma_h, lam = body_abscissa(np.array(jh(t.z, t.u, t.p, dt)[1]), dt)
        report.findings.append(Finding(t.describe(), sigma_p, sigma_h,
                                       allowed_abscissa(sigma_p, margin), lam))
    return report


def stability_penalty(model, trims: list[TrimSample], targets, dt: float):
    """Differentiable penalty (torch): ``sum relu(sigma_hybrid - target)`` over the trim
    points, ``sigma`` from the eigenvalues of the body block of the torch hybrid step's
    Jacobian; ``targets`` are the allowed abscissas minus a safety buffer."""
    import torch

    total = torch.zeros((), dtype=torch.float64)
    for t, target in zip(trims, targets):
        z = torch.as_tensor(t.z, dtype=torch.float64)
        u = torch.as_tensor(t.u, dtype=torch.float64).reshape(1, -1)
        p = torch.as_tensor(t.p, dtype=torch.float64)
        rest = z[BODY:].reshape(1, -1)

        def body_map(x, rest=rest, u=u, p=p):
            return model.step(torch.cat([x.reshape(1, -1), rest], dim=1), u, p, dt)[0, :BODY]

        jac = torch.autograd.functional.jacobian(body_map, z[:BODY], create_graph=True)
        lam = torch.linalg.eigvals(jac)
        sigma = torch.log(torch.abs(lam).max()) / dt
        excess = torch.relu(sigma - float(target))
        if torch.isfinite(excess):
            total = total + excess  # linear (exact-penalty) hinge: a squared one lets small
            # violations through at any weight, which a neutral physics mode cannot afford
    return total


def envelope_check(net, airframe: Airframe, dt: float | None = None,
                   margin: float = DEFAULT_MARGIN, n_speeds: int = 4,
                   model: DiscreteModel | None = None) -> StabilityReport:
    """The stability rule of a trained correction at trims over its own training envelope and
    out to where its gate reaches zero (:func:`gate_trims`).

    Parameters
    ----------
    net : CorrectionNet
        Weights of the ``improved`` formulation with a stored envelope.
    airframe : Airframe
        The airframe the weights were trained on (hash-checked).
    dt : float, optional
        Map step (default: the step the network was trained at).
    margin : float
        See the module docstring.
    model : DiscreteModel, optional
        The (uncompiled) hybrid step of ``net`` if the caller has already built it.

    Raises
    ------
    ValueError
        For weights without an envelope (formats 1-2: no training envelope is stored).
    """
    from uavdyn.integrate import physics_step
    from uavdyn.learned.hybrid import hybrid_step

    if net.envelope is None or net.formulation != "improved":
        raise ValueError("these weights store no training envelope (weight formats 3-4, "
                         "'improved' formulation, have one): no envelope sweep")
    model = model if model is not None else hybrid_step(net, airframe, compile=False)
    trims = gate_trims(airframe, net.envelope, model.layout, n_speeds,
                       airspeed_input(net.kind, net.inputs))
    return check_map_stability(model, physics_step(model.structure), trims.all, dt or net.dt,
                               margin, trims.skipped)
