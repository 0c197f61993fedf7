"""Dispersion files for Monte-Carlo studies: per-parameter, initial-state, trim-speed and gust
distributions read from TOML, validated key by key, and sampled per run from ``(seed, run)``.

File schema (unknown keys are errors, so a typo never passes silently)::

    seed = 0                         # optional integer >= 0 (the CLI's --seed overrides it)
    description = "..."              # optional string

    [params.mass]                    # any parameter of the airframe (Airframe.param_names)
    dist = "uniform"                 # "normal", "uniform" or "truncnormal"
    low = -0.15                      # uniform and truncnormal: bounds of the offset
    high = 0.15
    relative = true                  # params: default true, offset is a fraction of nominal

    [params.C_m_alpha]
    dist = "normal"
    sd = 0.05                        # normal and truncnormal: standard deviation (> 0)
    mean = 0.0                       # optional, default 0

    [initial]                        # offsets added to each run's trim state (SI, radians)
    theta = { dist = "normal", sd = 0.02 }
    q = { dist = "uniform", low = -0.05, high = 0.05 }

    [trim]
    airspeed = { dist = "uniform", low = -2.0, high = 2.0 }   # m/s added to the trim speed

    [gust]                           # Dryden turbulence (uavdyn.emulation.dryden_gusts)
    intensity = 1.0                  # multiplier of light turbulence, 0 = calm; or a
                                     # distribution of the value itself (bounds >= 0)
    sigma_u = 1.06                   # optional: rms gusts (m/s) and scale lengths (m) at
    sigma_w = 0.7                    # intensity 1 (defaults: Beard & McLain, low altitude)
    L_u = 200.0
    L_w = 50.0
    sample_dt = 0.05                 # optional (s): gusts drawn this often and held (default:
                                     # every step; coarser is faster to draw, see the docs)

    [limits]                         # thresholds of the exceedance statistics; false = off
    pitch_deg = 30.0                 # |theta| above
    alpha_deg = 12.0                 # alpha above (default: the airframe's stall angle)
    airspeed_min_mps = 15.0          # airspeed below (default: the nominal stall speed)
    load_factor_max = 2.5            # -Z / (m g) above

A parameter value is ``nominal * (1 + x)`` when ``relative`` and ``nominal + x`` otherwise, with
``x`` the drawn offset; initial-state and trim-speed offsets are absolute unless ``relative``.
Every run draws its numbers from its own generator, ``numpy.random.default_rng([seed, run,
0])`` (the gusts from ``[seed, run, 1]``), in a fixed order (sorted section and name), so a
run is reproducible from ``(seed, run)`` alone, whatever the chunking or the number of workers.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.special import ndtr, ndtri

from uavdyn.airframes import Airframe, AirframeError
from uavdyn.safefiles import UnreadableFile, read_regular

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

DISPERSION_MAX_BYTES = 256 * 1024
DISTRIBUTIONS = ("normal", "uniform", "truncnormal")
STATE_KEYS = ("u", "w", "q", "theta")
TRIM_KEYS = ("airspeed",)
GUST_SCALE_KEYS = ("sigma_u", "sigma_w", "L_u", "L_w")
LIMIT_KEYS = ("pitch_deg", "alpha_deg", "airspeed_min_mps", "load_factor_max")
TOP_LEVEL_KEYS = ("seed", "description", "params", "initial", "trim", "gust", "limits")
ENTRY_KEYS = ("dist", "mean", "sd", "low", "high", "relative")
MIN_TRUNCATED_MASS = 1e-12  # a truncation interval must hold at least this probability


class DispersionError(ValueError):
    """A dispersion file is malformed; the one-line message names the file and the key."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(message.split()))


@dataclass(frozen=True)
class Distribution:
    """One dispersed quantity: the distribution of its offset ``x`` and how it applies.

    Attributes
    ----------
    kind : str
        ``normal`` (``mean + sd z``), ``uniform`` (on ``[low, high)``) or ``truncnormal``
        (normal restricted to ``[low, high]``, drawn by inverse CDF).
    mean, sd, low, high : float
        Parameters of the offset, in the quantity's units (a fraction when ``relative``).
    relative : bool
        Value ``nominal * (1 + x)`` if True, ``nominal + x`` otherwise.
    """

    kind: str
    mean: float = 0.0
    sd: float = 0.0
    low: float = -math.inf
    high: float = math.inf
    relative: bool = False

    def draw(self, rng: np.random.Generator) -> float:
        """One offset ``x`` from ``rng`` (exactly one generator call per draw)."""
        if self.kind == "normal":
            return self.mean + self.sd * float(rng.standard_normal())
        if self.kind == "uniform":
            return float(rng.uniform(self.low, self.high))
        a, b = ndtr((self.low - self.mean) / self.sd), ndtr((self.high - self.mean) / self.sd)
        z = float(ndtri(a + float(rng.random()) * (b - a)))
        return float(min(max(self.mean + self.sd * z, self.low), self.high))

    def apply(self, nominal: float, offset: float) -> float:
        """The dispersed value of a quantity whose nominal value is ``nominal``."""
        return nominal * (1.0 + offset) if self.relative else nominal + offset

    @property
    def bounded(self) -> bool:
        """Whether every draw lies in a finite ``[low, high]``."""
        return self.kind in ("uniform", "truncnormal")

    def describe(self) -> str:
        """Short text, e.g. ``uniform [-0.15, 0.15] relative``."""
        how = "relative" if self.relative else "absolute"
        if self.kind == "normal":
            return f"normal(mean {self.mean:g}, sd {self.sd:g}) {how}"
        if self.kind == "uniform":
            return f"uniform [{self.low:g}, {self.high:g}) {how}"
        return (f"truncated normal(mean {self.mean:g}, sd {self.sd:g}) on "
                f"[{self.low:g}, {self.high:g}] {how}")

    def as_dict(self) -> dict:
        out: dict = {"dist": self.kind, "relative": self.relative}
        if self.kind != "uniform":
            out.update(mean=self.mean, sd=self.sd)
        if self.bounded:
            out.update(low=self.low, high=self.high)
        return out


@dataclass(frozen=True)
class Dispersions:
    """A parsed dispersion file (see the module docstring for the schema).

    Attributes
    ----------
    params, initial, trim : dict of str to Distribution
        Dispersed airframe parameters, initial-state offsets and trim-speed offsets.
    gust_intensity : float or Distribution
        Dryden intensity (fixed, or the distribution of its value).
    gust_scales : dict of str to float
        Overrides of :func:`uavdyn.emulation.dryden_gusts` scales.
    gust_sample_dt : float or None
        Interval at which gusts are drawn and then held (None: every step).
    limits : dict of str to float or None
        Exceedance thresholds the file sets (None: switched off with ``false``); the others
        take the airframe's defaults (:func:`uavdyn.montecarlo.resolve_limits`).
    seed : int or None
        The file's seed.
    origin : str
        Where it was read from (for messages).
    """

    params: dict[str, Distribution] = field(default_factory=dict)
    initial: dict[str, Distribution] = field(default_factory=dict)
    trim: dict[str, Distribution] = field(default_factory=dict)
    gust_intensity: float | Distribution = 0.0
    gust_scales: dict[str, float] = field(default_factory=dict)
    gust_sample_dt: float | None = None
    limits: dict[str, float | None] = field(default_factory=dict)
    seed: int | None = None
    description: str = ""
    origin: str = "<in memory>"

    @property
    def has_gusts(self) -> bool:
        """Whether any run can see turbulence."""
        g = self.gust_intensity
        return g.high > 0 if isinstance(g, Distribution) else g > 0

    def quantities(self) -> list[tuple[str, str, Distribution]]:
        """``(section, name, distribution)`` in draw order (sorted section, then name)."""
        out = [("gust", "intensity", self.gust_intensity)] \
            if isinstance(self.gust_intensity, Distribution) else []
        for section in ("initial", "params", "trim"):
            table = getattr(self, section)
            out += [(section, name, table[name]) for name in sorted(table)]
        return sorted(out, key=lambda e: (e[0], e[1]))

    def column_names(self) -> list[str]:
        """Summary-table column of each drawn quantity: ``<section>.<name>``."""
        return [f"{s}.{n}" for s, n, _ in self.quantities()]

    def sample(self, seed: int, run: int) -> RunDraw:
        """The draws of run ``run`` (reproducible from ``(seed, run)`` alone).

        Parameters
        ----------
        seed : int
            Study seed (>= 0).
        run : int
            Run index (>= 0).
        """
        rng = np.random.default_rng([int(seed), int(run), 0])
        values: dict[str, float] = {}
        for section, name, dist in self.quantities():
            values[f"{section}.{name}"] = dist.draw(rng)
        intensity = (values["gust.intensity"] if "gust.intensity" in values
                     else float(self.gust_intensity))
        return RunDraw(run=int(run), offsets=values, gust_intensity=max(intensity, 0.0))

    def to_dict(self) -> dict:
        """JSON-friendly content (what the study key hashes)."""
        g = self.gust_intensity
        return {
            "params": {k: v.as_dict() for k, v in sorted(self.params.items())},
            "initial": {k: v.as_dict() for k, v in sorted(self.initial.items())},
            "trim": {k: v.as_dict() for k, v in sorted(self.trim.items())},
            "gust": {"intensity": g.as_dict() if isinstance(g, Distribution) else g,
                     "sample_dt": self.gust_sample_dt,
                     **dict(sorted(self.gust_scales.items()))},
            "limits": dict(sorted(self.limits.items())),
        }

    def describe(self) -> list[str]:
        """One line per dispersed quantity."""
        lines = [f"{s}.{n}: {d.describe()}" for s, n, d in self.quantities()]
        if not isinstance(self.gust_intensity, Distribution):
            lines.append(f"gust.intensity: {self.gust_intensity:g}"
                         + (" (calm)" if self.gust_intensity == 0 else ""))
        return lines


@dataclass(frozen=True)
class RunDraw:
    """What one run drew: ``offsets`` by column name (``params.mass`` etc.) and its gust
    intensity."""

    run: int
    offsets: dict[str, float]
    gust_intensity: float

    def params(self, dispersions: Dispersions, airframe: Airframe) -> dict[str, float]:
        """The dispersed parameter values (name -> value) of this run."""
        nominal = dict(zip(airframe.param_names, airframe.p))
        return {name: dist.apply(float(nominal[name]), self.offsets[f"params.{name}"])
                for name, dist in dispersions.params.items()}


def _fail(origin: str, key: str, message: str) -> DispersionError:
    return DispersionError(f"{origin}: key '{key}' {message}")


def _number(value: object, origin: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(origin, key, f"must be a number, got {type(value).__name__} "
                                 f"{str(value)[:40]!r}")
    value = float(value)
    if not math.isfinite(value):
        raise _fail(origin, key, f"must be finite, got {value}")
    return value


def _distribution(raw: object, origin: str, key: str, relative_default: bool) -> Distribution:
    if not isinstance(raw, dict):
        raise _fail(origin, key, "must be a table such as { dist = \"normal\", sd = 0.05 }, "
                                 f"got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(ENTRY_KEYS))
    if unknown:
        raise _fail(origin, f"{key}.{unknown[0]}", f"is not a distribution key; expected "
                                                   f"{', '.join(ENTRY_KEYS)}")
    kind = raw.get("dist")
    if kind not in DISTRIBUTIONS:
        raise _fail(origin, f"{key}.dist", f"must be one of {', '.join(DISTRIBUTIONS)}, got "
                                           f"{str(kind)[:40]!r}")
    relative = raw.get("relative", relative_default)
    if not isinstance(relative, bool):
        raise _fail(origin, f"{key}.relative", "must be true or false")
    needs = {"normal": ("sd",), "uniform": ("low", "high"),
             "truncnormal": ("sd", "low", "high")}[kind]
    allowed = set(needs) | {"dist", "relative"} | ({"mean"} if kind != "uniform" else set())
    for k in raw:
        if k not in allowed:
            raise _fail(origin, f"{key}.{k}", f"does not apply to dist = \"{kind}\" (it takes "
                                              f"{', '.join(sorted(allowed - {'dist'}))})")
    for k in needs:
        if k not in raw:
            raise _fail(origin, f"{key}.{k}", f"is required for dist = \"{kind}\"")
    values = {k: _number(raw[k], origin, f"{key}.{k}") for k in ("mean", "sd", "low", "high")
              if k in raw}
    if "sd" in values and not values["sd"] > 0:
        raise _fail(origin, f"{key}.sd", f"must be > 0, got {values['sd']:g}")
    if "low" in values and not values["low"] < values["high"]:
        raise _fail(origin, f"{key}.low", f"must be below high ({values['low']:g} >= "
                                          f"{values['high']:g})")
    dist = Distribution(kind, relative=relative, **values)
    if kind == "truncnormal":
        mass = ndtr((dist.high - dist.mean) / dist.sd) - ndtr((dist.low - dist.mean) / dist.sd)
        if not mass > MIN_TRUNCATED_MASS:
            raise _fail(origin, key, f"truncates its normal to [{dist.low:g}, {dist.high:g}], "
                                     f"which holds probability {mass:.1e}: move mean or bounds")
    if relative and dist.bounded and dist.low <= -1.0:
        raise _fail(origin, f"{key}.low", f"= {dist.low:g} would flip or zero the sign of the "
                                          "nominal value (relative offsets must stay > -1)")
    return dist


def _table(raw: object, origin: str, key: str) -> dict:
    if not isinstance(raw, dict):
        raise _fail(origin, key, f"must be a table, got {type(raw).__name__}")
    return raw


def parse_dispersions(data: dict, airframe: Airframe, origin: str = "<in memory>"
                      ) -> Dispersions:
    """Validate the content of a dispersion file against ``airframe``.

    Parameters
    ----------
    data : dict
        The decoded TOML.
    airframe : Airframe
        The nominal airframe (parameter names, nominal values and their physical bounds).
    origin : str
        Name used in messages (the file path).

    Returns
    -------
    Dispersions

    Raises
    ------
    DispersionError
        On the first problem, naming ``origin`` and the key.
    """
    unknown = sorted(set(data) - set(TOP_LEVEL_KEYS))
    if unknown:
        raise _fail(origin, unknown[0], f"is not a dispersion-file key; expected "
                                        f"{', '.join(TOP_LEVEL_KEYS)}")
    seed = data.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0
                             or seed >= 2**63):
        raise _fail(origin, "seed", f"must be an integer >= 0, got {str(seed)[:40]!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise _fail(origin, "description", "must be a string")
    nominal = dict(zip(airframe.param_names, airframe.p))
    params: dict[str, Distribution] = {}
    for name, raw in _table(data.get("params", {}), origin, "params").items():
        key = f"params.{name}"
        if name not in nominal:
            raise _fail(origin, key, f"is not a parameter of airframe '{airframe.name}' "
                                     f"({airframe.kind}); parameters: "
                                     f"{', '.join(airframe.param_names[:12])}, ...")
        dist = _distribution(raw, origin, key, relative_default=True)
        if dist.relative and nominal[name] == 0.0:
            raise _fail(origin, key, f"is 0 in airframe '{airframe.name}', so a relative "
                                     "dispersion would do nothing; give relative = false")
        if dist.bounded:  # both extremes must be physical airframes
            for end in (dist.low, dist.high):
                try:
                    airframe.replace(**{name: dist.apply(float(nominal[name]), end)})
                except AirframeError as exc:
                    raise _fail(origin, key, f"reaches {dist.apply(float(nominal[name]), end):g}"
                                             f" at its bound: {_reason(exc)}") from None
        params[name] = dist
    states: dict[str, dict[str, Distribution]] = {}
    for section, allowed in (("initial", STATE_KEYS), ("trim", TRIM_KEYS)):
        states[section] = {}
        for name, raw in _table(data.get(section, {}), origin, section).items():
            if name not in allowed:
                raise _fail(origin, f"{section}.{name}", f"is not dispersible; expected one of "
                                                         f"{', '.join(allowed)}")
            states[section][name] = _distribution(raw, origin, f"{section}.{name}",
                                                  relative_default=False)
    gust = _table(data.get("gust", {}), origin, "gust")
    for k in gust:
        if k not in ("intensity", "sample_dt") + GUST_SCALE_KEYS:
            raise _fail(origin, f"gust.{k}", f"is not a gust key; expected intensity, "
                                             f"sample_dt, {', '.join(GUST_SCALE_KEYS)}")
    intensity: float | Distribution = 0.0
    if "intensity" in gust:
        raw = gust["intensity"]
        if isinstance(raw, dict):
            intensity = _distribution(raw, origin, "gust.intensity", relative_default=False)
            if intensity.relative or not intensity.bounded or intensity.low < 0:
                raise _fail(origin, "gust.intensity", "as a distribution describes the "
                                                      "intensity itself: use uniform or "
                                                      "truncnormal with low >= 0, relative = "
                                                      "false")
        else:
            intensity = _number(raw, origin, "gust.intensity")
            if intensity < 0:
                raise _fail(origin, "gust.intensity", f"must be >= 0, got {intensity:g}")
    scales = {}
    for k in GUST_SCALE_KEYS:
        if k in gust:
            scales[k] = _number(gust[k], origin, f"gust.{k}")
            if not scales[k] > 0:
                raise _fail(origin, f"gust.{k}", f"must be > 0, got {scales[k]:g}")
    sample_dt = None
    if "sample_dt" in gust:
        sample_dt = _number(gust["sample_dt"], origin, "gust.sample_dt")
        if not sample_dt > 0:
            raise _fail(origin, "gust.sample_dt", f"must be > 0 s, got {sample_dt:g}")
    limits: dict[str, float | None] = {}
    for k, raw in _table(data.get("limits", {}), origin, "limits").items():
        if k not in LIMIT_KEYS:
            raise _fail(origin, f"limits.{k}", f"is not a limit; expected "
                                               f"{', '.join(LIMIT_KEYS)}")
        if raw is False:
            limits[k] = None
            continue
        limits[k] = _number(raw, origin, f"limits.{k}")
        if k != "alpha_deg" and not limits[k] > 0:
            raise _fail(origin, f"limits.{k}", f"must be > 0 (or false to switch it off), got "
                                               f"{limits[k]:g}")
    return Dispersions(params=params, initial=states["initial"], trim=states["trim"],
                       gust_intensity=intensity, gust_scales=scales, gust_sample_dt=sample_dt,
                       limits=limits, seed=seed,
                       description=description, origin=origin)


def _reason(exc: BaseException) -> str:
    text = str(exc)
    return text.split(": ", 1)[1] if ": " in text else text


SHIPPED_DISPERSIONS = "uavdyn.montecarlo.shipped"


def shipped_dispersions() -> list[str]:
    """Names of the example dispersion files shipped with the package."""
    return sorted(str(f.name)[:-5] for f in resources.files(SHIPPED_DISPERSIONS).iterdir()
                  if str(f.name).endswith(".toml"))


def load_dispersions(path: str | Path, airframe: Airframe) -> Dispersions:
    """Read and validate a dispersion file (TOML) for ``airframe``.

    Parameters
    ----------
    path : str or Path
        The ``.toml`` file (a regular file of at most :data:`DISPERSION_MAX_BYTES`), or the
        name of a shipped example (:func:`shipped_dispersions`, e.g. ``aerosonde_pm15``) when
        no such file exists.
    airframe : Airframe
        The nominal airframe.

    Returns
    -------
    Dispersions

    Raises
    ------
    DispersionError
        One line naming the file and the key (or why the file cannot be read).
    """
    shown = str(path)
    if isinstance(path, str) and path in shipped_dispersions() and not Path(path).exists():
        path = Path(str(resources.files(SHIPPED_DISPERSIONS).joinpath(f"{path}.toml")))
        shown = f"shipped dispersions '{shown}'"
    try:
        raw = read_regular(path, DISPERSION_MAX_BYTES, "a dispersion file")
    except UnreadableFile as exc:
        hint = (f" (or the name of a shipped example: {', '.join(shipped_dispersions())})"
                if not Path(path).exists() else "")
        raise DispersionError(f"{shown}: {exc.reason}{hint}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise DispersionError(f"{shown}: not UTF-8 text (a dispersion file is TOML)") from None
    except tomllib.TOMLDecodeError as exc:
        raise DispersionError(f"{shown}: not valid TOML: {exc}") from None
    return parse_dispersions(data, airframe, shown)
