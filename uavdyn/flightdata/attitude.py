"""Attitude from logged quaternions: pitch, roll, body-to-world rotation, unit-length check.

Quaternions are ``N x 4`` arrays ``(w, x, y, z)`` rotating FRD body axes into NED (PX4's
``vehicle_attitude.q``); an ENU/FLU quaternion (MAVROS) gives the negative nose-up pitch.
"""

from __future__ import annotations

import numpy as np

QUATERNION_NORM_TOLERANCE = 0.1     # |norm - 1| of logged attitude quaternions


def pitch_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Pitch of FRD-to-NED quaternions, ``asin(2(q0q2 - q3q1))``.

    Parameters
    ----------
    q : array_like, shape (N, 4)
        Unit quaternions; the sine is clipped to [-1, 1], so rounding off unit length
        cannot give NaN.

    Returns
    -------
    ndarray, shape (N,)
        Pitch angles (rad), nose up positive.
    """
    q = np.asarray(q, float)
    return np.arcsin(np.clip(2 * (q[:, 0] * q[:, 2] - q[:, 3] * q[:, 1]), -1.0, 1.0))


def roll_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Roll of FRD-to-NED quaternions (kept in ``meta`` to judge the pitch-plane assumption),
    ``atan2(2(q0q1 + q2q3), 1 - 2(q1^2 + q2^2))``.

    Parameters
    ----------
    q : array_like, shape (N, 4)
        Unit quaternions.

    Returns
    -------
    ndarray, shape (N,)
        Roll angles (rad), right wing down positive.
    """
    q = np.asarray(q, float)
    return np.arctan2(2 * (q[:, 0] * q[:, 1] + q[:, 2] * q[:, 3]),
                      1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices body -> world, to rotate NED velocities into body axes (multiply by
    the transpose).

    Parameters
    ----------
    q : ndarray, shape (N, 4)
        Unit quaternions (a quaternion off unit length gives a matrix that is no rotation).

    Returns
    -------
    ndarray, shape (N, 3, 3)
        One matrix per quaternion.
    """
    w, x, y, z = (q[:, i] for i in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def _first_non_unit(q: np.ndarray) -> tuple[int, float] | None:
    """Index and norm of the first quaternion whose norm differs from 1 by more than
    :data:`QUATERNION_NORM_TOLERANCE` (a zero quaternion is PX4's 'no estimate'; normalising
    it would give NaN pitch), or None when all are unit."""
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
    if not len(bad):
        return None
    k = int(bad[0])
    return k, float(norm[k])


def body_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotation matrices NED -> FRD body for 3-2-1 (yaw, pitch, roll) Euler angles.

    Logs give attitude as Euler angles, velocities in NED; ``matrix @ v_ned`` is the velocity
    in body axes.

    Parameters
    ----------
    roll, pitch, yaw : ndarray, shape (N,)
        Angles (rad); NaN gives a NaN matrix.

    Returns
    -------
    ndarray, shape (N, 3, 3)
        One matrix per sample (the transpose of the body-to-NED direction cosine matrix).
    """
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack([
        np.stack([cp * cy, cp * sy, -sp], -1),
        np.stack([sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp], -1),
        np.stack([cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp], -1),
    ], axis=1)


def rotate_to_body(matrices: np.ndarray, v_ned: np.ndarray) -> np.ndarray:
    """``N x 3`` NED vectors in body axes (:func:`body_from_euler` matrices)."""
    return np.einsum("nij,nj->ni", matrices, v_ned)
