"""Compiled (numba) kernels of the on-board EKF (:mod:`lunar_drake.autonomy.ekf`): one
call per filter step instead of some forty small numpy operations. The model, the state
layout and the frames are :mod:`~lunar_drake.autonomy.ekf`'s; results equal the numpy
formulation up to round-off (sums taken in a fixed order, no BLAS). No Drake.
"""

from __future__ import annotations

import math

import numba
import numpy as np

N_ERR = 14
NX = 15
# Error-state offsets: dp 0-2, dtheta 3-5, db_g 6-8, ds 9, dbeta 10, db_a 11-13.
_P, _TH, _BG, _S, _B, _BA = 0, 3, 6, 9, 10, 11
#: Order of the noise parameters :func:`predict` reads (``noise`` (8,)).
NOISE_FIELDS = (
    "odometry_noise_fraction",
    "odometry_vertical_fraction",
    "gyro_noise_density",
    "attitude_process_noise",
    "gyro_bias_random_walk",
    "slip_random_walk_per_sqrt_m",
    "side_slip_random_walk_per_sqrt_m",
    "accel_bias_random_walk",
)


@numba.njit(cache=True)
def quat_to_matrix(q):  # pragma: no cover - numba
    """Rotation matrix (3, 3) of the quaternion ``q`` = (w, x, y, z), normalised first."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    R = np.empty((3, 3))
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)
    return R


@numba.njit(cache=True)
def matrix_to_quat(R):  # pragma: no cover - numba
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (3, 3)."""
    t = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q[0] = 0.25 * s
        q[1] = (R[2, 1] - R[1, 2]) / s
        q[2] = (R[0, 2] - R[2, 0]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    else:
        i = 0
        if R[1, 1] > R[i, i]:
            i = 1
        if R[2, 2] > R[i, i]:
            i = 2
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = -1.0 if q[0] / n < 0 else 1.0
    for m in range(4):
        q[m] = sign * (q[m] / n)
    return q


@numba.njit(cache=True)
def so3_exp(w0, w1, w2):  # pragma: no cover - numba
    """Rotation matrix (3, 3) of the rotation vector ``(w0, w1, w2)`` (rad) (Rodrigues)."""
    th = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2], K[1, 0], K[1, 2], K[2, 0], K[2, 1] = -w2, w1, w2, -w0, -w1, w0
    if th < 1e-8:
        a, b = 1.0, 0.5
    else:
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / (th * th)
    E = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            kk = K[r, 0] * K[0, c] + K[r, 1] * K[1, c] + K[r, 2] * K[2, c]
            E[r, c] = (1.0 if r == c else 0.0) + a * K[r, c] + b * kk
    return E


@numba.njit(cache=True)
def _mat3(A, B):  # pragma: no cover - numba
    C = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            C[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c]
    return C


@numba.njit(cache=True)
def _symmetrized(P):  # pragma: no cover - numba
    n = P.shape[0]
    S = np.empty((n, n))
    for r in range(n):
        for c in range(n):
            S[r, c] = 0.5 * (P[r, c] + P[c, r])
    return S


@numba.njit(cache=True)
def predict(x, P, gyro, dx, dy, dt, table_deg, table_slip, noise):  # pragma: no cover
    """(x (15,), P (14, 14)) after one tick (:func:`lunar_drake.autonomy.ekf.predict`):
    gyro rate (3,) (rad/s, body), encoder displacement (dx, dy) (m, body), ``dt`` (s),
    the slip-vs-slope table as two arrays (deg, slip; empty: none) and ``noise``
    (:data:`NOISE_FIELDS`)."""
    R = quat_to_matrix(x[3:7])
    s, beta = x[10], x[11]
    if table_deg.size:
        sin_climb = R[2, 0] * (1.0 if dx >= 0.0 else -1.0)
        climb_deg = math.degrees(math.asin(max(-1.0, min(1.0, sin_climb))))
        ds = np.interp(climb_deg, table_deg, table_slip) - np.interp(0.0, table_deg, table_slip)
        s = min(max(s + ds, -1.0), 0.99)
    g = 1.0 - s
    Ru = np.empty(3)
    Rside = np.empty(3)
    move = np.empty(3)
    for r in range(3):
        Ru[r] = R[r, 0] * dx + R[r, 1] * dy
        Rside[r] = R[r, 1] * dx
        move[r] = g * Ru[r] + beta * Rside[r]
    xn = x.copy()
    for r in range(3):
        xn[r] = x[r] + move[r]
    dR = so3_exp((gyro[0] - x[7]) * dt, (gyro[1] - x[8]) * dt, (gyro[2] - x[9]) * dt)
    xn[3:7] = matrix_to_quat(_mat3(R, dR))
    # F = I + A; A's non-zero blocks: dp/dtheta = -[move]x, dp/ds = -Ru, dp/dbeta = Rside,
    # dtheta/db_g = -R dt.
    A = np.zeros((N_ERR, N_ERR))
    A[0, _TH + 1], A[0, _TH + 2] = move[2], -move[1]
    A[1, _TH + 0], A[1, _TH + 2] = -move[2], move[0]
    A[2, _TH + 0], A[2, _TH + 1] = move[1], -move[0]
    for r in range(3):
        A[r, _S] = -Ru[r]
        A[r, _B] = Rside[r]
        for c in range(3):
            A[_TH + r, _BG + c] = -R[r, c] * dt
    # F P F^T = P + A P + (A P)^T + A P A^T, with only A's non-zero columns summed.
    cols = (_TH, _TH + 1, _TH + 2, _BG, _BG + 1, _BG + 2, _S, _B)
    AP = np.zeros((N_ERR, N_ERR))
    for r in range(6):
        for c in range(N_ERR):
            acc = 0.0
            for k in cols:
                acc += A[r, k] * P[k, c]
            AP[r, c] = acc
    Pn = P.copy()
    for r in range(N_ERR):
        for c in range(N_ERR):
            v = AP[r, c] + AP[c, r]
            if r < 6 and c < 6:
                acc = 0.0
                for k in cols:
                    acc += AP[r, k] * A[c, k]
                v += acc
            Pn[r, c] += v
    dist = math.hypot(dx, dy)
    sh = (noise[0] * dist) ** 2
    sv = (noise[1] * dist) ** 2
    for r in range(3):
        for c in range(3):
            Pn[r, c] += R[r, 0] * sh * R[c, 0] + R[r, 1] * sh * R[c, 1] + R[r, 2] * sv * R[c, 2]
        Pn[_TH + r, _TH + r] += (noise[2] ** 2 + noise[3] ** 2) * dt
        Pn[_BG + r, _BG + r] += noise[4] ** 2 * dt
        Pn[_BA + r, _BA + r] += noise[7] ** 2 * dt
    Pn[_S, _S] += noise[5] ** 2 * dist
    Pn[_B, _B] += noise[6] ** 2 * dist
    return xn, _symmetrized(Pn)


@numba.njit(cache=True)
def _inject(x, d):  # pragma: no cover - numba
    xn = x.copy()
    for r in range(3):
        xn[r] += d[_P + r]
        xn[7 + r] += d[_BG + r]
        xn[12 + r] += d[_BA + r]
    xn[3:7] = matrix_to_quat(_mat3(so3_exp(d[_TH], d[_TH + 1], d[_TH + 2]), quat_to_matrix(x[3:7])))
    xn[10] += d[_S]
    xn[11] += d[_B]
    return xn


@numba.njit(cache=True)
def update(x, P, r, H, Rn):  # pragma: no cover - numba
    """(x, P, NIS) after a measurement with residual ``r`` (m,), Jacobian ``H`` (m, 14)
    and noise ``Rn`` (m, m): the Kalman update in Joseph form, then the reset."""
    HP = H @ P
    S = HP @ H.T + Rn
    K = np.linalg.solve(S, HP).T
    IKH = np.eye(N_ERR) - K @ H
    Pn = IKH @ P @ IKH.T + K @ Rn @ K.T
    nis = r @ np.linalg.solve(S, r)
    return _inject(x, K @ r), _symmetrized(Pn), nis
