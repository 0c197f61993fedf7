"""The controllers a controller-in-the-loop Monte Carlo flies, all behind the interface of
:class:`uavdyn.mpc.Controller` (``reset``, ``solve``, ``config.dt``, ``bounds``, ``rates``) so
:func:`uavdyn.mpc.fly_closed_loop` flies either on the same dispersed airframes and gusts:

- :class:`LQRController`: the stated LQR of :func:`uavdyn.montecarlo.feedback.lqr_gain` (the
  nominal airframe at its nominal trim) tracking the scenario's pitch reference about the
  run's trim state, its command clipped to the MPC's control bounds and rate limits;
- :class:`CMPCController`: the real-time-iteration MPC as the exported C bundle
  (:func:`uavdyn.deploy.mpc_bundle.export_mpc_bundle`) compiled into a shared library and
  called through ``ctypes``: the C controller inside the chunk loop. Equal to the Python
  controller it is exported from to round-off (``tests/test_montecarlo_controllers.py``).
"""

from __future__ import annotations

import ctypes
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.mpc import Controller, MPCResult
from uavdyn.mpc.policy import HELD, SHIFTED, SOLVED

C_SOURCES = ("mpc_rti.c", "mpc_data.c", "mpc_generated.c", "qp_dense.c", "mpc_size.c")
_SOURCE = {0: SOLVED, 1: SHIFTED, 2: HELD}


class _Info(ctypes.Structure):
    """``mpc_info`` of ``mpc_rti.h``."""

    _fields_ = [("source", ctypes.c_int), ("success", ctypes.c_int),
                ("qp_status", ctypes.c_int), ("qp_iterations", ctypes.c_int),
                ("t_lin_s", ctypes.c_double), ("t_cond_s", ctypes.c_double),
                ("t_qp_s", ctypes.c_double)]


class LQRController:
    """LQR pitch tracking with the interface of :class:`uavdyn.mpc.Controller`.

    ``u = u_0 - K (x - x_ref)`` on the body states ``[u, w, q, theta]``, where ``u_0`` and
    ``x_ref`` are the command and state at the first call after :meth:`reset` (the run's
    trim) with the pitch reference's step added to ``theta``; ``K`` is the stated gain of the
    nominal airframe. The command is clipped to ``rates * dt`` of the last one, then to
    ``bounds``: what the actuators can do. No solve, so never a failure.

    Parameters
    ----------
    gain : ndarray
        ``nu x 4`` state feedback.
    config : MPCConfig
        The MPC's (interval, horizon): both fly the same grid.
    kind : str
        Airframe kind.
    bounds, rates : ndarray
        The MPC's control bounds (``nu x 2``) and rate limits (per second).
    """

    def __init__(self, gain: np.ndarray, config, kind: str, bounds: np.ndarray,
                 rates: np.ndarray) -> None:
        self.gain = np.asarray(gain, float)
        self.config, self.kind = config, kind
        self.bounds, self.rates = np.asarray(bounds, float), np.asarray(rates, float)
        self.reset()

    def reset(self) -> None:
        """Forget the run's trim (taken again at the next call)."""
        self._x0: np.ndarray | None = None
        self._u0: np.ndarray | None = None

    def solve(self, x0, u_prev, theta_ref, h_ref, speed_ref, weights=None) -> MPCResult:
        """One control interval (the arguments of :meth:`uavdyn.mpc.Controller.solve`; only
        the first pitch reference is used)."""
        y = np.asarray(x0, float)[:4]
        u_prev = np.asarray(u_prev, float)
        if self._x0 is None:
            self._x0, self._u0 = y.copy(), u_prev.copy()
            self._theta0 = float(np.ravel(theta_ref)[0])
        ref = self._x0.copy()
        ref[3] += float(np.ravel(theta_ref)[0]) - self._theta0
        u = self._u0 - self.gain @ (y - ref)
        step = self.rates * self.config.dt
        u = np.clip(np.clip(u, u_prev - step, u_prev + step), self.bounds[:, 0],
                    self.bounds[:, 1])
        return MPCResult(u=u, source=SOLVED, success=True, solve_time_s=0.0, iterations=0,
                         status="lqr", predicted_states=None, predicted_controls=None)


class CMPCController:
    """The exported C real-time-iteration MPC of a Python :class:`uavdyn.mpc.RTIController`
    (same problem: model, horizon, weights, bounds), built into a private temporary folder
    and loaded with ``ctypes``; the interface of :class:`uavdyn.mpc.Controller`.

    Raises
    ------
    RuntimeError
        If the bundle does not build (the compiler's first error line).
    """

    def __init__(self, python: Controller, plant_airframe: Airframe, compiler: str) -> None:
        from uavdyn.deploy.mpc_bundle import example_closed_loop, export_mpc_bundle

        self.config, self.kind = python.config, python.kind
        self.bounds, self.rates, self.nu = python.bounds, python.rates, python.nu
        self.N = python.N
        self._tmp = tempfile.TemporaryDirectory(prefix="uavdyn-cmpc-")
        folder = Path(self._tmp.name) / "bundle"
        example = example_closed_loop(plant_airframe, python.config.dt)
        export_mpc_bundle(python.problem, example, folder)
        (folder / "mpc_size.c").write_text(
            '#include <stddef.h>\n#include "mpc_rti.h"\n'
            "size_t uavdyn_mpc_workspace_size(void) { return sizeof(mpc_workspace); }\n")
        lib = folder / "libuavdyn_mpc.so"
        done = subprocess.run([compiler, "-std=c99", "-O2", "-fPIC", "-shared", "-o",
                               str(lib), *C_SOURCES, "-lm"], cwd=folder, capture_output=True,
                              text=True)
        if done.returncode != 0:
            first = (done.stderr.strip().splitlines() or ["no output"])[0]
            raise RuntimeError(f"the C controller did not build: {first}")
        self._lib = ctypes.CDLL(str(lib))
        self._lib.uavdyn_mpc_workspace_size.restype = ctypes.c_size_t
        self._ws = ctypes.create_string_buffer(self._lib.uavdyn_mpc_workspace_size())
        self._info = _Info()
        self._u = np.zeros(self.nu)
        self.reset()

    def reset(self) -> None:
        """Forget the plan and the carried states (``mpc_init``)."""
        self._lib.mpc_init(self._ws)

    def solve(self, x0, u_prev, theta_ref, h_ref, speed_ref, weights=None) -> MPCResult:
        """One ``mpc_step`` (the arguments of :meth:`uavdyn.mpc.Controller.solve`)."""
        t0 = time.perf_counter()
        refs = np.empty((3, self.N))
        refs[0], refs[1], refs[2] = theta_ref, h_ref, speed_ref
        y = np.ascontiguousarray(x0, float)
        up = np.ascontiguousarray(u_prev, float)
        r = np.ascontiguousarray(refs.ravel(order="F"))
        w = None if weights is None else np.ascontiguousarray(weights, float)
        u = np.zeros(self.nu)
        p = ctypes.POINTER(ctypes.c_double)
        source = self._lib.mpc_step(self._ws, y.ctypes.data_as(p), up.ctypes.data_as(p),
                                    r.ctypes.data_as(p), None if w is None else
                                    w.ctypes.data_as(p), u.ctypes.data_as(p),
                                    ctypes.byref(self._info))
        success = bool(self._info.success)
        return MPCResult(u=u, source=_SOURCE[source], success=success,
                         solve_time_s=time.perf_counter() - t0, iterations=1,
                         status="solved" if success else "failed", predicted_states=None,
                         predicted_controls=None)


__all__ = ["CMPCController", "LQRController"]
