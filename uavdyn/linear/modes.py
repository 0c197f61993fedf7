"""Linearised stability: A, B from CasADi Jacobians at a trim point, and the modes (natural
frequency, damping, period, time to half/double amplitude) named the way a flight-dynamics
engineer reads them (short period, phugoid; for the quadrotor the real pitch/speed/heave modes).

An airframe with actuator lags is linearised with its actuator states (``a_dot = (u - a)/tau``),
so its continuous modes include the actuator poles ``-1/tau``. Transport delays have no finite
continuous state; they appear in the discrete map (:func:`discrete_map_modes`) as one
eigenvalue 0 per delay-buffer state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from uavdyn.airframes import Airframe
from uavdyn.integrate import DiscreteModel
from uavdyn.linear.trim import TrimPoint, body_structure, point_params
from uavdyn.model import STATE_NAMES, build_model, structure_of


@dataclass(frozen=True)
class Mode:
    """One eigenvalue (or complex pair, listed once with positive imaginary part)."""

    name: str
    eigenvalue: complex
    natural_frequency: float  # rad/s
    damping: float
    period: float  # s (inf for a real mode)
    time_to_half: float  # s (inf if not convergent)
    time_to_double: float  # s (inf if not divergent)
    dominant_state: str

    @property
    def stable(self) -> bool:
        return self.eigenvalue.real < 0

    def as_dict(self) -> dict:
        return {
            "name": self.name, "real": self.eigenvalue.real, "imag": self.eigenvalue.imag,
            "wn_rad_s": self.natural_frequency, "damping": self.damping, "period_s": self.period,
            "t_half_s": self.time_to_half, "t_double_s": self.time_to_double,
            "dominant_state": self.dominant_state, "stable": self.stable,
        }


def linear_state_names(airframe: Airframe, actuators: bool = True) -> tuple[str, ...]:
    """Names of the states of :func:`linearise`: the body, then one actuator state per lagged
    control (``"<control>_actuator"``)."""
    structure = structure_of(airframe)
    return STATE_NAMES + (tuple(f"{c}_actuator" for c in structure.lagged) if actuators
                          else ())


def linearise(airframe: Airframe, point: TrimPoint, actuators: bool = True
              ) -> tuple[np.ndarray, np.ndarray]:
    """``A = df/dx`` and ``B = df/du`` at a trim point (exact, from CasADi), of the airframe's
    own model (tables, alpha-dot terms; an ISA airframe at the point's altitude).

    With actuator lags (and ``actuators``), the state is augmented by one actuator state per
    lagged control (:func:`linear_state_names`), ``a_dot = (u - a) / tau``: the body sees
    ``a`` instead of the command, so ``A = [[A_body, B_body[:, lagged]], [0, -1/tau]]`` and
    the command enters through ``1/tau``. Without lags: the body's ``A`` (4 x 4), ``B`` (4 x 2).
    """
    airframe = airframe.for_inputs(False)  # modes at wings level: the lateral inputs zero
    p = point_params(airframe, point)
    jac = build_model(body_structure(airframe)).jacobians(point.x, point.u, p)
    A, B = np.array(jac[0]), np.array(jac[1])
    structure = structure_of(airframe)
    if not (actuators and structure.n_actuator):
        return A, B
    lag = list(structure.lag_indices)
    inv_tau = np.array([1.0 / p[i] for i in structure.tau_indices])
    n, m, nu = A.shape[0], len(lag), B.shape[1]
    A_aug = np.zeros((n + m, n + m))
    A_aug[:n, :n] = A
    A_aug[:n, n:] = B[:, lag]
    A_aug[n:, n:] = -np.diag(inv_tau)
    B_aug = np.zeros((n + m, nu))
    B_aug[:n] = B
    B_aug[:n, lag] = 0.0  # a lagged command reaches the body only through its actuator
    B_aug[n + np.arange(m), lag] = inv_tau
    return A_aug, B_aug


def participation(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and modal participation factors ``|l_ki r_ki|`` (state k in mode i), which
    unlike raw eigenvectors do not depend on the units of the states."""
    eig, right = np.linalg.eig(A)
    try:
        left = np.linalg.inv(right)
        factors = np.abs(right * left.T)
    except np.linalg.LinAlgError:  # defective matrix: fall back to eigenvector magnitudes
        factors = np.abs(right)
    return eig, factors


def modes(A: np.ndarray, kind: str, B: np.ndarray | None = None,
          state_names: tuple[str, ...] | None = None) -> list[Mode]:
    """Modes of ``x_dot = A x``: eigenvalues and damping through python-control; names from the
    kind, the frequency ordering and the modal participation factors.

    ``state_names`` names the states of ``A`` (default: the body state, then ``x_n``, ``h``);
    give :func:`linear_state_names` for an airframe with actuator states, whose poles are then
    named ``"<control> actuator lag"``."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    B = np.zeros((n, 1)) if B is None else np.asarray(B, dtype=float)
    import control as ct  # python-control imports matplotlib: only when modes are asked for

    sys = ct.ss(A, B, np.eye(n), np.zeros((n, B.shape[1])))
    with np.errstate(invalid="ignore", divide="ignore"):
        wn, zeta, poles = ct.damp(sys, doprint=False)
    eig, factors = participation(A)
    if state_names is None:
        state_names = STATE_NAMES + ("x_n", "h")
    if len(state_names) < n:
        raise ValueError(f"{n} states but {len(state_names)} state names {state_names}")
    entries = []
    unused = list(range(len(eig)))
    for w, z, pole in zip(wn, zeta, poles):
        pole = complex(pole)
        idx = min(unused, key=lambda i: abs(eig[i] - pole))
        unused.remove(idx)
        if pole.imag < 0:
            continue
        dominant = state_names[int(np.argmax(factors[:, idx]))]
        z = float(z) if np.isfinite(z) else (1.0 if pole.real < 0 else -1.0 if pole.real > 0
                                             else 0.0)
        entries.append((pole, float(w), z, dominant))
    named = _name_modes(entries, kind)
    out = []
    for (pole, w, z, dom), name in zip(entries, named):
        sigma = pole.real
        period = 2 * math.pi / pole.imag if pole.imag > 1e-12 else math.inf
        t_half = math.log(2) / -sigma if sigma < 0 else math.inf
        t_double = math.log(2) / sigma if sigma > 0 else math.inf
        out.append(Mode(name, pole, w, z, period, t_half, t_double, dom))
    out.sort(key=lambda m: -m.natural_frequency)
    return out


def _name_modes(entries, kind: str) -> list[str]:
    names = [""] * len(entries)
    oscillatory = [i for i, e in enumerate(entries) if e[0].imag > 1e-9]
    if kind == "fixed_wing" and len(oscillatory) == 2:
        fast, slow = sorted(oscillatory, key=lambda i: -entries[i][1])
        names[fast], names[slow] = "short period", "phugoid"
    labels = {"u": "speed", "w": "heave", "q": "pitch", "theta": "pitch attitude"}
    for i, (pole, _, _, dom) in enumerate(entries):
        if names[i]:
            continue
        if dom.endswith("_actuator") and abs(pole.imag) <= 1e-9 and pole.real < 0:
            names[i] = f"{dom[:-len('_actuator')]} actuator lag"
            continue
        base = labels.get(dom, dom)
        if abs(pole) < 1e-9:
            names[i] = f"{base} (neutral)"
        elif pole.imag > 1e-9:
            names[i] = f"{base} oscillation"
        else:
            names[i] = f"{base} {'subsidence' if pole.real < 0 else 'divergence'}"
    return names


def mode_table(mode_list: list[Mode]) -> str:
    """A Markdown table of modes."""
    def fmt(v: float) -> str:
        return "inf" if math.isinf(v) else f"{v:.4g}"

    rows = ["| mode | eigenvalue | wn (rad/s) | damping | period (s) | t_half (s) | t_double (s) |",
            "|---|---|---|---|---|---|---|"]
    for m in mode_list:
        ev = m.eigenvalue
        ev_text = f"{ev.real:.4g} ± {ev.imag:.4g}j" if ev.imag > 1e-12 else f"{ev.real:.4g}"
        rows.append(f"| {m.name} | {ev_text} | {m.natural_frequency:.4g} | {m.damping:.4g} | "
                    f"{fmt(m.period)} | {fmt(m.time_to_half)} | {fmt(m.time_to_double)} |")
    return "\n".join(rows)


@dataclass(frozen=True)
class DiscreteModeComparison:
    """Modes of a discrete step map ``x_next = F(x, u, p, dt)`` at a trim point, next to the
    continuous physics model and its exact discretisation ``exp(A dt)``."""

    dt: float
    map_eigenvalues: np.ndarray  # eigenvalues of dF/dx
    map_continuous: np.ndarray  # log(lambda)/dt
    exact_eigenvalues: np.ndarray  # eigenvalues of exp(A dt), matched to map_eigenvalues
    physics_modes: list[Mode]
    map_modes: list[Mode]

    @property
    def unstable(self) -> list[int]:
        """Indices of map eigenvalues outside the unit circle (the map diverges there)."""
        return [i for i, lam in enumerate(self.map_eigenvalues) if abs(lam) > 1.0 + 1e-12]

    @property
    def made_unstable(self) -> list[int]:
        """Map eigenvalues outside the unit circle whose exact counterpart is inside it."""
        return [i for i in self.unstable if abs(self.exact_eigenvalues[i]) <= 1.0]

    def table(self) -> str:
        rows = ["| # | map eigenvalue | log(lambda)/dt | exp(A dt) eigenvalue | |lambda| | flag |",
                "|---|---|---|---|---|---|"]
        for i, (lam, s, ex) in enumerate(zip(self.map_eigenvalues, self.map_continuous,
                                             self.exact_eigenvalues)):
            flag = ("UNSTABLE (made so by the correction)" if i in self.made_unstable
                    else "unstable" if i in self.unstable else "")
            rows.append(f"| {i} | {lam.real:.8f}{lam.imag:+.8f}j | {s.real:.5g}{s.imag:+.5g}j | "
                        f"{ex.real:.8f}{ex.imag:+.8f}j | {abs(lam):.8f} | {flag} |")
        return "\n".join(rows)


def _match(reference: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Reorder ``values`` to pair each entry of ``reference`` with its nearest partner."""
    remaining = list(values)
    out = []
    for r in reference:
        j = int(np.argmin([abs(r - v) for v in remaining]))
        out.append(remaining.pop(j))
    return np.array(out)


def discrete_map_modes(model: DiscreteModel, point: TrimPoint, dt: float,
                       airframe: Airframe | None = None) -> DiscreteModeComparison:
    """Linearise a step map (hybrid or physics) at a trim point: eigenvalues of its Jacobian,
    their continuous equivalents ``log(lambda)/dt``, and the exact ``exp(A dt)`` beside them.

    The map is linearised at the model's state at the trim
    (:meth:`DiscreteModel.initial_state`: actuators, delay buffers and command memory at rest
    on the trim command). The exact counterparts of the map's eigenvalues are those of
    ``exp(A dt)`` of the continuous body (+ actuator, when the model carries actuator states)
    model (:func:`linearise`), one 0 per delay-buffer state (a shift register) and
    ``exp(-dt/tau)`` per command-memory state (driven by the command only, so the map is
    block triangular). The map's continuous-equivalent modes are those of its body +
    actuator block.

    Parameters
    ----------
    model : DiscreteModel
        The step (body state only, or the airframe's augmented state).
    point : TrimPoint
        Trim point of the airframe.
    dt : float
        Step size the map is taken at.
    airframe : Airframe, optional
        The airframe (default the model's own).

    Raises
    ------
    ValueError
        If no airframe is known, or the model's physics is neither the body state nor the
        airframe's augmented state.
    """
    airframe = airframe if airframe is not None else model.airframe
    if airframe is None:
        raise ValueError(f"model '{model.name}' has no airframe: give airframe=")
    structure = structure_of(airframe)
    n_physics = model.layout.n_physics
    if n_physics == 4:
        augmented = False
    elif n_physics == structure.nx():
        augmented = True
    else:
        raise ValueError(f"model '{model.name}' has {n_physics} physics states; airframe "
                         f"'{airframe.name}' has 4 body states or {structure.nx()} augmented "
                         f"ones {structure.state_names()}")
    memory_tau = model.layout.memory_tau
    u_trim = np.asarray(point.u, float)
    p = point_params(airframe, point)
    z0 = model.initial_state(np.asarray(point.x, float), u_trim, p)
    F = np.array(model.jacobians()(z0, u_trim, p, dt)[1])
    lam = np.linalg.eigvals(F)
    A, B = linearise(airframe, point, actuators=augmented)
    names = linear_state_names(airframe, actuators=augmented)
    exact_all = np.linalg.eigvals(scipy.linalg.expm(A * dt))
    if augmented:
        exact_all = np.concatenate([exact_all, np.zeros(structure.n_buffer)])
    exact_all = np.concatenate([exact_all, np.repeat(np.exp(-dt / np.asarray(memory_tau, float)),
                                                     len(u_trim))])
    exact = _match(lam, exact_all)
    zero = lam == 0
    cont = np.full(lam.shape, -np.inf + 0j)  # a delay state's 0 maps to -inf
    cont[~zero] = np.log(lam[~zero].astype(complex)) / dt
    # the buffers are a shift register beneath the body + actuator block (block triangular)
    n = A.shape[0]
    F_body = F[:n, :n]
    lam_body = np.linalg.eigvals(F_body)
    A_equiv = (np.real_if_close(scipy.linalg.logm(F_body) / dt) if np.all(np.abs(lam_body) > 0)
               else F_body)
    return DiscreteModeComparison(
        dt=dt, map_eigenvalues=lam, map_continuous=cont, exact_eigenvalues=exact,
        physics_modes=modes(A, airframe.kind, B, names),
        map_modes=modes(np.real(A_equiv), airframe.kind, state_names=names))
