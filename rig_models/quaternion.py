"""Unit quaternions (scalar first, body -> inertial): product, rotation, Euler 3-2-1, angle
between attitudes. Generic helpers (paper 004's spacecraft and the variable-amplitude
shaper use them)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = ["euler_321_to_quaternion", "quaternion_angle_error", "quaternion_multiply",
           "quaternion_rotate"]



def quaternion_multiply(p: FloatArray, q: FloatArray) -> FloatArray:
    """Hamilton product p (x) q, scalar first; broadcasts over leading axes."""
    p0, p1, p2, p3 = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    q0, q1, q2, q3 = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
            p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
            p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
        ],
        axis=-1,
    )


def quaternion_rotate(q: FloatArray, v: FloatArray) -> FloatArray:
    """Rotate a body vector to the inertial frame with q (body -> inertial)."""
    qv = np.concatenate([[0.0], v])
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    return quaternion_multiply(quaternion_multiply(q, qv), conj)[1:]


def euler_321_to_quaternion(angles_rad: Sequence[float]) -> FloatArray:
    """Quaternion (scalar first, body -> inertial) of Euler angles [roll x, pitch y, yaw z].

    Rotation sequence 3-2-1 (yaw about z, then pitch about y, then roll about x), the usual
    aerospace convention; the paper does not state its sequence.
    """
    roll, pitch, yaw = (float(a) for a in angles_rad)
    qx = np.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0])
    qy = np.array([math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0])
    qz = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    return quaternion_multiply(quaternion_multiply(qz, qy), qx)


def quaternion_angle_error(q: ArrayLike, q_target: ArrayLike) -> FloatArray:
    """Rotation angle (rad) between attitude(s) q and q_target (accurate for small angles)."""
    q_arr = np.asarray(q, dtype=float)
    q_arr = q_arr / np.linalg.norm(q_arr, axis=-1, keepdims=True)
    conj = np.asarray(q_target, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])
    err = quaternion_multiply(conj, q_arr)
    return 2.0 * np.arctan2(np.linalg.norm(err[..., 1:], axis=-1), np.abs(err[..., 0]))
