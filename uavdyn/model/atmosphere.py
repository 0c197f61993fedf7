"""The International Standard Atmosphere density ratio (troposphere and the isothermal lower
stratosphere), written once against ``ops``.

ISA (ICAO Doc 7488, ISO 2533): sea level 288.15 K, 101325 Pa, 1.225 kg/m^3; temperature falls
6.5 K/km up to the tropopause at 11 km (216.65 K), then stays constant up to 20 km. Density
ratio::

    h <= 11 km:  (1 - L h / T0) ** (g M / (R L) - 1)
    11..20 km:   ratio(11 km) * exp(-g M (h - 11 km) / (R T11))

continuous in ``h`` (its slope jumps at 11 km, as the standard's temperature gradient does).
Altitudes are geopotential metres above mean sea level, clamped to -1 km..20 km (below and
above, the end values: no UAV flies outside).
"""

from __future__ import annotations

from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS

ISA_T0 = 288.15                          # K, sea-level temperature
ISA_LAPSE = 0.0065                       # K/m, troposphere temperature lapse rate
ISA_G_M_OVER_R = 9.80665 * 0.0289644 / 8.3144598   # g M / R, K/m
ISA_LAPSE_OVER_T0 = ISA_LAPSE / ISA_T0   # 1/m, temperature lapse over sea-level temperature
ISA_EXPONENT = ISA_G_M_OVER_R / ISA_LAPSE - 1.0   # g M / (R L) - 1 = 4.2559
ISA_TROPOPAUSE_M = 11000.0               # top of the troposphere
ISA_T11 = ISA_T0 - ISA_LAPSE * ISA_TROPOPAUSE_M   # 216.65 K, the isothermal layer's temperature
ISA_CEILING_M = 20000.0                  # top of the isothermal layer: held constant above
ISA_FLOOR_M = -1000.0


def isa_density_ratio(altitude_m, ops=CASADI_OPS):
    """``rho(h) / rho(0)`` of the ISA (altitude clamped to -1 km..20 km; module docstring).

    Parameters
    ----------
    altitude_m : scalar, array, tensor or CasADi expression
        Geopotential altitude above mean sea level (m).
    ops : namespace
        The math namespace (:mod:`uavdyn.model.ops`).
    """
    h = ops.fmin(ops.fmax(altitude_m, ISA_FLOOR_M), ISA_CEILING_M)
    h_tropo = ops.fmin(h, ISA_TROPOPAUSE_M)
    h_strat = ops.fmax(h - ISA_TROPOPAUSE_M, 0.0)
    return ((1.0 - ISA_LAPSE_OVER_T0 * h_tropo) ** ISA_EXPONENT
            * ops.exp(-ISA_G_M_OVER_R / ISA_T11 * h_strat))


def isa_density(altitude_m: float, sea_level: float = 1.225) -> float:
    """ISA density (kg/m^3) at ``altitude_m`` (m above mean sea level) for a sea-level density
    ``sea_level`` (the standard's 1.225 kg/m^3 by default)."""
    return float(sea_level * isa_density_ratio(altitude_m, NUMPY_OPS))
