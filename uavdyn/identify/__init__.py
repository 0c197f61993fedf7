"""Identification of physical parameters from flight data: output-error least squares over
windows restarted from recorded states (bounded Levenberg-Marquardt, ``identify.lm``, on the
windows' exact CasADi Jacobians) on the model structure of the airframe (actuator lags,
searched integer delays, per-sortie density, table values), standard errors and correlations,
and a complete airframe file with provenance."""

from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.output_error import (
    Estimate,
    IdentificationResult,
    identify,
    measurement_noise,
)
from uavdyn.identify.report import airframe_toml, write_outputs
from uavdyn.identify.windows import Windows, make_windows, physics_windows

__all__ = ["Estimate", "IdentificationResult", "IdentifyError", "Windows", "identify",
           "make_windows", "measurement_noise", "physics_windows",
           "airframe_toml", "write_outputs"]
