"""The learned correction network's weight file (plain ``.npz``, no pickles): format, checks,
save and load, with no torch import at run time.

The network is an MLP: an input (normalisation) layer, three hidden layers with one activation,
and a linear output layer whose de-normalisation is folded in, so a weight file is
self-contained::

    z = (input - in_mean) / in_scale
    h1 = act(W0 z + b0); h2 = act(W1 h1 + b1); h3 = act(W2 h2 + b2)
    y = (W3 h3 + b3) * out_scale + out_mean

How ``y`` enters the step is the formulation's business (:mod:`uavdyn.learned.formulations`).
A formulation that takes time or is tied to its step size records the trained ``dt`` and time
range (``t_range``), and the hybrid step refuses to be built for another ``dt``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavdyn.learned.formulations import FORMULATIONS, Formulation
from uavdyn.learned.mlp import ACTIVATIONS, mlp_forward
from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS

FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
N_HIDDEN_LAYERS = 3

REQUIRED_KEYS = (
    "format_version", "formulation", "activation", "kind", "airframe_hash", "dt",
    "in_mean", "in_scale", "out_mean", "out_scale",
    *(f"W{i}" for i in range(N_HIDDEN_LAYERS + 1)), *(f"b{i}" for i in range(N_HIDDEN_LAYERS + 1)),
)


class WeightFileError(ValueError):
    """A weight file is missing, malformed or made for another airframe; the message names the
    file and the offending key."""


@dataclass(frozen=True)
class CorrectionNet:
    """Frozen weights of one correction network, with everything needed to rebuild it.

    ``weights[i]`` has shape ``(n_out_i, n_in_i)`` (torch ``nn.Linear`` layout); ``dt`` is the
    step size the network was trained at; ``airframe_hash`` ties it to the airframe parameters
    it was trained against (:meth:`uavdyn.airframes.Airframe.param_hash`).
    """

    formulation: str
    activation: str
    kind: str
    airframe_hash: str
    dt: float
    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    in_mean: np.ndarray
    in_scale: np.ndarray
    out_mean: np.ndarray
    out_scale: np.ndarray
    info: dict = field(default_factory=dict)
    t_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        check_consistent(self, "<in memory>")

    @property
    def form(self) -> Formulation:
        return FORMULATIONS[self.formulation]

    @property
    def n_in(self) -> int:
        return self.form.n_in

    @property
    def n_out(self) -> int:
        return self.form.n_out

    def forward(self, inp, ops=NUMPY_OPS, relu_smoothing: float | None = None):
        """The network on a feature-first block ``inp`` (``(n_in,)`` CasADi column or
        ``(n_in, batch)`` array), evaluated with ``ops``."""
        return mlp_forward(self.weights, self.biases, self.in_mean, self.in_scale,
                           self.out_mean, self.out_scale, inp, ops, self.activation,
                           relu_smoothing)

    def casadi(self, inp, relu_smoothing: float | None = None):
        """The network as a CasADi expression of the column ``inp`` (SX or MX)."""
        return self.forward(inp, CASADI_OPS, relu_smoothing)

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(int(w.shape[0]) for w in self.weights[:-1])

    def describe(self) -> str:
        return (f"{self.formulation} MLP {self.n_in}-{'-'.join(map(str, self.hidden))}-"
                f"{self.n_out} ({self.activation}), kind {self.kind}, trained at dt {self.dt:g} s")


def check_consistent(net: CorrectionNet, origin: str) -> None:
    """Validate names and every array shape; raise :class:`WeightFileError` naming the key."""
    if net.formulation not in FORMULATIONS:
        raise WeightFileError(f"{origin}: key 'formulation' is '{net.formulation}'; expected one "
                              f"of {tuple(FORMULATIONS)}")
    if net.activation not in ACTIVATIONS:
        raise WeightFileError(f"{origin}: key 'activation' is '{net.activation}'; expected one "
                              f"of {ACTIVATIONS}")
    if net.kind not in ("fixed_wing", "multirotor"):
        raise WeightFileError(f"{origin}: key 'kind' is '{net.kind}'; expected 'fixed_wing' or "
                              "'multirotor'")
    if not (np.isfinite(net.dt) and net.dt > 0):
        raise WeightFileError(f"{origin}: key 'dt' must be a positive step size, got {net.dt}")
    n_layers = N_HIDDEN_LAYERS + 1
    if len(net.weights) != n_layers or len(net.biases) != n_layers:
        raise WeightFileError(f"{origin}: expected {n_layers} weight matrices W0..W3 and biases "
                              f"b0..b3, got {len(net.weights)} and {len(net.biases)}")
    n_in, n_out = FORMULATIONS[net.formulation].n_in, FORMULATIONS[net.formulation].n_out
    expect_in = n_in
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        if w.ndim != 2 or w.shape[1] != expect_in:
            raise WeightFileError(f"{origin}: key 'W{i}' has shape {w.shape}; expected "
                                  f"(width, {expect_in})")
        if i == n_layers - 1 and w.shape[0] != n_out:
            raise WeightFileError(f"{origin}: key 'W{i}' has shape {w.shape}; the "
                                  f"'{net.formulation}' formulation needs ({n_out}, {expect_in})")
        if b.shape != (w.shape[0],):
            raise WeightFileError(f"{origin}: key 'b{i}' has shape {b.shape}; expected "
                                  f"({w.shape[0]},) to match 'W{i}'")
        expect_in = w.shape[0]
    for key, size in (("in_mean", n_in), ("in_scale", n_in), ("out_mean", n_out),
                      ("out_scale", n_out)):
        value = getattr(net, key)
        if value.shape != (size,):
            raise WeightFileError(f"{origin}: key '{key}' has shape {value.shape}; expected "
                                  f"({size},) for the '{net.formulation}' formulation")
    arrays = {**{f"W{i}": w for i, w in enumerate(net.weights)},
              **{f"b{i}": b for i, b in enumerate(net.biases)},
              "in_mean": net.in_mean, "in_scale": net.in_scale, "out_mean": net.out_mean,
              "out_scale": net.out_scale}
    for key, value in arrays.items():
        if not np.all(np.isfinite(value)):
            raise WeightFileError(f"{origin}: key '{key}' contains non-finite values")
    if np.any(net.in_scale <= 0):
        raise WeightFileError(f"{origin}: key 'in_scale' must be > 0")
    if net.form.takes_time:
        t_range = net.t_range
        if (t_range is None or len(t_range) != 2 or not all(map(np.isfinite, t_range))
                or not t_range[0] < t_range[1]):
            raise WeightFileError(f"{origin}: key 't_range' must be [t_min, t_max] (s since the "
                                  f"sortie start) for the '{net.formulation}' formulation, got "
                                  f"{t_range}")


def save_weights(net: CorrectionNet, path: str | Path) -> Path:
    """Write ``net`` as a plain ``.npz`` (numbers and strings only; loads without pickle)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "format_version": np.array(FORMAT_VERSION), "formulation": np.array(net.formulation),
        "activation": np.array(net.activation), "kind": np.array(net.kind),
        "airframe_hash": np.array(net.airframe_hash), "dt": np.array(float(net.dt)),
        "in_mean": net.in_mean, "in_scale": net.in_scale, "out_mean": net.out_mean,
        "out_scale": net.out_scale, "info": np.array(json.dumps(net.info, sort_keys=True)),
    }
    if net.t_range is not None:
        arrays["t_range"] = np.asarray(net.t_range, float)
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        arrays[f"W{i}"], arrays[f"b{i}"] = np.asarray(w, float), np.asarray(b, float)
    with open(path, "wb") as fh:  # np.savez would append .npz to other suffixes
        np.savez(fh, **arrays)
    return path


def load_weights(path: str | Path, airframe=None) -> CorrectionNet:
    """Read a weight file; with ``airframe`` given, refuse weights trained for another one.

    Raises :class:`WeightFileError` naming the file and the key for a missing key, a wrong
    shape, an unknown formulation/activation, or an airframe-hash mismatch.
    """
    path = Path(path)
    if not path.exists():
        raise WeightFileError(f"{path}: weight file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            content = {k: data[k] for k in data.files}
    except (ValueError, OSError) as exc:
        raise WeightFileError(f"{path}: not a readable .npz weight file ({exc})") from exc
    missing = [k for k in REQUIRED_KEYS if k not in content]
    if missing:
        raise WeightFileError(f"{path}: missing key(s) {missing}")
    version = int(content["format_version"])
    if version not in READABLE_VERSIONS:
        raise WeightFileError(f"{path}: key 'format_version' is {version}; this uavdyn reads "
                              f"versions {READABLE_VERSIONS}")
    try:
        info = json.loads(str(content["info"])) if "info" in content else {}
    except json.JSONDecodeError as exc:
        raise WeightFileError(f"{path}: key 'info' is not valid JSON ({exc.msg})") from None
    try:
        net = CorrectionNet(
            formulation=str(content["formulation"]), activation=str(content["activation"]),
            kind=str(content["kind"]), airframe_hash=str(content["airframe_hash"]),
            dt=float(content["dt"]),
            weights=tuple(np.asarray(content[f"W{i}"], float)
                          for i in range(N_HIDDEN_LAYERS + 1)),
            biases=tuple(np.asarray(content[f"b{i}"], float) for i in range(N_HIDDEN_LAYERS + 1)),
            in_mean=np.asarray(content["in_mean"], float),
            in_scale=np.asarray(content["in_scale"], float),
            out_mean=np.asarray(content["out_mean"], float),
            out_scale=np.asarray(content["out_scale"], float), info=info,
            t_range=(tuple(float(v) for v in np.asarray(content["t_range"], float).ravel())
                     if "t_range" in content else None))
    except WeightFileError as exc:
        raise WeightFileError(str(exc).replace("<in memory>", str(path))) from None
    if airframe is not None:
        if airframe.kind != net.kind:
            raise WeightFileError(f"{path}: key 'kind' is '{net.kind}' but airframe "
                                  f"'{airframe.name}' is '{airframe.kind}'")
        if airframe.param_hash() != net.airframe_hash:
            raise WeightFileError(
                f"{path}: key 'airframe_hash' is {net.airframe_hash} but airframe "
                f"'{airframe.name}' has parameter hash {airframe.param_hash()}: these weights "
                "were trained for another airframe (retrain with `uavdyn train`)")
    return net
