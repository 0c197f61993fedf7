"""Flight data: the in-memory sortie type, the SPEC section 3 interchange format (a folder with
``manifest.json`` and one CSV per sortie), loading with consistency checks, preprocessing
(zero-phase low-pass filter, normalisation from the training split) and export.

CSV header: fixed wing ``time,u,w,q,theta,elevator,throttle``; multirotor
``time,u,w,q,theta,collective,pitch_cmd``. SI units, radians, body axes (x forward, z down).
Row k's controls are held over [t_k, t_k+1) (zero-order hold).

Every problem found in a file raises :class:`FlightDataError` whose message names the file, the
row (``data row r`` counts data rows from 1; ``CSV line r+1`` counts the header as line 1), the
column, and what is wrong. Nothing is silently dropped or repaired.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt

from uavdyn.model import CONTROL_BOUNDS, CONTROL_NAMES, STATE_NAMES

SPLIT_NAMES = ("train", "validation", "test")
# Physical plausibility limits (units slip-ups such as degrees or km/h land outside them).
SPEED_LIMIT = {"fixed_wing": 100.0, "multirotor": 50.0}  # |u|, |w| in m/s
PITCH_RATE_LIMIT = 10.0  # rad/s (573 deg/s)
PITCH_LIMIT = math.pi    # rad
CONTROL_TOLERANCE = 1e-9
TIME_TOLERANCE = 1e-3    # allowed relative deviation of each interval from the nominal one
KINEMATIC_WINDOW_S = 1.0
KINEMATIC_TOLERANCE = 0.05  # rad, plus 10 % of the pitch travelled in the window


class FlightDataError(ValueError):
    """A flight-data file is malformed; the message names file, row and column.

    The parts are also kept as attributes: ``file``, ``row`` (1-based data row), ``line``
    (1-based CSV line, header = line 1) and ``column`` (each may be None)."""

    def __init__(self, message: str, file: str | Path | None = None, row: int | None = None,
                 column: str | None = None, line: int | None = None) -> None:
        self.file = None if file is None else str(file)
        self.row = row
        self.line = line if line is not None else (None if row is None else row + 1)
        self.column = column
        where = []
        if self.file is not None:
            where.append(self.file)
        if row is not None:
            where.append(f"data row {row} (CSV line {self.line})")
        elif self.line is not None:
            where.append(f"CSV line {self.line}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__(": ".join([", ".join(where), message]) if where else message)


def csv_columns(kind: str) -> tuple[str, ...]:
    """The interchange-format header for an airframe kind."""
    if kind not in CONTROL_NAMES:
        raise FlightDataError(f"unknown airframe kind '{kind}'; expected one of "
                              f"{tuple(CONTROL_NAMES)}")
    return ("time",) + STATE_NAMES + CONTROL_NAMES[kind]


@dataclass
class Sortie:
    """One flight: uniformly sampled time, states ``N x 4`` and controls ``N x 2``;
    ``true_states`` (optional) are the noise-free states of an emulated flight."""

    name: str
    kind: str
    time: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    mission: str = ""
    meta: dict = field(default_factory=dict)
    true_states: np.ndarray | None = None

    @property
    def dt(self) -> float:
        """Median sample interval (s)."""
        return float(np.median(np.diff(self.time)))

    @property
    def duration(self) -> float:
        """Last minus first time stamp (s)."""
        return float(self.time[-1] - self.time[0])

    @property
    def split(self) -> str:
        """``train``/``validation``/``test`` as recorded in the manifest ('' if none)."""
        return str(self.meta.get("split", ""))

    def to_array(self) -> np.ndarray:
        """``N x 7`` table in the CSV column order (time, states, controls)."""
        return np.column_stack([self.time, self.states, self.controls])


def write_csv(sortie: Sortie, path: str | Path) -> Path:
    """Write one sortie in the interchange CSV format (17 significant digits: lossless)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = ",".join(csv_columns(sortie.kind))
    np.savetxt(path, sortie.to_array(), delimiter=",", header=header, comments="", fmt="%.17g")
    return path


def export(sortie: Sortie, path: str | Path, true_states: bool = False) -> Path:
    """Export any sortie (emulated, loaded or imported from a ULog) to the CSV format;
    ``true_states=True`` writes its noise-free states instead of the measured ones."""
    if true_states:
        if sortie.true_states is None:
            raise FlightDataError(f"sortie '{sortie.name}' has no true (noise-free) states")
        sortie = replace(sortie, states=sortie.true_states)
    return write_csv(sortie, path)


def write_manifest(folder: str | Path, airframe: str, kind: str, sample_rate_hz: float,
                   source: str, sorties: list[dict], **extra) -> Path:
    """Write ``manifest.json``: ``sorties`` entries need ``file``, ``mission``, ``duration_s``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = {"airframe": airframe, "kind": kind, "sample_rate_hz": sample_rate_hz,
                "source": source, "sorties": sorties, **extra}
    path = folder / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, sort_keys=False) + "\n")
    return path


# ----------------------------------------------------------------------------- reading


def _kind_from_header(header: list[str], path: Path) -> str:
    cols = set(header)
    for kind, names in CONTROL_NAMES.items():
        if set(names) & cols:
            return kind
    raise FlightDataError(
        f"cannot tell the airframe kind from the header {','.join(header)!r}: expected the "
        f"control columns {CONTROL_NAMES['fixed_wing']} (fixed wing) or "
        f"{CONTROL_NAMES['multirotor']} (multirotor)", path, line=1)


def _check_header(header: list[str], expected: tuple[str, ...], path: Path) -> None:
    for name in expected:
        if name not in header:
            raise FlightDataError(f"missing column '{name}' in the header; expected "
                                  f"'{','.join(expected)}'", path, line=1, column=name)
    for name in header:
        if name not in expected:
            raise FlightDataError(f"unexpected column '{name}' in the header; expected "
                                  f"'{','.join(expected)}'", path, line=1, column=name)
    if len(header) != len(set(header)):
        dup = next(h for h in header if header.count(h) > 1)
        raise FlightDataError("duplicated column in the header", path, line=1, column=dup)
    if tuple(header) != expected:
        raise FlightDataError(f"columns out of order: header '{','.join(header)}', expected "
                              f"'{','.join(expected)}'", path, line=1)


def _parse_rows(lines: list[str], header: list[str], path: Path) -> np.ndarray:
    ncol = len(header)
    out = np.empty((len(lines), ncol))
    for r, line in enumerate(lines, start=1):
        fields = line.split(",")
        if len(fields) != ncol:
            raise FlightDataError(f"has {len(fields)} fields, the header has {ncol}", path, r)
        for c, text in enumerate(fields):
            try:
                out[r - 1, c] = float(text)
            except ValueError:
                raise FlightDataError(f"cannot read {text.strip()!r} as a number", path, r,
                                      header[c]) from None
    return out


def _read_table(path: Path) -> tuple[list[str], np.ndarray]:
    if not path.exists():
        raise FlightDataError("file not found", path)
    if path.is_dir():
        raise FlightDataError("is a folder, expected a CSV file (or load the folder with "
                              "load_dataset)", path)
    raw = path.read_bytes()
    if len(raw) == 0 or not raw.strip():
        raise FlightDataError("empty file: expected a header row and data rows", path)
    try:
        if b"\x00" in raw[:65536]:
            raise UnicodeDecodeError("utf-8", raw, raw.index(b"\x00"), raw.index(b"\x00") + 1,
                                     "NUL byte")
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FlightDataError(f"not a text CSV file (binary content: byte "
                              f"0x{raw[exc.start]:02x} at offset {exc.start})", path) from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    header = [h.strip() for h in lines[0].split(",")]
    if len(header) < 2:
        raise FlightDataError(f"not a CSV file: the first line {lines[0][:60]!r} is not a "
                              "comma-separated header", path, line=1)
    body = lines[1:]
    for r, line in enumerate(body, start=1):
        if not line.strip():
            raise FlightDataError("blank line inside the data", path, r)
    if not body:
        raise FlightDataError("no data rows after the header", path)
    try:  # fast path; the slow path below finds the exact row and column of a problem
        data = np.loadtxt(body, delimiter=",", ndmin=2)
        if data.shape != (len(body), len(header)):
            raise ValueError
    except ValueError:
        data = _parse_rows(body, header, path)
    return header, data


def check_values(path: str | Path, kind: str, time: np.ndarray, states: np.ndarray,
                 controls: np.ndarray, sample_rate_hz: float | None = None,
                 kinematic: bool = True) -> None:
    """Consistency checks of one sortie's arrays (raises :class:`FlightDataError`): finite
    values, at least 2 rows, strictly increasing and uniform time, physical ranges, controls
    within bounds and, if ``kinematic``, d theta/dt against q."""
    columns = csv_columns(kind)
    table = np.column_stack([time, states, controls])
    bad = np.argwhere(~np.isfinite(table))
    if len(bad):
        r, c = bad[0]
        raise FlightDataError(f"value {table[r, c]} is not finite", path, int(r) + 1,
                              columns[c])
    if len(time) < 2:
        raise FlightDataError(f"only {len(time)} data row(s); need at least 2", path)
    steps = np.diff(time)
    nonpos = np.flatnonzero(steps <= 0)
    if len(nonpos):
        k = int(nonpos[0]) + 1
        raise FlightDataError(f"time {float(time[k])!r} s is not greater than the previous "
                              f"row's {float(time[k - 1])!r} s (time must strictly increase)",
                              path, k + 1,
                              "time")
    nominal = float(np.median(steps))
    if sample_rate_hz is not None:
        if abs(nominal * sample_rate_hz - 1.0) > TIME_TOLERANCE:
            raise FlightDataError(f"median sample interval {nominal:.6g} s does not match the "
                                  f"manifest's sample_rate_hz {sample_rate_hz:g}", path,
                                  column="time")
        nominal = 1.0 / sample_rate_hz
    off = np.flatnonzero(np.abs(steps - nominal) > TIME_TOLERANCE * nominal)
    if len(off):
        k = int(off[0]) + 1
        raise FlightDataError(f"time step {steps[k - 1]:.6g} s from the previous row differs "
                              f"from the nominal {nominal:.6g} s by more than "
                              f"{TIME_TOLERANCE:.1%} (time must be uniform)", path, k + 1, "time")
    limits = {"u": SPEED_LIMIT[kind], "w": SPEED_LIMIT[kind], "q": PITCH_RATE_LIMIT,
              "theta": PITCH_LIMIT}
    units = {"u": "m/s", "w": "m/s", "q": "rad/s", "theta": "rad"}
    for j, name in enumerate(STATE_NAMES):
        over = np.flatnonzero(np.abs(states[:, j]) > limits[name])
        if len(over):
            r = int(over[0])
            raise FlightDataError(
                f"value {states[r, j]:.6g} {units[name]} is outside the physical range "
                f"[-{limits[name]:g}, {limits[name]:g}] {units[name]} (wrong units, e.g. "
                f"degrees or km/h?)", path, r + 1, name)
    for j, (name, (lo, hi)) in enumerate(zip(CONTROL_NAMES[kind], CONTROL_BOUNDS[kind])):
        out = np.flatnonzero((controls[:, j] < lo - CONTROL_TOLERANCE)
                             | (controls[:, j] > hi + CONTROL_TOLERANCE))
        if len(out):
            r = int(out[0])
            raise FlightDataError(f"value {controls[r, j]:.6g} is outside the control range "
                                  f"[{lo:g}, {hi:g}]", path, r + 1, name)
    if kinematic:
        check_kinematics(path, time, states)


def kinematic_residual(time: np.ndarray, states: np.ndarray,
                       window_s: float = KINEMATIC_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """Per window of ``window_s`` seconds (half-overlapping): the pitch change minus the
    trapezoid integral of q, and the pitch travelled (integral of |q|). Start indices are
    the first return value's index times the hop; see :func:`check_kinematics`."""
    theta, q = states[:, 3], states[:, 2]
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(time))])
    cum_abs = np.concatenate([[0.0], np.cumsum(0.5 * np.abs(q[1:] + q[:-1]) * np.diff(time))])
    n = len(time)
    width = max(1, int(round(window_s / float(np.median(np.diff(time))))))
    width = min(width, n - 1)
    starts = np.arange(0, n - width, max(1, width // 2))
    if len(starts) == 0:
        starts = np.array([0])
    ends = starts + width
    diff = (theta[ends] - theta[starts]) - (cum[ends] - cum[starts])
    travel = cum_abs[ends] - cum_abs[starts]
    return np.column_stack([starts, ends, diff]), travel


def check_kinematics(path: str | Path, time: np.ndarray, states: np.ndarray,
                     window_s: float = KINEMATIC_WINDOW_S,
                     tolerance: float = KINEMATIC_TOLERANCE) -> None:
    """d theta/dt ~ q: over every window the pitch change must match the integrated pitch rate
    within ``tolerance`` rad plus 10 % of the pitch travelled (noise and gyro bias of valid
    logs pass; pitch in degrees, q in deg/s or a flipped sign do not)."""
    windows, travel = kinematic_residual(time, states, window_s)
    allowed = tolerance + 0.1 * travel
    bad = np.flatnonzero(np.abs(windows[:, 2]) > allowed)
    if len(bad):
        i = int(bad[0])
        a, b, d = int(windows[i, 0]), int(windows[i, 1]), windows[i, 2]
        raise FlightDataError(
            f"kinematic inconsistency over data rows {a + 1}-{b + 1} (t = {time[a]:.3f}-"
            f"{time[b]:.3f} s): the pitch change differs from the integral of q by {d:.4g} rad "
            f"(allowed {allowed[i]:.3g} rad); theta and q disagree (units or sign?)", path,
            b + 1, "theta")


def read_csv(path: str | Path, kind: str | None = None, sample_rate_hz: float | None = None,
             check: bool = True, name: str | None = None) -> Sortie:
    """Read one interchange-format CSV into a :class:`Sortie` (kind from the header if not
    given), with all consistency checks of :func:`check_values` unless ``check=False``."""
    path = Path(path)
    header, data = _read_table(path)
    if kind is None:
        kind = _kind_from_header(header, path)
    expected = csv_columns(kind)
    _check_header(header, expected, path)
    time, states, controls = data[:, 0], data[:, 1:5], data[:, 5:7]
    if check:
        check_values(path, kind, time, states, controls, sample_rate_hz)
    else:
        bad = np.argwhere(~np.isfinite(data))
        if len(bad):
            raise FlightDataError(f"value {data[tuple(bad[0])]} is not finite", path,
                                  int(bad[0][0]) + 1, expected[bad[0][1]])
    return Sortie(name=name or path.stem, kind=kind, time=time.copy(), states=states.copy(),
                  controls=controls.copy(), meta={"file": str(path)})


# ----------------------------------------------------------------------------- datasets


@dataclass(frozen=True)
class Normalisation:
    """Mean and standard deviation of states and controls (from the training split only)."""

    state_mean: np.ndarray
    state_std: np.ndarray
    control_mean: np.ndarray
    control_std: np.ndarray
    sorties: tuple[str, ...] = ()

    def normalise(self, states: np.ndarray, controls: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Zero-mean, unit-std states and controls (statistics of the training split)."""
        return ((states - self.state_mean) / self.state_std,
                (controls - self.control_mean) / self.control_std)

    def denormalise(self, states: np.ndarray, controls: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`normalise`."""
        return (states * self.state_std + self.state_mean,
                controls * self.control_std + self.control_mean)

    def as_dict(self) -> dict:
        """JSON-friendly form (to store beside trained weights)."""
        return {"state_mean": self.state_mean.tolist(), "state_std": self.state_std.tolist(),
                "control_mean": self.control_mean.tolist(),
                "control_std": self.control_std.tolist(), "sorties": list(self.sorties)}


def normalisation(sorties: list[Sortie]) -> Normalisation:
    """Statistics pooled over ``sorties`` (pass the training split only). A channel that is
    constant gets std 1 so normalising never divides by zero."""
    if not sorties:
        raise FlightDataError("no sorties to compute normalisation statistics from (is the "
                              "training split empty?)")
    S = np.vstack([s.states for s in sorties])
    U = np.vstack([s.controls for s in sorties])

    def std(a):
        sd = a.std(axis=0)
        return np.where(sd > 1e-12, sd, 1.0)

    return Normalisation(S.mean(axis=0), std(S), U.mean(axis=0), std(U),
                         tuple(s.name for s in sorties))


def lowpass(sortie: Sortie, cutoff_hz: float, order: int = 4) -> Sortie:
    """Zero-phase Butterworth low-pass (``scipy.signal.filtfilt``) of the measured states.
    Controls (commands, held per interval) and true states are left as they are."""

    fs = 1.0 / sortie.dt
    if not 0 < cutoff_hz < fs / 2:
        raise FlightDataError(f"sortie '{sortie.name}': cutoff {cutoff_hz} Hz must be between 0 "
                              f"and the Nyquist frequency {fs / 2:g} Hz")
    b, a = butter(order, cutoff_hz / (fs / 2))
    if len(sortie.time) <= 3 * max(len(a), len(b)):
        raise FlightDataError(f"sortie '{sortie.name}' is too short ({len(sortie.time)} rows) "
                              f"for an order-{order} zero-phase filter")
    states = filtfilt(b, a, sortie.states, axis=0)
    meta = dict(sortie.meta, lowpass_hz=cutoff_hz, lowpass_order=order)
    return replace(sortie, states=states, meta=meta)


@dataclass
class Dataset:
    """A loaded dataset: its manifest and sorties (in manifest order), split by sortie."""

    path: Path
    manifest: dict
    sorties: list[Sortie]

    @property
    def kind(self) -> str:
        """``fixed_wing`` or ``multirotor`` (from the manifest)."""
        return self.manifest["kind"]

    @property
    def sample_rate_hz(self) -> float:
        """Log rate (Hz) from the manifest."""
        return float(self.manifest["sample_rate_hz"])

    @property
    def splits(self) -> dict[str, list[str]]:
        """Sortie names per split (``unsplit`` for sorties the manifest gives no split)."""
        out: dict[str, list[str]] = {name: [] for name in SPLIT_NAMES}
        for s in self.sorties:
            out.setdefault(s.split or "unsplit", []).append(s.name)
        return out

    def split(self, name: str) -> list[Sortie]:
        """The sorties of one split, in manifest order."""
        if name not in SPLIT_NAMES:
            raise ValueError(f"unknown split '{name}'; expected one of {SPLIT_NAMES}")
        return [s for s in self.sorties if s.split == name]

    @property
    def train(self) -> list[Sortie]:
        """Training sorties (the only ones normalisation statistics come from)."""
        return self.split("train")

    @property
    def validation(self) -> list[Sortie]:
        """Validation sorties (model selection, early stopping)."""
        return self.split("validation")

    @property
    def test(self) -> list[Sortie]:
        """Held-out test sorties (final figures only)."""
        return self.split("test")

    def normalisation(self) -> Normalisation:
        """Normalisation statistics from the training split only (never validation/test)."""
        return normalisation(self.train)

    def lowpass(self, cutoff_hz: float, order: int = 4) -> Dataset:
        """A copy with every sortie's measured states low-pass filtered (zero phase)."""
        return Dataset(self.path, dict(self.manifest, lowpass_hz=cutoff_hz),
                       [lowpass(s, cutoff_hz, order) for s in self.sorties])

    def export(self, folder: str | Path) -> Path:
        """Write the dataset (manifest + CSVs, true states too where present) to ``folder``."""
        folder = Path(folder)
        entries = []
        for s in self.sorties:
            entry = dict(s.meta.get("manifest_entry", {}))
            entry.update(file=f"{s.name}.csv", mission=s.mission, duration_s=s.duration)
            write_csv(s, folder / entry["file"])
            if s.true_states is not None:
                entry["true_file"] = f"{s.name}_true.csv"
                export(s, folder / entry["true_file"], true_states=True)
            entries.append(entry)
        extra = {k: v for k, v in self.manifest.items()
                 if k not in ("airframe", "kind", "sample_rate_hz", "source", "sorties")}
        return write_manifest(folder, self.manifest.get("airframe", ""), self.kind,
                              self.sample_rate_hz, self.manifest.get("source", ""), entries,
                              **extra)


def _manifest_error(path: Path, message: str) -> FlightDataError:
    return FlightDataError(message, path)


def read_manifest(path: str | Path) -> dict:
    """Read and validate ``manifest.json`` (keys, types, kind, split names)."""
    path = Path(path)
    if not path.exists():
        raise FlightDataError("no manifest.json in the dataset folder", path)
    try:
        manifest = json.loads(path.read_text())
    except UnicodeDecodeError:
        raise _manifest_error(path, "not a text JSON file") from None
    except json.JSONDecodeError as exc:
        raise FlightDataError(f"line {exc.lineno}, column {exc.colno}: invalid JSON: "
                              f"{exc.msg}", path) from None
    if not isinstance(manifest, dict):
        raise _manifest_error(path, "the manifest must be a JSON object")
    for key in ("airframe", "kind", "sample_rate_hz", "source", "sorties"):
        if key not in manifest:
            raise _manifest_error(path, f"missing key '{key}'")
    if manifest["kind"] not in CONTROL_NAMES:
        raise _manifest_error(path, f"key 'kind': '{manifest['kind']}' is not one of "
                                    f"{tuple(CONTROL_NAMES)}")
    rate = manifest["sample_rate_hz"]
    if not isinstance(rate, (int, float)) or isinstance(rate, bool) or not rate > 0 \
            or not math.isfinite(rate):
        raise _manifest_error(path, f"key 'sample_rate_hz': {rate!r} is not a positive number")
    sorties = manifest["sorties"]
    if not isinstance(sorties, list) or not sorties:
        raise _manifest_error(path, "key 'sorties' must be a non-empty list")
    seen = set()
    for i, entry in enumerate(sorties):
        if not isinstance(entry, dict):
            raise _manifest_error(path, f"sorties[{i}] must be an object")
        for key, types in (("file", str), ("mission", str), ("duration_s", (int, float))):
            if key not in entry:
                raise _manifest_error(path, f"sorties[{i}]: missing key '{key}'")
            if not isinstance(entry[key], types) or isinstance(entry[key], bool):
                raise _manifest_error(path, f"sorties[{i}]: key '{key}' has the wrong type "
                                            f"({type(entry[key]).__name__})")
        if entry["file"] in seen:
            raise _manifest_error(path, f"sorties[{i}]: file '{entry['file']}' listed twice")
        seen.add(entry["file"])
        split = entry.get("split")
        if split is not None and split not in SPLIT_NAMES:
            raise _manifest_error(path, f"sorties[{i}]: split '{split}' is not one of "
                                        f"{SPLIT_NAMES}")
    return manifest


def load_dataset(path: str | Path, check: bool = True, lowpass_hz: float | None = None,
                 load_true: bool = True) -> Dataset:
    """Load a dataset folder (``manifest.json`` + CSVs) or one CSV file, checking everything
    (see :func:`check_values`); optionally low-pass filter the measured states."""
    path = Path(path)
    if not path.exists():
        raise FlightDataError("no such file or folder", path)
    if path.is_file() and path.name != "manifest.json":
        s = read_csv(path, check=check)
        rate = 1.0 / s.dt
        manifest = {"airframe": "", "kind": s.kind, "sample_rate_hz": rate,
                    "source": f"single CSV {path.name}",
                    "sorties": [{"file": path.name, "mission": "", "duration_s": s.duration}]}
        ds = Dataset(path, manifest, [s])
        return ds.lowpass(lowpass_hz) if lowpass_hz else ds
    folder = path if path.is_dir() else path.parent
    manifest_path = folder / "manifest.json"
    manifest = read_manifest(manifest_path)
    kind, rate = manifest["kind"], float(manifest["sample_rate_hz"])
    sorties = []
    for entry in manifest["sorties"]:
        file = folder / entry["file"]
        s = read_csv(file, kind=kind, sample_rate_hz=rate, check=check,
                     name=Path(entry["file"]).stem)
        if abs(s.duration - float(entry["duration_s"])) > 1.5 / rate:
            raise FlightDataError(f"the manifest says duration_s {entry['duration_s']} but the "
                                  f"file spans {s.duration:.6g} s", file, column="time")
        if load_true and entry.get("true_file"):
            tfile = folder / entry["true_file"]
            t = read_csv(tfile, kind=kind, sample_rate_hz=rate, check=check)
            if len(t.time) != len(s.time) or not np.array_equal(t.time, s.time):
                raise FlightDataError(f"time column differs from its measured file "
                                      f"{entry['file']}", tfile, column="time")
            if not np.array_equal(t.controls, s.controls):
                r = int(np.flatnonzero(np.any(t.controls != s.controls, axis=1))[0]) + 1
                raise FlightDataError(f"controls differ from its measured file {entry['file']}",
                                      tfile, r)
            s.true_states = t.states
        s.mission = entry["mission"]
        s.meta.update(split=entry.get("split", ""), condition=entry.get("condition", ""),
                      manifest_entry=entry)
        sorties.append(s)
    ds = Dataset(folder, manifest, sorties)
    return ds.lowpass(lowpass_hz) if lowpass_hz else ds
