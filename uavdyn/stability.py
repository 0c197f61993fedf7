"""Linearised stability: A, B from CasADi Jacobians at a trim point, and the modes (natural
frequency, damping, period, time to half/double amplitude) named the way a flight-dynamics
engineer reads them (short period, phugoid; for the quadrotor the real pitch/speed/heave modes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.model import STATE_NAMES, build_model
from uavdyn.trim import TrimPoint


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


def linearise(airframe: Airframe, point: TrimPoint) -> tuple[np.ndarray, np.ndarray]:
    """``A = df/dx`` and ``B = df/du`` at a trim point (exact, from CasADi)."""
    jac = build_model(airframe).jacobians(point.x, point.u, airframe.p)
    return np.array(jac[0]), np.array(jac[1])


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


def modes(A: np.ndarray, kind: str, B: np.ndarray | None = None) -> list[Mode]:
    """Modes of ``x_dot = A x``: eigenvalues and damping through python-control; names from the
    kind, the frequency ordering and the modal participation factors."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    B = np.zeros((n, 1)) if B is None else np.asarray(B, dtype=float)
    sys = ct.ss(A, B, np.eye(n), np.zeros((n, B.shape[1])))
    with np.errstate(invalid="ignore", divide="ignore"):
        wn, zeta, poles = ct.damp(sys, doprint=False)
    eig, factors = participation(A)
    state_names = STATE_NAMES + ("x_n", "h")
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
