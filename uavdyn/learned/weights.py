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
range (``t_range``), and the hybrid step refuses to be built for another ``dt``. The file's
container is read by :mod:`uavdyn.learned.weight_archive` (size bounds, no pickles, typed keys).
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import tempfile
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from uavdyn.learned.envelope import DEFAULT_GUARD, GUARDS, LEGACY_GUARD, Envelope
from uavdyn.learned.formulations import (
    FORMULATIONS,
    PHYSICAL_INPUTS,
    STATE_DIM,
    CorrectionLayout,
    Formulation,
    design_problem,
)
from uavdyn.learned.mlp import ACTIVATIONS, folded_forward, folded_layers, mlp_forward
from uavdyn.learned.weight_archive import (
    ENVELOPE_KEYS,
    MAX_FILE_BYTES,
    MAX_MEMBERS,
    MAX_UNCOMPRESSED_BYTES,
    STEADY_KEYS,
    WeightFileError,
    envelope_arrays,
    info_key,
    integer_key,
    read_envelope,
    read_npz,
    real_key,
    show,
    text_key,
)
from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS

FORMAT_VERSION = 6
READABLE_VERSIONS = (1, 2, 3, 4, 5, 6)
MAX_MEMORY_FILTERS = 8
N_HIDDEN_LAYERS = 3
MAX_NAME_CHARS = 256

REQUIRED_KEYS = (
    "format_version", "formulation", "activation", "kind", "airframe_hash", "dt",
    "in_mean", "in_scale", "out_mean", "out_scale",
    *(f"W{i}" for i in range(N_HIDDEN_LAYERS + 1)), *(f"b{i}" for i in range(N_HIDDEN_LAYERS + 1)),
)
# format 3 (the safe correction): the state size of the step (physics augmented state plus the
# command memory), the memory filters' time constants, the training input envelope and the
# output bound; absent (format 1-2), the correction is ungated and unbounded on 4 body states.
# format 4: the key 'guard' names the form of gate and bound (format 3 is 'product-tanh')
# format 5: the keys 'inputs' and 'output' name the improved network's input and output
# designs (absent: 'state' and 'acceleration', as before); 'W_skip' (optional) is the linear
# path beside the hidden layers
# format 6: a multirotor's 'physical' inputs add the front-rear difference of rotor speed
# times u and w (pitch moments of translational lift and axial inflow); a format-5 file of
# that design was trained on the earlier inputs and is refused with the reason
# 'n_controls' (optional, absent: 2): the step's inputs, 6 for a model with the lateral inputs
# of turning flight (the controls, then phi, p, r, beta), which the network also sees
OPTIONAL_KEYS = ("info", "t_range", "n_state", "memory_tau", "out_bound", "guard",
                 "inputs", "output", "W_skip", "n_controls", *ENVELOPE_KEYS,
                 *STEADY_KEYS)
NAME_KEYS = ("formulation", "activation", "kind", "airframe_hash")
# the extra network inputs of each input design over the step's state and command (the
# physical inputs replace the body states)
EXTRA_INPUTS = {**{("state", kind): 0 for kind in PHYSICAL_INPUTS},
                **{("physical", kind): len(names) - STATE_DIM
                   for kind, names in PHYSICAL_INPUTS.items()}}

# the archive's limits and error are part of this module's names
__all__ = ["CorrectionNet", "FORMAT_VERSION", "MAX_FILE_BYTES", "MAX_MEMBERS",
           "MAX_UNCOMPRESSED_BYTES", "N_HIDDEN_LAYERS", "READABLE_VERSIONS",
           "WeightFileError", "check_consistent", "load_weights", "save_weights"]


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
    n_state: int = 4
    memory_tau: tuple[float, ...] = ()
    envelope: Envelope | None = None
    out_bound: np.ndarray | None = None
    guard: str = DEFAULT_GUARD
    inputs: str = "state"
    output: str = "acceleration"
    skip: np.ndarray | None = None
    n_controls: int = 2

    def __post_init__(self) -> None:
        check_consistent(self, "<in memory>")

    def layout(self, structure=None) -> CorrectionLayout:
        """The state layout, gate and bound of the ``improved`` step on the physics
        ``structure`` (an airframe's :func:`uavdyn.model.structure_of`).

        Raises
        ------
        WeightFileError
            If the network was made for a step with another number of states.
        """
        gate = (partial(self.envelope.gate, form=GUARDS[self.guard][0])
                if self.envelope is not None else None)
        try:
            layout = CorrectionLayout(structure, tuple(self.memory_tau), gate, self.out_bound,
                                      self.guard, self.inputs, self.output)
        except ValueError as exc:
            raise WeightFileError(f"correction network: {exc}") from None
        if layout.nu != self.n_controls:
            raise WeightFileError(
                f"correction network key 'n_controls' is {self.n_controls} but the airframe's "
                f"step takes {layout.nu} inputs ("
                + ("with" if layout.nu > 2 else "without")
                + " the turning-flight inputs phi, p, r, beta): train it on data of the same "
                "kind (import-log with or without --turns)")
        if layout.n_state != self.n_state:
            raise WeightFileError(
                f"correction network key 'n_state' is {self.n_state} but the airframe's step "
                f"with {len(self.memory_tau)} memory filter(s) per command has "
                f"{layout.n_state} states ({', '.join(layout.state_names())})")
        return layout

    @property
    def form(self) -> Formulation:
        return FORMULATIONS[self.formulation]

    @property
    def n_in(self) -> int:
        if self.formulation != "improved":
            return self.form.n_in
        return self.n_state + self.n_controls + EXTRA_INPUTS[(self.inputs, self.kind)]

    @property
    def n_out(self) -> int:
        return self.form.n_out

    def forward(self, inp, ops=NUMPY_OPS, relu_smoothing: float | None = None):
        """The network on a feature-first block ``inp`` (``(n_in,)`` CasADi column or
        ``(n_in, batch)`` array), evaluated with ``ops``."""
        return mlp_forward(self.weights, self.biases, self.in_mean, self.in_scale,
                           self.out_mean, self.out_scale, inp, ops, self.activation,
                           relu_smoothing, self.skip)

    def casadi(self, inp, relu_smoothing: float | None = None):
        """The network as a CasADi expression of the column ``inp`` (SX or MX); a plain ReLU
        network with its normalisation folded into the weights (fewer instructions in every
        compiled step, equal to round-off)."""
        if self.activation != "relu" or relu_smoothing:
            return self.forward(inp, CASADI_OPS, relu_smoothing)
        weights, biases, skip = folded_layers(self.weights, self.biases, self.in_mean,
                                              self.in_scale, self.out_mean, self.out_scale,
                                              self.skip)
        return folded_forward(weights, biases, inp, CASADI_OPS, skip)

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(int(w.shape[0]) for w in self.weights[:-1])

    def describe(self) -> str:
        design = (f", {self.inputs} inputs, {self.output} output"
                  if self.formulation == "improved" else "")
        design += ", linear path" if self.skip is not None else ""
        return (f"{self.formulation} MLP {self.n_in}-{'-'.join(map(str, self.hidden))}-"
                f"{self.n_out} ({self.activation}{design}), kind {self.kind}, trained at dt "
                f"{self.dt:g} s")


def check_consistent(net: CorrectionNet, origin: str) -> None:
    """Validate names and every array shape, so a network is checked once, wherever it comes
    from (file or memory).

    Parameters
    ----------
    net : CorrectionNet
        The network.
    origin : str
        Where it came from (a file name), for the message.

    Raises
    ------
    WeightFileError
        One line naming ``origin`` and the offending key.
    """
    if net.formulation not in FORMULATIONS:
        raise WeightFileError(f"{origin}: key 'formulation' is {show(net.formulation)}; expected "
                              f"one of {tuple(FORMULATIONS)}")
    if net.activation not in ACTIVATIONS:
        raise WeightFileError(f"{origin}: key 'activation' is {show(net.activation)}; expected "
                              f"one of {ACTIVATIONS}")
    if net.kind not in ("fixed_wing", "multirotor"):
        raise WeightFileError(f"{origin}: key 'kind' is {show(net.kind)}; expected 'fixed_wing' "
                              "or 'multirotor'")
    problem = design_problem(net.inputs, net.output, net.kind)
    if problem:
        raise WeightFileError(f"{origin}: {problem}")
    if (net.inputs, net.output) != ("state", "acceleration") and net.formulation != "improved":
        raise WeightFileError(f"{origin}: keys 'inputs'/'output' are for the 'improved' "
                              f"formulation, not '{net.formulation}'")
    if not (np.isfinite(net.dt) and net.dt > 0):
        raise WeightFileError(f"{origin}: key 'dt' must be a positive step size, got {net.dt}")
    n_layers = N_HIDDEN_LAYERS + 1
    if len(net.weights) != n_layers or len(net.biases) != n_layers:
        raise WeightFileError(f"{origin}: expected {n_layers} weight matrices W0..W3 and biases "
                              f"b0..b3, got {len(net.weights)} and {len(net.biases)}")
    if isinstance(net.n_state, bool) or not isinstance(net.n_state, (int, np.integer)) \
            or not 4 <= net.n_state <= 200 or (net.formulation != "improved" and net.n_state != 4):
        raise WeightFileError(f"{origin}: key 'n_state' must be a whole number of states in "
                              f"4..200 (4 for the '{net.formulation}' formulation), got "
                              f"{show(net.n_state)}")
    if net.n_controls not in (2, 6) or (net.formulation != "improved" and net.n_controls != 2):
        raise WeightFileError(f"{origin}: key 'n_controls' must be 2, or 6 with the "
                              "turning-flight inputs (the 'improved' formulation only), got "
                              f"{show(net.n_controls)}")
    taus = tuple(net.memory_tau)
    if len(taus) > MAX_MEMORY_FILTERS or not all(np.isfinite(t) and t > 0 for t in taus):
        raise WeightFileError(f"{origin}: key 'memory_tau' must hold at most "
                              f"{MAX_MEMORY_FILTERS} positive time constants, got {show(taus)}")
    n_in, n_out = net.n_in, FORMULATIONS[net.formulation].n_out
    expect_in = n_in
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        if w.ndim != 2 or w.shape[1] != expect_in:
            raise WeightFileError(f"{origin}: key 'W{i}' has shape {w.shape}; expected "
                                  f"(width, {expect_in})")
        if i == n_layers - 1 and w.shape[0] != n_out:
            raise WeightFileError(f"{origin}: key 'W{i}' has shape {w.shape}; the "
                                  f"'{net.formulation}' formulation needs ({n_out}, {expect_in})")
        if w.shape[0] < 1:
            raise WeightFileError(f"{origin}: key 'W{i}' has shape {w.shape}; a layer needs at "
                                  "least one neuron")
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
    if net.skip is not None and np.shape(net.skip) != (n_out, n_in):
        raise WeightFileError(f"{origin}: key 'W_skip' has shape {np.shape(net.skip)}; "
                              f"expected ({n_out}, {n_in})")
    arrays = {**{f"W{i}": w for i, w in enumerate(net.weights)},
              **({"W_skip": net.skip} if net.skip is not None else {}),
              **{f"b{i}": b for i, b in enumerate(net.biases)},
              "in_mean": net.in_mean, "in_scale": net.in_scale, "out_mean": net.out_mean,
              "out_scale": net.out_scale}
    for key, value in arrays.items():
        if not np.all(np.isfinite(value)):
            raise WeightFileError(f"{origin}: key '{key}' contains non-finite values")
    if np.any(net.in_scale <= 0):
        raise WeightFileError(f"{origin}: key 'in_scale' must be > 0")
    if net.guard not in GUARDS:
        raise WeightFileError(f"{origin}: key 'guard' is {show(net.guard)}; expected one of "
                              f"{tuple(GUARDS)}")
    if net.out_bound is not None:
        bound = np.asarray(net.out_bound)
        if bound.shape != (n_out,) or not np.all(np.isfinite(bound)) or np.any(bound <= 0):
            raise WeightFileError(f"{origin}: key 'out_bound' must hold {n_out} positive finite "
                                  f"numbers, got {show(bound.tolist())}")
    if net.envelope is not None and net.envelope.n_in != n_in:
        raise WeightFileError(f"{origin}: key 'env_low' has {net.envelope.n_in} entries; the "
                              f"network has {n_in} inputs")
    if net.t_range is not None or net.form.takes_time:
        t_range = net.t_range
        if (t_range is None or len(t_range) != 2 or not all(map(np.isfinite, t_range))
                or not t_range[0] < t_range[1]):
            raise WeightFileError(f"{origin}: key 't_range' must be [t_min, t_max] with t_min < "
                                  f"t_max (s since the sortie start) for the '{net.formulation}' "
                                  f"formulation, got {show(t_range)}")


def save_weights(net: CorrectionNet, path: str | Path) -> Path:
    """Write ``net`` as a plain ``.npz`` (numbers and strings only; loads without pickle).

    The file is written to a temporary sibling, synced and renamed over ``path``, so an
    interrupt never leaves a truncated weight file and an old file stays intact until the new
    one is complete.

    Parameters
    ----------
    net : CorrectionNet
        The network to store.
    path : path
        Destination (any suffix; parent folders are created).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    WeightFileError
        If the file cannot be written (the message names it).
    """
    path = Path(path)
    arrays = {
        "format_version": np.array(FORMAT_VERSION), "formulation": np.array(net.formulation),
        "activation": np.array(net.activation), "kind": np.array(net.kind),
        "airframe_hash": np.array(net.airframe_hash), "dt": np.array(float(net.dt)),
        "in_mean": net.in_mean, "in_scale": net.in_scale, "out_mean": net.out_mean,
        "out_scale": net.out_scale, "info": np.array(json.dumps(net.info, sort_keys=True)),
        "guard": np.array(net.guard), "inputs": np.array(net.inputs),
        "output": np.array(net.output),
    }
    if net.t_range is not None:
        arrays["t_range"] = np.asarray(net.t_range, float)
    if net.n_state != 4 or net.memory_tau:
        arrays["n_state"] = np.array(int(net.n_state))
        arrays["memory_tau"] = np.asarray(net.memory_tau, float)
    if net.n_controls != 2:  # written only with lateral inputs: other files are unchanged
        arrays["n_controls"] = np.array(int(net.n_controls))
    if net.out_bound is not None:
        arrays["out_bound"] = np.asarray(net.out_bound, float)
    if net.skip is not None:
        arrays["W_skip"] = np.asarray(net.skip, float)
    if net.envelope is not None:
        arrays.update(envelope_arrays(net.envelope))
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        arrays[f"W{i}"], arrays[f"b{i}"] = np.asarray(w, float), np.asarray(b, float)
    tmp: str | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            mode = stat.S_IMODE(os.stat(path).st_mode)
        except OSError:
            mode = 0o644
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:  # np.savez would append .npz to other suffixes
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise WeightFileError(f"{path}: cannot write weight file ({exc.strerror or exc})") \
            from None
    finally:
        if tmp is not None:  # failed or interrupted (KeyboardInterrupt too): drop the partial
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    return path


def load_weights(path: str | Path, airframe=None) -> CorrectionNet:
    """Read a weight file; with ``airframe`` given, refuse weights trained for another one.

    Only a regular file of at most 64 MB is opened (FIFOs, devices and folders are refused
    without blocking); the zip directory's declared sizes are checked before anything is
    extracted, every member must be a plain ``.npy`` array (no pickles), and every key is
    checked for dtype, shape and finiteness.

    Parameters
    ----------
    path : path
        The ``.npz`` weight file.
    airframe : Airframe, optional
        If given, the file's ``kind`` and ``airframe_hash`` must match it.

    Returns
    -------
    CorrectionNet
        The validated network.

    Raises
    ------
    WeightFileError
        One line naming the file and the key, for any unreadable, malformed or mismatched file.
    """
    path = Path(path)
    content = read_npz(path)
    missing = [k for k in REQUIRED_KEYS if k not in content]
    if missing:
        raise WeightFileError(f"{path}: missing key(s) {missing}")
    unknown = sorted(set(content) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise WeightFileError(f"{path}: key {show(unknown[0])} is not part of the weight-file "
                              f"format (version {FORMAT_VERSION})")
    version = integer_key(path, content, "format_version")
    if version not in READABLE_VERSIONS:
        raise WeightFileError(f"{path}: key 'format_version' is {version}; this uavdyn reads "
                              f"versions {READABLE_VERSIONS}")
    names = {key: text_key(path, content, key) for key in NAME_KEYS}
    for key, value in names.items():
        if len(value) > MAX_NAME_CHARS or not value.isprintable():
            raise WeightFileError(f"{path}: key '{key}' must be a short printable name, got "
                                  f"{show(value)}")
    info = info_key(path, content)
    guard = text_key(path, content, "guard") if "guard" in content else None
    if guard is None and version >= 4:
        raise WeightFileError(f"{path}: key 'guard' is missing; format {version} names the "
                              f"form of its gate and bound (one of {tuple(GUARDS)})")
    extra: dict = {"guard": guard or LEGACY_GUARD}
    for key in ("inputs", "output"):
        if key in content:
            extra[key] = text_key(path, content, key)
    if version <= 5 and (extra.get("inputs"), names["kind"]) == ("physical", "multirotor"):
        raise WeightFileError(f"{path}: a format-{version} multirotor correction with "
                              "'physical' inputs was trained on the earlier input set (without "
                              "the front-rear rotor-speed difference terms); retrain it with "
                              f"`uavdyn train` (this uavdyn writes format {FORMAT_VERSION})")
    n_layers = N_HIDDEN_LAYERS + 1
    t_range = None
    if "t_range" in content:
        t_range = tuple(float(v) for v in real_key(path, content, "t_range", 1))
    if "n_state" in content:
        extra["n_state"] = integer_key(path, content, "n_state")
    if "memory_tau" in content:
        extra["memory_tau"] = tuple(float(v) for v in real_key(path, content, "memory_tau", 1))
    if "n_controls" in content:
        extra["n_controls"] = integer_key(path, content, "n_controls")
    if "out_bound" in content:
        extra["out_bound"] = real_key(path, content, "out_bound", 1)
    if "W_skip" in content:
        extra["skip"] = real_key(path, content, "W_skip", 2)
    envelope = read_envelope(path, content)
    if envelope is not None:
        extra["envelope"] = envelope
    try:
        net = CorrectionNet(
            formulation=names["formulation"], activation=names["activation"],
            kind=names["kind"], airframe_hash=names["airframe_hash"],
            dt=float(real_key(path, content, "dt", 0)),
            weights=tuple(real_key(path, content, f"W{i}", 2) for i in range(n_layers)),
            biases=tuple(real_key(path, content, f"b{i}", 1) for i in range(n_layers)),
            in_mean=real_key(path, content, "in_mean", 1),
            in_scale=real_key(path, content, "in_scale", 1),
            out_mean=real_key(path, content, "out_mean", 1),
            out_scale=real_key(path, content, "out_scale", 1), info=info, t_range=t_range,
            **extra)
    except WeightFileError as exc:
        raise WeightFileError(str(exc).replace("<in memory>", str(path))) from None
    if airframe is not None:
        if airframe.kind != net.kind:
            raise WeightFileError(f"{path}: key 'kind' is '{net.kind}' but airframe "
                                  f"'{airframe.name}' is '{airframe.kind}'")
        if airframe.param_hash() != net.airframe_hash:
            raise WeightFileError(
                f"{path}: key 'airframe_hash' is {show(net.airframe_hash)} but airframe "
                f"'{airframe.name}' has parameter hash {airframe.param_hash()}: these weights "
                "were trained for another airframe (retrain with `uavdyn train`)")
    return net
