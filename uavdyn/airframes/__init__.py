"""Airframe parameters as data: typed dataclasses loaded from TOML/JSON files with sources.

The file schema is described in :mod:`uavdyn.airframes.loader`; the parameters of each kind and
their physical bounds in :mod:`uavdyn.airframes.params`.
"""

from uavdyn.airframes.airframe import Airframe
from uavdyn.airframes.bounds import (
    ALPHA_DOT_DENOMINATOR_MIN,
    BOUNDS,
    NONNEGATIVE_KEYS,
    POSITIVE_KEYS,
    SIGNS,
    Bound,
    Sign,
    alpha_dot_denominator,
    sign_range,
)
from uavdyn.airframes.errors import AirframeError
from uavdyn.airframes.limits import CONTROL_RANGES, DELAY_MAX_SAMPLES, RATE_SUFFIX
from uavdyn.airframes.loader import (
    AIRFRAME_MAX_BYTES,
    ATMOSPHERES,
    NAME_PATTERN,
    NOMINAL_AIRSPEED_MAX,
    PARAM_ENTRY_KEYS,
    TOP_LEVEL_KEYS,
    load_airframe,
    to_toml_dict,
    tomllib,
)
from uavdyn.airframes.params import (
    KINDS,
    OPTIONAL_PARAMS,
    PARAM_CLASSES,
    FixedWingParams,
    MultirotorParams,
    ParamsType,
    param_names,
)
from uavdyn.airframes.plausibility import (
    AirframePlausibilityWarning,
    check_plausible,
    has_pitch_authority,
    plausibility_findings,
)
from uavdyn.airframes.presets import ALIASES, PERTURBATION_KEYS, PRESETS, list_presets, perturb

__all__ = ["AIRFRAME_MAX_BYTES", "ALIASES", "ALPHA_DOT_DENOMINATOR_MIN", "ATMOSPHERES", "BOUNDS",
           "CONTROL_RANGES", "DELAY_MAX_SAMPLES", "KINDS", "NAME_PATTERN", "NOMINAL_AIRSPEED_MAX",
           "NONNEGATIVE_KEYS", "OPTIONAL_PARAMS", "PARAM_CLASSES", "PARAM_ENTRY_KEYS",
           "PERTURBATION_KEYS", "POSITIVE_KEYS", "PRESETS", "RATE_SUFFIX", "SIGNS",
           "TOP_LEVEL_KEYS",
           "Airframe", "AirframeError", "Bound", "FixedWingParams", "MultirotorParams",
           "ParamsType", "Sign", "alpha_dot_denominator", "list_presets", "load_airframe",
           "param_names", "perturb", "sign_range", "to_toml_dict", "tomllib",
           "AirframePlausibilityWarning",
           "check_plausible", "has_pitch_authority", "plausibility_findings"]
