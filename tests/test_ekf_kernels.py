"""The EKF's compiled kernels (autonomy/ekf_kernels.py) against a plain numpy statement of
the same model (dense F P F^T + Q, a dense Joseph update), on random states."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lunar_drake.autonomy import ekf

TABLE = [[-8.0, -0.07], [-4.0, 0.01], [0.0, 0.08], [2.0, 0.11], [8.0, 0.3]]


def _quat(R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return -q if w < 0 else q


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _predict_reference(x, P, gyro, d, dt, cfg):
    """The filter's predict written out densely (module docstring of ekf.py)."""
    R = Rotation.from_quat([x[4], x[5], x[6], x[3]]).as_matrix()
    s, beta = x[10], x[11]
    u = np.array([d[0], d[1], 0.0])
    if cfg.slip_vs_slope:
        t = np.array(cfg.slip_vs_slope)
        climb = math.degrees(math.asin(R[2, 0])) * (1.0 if d[0] >= 0 else -1.0)
        s = min(max(s + np.interp(climb, t[:, 0], t[:, 1]) - np.interp(0, t[:, 0], t[:, 1]),
                    -1.0), 0.99)  # fmt: skip
    move = (1.0 - s) * R @ u + beta * d[0] * R[:, 1]
    xn = x.copy()
    xn[:3] += move
    xn[3:7] = _quat(R @ Rotation.from_rotvec((gyro - x[7:10]) * dt).as_matrix())
    F = np.eye(14)
    F[0:3, 3:6] = -_skew(move)
    F[0:3, 9] = -R @ u
    F[0:3, 10] = d[0] * R[:, 1]
    F[3:6, 6:9] = -R * dt
    dist = math.hypot(d[0], d[1])
    Q = np.zeros((14, 14))
    h, v = (cfg.odometry_noise_fraction * dist) ** 2, (cfg.odometry_vertical_fraction * dist) ** 2
    Q[0:3, 0:3] = R @ np.diag([h, h, v]) @ R.T
    Q[3:6, 3:6] = np.eye(3) * (cfg.gyro_noise_density**2 + cfg.attitude_process_noise**2) * dt
    Q[6:9, 6:9] = np.eye(3) * cfg.gyro_bias_random_walk**2 * dt
    Q[9, 9] = cfg.slip_random_walk_per_sqrt_m**2 * dist
    Q[10, 10] = cfg.side_slip_random_walk_per_sqrt_m**2 * dist
    Q[11:14, 11:14] = np.eye(3) * cfg.accel_bias_random_walk**2 * dt
    return xn, F @ P @ F.T + Q


def _random_state(g):
    x = np.zeros(15)
    x[:3] = g.normal(0, 10, 3)
    rotvec = g.normal(0, 0.3, 3)
    rotvec[2] += g.uniform(-3, 3)
    x[3:7] = _quat(Rotation.from_rotvec(rotvec).as_matrix())
    x[7:10] = g.normal(0, 1e-4, 3)
    x[10], x[11] = g.uniform(-0.2, 0.5), g.normal(0, 0.05)
    x[12:15] = g.normal(0, 1e-2, 3)
    A = g.normal(0, 1, (14, 14))
    return x, A @ A.T * 1e-3 + np.eye(14) * 1e-6


@pytest.mark.parametrize("table", [[], TABLE])
def test_predict_matches_the_dense_numpy_model(table):
    cfg = ekf.EstimatorConfig(slip_vs_slope=table)
    g = np.random.default_rng(3)
    for _ in range(50):
        x, P = _random_state(g)
        gyro = g.normal(0, 0.05, 3)
        d = g.normal(0, 0.01, 2) * [1, 0.1]
        xr, Pr = _predict_reference(x, P, gyro, d, 0.01, cfg)
        xk, Pk = ekf.predict(x, P, gyro_radps=gyro, d_body=d, dt=0.01, config=cfg)
        np.testing.assert_allclose(xk, xr, rtol=0, atol=1e-12)
        np.testing.assert_allclose(Pk, Pr, rtol=1e-12, atol=1e-15)
        assert np.array_equal(Pk, Pk.T)


def test_a_predict_without_motion_only_adds_the_time_noises():
    cfg = ekf.EstimatorConfig()
    x, P = _random_state(np.random.default_rng(0))
    x[7:10] = 0.0
    xk, Pk = ekf.predict(x, P, gyro_radps=np.zeros(3), d_body=(0.0, 0.0), dt=0.5, config=cfg)
    np.testing.assert_allclose(xk, x, atol=1e-15)
    dP = Pk - P
    np.testing.assert_allclose(np.diag(dP)[:3], 0.0, atol=1e-18)
    # dtheta grows by the gyro noise and dtheta/db_g = -R dt couples in the bias covariance.
    q = (cfg.gyro_noise_density**2 + cfg.attitude_process_noise**2) * 0.5
    R = Rotation.from_quat([x[4], x[5], x[6], x[3]]).as_matrix()
    A = -R * 0.5
    expect = (A @ P[6:9, 3:6] + P[3:6, 6:9] @ A.T + A @ P[6:9, 6:9] @ A.T) + np.eye(3) * q
    np.testing.assert_allclose(dP[3:6, 3:6], expect, rtol=1e-9, atol=1e-18)


def test_kalman_update_matches_the_dense_joseph_form():
    g = np.random.default_rng(7)
    for _ in range(20):
        x, P = _random_state(g)
        H = g.normal(0, 1, (3, 14))
        Rn = np.diag(g.uniform(0.1, 1.0, 3))
        r = g.normal(0, 0.01, 3)
        xk, Pk, nis = ekf._update(x, P, r, H, Rn)
        S = H @ P @ H.T + Rn
        K = P @ H.T @ np.linalg.inv(S)
        IKH = np.eye(14) - K @ H
        Pr = IKH @ P @ IKH.T + K @ Rn @ K.T
        dx = K @ r
        R0 = Rotation.from_quat([x[4], x[5], x[6], x[3]]).as_matrix()
        q = _quat(Rotation.from_rotvec(dx[3:6]).as_matrix() @ R0)
        np.testing.assert_allclose(Pk, 0.5 * (Pr + Pr.T), rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(xk[:3], x[:3] + dx[:3], atol=1e-12)
        np.testing.assert_allclose(xk[3:7], q, atol=1e-12)
        np.testing.assert_allclose(xk[7:], x[7:] + dx[6:], atol=1e-12)
        assert nis == pytest.approx(float(r @ np.linalg.solve(S, r)), rel=1e-9)
