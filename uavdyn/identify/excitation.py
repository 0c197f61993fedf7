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
    "slew_elevator": "large fast elevator steps (the servo at its rate limit) beside small "
                     "ones (its lag)",
    "slew_throttle": "large fast throttle steps (the engine at its rate limit) beside small "
                     "ones (its lag)",
    "eta_slipstream": "open-loop elevator inputs flown at two or more throttle settings (the "
                      "slipstream's share of elevator power grows with thrust)",
    "C_D_Re": "speed changes over a wide airspeed range (its 1/sqrt(V) drag is told from "
              "C_D_0 only by how drag varies with speed)",
    "C_m_Re": "steady trims over a wide airspeed range (its 1/sqrt(V) moment is told from "
              "C_m_0 only by how the trim elevator varies with speed)",
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


# --- screening before the fit -------------------------------------------------------------
# A parameter is only identifiable if the signal its term multiplies moves in the data well
# above that signal's own noise: a pitch derivative on a hover-only log fits the autopilot's
# closed-loop wobble, not the aircraft. The rule is stated, not tuned: the signal's spread
# (standard deviation over the train sorties) must be at least EXCITATION_SNR times its
# white-noise level (uavdyn.flightdata.white_noise_std), and not zero. That is the hard gate.
# The absolute floors below are advice only (a warning): on clean data a small manoeuvre
# (uavdyn simulate's 2-degree doublet moves alpha by 0.003 rad) determines a derivative, and
# the corrected standard errors and the halves check are what say whether it did.
EXCITATION_SNR = 3.0
# A spread below this share of the advisory floor is rounding, not motion (a noise-free trim
# holds q at 1e-17 rad/s, whose "noise" is 0): the signal does not move at all.
STILL_SHARE = 1e-6

# signal name -> (description, unit, advisory floor of its standard deviation)
SIGNALS: dict[str, tuple[str, str, float]] = {  # floors: a quarter of a degree and the like
    "alpha": ("angle of attack atan2(w, u)", "rad", 0.0044),   # 0.25 deg
    "q": ("pitch rate q", "rad/s", 0.0087),                     # 0.5 deg/s
    "u": ("forward speed u", "m/s", 0.05),
    "w": ("vertical speed w", "m/s", 0.05),
    "elevator": ("elevator", "rad", 0.0035),                    # 0.5 % of +-0.35 rad
    "throttle": ("throttle", "", 0.005),
    "collective": ("collective", "", 0.005),
    "pitch_cmd": ("pitch command", "", 0.01),                   # 0.5 % of [-1, 1]
}

# parameter -> the signal its term multiplies (parameters not listed are not screened: a
# constant term such as C_m_0 is excited by any data)
EXCITED_BY: dict[str, str] = {
    "C_m_alpha": "alpha", "C_L_alpha": "alpha", "C_L_alpha2": "alpha",
    "C_m_q": "q", "C_L_q": "q", "C_D_q": "q", "C_m_alpha_dot": "q", "C_L_alpha_dot": "q",
    "C_m_delta_e": "elevator", "C_L_delta_e": "elevator", "C_D_delta_e": "elevator",
    "C_D_0": "u", "tau_elevator": "elevator", "tau_throttle": "throttle",
    "slew_elevator": "elevator", "slew_throttle": "throttle",
    "eta_slipstream": "elevator",
    "pitch_damping": "q", "pitch_mix": "pitch_cmd", "M_u": "u", "drag_linear": "u",
    "CdA_x": "u", "CdA_z": "w", "k_inflow": "w", "c_T": "collective",
    "tau_rotor": "collective",
}


def _signal(sortie, name: str):
    """One signal of a sortie (states u, w, q, theta; controls by name; alpha derived)."""
    import numpy as np

    from uavdyn.model import CONTROL_NAMES

    columns = {"u": 0, "w": 1, "q": 2}
    if name == "alpha":
        return np.arctan2(sortie.states[:, 1], sortie.states[:, 0])
    if name in columns:
        return sortie.states[:, columns[name]]
    return sortie.controls[:, CONTROL_NAMES[sortie.kind].index(name)]


def screen_excitation(names: list[str], sorties: list) -> tuple[list[str], list[str]]:
    """Screen ``names`` against the ``sorties``: what refuses the fit, and what is advice.

    Parameters
    ----------
    names : list of str
        Parameters to fit (those not in :data:`EXCITED_BY` are not screened).
    sorties : list of Sortie
        The train sorties.

    Returns
    -------
    refused : list of str
        One sentence per parameter whose signal does not move at all (below
        :data:`STILL_SHARE` of the floor) or not
        :data:`EXCITATION_SNR` times above its noise: the data cannot hold it.
    advice : list of str
        One sentence per parameter whose signal moves above its noise but less than the
        absolute floor of :data:`SIGNALS`: fitted, with a warning (its standard errors and
        the halves check decide whether it is determined).
    """
    import numpy as np

    from uavdyn.flightdata.noise import white_noise_std
    from uavdyn.model import CONTROL_NAMES

    refused: list[str] = []
    advice: list[str] = []
    for name in names:
        signal = EXCITED_BY.get(name)
        if signal is None or not sorties:
            continue
        kind = sorties[0].kind
        if signal in CONTROL_NAMES["fixed_wing"] + CONTROL_NAMES["multirotor"] \
                and signal not in CONTROL_NAMES[kind]:
            continue
        what, unit, floor = SIGNALS[signal]
        unit = f" {unit}" if unit else ""
        values = np.concatenate([_signal(s, signal) for s in sorties])
        spread = float(np.std(values))
        noise = float(np.median([white_noise_std(_signal(s, signal)) for s in sorties]))
        against = (f"{spread / noise:.1f}x its noise of {noise:.2g}{unit}" if noise > 0
                   else "with no measurable noise")
        moved = f"{name}: the {what} varies by {spread:.3g}{unit} (standard deviation), " \
                f"{against}"
        if not spread > STILL_SHARE * floor or spread < EXCITATION_SNR * noise:
            refused.append(f"{moved} (needs {EXCITATION_SNR:g}x its noise and more than "
                           f"{STILL_SHARE * floor:.2g}{unit}); "
                           f"would need: {excitation_for(name, [])}")
        elif spread < floor:
            advice.append(f"{moved}, less than {floor:g}{unit}: a small manoeuvre; its "
                          "standard errors and the halves check say whether it is determined")
    return refused, advice


def unexcited(names: list[str], sorties: list) -> list[str]:
    """One sentence for each of ``names`` whose signal the ``sorties`` do not move above its
    noise (empty when all are excited): what moved how much, and what would excite it
    (the refusals of :func:`screen_excitation`)."""
    return screen_excitation(names, sorties)[0]


def refuse_unexcited(names: list[str], sorties: list) -> list[str]:
    """Raise :class:`~uavdyn.identify.errors.IdentifyError` naming every parameter of
    ``names`` the ``sorties`` do not excite (:func:`screen_excitation`), in one line; return
    the advice on the others (signals that moved less than the advisory floors)."""
    from uavdyn.identify.errors import IdentifyError

    problems, advice = screen_excitation(names, sorties)
    if problems:
        raise IdentifyError("the train data do not excite " + "; ".join(problems)
                            + " (drop it from the parameters, fly that manoeuvre, or fit "
                            "anyway with --allow-low-excitation)")
    return advice
