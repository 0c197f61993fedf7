"""The standard atmosphere (ISA troposphere) density ratio, written once against ``ops``."""

from __future__ import annotations

from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS

ISA_LAPSE_OVER_T0 = 0.0065 / 288.15      # 1/m, temperature lapse over sea-level temperature
ISA_EXPONENT = 9.80665 * 0.0289644 / (8.3144598 * 0.0065) - 1.0   # g M / (R L) - 1 = 4.2559
ISA_CEILING_M = 11000.0                  # top of the troposphere: the formula holds below it
ISA_FLOOR_M = -1000.0


def isa_density_ratio(altitude_m, ops=CASADI_OPS):
    """``rho(h) / rho(0)`` of the ISA troposphere (altitude clamped to -1 km..11 km)."""
    h = ops.fmin(ops.fmax(altitude_m, ISA_FLOOR_M), ISA_CEILING_M)
    return (1.0 - ISA_LAPSE_OVER_T0 * h) ** ISA_EXPONENT


def isa_density(altitude_m: float, sea_level: float = 1.225) -> float:
    """ISA density (kg/m^3) at ``altitude_m``."""
    return float(sea_level * isa_density_ratio(altitude_m, NUMPY_OPS))
