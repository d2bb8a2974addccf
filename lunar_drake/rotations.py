"""Rotation helpers on numpy arrays: rotation vectors, matrices and unit quaternions.

Quaternions are (w, x, y, z) with w >= 0 (``q_WB`` rotates B into W, like ``R_WB``).
All functions broadcast over leading axes.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "quaternion_from_rotation_matrix",
    "roll_pitch_yaw",
    "rotation_exp",
    "rotation_log",
    "rotation_matrix_from_quaternion",
    "rotation_matrix_from_rpy",
]


def rotation_exp(theta) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors ``theta`` (..., 3) (rad), Rodrigues."""
    t = np.asarray(theta, dtype=np.float64)
    ang = np.linalg.norm(t, axis=-1)[..., None, None]
    k = np.zeros((*t.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -t[..., 2], t[..., 1], -t[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = t[..., 2], -t[..., 1], t[..., 0]
    small = ang < 1e-6
    safe = np.where(small, 1.0, ang)
    a = np.where(small, 1.0 - ang**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - ang**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def rotation_log(R) -> np.ndarray:
    """Rotation vectors (..., 3) (rad) of rotation matrices (..., 3, 3), angle in [0, pi)."""
    q = quaternion_from_rotation_matrix(R)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    ang = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s < 1e-12, 2.0, ang / np.where(s < 1e-12, 1.0, s))
    return v * scale[..., None]


def quaternion_from_rotation_matrix(R) -> np.ndarray:
    """Unit quaternions (..., 4) = (w, x, y, z) with w >= 0 of rotation matrices (..., 3, 3).

    Shepperd's method (largest-diagonal branch), then normalised.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack([tr, m00, m11, m22], axis=-1)
    pick = np.argmax(cand, axis=-1)
    q = np.empty((*R.shape[:-2], 4))
    d21, d02, d10 = (
        R[..., 2, 1] - R[..., 1, 2],
        R[..., 0, 2] - R[..., 2, 0],
        R[..., 1, 0] - R[..., 0, 1],
    )
    s21, s02, s10 = (
        R[..., 2, 1] + R[..., 1, 2],
        R[..., 0, 2] + R[..., 2, 0],
        R[..., 1, 0] + R[..., 0, 1],
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        for branch in range(4):
            if branch == 0:
                r = np.sqrt(np.maximum(1.0 + tr, 0.0))
                qq = np.stack([0.5 * r, 0.5 * d21 / r, 0.5 * d02 / r, 0.5 * d10 / r], -1)
            elif branch == 1:
                r = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 0.0))
                qq = np.stack([0.5 * d21 / r, 0.5 * r, 0.5 * s10 / r, 0.5 * s02 / r], -1)
            elif branch == 2:
                r = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 0.0))
                qq = np.stack([0.5 * d02 / r, 0.5 * s10 / r, 0.5 * r, 0.5 * s21 / r], -1)
            else:
                r = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 0.0))
                qq = np.stack([0.5 * d10 / r, 0.5 * s02 / r, 0.5 * s21 / r, 0.5 * r], -1)
            sel = pick == branch
            q[sel] = qq[sel]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def rotation_matrix_from_quaternion(q) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) = (w, x, y, z) (normalised)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 1:  # one quaternion: scalar arithmetic (a flight-software tick's case)
        w, x, y, z = (q / np.sqrt(q @ q)).tolist()
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def roll_pitch_yaw(R) -> np.ndarray:
    """(..., 3) roll, pitch, yaw (rad) of rotation matrices (..., 3, 3) in Drake's
    convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``; pitch in [-pi/2, pi/2]."""
    R = np.asarray(R, dtype=np.float64)
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def rotation_matrix_from_rpy(rpy) -> np.ndarray:
    """(..., 3, 3) rotation matrices ``Rz(yaw) Ry(pitch) Rx(roll)`` of (..., 3) roll,
    pitch, yaw (rad); the inverse of :func:`roll_pitch_yaw`."""
    a = np.asarray(rpy, dtype=np.float64)
    cr, sr = np.cos(a[..., 0]), np.sin(a[..., 0])
    cp, sp = np.cos(a[..., 1]), np.sin(a[..., 1])
    cy, sy = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )
