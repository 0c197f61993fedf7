"""What flight data would determine a parameter the data at hand do not: the manoeuvre that
moves its term independently of the others (standard flight-test practice, e.g. Morelli and
Klein, *Aircraft System Identification*, ch. 9; Jategaonkar, *Flight Vehicle System
Identification*, ch. 2)."""

from __future__ import annotations

EXCITATION: dict[str, str] = {
    # fixed wing
    "C_m_alpha": "elevator doublets or 3-2-1-1 inputs at two or more airspeeds, so angle of "
                 "attack varies apart from pitch rate",
    "C_m_q": "pitch-rate changes with little angle-of-attack change (pull-ups and push-overs, "
             "a phugoid excited by a throttle step)",
    "C_m_alpha_dot": "pitch-rate changes with little angle-of-attack change (pull-ups and "
                     "push-overs), which separate it from C_m_q",
    "C_m_delta_e": "open-loop elevator inputs (doublets, 3-2-1-1) flown with the pitch loop "
                   "off, so the elevator is not a copy of the pitch rate",
    "C_m_0": "steady trims at several airspeeds with the elevator at different positions",
    "C_L_alpha": "angle-of-attack changes at constant speed (elevator doublets) and trims "
                 "at several airspeeds",
    "C_L_0": "steady trims at several airspeeds",
    "C_D_0": "speed changes at constant altitude (throttle steps, accelerations and "
             "decelerations)",
    "tau_elevator": "sharp elevator steps (a 3-2-1-1 with short pulses)",
    "tau_throttle": "sharp throttle steps",
    # multirotor
    "pitch_mix": "open-loop pitch-command steps or doublets (attitude loop off or with "
                 "injected inputs)",
    "pitch_damping": "pitch-rate changes at several speeds (pitch doublets)",
    "drag_linear": "forward-speed changes (accelerations and decelerations)",
    "CdA_x": "forward-speed changes at high speed (the quadratic drag grows with speed)",
    "CdA_z": "climbs and descents at several vertical speeds",
    "c_T": "collective steps and climbs",
    "k_inflow": "climbs and descents at several vertical speeds (axial inflow)",
    "tau_rotor": "sharp collective or pitch-command steps",
    "M_u": "forward-speed changes with the attitude held (the moment grows with speed)",
    "M_0": "hovers and slow flight with the pitch command recorded",
}


def excitation_for(name: str, group: list[str]) -> str:
    """The flight data that would determine ``name`` (apart from the ``group`` it is
    confounded with, if any)."""
    hint = EXCITATION.get(name)
    if hint is None:
        hint = "inputs that move its term independently of the other parameters"
    others = [g for g in group if g != name]
    return hint + (f" (to separate it from {', '.join(others)})" if others else "")
