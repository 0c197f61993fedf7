"""Identification of physical parameters from flight data: output-error least squares over
windows restarted from recorded states (CasADi ``nlpsol``, exact Jacobians, Gauss-Newton
Hessian), standard errors and correlations, and an airframe file with provenance."""

from uavdyn.identify.output_error import (
    Estimate,
    IdentificationResult,
    IdentifyError,
    Windows,
    identify,
    make_windows,
    measurement_noise,
)
from uavdyn.identify.report import airframe_toml, write_outputs

__all__ = ["Estimate", "IdentificationResult", "IdentifyError", "Windows", "identify",
           "make_windows", "measurement_noise", "airframe_toml", "write_outputs"]
