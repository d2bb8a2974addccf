"""The on-board EKF (autonomy/ekf.py) against a Monte Carlo of its own sensor models:
consistency (NEES within chi-square bounds), heading bounded with the star tracker and
drifting without it, tilt from the accelerometer, rotation helpers."""

import dataclasses as dc
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from lunar_drake.autonomy import ekf
from lunar_drake.errors import OutOfRangeError

RATE = 20.0  # the filter's own rate is a parameter of predict()
DT = 1.0 / RATE
G = 1.62


def _drive(cfg, *, seed, seconds=60.0, star_tracker=True, speed=0.2):
    """One seeded drive: truth from the filter's own process model (the slip, the gyro
    bias and the noises drawn from the filter's assumptions), sensors from it, and the
    filter run on the sensors. Returns the pose errors (k, 6) and covariances (k, 6, 6)
    once a second, and the final full error/covariance."""
    g = np.random.default_rng(seed)
    R = Rotation.from_euler("xyz", [0.02, -0.03, 0.4]).as_matrix()
    p = np.array([1.0, 2.0, 0.0])
    bg = g.normal(0.0, cfg.gyro_bias_sigma0, 3)
    s = cfg.slip_prior + g.normal(0.0, cfg.slip_sigma0)
    beta = g.normal(0.0, cfg.side_slip_sigma0)
    x, P = ekf.initial_state(p0=p + g.normal(0, cfg.position_sigma0_m, 3),
                             q0=ekf.matrix_to_quat(R), config=cfg)  # fmt: skip
    if star_tracker:
        x, P, _ = ekf.update_attitude(x, P, q_measured=ekf.matrix_to_quat(R), config=cfg)
    sig_st = np.array([cfg.star_tracker_cross_sigma_arcsec] * 2
                      + [cfg.star_tracker_roll_sigma_arcsec]) * math.pi / 648000  # fmt: skip
    errs, covs = [], []
    n = int(seconds * RATE)
    for k in range(n):
        t = k * DT
        w_true = np.array(
            [0.01 * math.sin(0.5 * t), 0.01 * math.cos(0.3 * t), 0.05 * math.sin(0.1 * t)]
        )
        u_wheel = np.array([speed * DT, 0.002 * math.sin(t) * DT, 0.0])
        dist = math.hypot(u_wheel[0], u_wheel[1])
        # Truth (the filter's model): position along R, then the attitude turns.
        frac = np.array([cfg.odometry_noise_fraction] * 2 + [cfg.odometry_vertical_fraction])
        noise = g.normal(0.0, 1.0, 3) * frac * dist
        u_true = (1.0 - s) * u_wheel + beta * np.array([0.0, u_wheel[0], 0.0])
        p = p + R @ u_true + R @ noise
        gyro = w_true + bg + g.normal(0.0, cfg.gyro_noise_density / math.sqrt(DT), 3)
        R = R @ ekf.so3_exp(w_true * DT)
        R = ekf.so3_exp(g.normal(0.0, cfg.attitude_process_noise * math.sqrt(DT), 3)) @ R
        bg = bg + g.normal(0.0, cfg.gyro_bias_random_walk * math.sqrt(DT), 3)
        s = s + g.normal(0.0, cfg.slip_random_walk_per_sqrt_m * math.sqrt(dist))
        beta = beta + g.normal(0.0, cfg.side_slip_random_walk_per_sqrt_m * math.sqrt(dist))
        x, P = ekf.predict(x, P, gyro_radps=gyro, d_body=u_wheel[:2], dt=DT, config=cfg)
        if star_tracker and (k + 1) % int(RATE / 2) == 0:
            Rm = R @ ekf.so3_exp(g.normal(0.0, 1.0, 3) * sig_st)
            x, P, _ = ekf.update_attitude(x, P, q_measured=ekf.matrix_to_quat(Rm), config=cfg)
        if (k + 1) % int(RATE) == 0:
            e = ekf.pose_error(p_true=p, R_true=R, x=x)
            errs.append(e)
            covs.append(ekf.pose_and_covariance(x, P)[1])
    return np.array(errs), np.array(covs)


def _nees(errs, covs):
    return np.einsum("ki,ki->k", errs, np.linalg.solve(covs, errs[..., None])[..., 0])


def test_nees_is_within_the_95_percent_chi_square_bounds_over_seeded_drives():
    cfg = ekf.EstimatorConfig()
    runs = 12
    nees = np.array([_nees(*_drive(cfg, seed=100 + k)) for k in range(runs)])  # (runs, 60)
    # Ensemble average at each of the 60 one-second marks, then over time.
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    avg_t = nees.mean(axis=0)
    inside = np.mean((avg_t > lo) & (avg_t < hi))
    assert inside > 0.85, (inside, lo, hi, avg_t.round(2))
    assert 5.0 < nees.mean() < 7.0  # dof 6


def test_heading_is_bounded_with_the_star_tracker_and_drifts_without_it():
    cfg = ekf.EstimatorConfig(gyro_bias_sigma0=1e-4)
    with_st = [_drive(cfg, seed=200 + k, seconds=120.0) for k in range(4)]
    blind = [_drive(cfg, seed=200 + k, seconds=120.0, star_tracker=False) for k in range(4)]
    yaw_sig_st = np.array([np.sqrt(c[:, 5, 5]) for _, c in with_st])
    yaw_sig_blind = np.array([np.sqrt(c[:, 5, 5]) for _, c in blind])
    # With the tracker: arcsec-level and flat; without: grows monotonically.
    assert yaw_sig_st.max() < 60 * math.pi / 648000
    assert np.all(np.diff(yaw_sig_blind, axis=1) > 0)
    assert yaw_sig_blind[:, -1].min() > 20 * yaw_sig_st[:, -1].max()
    yaw_err_st = np.abs(np.concatenate([e[:, 5] for e, _ in with_st]))
    yaw_err_blind = np.abs(np.array([e[-1, 5] for e, _ in blind]))
    assert yaw_err_st.max() < 4 * yaw_sig_st.max()
    assert yaw_err_blind.mean() > 10 * yaw_err_st.mean()


def test_tilt_update_observes_roll_pitch_and_accelerometer_bias_not_yaw():
    cfg = ekf.EstimatorConfig(attitude_sigma0_rad=0.1, accel_sigma_mps2=0.005)
    R_true = Rotation.from_euler("xyz", [0.05, -0.04, 1.0]).as_matrix()
    b_a = np.array([0.004, -0.006, 0.002])  # within the 1 mg prior
    f = R_true.T @ np.array([0.0, 0.0, G]) + b_a  # at rest: the specific force is up
    x, P = ekf.initial_state(p0=np.zeros(3), q0=ekf.matrix_to_quat(np.eye(3)), config=cfg)
    for _ in range(50):
        x, P, nis = ekf.update_tilt(x, P, accel_mps2=f, gyro_radps=np.zeros(3),
                                    gravity_mps2=G, config=cfg)  # fmt: skip
        assert nis is not None
    pose, cov = ekf.pose_and_covariance(x, P)
    # Tilt and bias are confounded without the tracker: roll and pitch are known to
    # about bias / g (6 mrad), and the truth lies within 3 sigma.
    sig = np.sqrt(np.diag(cov))
    assert 0.003 < sig[3] < 0.01 and 0.003 < sig[4] < 0.01
    assert abs(pose[3] - 0.05) < 3 * sig[3] and abs(pose[4] + 0.04) < 3 * sig[4]
    assert cov[5, 5] == pytest.approx(0.1**2, rel=1e-6)  # yaw untouched
    # With the attitude pinned by the star tracker, the bias becomes observable.
    x, P = ekf.initial_state(p0=np.zeros(3), q0=ekf.matrix_to_quat(R_true), config=cfg)
    for _ in range(20):
        x, P, _ = ekf.update_attitude(x, P, q_measured=ekf.matrix_to_quat(R_true), config=cfg)
        x, P, _ = ekf.update_tilt(x, P, accel_mps2=f, gyro_radps=np.zeros(3),
                                  gravity_mps2=G, config=cfg)  # fmt: skip
    assert np.allclose(x[12:15], b_a, atol=3e-4)
    # Driving (specific force off gravity by more than the gate): no update.
    _, _, nis = ekf.update_tilt(x, P, accel_mps2=f * 1.2, gyro_radps=np.zeros(3),
                                gravity_mps2=G, config=cfg)  # fmt: skip
    assert nis is None


def test_rotation_helpers_round_trip():
    g = np.random.default_rng(0)
    for _ in range(50):
        w = g.normal(0, 1.0, 3)
        R = ekf.so3_exp(w)
        assert np.allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
        assert np.allclose(ekf.so3_log(R), Rotation.from_matrix(R).as_rotvec(), atol=1e-9)
        q = ekf.matrix_to_quat(R)
        assert np.allclose(ekf.quat_to_matrix(q), R, atol=1e-12) and q[0] >= 0


def test_config_errors_name_the_field():
    with pytest.raises(OutOfRangeError, match="slip_prior"):
        ekf.EstimatorConfig(slip_prior=1.5)
    with pytest.raises(OutOfRangeError, match="accel_sigma_mps2"):
        dc.replace(ekf.EstimatorConfig(), accel_sigma_mps2=0.0)


def test_mission_estimate_is_consistent_and_heading_needs_the_star_tracker(small_site):
    """The flight EKF in the simulated mission (30 s drive on the small site): NEES
    inside its 95 % chi-square interval for >= 90 % of the samples with and without the
    star tracker; heading sigma bounded with it, growing without it."""
    from lunar_drake import metrics
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    out = {}
    for name, text in (("tracker", "{}"), ("blind", "{use_star_tracker: false}")):
        s = apply_overrides(
            scenario,
            "{simulation_duration: 30.0, sensors: {camera: {enabled: false}},"
            f" flight: {{estimator: {text}}}}}",
        )
        logs = simulate(scenario=s, site=site, progress=False)
        loc = metrics.summarize(scenario=s, site=site, logs=logs)["localization"]
        yaw_sig = np.sqrt(logs.vectors["flight.pose_covariance"].column("cov_rz_rz"))
        out[name] = (loc, yaw_sig)
        assert loc["nees_inside_95"] >= 0.9, (name, loc)
        assert 1.0 < loc["nees_mean"] < 14.0, (name, loc)
    (_, sig_t), (_, sig_b) = out["tracker"][:2], out["blind"][:2]
    assert sig_t[10:].max() < math.radians(0.02)
    assert np.all(np.diff(sig_b[10:]) > 0) and sig_b[-1] > 50 * sig_t[-1]


def test_slip_vs_slope_scales_the_odometry_with_the_climb_along_the_travel():
    """Climbing 4 deg with table slips 0.08 (level) and 0.14 (4 deg): the step is
    (1 - prior - 0.06) of the encoder's; descending or backing down it uses the table's
    negative side; the validation wants increasing slopes with 0 among them."""
    from lunar_drake.autonomy.ekf import (
        EstimatorConfig,
        initial_state,
        predict,
        slope_slip,
    )
    from lunar_drake.errors import ConfigError
    from lunar_drake.rotations import rotation_exp

    table = [[-4.0, 0.02], [0.0, 0.08], [4.0, 0.14]]
    R_up = rotation_exp([0.0, -math.radians(4.0), 0.0])  # nose up: climbing forward
    assert slope_slip(R_up, 0.1, table) == pytest.approx(0.06)
    assert slope_slip(R_up, -0.1, table) == pytest.approx(-0.06)  # backing down it
    assert slope_slip(np.eye(3), 0.1, table) == 0.0
    cfg = EstimatorConfig(slip_prior=0.1, slip_vs_slope=table)
    half = -math.radians(2.0)  # a 4 deg nose-up pitch
    x, P = initial_state(p0=[0, 0, 0], q0=[math.cos(half), 0, math.sin(half), 0], config=cfg)
    xn, _ = predict(x, P, gyro_radps=np.zeros(3), d_body=(1.0, 0.0), dt=0.01, config=cfg)
    assert np.linalg.norm(xn[:3]) == pytest.approx(1.0 - 0.1 - 0.06, rel=1e-9)
    with pytest.raises(ConfigError, match="must increase and include 0"):
        EstimatorConfig(slip_vs_slope=[[1.0, 0.1], [4.0, 0.2]])
