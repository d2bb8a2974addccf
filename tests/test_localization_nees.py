"""metrics.position_nees: the on-board estimate's horizontal position NEES, scored on
truth, on hand-made logs (references by hand and from chi-square theory)."""

from types import SimpleNamespace

import numpy as np
import pytest

from lunar_drake import metrics
from lunar_drake.simulation import VectorLog


def _logs(truth_xy, est_xy, cov_xy):
    """Logs with truth and estimate positions (n, 2) m and 2 x 2 covariances (n, 2, 2)."""
    n = len(truth_xy)
    t = np.arange(n) * 0.1
    pose = np.zeros((n, 12))
    pose[:, :2] = truth_xy
    est = np.zeros((n, 6))
    est[:, :2] = est_xy
    cov = np.tile(np.eye(6) * 1e-4, (n, 1, 1))
    cov[:, :2, :2] = cov_xy
    vec = {
        "truth.pose": VectorLog(t, pose, ()),
        "flight.pose_estimate": VectorLog(t, est, ()),
        "flight.pose_covariance": VectorLog(t, cov.reshape(n, 36), ()),
    }
    return SimpleNamespace(vectors=vec)


def test_position_nees_by_hand():
    # sample 0 precedes the filter (left out); then e = (2, 1) m against diag(4, 1) m^2:
    # 2^2 / 4 + 1^2 / 1 = 2; e = (1, 0) against [[2, 1], [1, 2]]: inverse [[2, -1],
    # [-1, 2]] / 3, so 2 / 3; e = (0, 3) against diag(1, 1): 9 (outside 7.38)
    truth = np.array([[5.0, 5.0], [2.0, 1.0], [1.0, 0.0], [0.0, 3.0]])
    est = np.zeros((4, 2))
    cov = np.array([np.eye(2) * 1e-6, np.diag([4.0, 1.0]), [[2.0, 1.0], [1.0, 2.0]], np.eye(2)])
    out = metrics.position_nees(_logs(truth, est, cov))
    assert out["mean"] == pytest.approx((2.0 + 2.0 / 3.0 + 9.0) / 3.0, abs=1e-4)
    assert out["final"] == pytest.approx(9.0)
    assert out["inside_95"] == pytest.approx(2.0 / 3.0, abs=1e-4)


def test_position_nees_of_a_consistent_estimate_is_two():
    """Errors drawn from the covariance the estimate claims (growing, rotating, correlated)
    give the chi-square(2) mean, 2, and 95 % of samples inside the interval; the same
    errors against a covariance 4 x too large give 0.5 (too pessimistic)."""
    g = np.random.default_rng(3)
    n = 4001
    a = np.linspace(0.0, 3.0, n)
    s1, s2 = 0.05 + 0.02 * np.arange(n) ** 0.5, 0.02 + 0.005 * np.arange(n) ** 0.5
    R = np.stack([np.stack([np.cos(a), -np.sin(a)], -1), np.stack([np.sin(a), np.cos(a)], -1)], 1)
    C = R @ (np.eye(2) * np.stack([s1**2, s2**2], -1)[:, None, :]) @ np.swapaxes(R, 1, 2)
    e = np.einsum("kij,kj->ki", np.linalg.cholesky(C), g.standard_normal((n, 2)))
    est = g.uniform(-50.0, 50.0, (n, 2))
    out = metrics.position_nees(_logs(est + e, est, C))
    assert out["mean"] == pytest.approx(2.0, abs=0.15)
    assert out["inside_95"] == pytest.approx(0.95, abs=0.015)
    pessimistic = metrics.position_nees(_logs(est + e, est, 4.0 * C))
    assert pessimistic["mean"] == pytest.approx(0.5, abs=0.04)


def test_position_nees_without_a_covariance_is_none():
    logs = _logs(np.zeros((3, 2)), np.zeros((3, 2)), np.tile(np.eye(2), (3, 1, 1)))
    del logs.vectors["flight.pose_covariance"]
    assert metrics.position_nees(logs) is None
