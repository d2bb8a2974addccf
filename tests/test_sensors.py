"""Localization sensors: IMU, star tracker and wheel encoder cores and Drake systems, and
the one sampling pattern they share (rate, delay, per-sample generator)."""

import math

import numpy as np
import pytest
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.multibody.tree import RevoluteJoint, SpatialInertia, UnitInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lunar_drake import rotations as rot
from lunar_drake.errors import OutOfRangeError
from lunar_drake.moon import GRAVITY_W
from lunar_drake.rng import generator, sample_generator, stream_key
from lunar_drake.sensors import imu as imu_core
from lunar_drake.sensors import star_tracker as st_core
from lunar_drake.sensors import wheel_encoders as enc_core
from lunar_drake.sensors.sampling import delivered_index, sample_index, samples_in_flight
from lunar_drake.systems.imu import add_imu
from lunar_drake.systems.star_tracker import StarTracker
from lunar_drake.systems.wheel_encoders import WheelEncoders, wheel_angle_selector

ARCSEC = math.pi / 180 / 3600
NO_BIAS = dict(
    gyro_bias_initial_sigma=0.0,
    gyro_bias_random_walk=0.0,
    accel_bias_initial_sigma=0.0,
    accel_bias_random_walk=0.0,
)

# ----------------------------------------------------------------------------- IMU core


def _imu_samples(key, n, cfg, ideal=(0.0,) * 6):
    """(n, 6) measurements and (n + 1, 6) biases of n consecutive samples from bias 0."""
    bias = np.zeros(6)
    meas, biases = [], [bias]
    for k in range(n):
        m, bias = imu_core.imu_measurement(ideal, bias, sample_generator(key, k), config=cfg)
        meas.append(m)
        biases.append(bias)
    return np.array(meas), np.array(biases)


@pytest.mark.parametrize("rate", [100.0, 400.0])
def test_imu_white_noise_std_is_density_times_sqrt_rate(rate):
    cfg = imu_core.ImuConfig(rate_hz=rate, **NO_BIAS)
    n, _ = _imu_samples(stream_key(5, "imu"), 20000, cfg)
    expected = np.repeat([cfg.gyro_noise_density, cfg.accel_noise_density], 3) * math.sqrt(rate)
    np.testing.assert_allclose(n.std(axis=0), expected, rtol=0.05)
    assert np.all(np.abs(n.mean(axis=0)) < 4 * expected / math.sqrt(20000))
    c = np.corrcoef(n.T)
    assert np.all(np.abs(c[~np.eye(6, dtype=bool)]) < 0.04)  # channels independent
    assert abs(np.corrcoef(n[:-1, 0], n[1:, 0])[0, 1]) < 0.04  # and white
    # Gaussian tails (not a truncated approximation): about 0.27% beyond 3 sigma.
    beyond = np.mean(np.abs(n / expected) > 3.0)
    assert 0.0015 < beyond < 0.004


def test_imu_bias_random_walk_variance_grows_linearly():
    cfg = imu_core.ImuConfig(rate_hz=50.0)
    steps = 400
    walks = np.array(
        [_imu_samples(stream_key(s, "imu"), steps, cfg)[1][1:] for s in range(600)]
    )  # (seeds, steps, 6): bias(k+1) - bias(0)
    q = np.repeat([cfg.gyro_bias_random_walk, cfg.accel_bias_random_walk], 3)
    times = []
    for k in (50, 100, 200, 400):
        t = k / cfg.rate_hz
        var = walks[:, k - 1].var(axis=0)
        np.testing.assert_allclose(var, q**2 * t, rtol=0.2)
        times.append(var / q**2)
    times = np.array(times)
    np.testing.assert_allclose(times[1:] / times[:-1], 2.0, rtol=0.25)  # linear in time
    init = np.array(
        [imu_core.imu_initial_bias(generator(s, "imu"), config=cfg) for s in range(2000)]
    )
    np.testing.assert_allclose(init.std(axis=0), cfg.bias_initial_sigma, rtol=0.10)


def test_imu_ideal_specific_force_and_lever_arm():
    level = imu_core.imu_ideal(
        R_WB=np.eye(3), w_WB_W=np.zeros(3), alpha_WB_W=np.zeros(3), a_WBo_W=np.zeros(3)
    )
    np.testing.assert_allclose(level, [0, 0, 0, 0, 0, 1.62])
    R = RollPitchYaw(0.0, 0.4, 0.0).ToRotationMatrix().matrix()  # pitched nose down 0.4 rad
    tilt = imu_core.imu_ideal(
        R_WB=R, w_WB_W=np.zeros(3), alpha_WB_W=np.zeros(3), a_WBo_W=np.zeros(3)
    )
    np.testing.assert_allclose(tilt[3:], [-1.62 * math.sin(0.4), 0, 1.62 * math.cos(0.4)])
    falling = imu_core.imu_ideal(
        R_WB=R, w_WB_W=np.zeros(3), alpha_WB_W=np.zeros(3), a_WBo_W=np.array(GRAVITY_W)
    )
    np.testing.assert_allclose(falling, 0.0, atol=1e-15)
    w = np.array([0.0, 0.0, 2.0])
    spin = imu_core.imu_ideal(
        R_WB=np.eye(3),
        w_WB_W=w,
        alpha_WB_W=np.zeros(3),
        a_WBo_W=np.zeros(3),
        p_BS=[0.5, 0, 0],
        gravity_W=np.zeros(3),
    )
    np.testing.assert_allclose(spin, [0, 0, 2.0, -2.0, 0, 0])  # centripetal w^2 r inwards


# ----------------------------------------------------------------- rotations, star tracker


def test_rotation_helpers_round_trip():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(200, 3))
    v *= (rng.uniform(0, math.pi - 1e-6, size=200) / np.linalg.norm(v, axis=1))[:, None]
    v[0] = 0.0
    v[1] = [math.pi - 1e-9, 0, 0]
    R = rot.rotation_exp(v)
    for i in (1, 2, 3):
        ang = np.linalg.norm(v[i])
        drake_R = RotationMatrix(AngleAxis(ang, v[i] / ang)).matrix()
        np.testing.assert_allclose(R[i], drake_R, atol=1e-12)
        drake_q = RotationMatrix(R[i]).ToQuaternion().wxyz()
        q = rot.quaternion_from_rotation_matrix(R[i])
        np.testing.assert_allclose(q, drake_q * np.sign(drake_q[0]), atol=1e-12)
    q = rot.quaternion_from_rotation_matrix(R)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(rot.rotation_matrix_from_quaternion(q), R, atol=1e-12)
    np.testing.assert_allclose(rot.rotation_log(R)[2:], v[2:], atol=1e-9)
    np.testing.assert_allclose(rot.rotation_log(R[:1]), 0.0, atol=1e-15)


def test_star_tracker_error_statistics():
    cfg = st_core.StarTrackerConfig(cross_boresight_sigma_arcsec=5.0, roll_sigma_arcsec=40.0)
    key = stream_key(2, "st")
    R_WB = RollPitchYaw(0.2, -0.1, 2.0).ToRotationMatrix().matrix()
    R_BS = RollPitchYaw(math.pi / 2, 0.3, 0.0).ToRotationMatrix().matrix()  # boresight sideways
    n = 8000
    q = np.array(
        [
            st_core.star_tracker_measurement(R_WB, sample_generator(key, k), config=cfg, R_BS=R_BS)
            for k in range(n)
        ]
    )
    assert q.shape == (n, 4) and np.all(q[:, 0] >= 0)
    R_meas = rot.rotation_matrix_from_quaternion(q)
    err_S = rot.rotation_log((R_WB @ R_BS).T @ R_meas @ R_BS)  # error in the sensor frame
    np.testing.assert_allclose(err_S.std(axis=0) / ARCSEC, [5.0, 5.0, 40.0], rtol=0.05)
    assert np.all(np.abs(err_S.mean(axis=0)) < 4 * cfg.sigma_rad / math.sqrt(n))
    expected = [
        st_core.star_tracker_error_angles(sample_generator(key, k), config=cfg) for k in (0, 17)
    ]
    np.testing.assert_allclose(err_S[[0, 17]], expected, atol=1e-12)


# ------------------------------------------------------------------------------- encoders


def test_encoder_quantization_round_trip():
    cfg = enc_core.WheelEncoderConfig(counts_per_revolution=4096)
    res = 2 * math.pi / 4096
    angles = np.random.default_rng(1).uniform(-50, 50, size=(1000, 4))
    meas = enc_core.encoder_angles(angles, config=cfg)
    counts = meas / res
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.all(np.abs(meas - angles) <= res / 2 + 1e-12)
    np.testing.assert_array_equal(enc_core.encoder_angles(meas, config=cfg), meas)
    np.testing.assert_allclose(
        enc_core.encoder_angles([0.0, 2 * math.pi, -math.pi], config=cfg) / res, [0, 4096, -2048]
    )
    noisy = enc_core.WheelEncoderConfig(angle_noise_sigma_rad=0.01)
    with pytest.raises(ValueError, match="generator"):
        enc_core.encoder_angles(angles, config=noisy)
    c = np.array(
        [
            enc_core.encoder_angles([0.0], config=noisy, generator=sample_generator(3, k))[0]
            for k in range(2000)
        ]
    )
    assert c.std() == pytest.approx(0.01, rel=0.1)
    with pytest.raises(OutOfRangeError, match="counts_per_revolution"):
        enc_core.WheelEncoderConfig(counts_per_revolution=0)


def test_configs_validate():
    with pytest.raises(OutOfRangeError, match="gyro_noise_density"):
        imu_core.ImuConfig(gyro_noise_density=-1.0)
    with pytest.raises(OutOfRangeError, match="rate_hz = 0 is out of range"):
        st_core.StarTrackerConfig(rate_hz=0.0)
    with pytest.raises(OutOfRangeError, match="delay_s"):
        enc_core.WheelEncoderConfig(delay_s=-0.1)
    with pytest.raises(OutOfRangeError, match="sample index"):
        sample_index(-1.0, 10.0)


def test_sampling_delivery_indices():
    assert samples_in_flight(rate_hz=10.0, delay_s=0.0) == 1
    assert samples_in_flight(rate_hz=10.0, delay_s=0.25) == 4
    assert samples_in_flight(rate_hz=10.0, delay_s=0.3) == 5
    # sample k at k/10 s delivered at k/10 + 0.25 s
    assert delivered_index(0.24, rate_hz=10.0, delay_s=0.25) == -1
    assert delivered_index(0.25, rate_hz=10.0, delay_s=0.25) == 0
    assert delivered_index(0.3499, rate_hz=10.0, delay_s=0.25) == 0
    assert delivered_index(0.35, rate_hz=10.0, delay_s=0.25) == 1


# ------------------------------------------------------------------------ Drake systems

RATE = 100.0


def _build(*, weld_pose=None, gravity=(0.0, 0.0, 0.0), imus=(), star_tracker=None,
           inertia=None):  # fmt: skip
    """Plant with one body ('box': sphere inertia unless ``inertia``, a UnitInertia), free
    or welded at ``weld_pose``."""
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, 0.0)
    unit = UnitInertia.SolidSphere(0.3) if inertia is None else inertia
    body = plant.AddRigidBody("box", SpatialInertia(3.0, np.zeros(3), unit))
    if weld_pose is not None:
        plant.WeldFrames(plant.world_frame(), body.body_frame(), weld_pose)
    plant.mutable_gravity_field().set_gravity_vector(gravity)
    plant.Finalize()
    systems = []
    for kw in imus:
        systems.append(add_imu(builder, plant=plant, body=body, **kw))
    if star_tracker is not None:
        st = builder.AddSystem(StarTracker(body_index=body.index(), **star_tracker))
        builder.Connect(plant.get_body_poses_output_port(), st.body_poses_input)
        systems.append(st)
    diagram = builder.Build()
    return diagram, plant, body, systems


def _run(diagram, systems, rate, n, setup=None):
    """Samples (n, ...) of each system's first output, read between sample times."""
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    if setup is not None:
        setup(ctx)
    sim.Initialize()
    ctxs = [s.GetMyContextFromRoot(ctx) for s in systems]
    out = [[] for _ in systems]
    for k in range(n):
        sim.AdvanceTo((k + 0.5) / rate)
        for o, s, c in zip(out, systems, ctxs, strict=True):
            o.append(s.get_output_port(0).Eval(c).copy())
    return [np.array(o) for o in out]


def _spinning(plant, body, R_WB0, w_W):
    def setup(ctx):
        pc = plant.GetMyMutableContextFromRoot(ctx)
        plant.SetFreeBodyPose(pc, body, RigidTransform(R_WB0, [0.0, 0.0, 1.0]))
        plant.SetFreeBodySpatialVelocity(pc, body, SpatialVelocity(w_W, np.zeros(3)))

    return setup


def test_imu_on_spinning_body_gyro_mean_noise_and_lever_arm():
    cfg = imu_core.ImuConfig(rate_hz=RATE, **NO_BIAS)
    p_BS = np.array([0.2, -0.1, 0.05])
    diagram, plant, body, (imu0, imu1) = _build(
        imus=[
            dict(seed=1, name="imu_a", config=cfg),
            dict(seed=1, name="imu_b", config=cfg, X_BS=RigidTransform(p_BS)),
        ]
    )
    R0 = RollPitchYaw(0.3, -0.5, 1.0).ToRotationMatrix()
    w_W = np.array([0.1, -0.2, 0.3])
    n = 400
    a, b = _run(diagram, [imu0, imu1], RATE, n, _spinning(plant, body, R0, w_W))
    # A sphere spins at constant w_W, so w_B = R_BW w_W stays R_B0W w_W.
    w_B = R0.matrix().T @ w_W
    sig = cfg.white_sigma
    assert np.all(np.abs(a[:, :3].mean(0) - w_B) < 4 * sig[:3] / math.sqrt(n))
    assert np.linalg.norm(w_B - w_W) > 0.1  # the test would catch a world-frame gyro
    np.testing.assert_allclose(a[:, :3].std(0), sig[:3], rtol=0.15)
    # no gravity, body origin at the centre of mass: accel reads only noise at Bo ...
    assert np.all(np.abs(a[:, 3:].mean(0)) < 4 * sig[3:] / math.sqrt(n))
    # ... and the centripetal acceleration w x (w x p) (in B) at the offset sensor
    expected = np.cross(w_B, np.cross(w_B, p_BS))
    assert np.all(np.abs(b[:, 3:].mean(0) - expected) < 4 * sig[3:] / math.sqrt(n))
    assert np.linalg.norm(expected) > 20 * sig[3] / math.sqrt(n)
    assert not np.array_equal(a[:, :3], b[:, :3])  # different names, different noise


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (0.25, -0.4, 1.2)])
def test_accelerometer_at_rest_reads_lunar_specific_force(rpy):
    R_WB = RollPitchYaw(*rpy).ToRotationMatrix()
    cfg = imu_core.ImuConfig(rate_hz=RATE, **NO_BIAS)
    diagram, _plant, _body, (imu,) = _build(
        weld_pose=RigidTransform(R_WB, [1.0, 2.0, 0.3]),
        gravity=GRAVITY_W,
        imus=[dict(seed=3, config=cfg)],
    )
    n = 200
    (m,) = _run(diagram, [imu], RATE, n)
    expected = R_WB.matrix().T @ np.array([0.0, 0.0, 1.62])
    tol = 4 * cfg.white_sigma / math.sqrt(n)
    assert np.all(np.abs(m[:, 3:].mean(0) - expected) < tol[3:])
    assert np.all(np.abs(m[:, :3].mean(0)) < tol[:3])
    if rpy == (0.0, 0.0, 0.0):
        assert abs(m[:, 5].mean() - 1.62) < tol[5]


def test_drakes_ideal_sensors_agree_with_the_ideal_reading_core():
    """The wiring of add_imu (the sensor frame, the lever arm, gravity in free fall):
    Drake's Gyroscope and Accelerometer on a tumbling box (torque free but not
    spherical: its angular acceleration is not zero) against ``imu_ideal`` (our own
    formulation) fed with the plant's body kinematics. Gravity's sign at rest:
    test_accelerometer_at_rest_reads_lunar_specific_force."""
    X_BS = RigidTransform(RollPitchYaw(0.3, -0.2, 0.9), [0.2, -0.1, 0.05])
    diagram, plant, body, _ = _build(
        gravity=GRAVITY_W,
        imus=[dict(seed=1, config=imu_core.ImuConfig(), X_BS=X_BS)],
        inertia=UnitInertia.SolidBox(0.2, 0.5, 0.9),
    )
    builder_systems = {s.get_name(): s for s in diagram.GetSystems()}
    gyro = next(s for n, s in builder_systems.items() if n.endswith(".gyroscope"))
    accel = next(s for n, s in builder_systems.items() if n.endswith(".accelerometer"))
    ctx = diagram.CreateDefaultContext()
    rng = np.random.default_rng(3)
    reads, euler = [], []
    for _ in range(5):
        pc = plant.GetMyMutableContextFromRoot(ctx)
        R = RollPitchYaw(*rng.uniform(-1, 1, 3)).ToRotationMatrix()
        plant.SetFreeBodyPose(pc, body, RigidTransform(R, rng.uniform(-1, 1, 3)))
        plant.SetFreeBodySpatialVelocity(
            pc, body, SpatialVelocity(rng.uniform(-2, 2, 3), rng.uniform(-1, 1, 3))
        )
        X_WB = plant.get_body_poses_output_port().Eval(pc)[body.index()]
        V_WB = plant.get_body_spatial_velocities_output_port().Eval(pc)[body.index()]
        A_WB = plant.get_body_spatial_accelerations_output_port().Eval(pc)[body.index()]
        r_W = X_WB.rotation().matrix() @ X_BS.translation()
        euler.append(np.linalg.norm(np.cross(A_WB.rotational(), r_W)))
        ideal = imu_core.imu_ideal(
            R_WB=X_WB.rotation().matrix(),
            w_WB_W=V_WB.rotational(),
            alpha_WB_W=A_WB.rotational(),
            a_WBo_W=A_WB.translational(),
            R_BS=X_BS.rotation().matrix(),
            p_BS=X_BS.translation(),
            gravity_W=GRAVITY_W,
        )
        w = gyro.get_measurement_output_port().Eval(gyro.GetMyContextFromRoot(ctx))
        f = accel.get_measurement_output_port().Eval(accel.GetMyContextFromRoot(ctx))
        np.testing.assert_allclose(w, ideal[:3], atol=1e-12)
        np.testing.assert_allclose(f, ideal[3:], atol=1e-12)
        # free fall: gravity cancels, the lever arm's centripetal term is what reads
        reads.append(np.linalg.norm(ideal[3:]))
    assert len(reads) == 5 and max(reads) > 0.3
    # the Euler term alpha x r is in the readings, far above the 1e-12 tolerance
    assert max(euler) > 0.02


def test_accelerometer_in_free_fall_reads_zero():
    cfg = imu_core.ImuConfig(rate_hz=RATE, **NO_BIAS)
    diagram, plant, body, (imu,) = _build(gravity=GRAVITY_W, imus=[dict(seed=3, config=cfg)])
    R0 = RollPitchYaw(0.4, 0.2, 0.0).ToRotationMatrix()
    (m,) = _run(diagram, [imu], RATE, 100, _spinning(plant, body, R0, np.zeros(3)))
    assert np.all(np.abs(m[:, 3:].mean(0)) < 4 * cfg.white_sigma[3:] / 10)


def test_imu_is_deterministic_per_seed_and_carries_its_bias():
    def run(seed):
        diagram, plant, body, (imu,) = _build(imus=[dict(seed=seed, name="imu")])
        R0 = RotationMatrix()
        return _run(diagram, [imu], RATE, 60, _spinning(plant, body, R0, np.array([0, 0, 0.2])))[0]

    a, b, c = run(7), run(7), run(8)
    assert np.array_equal(a, b)
    assert not np.any(a == c)
    # The gyro reads truth + bias + noise, each from the documented streams.
    cfg = imu_core.ImuConfig()
    key = stream_key(7, "imu")
    bias = imu_core.imu_initial_bias(generator(7, "imu/initial_bias"), config=cfg)
    expected = []
    for k in range(60):
        m, bias = imu_core.imu_measurement(
            np.array([0, 0, 0.2, 0, 0, 0]), bias, sample_generator(key, k), config=cfg
        )
        expected.append(m)
    np.testing.assert_allclose(a[:, :3], np.array(expected)[:, :3], atol=1e-12)


def test_a_delayed_sensor_delivers_each_sample_exactly_delay_later():
    """Same seed and name: the delayed IMU's output at t is the undelayed one's sample
    k = floor((t - delay) rate), bit for bit (zero before the first delivery)."""
    delay = 0.035

    def outputs(cfg):
        diagram, plant, body, (imu,) = _build(imus=[dict(seed=1, name="imu", config=cfg)])
        sim = Simulator(diagram)
        ctx = sim.get_mutable_context()
        _spinning(plant, body, RotationMatrix(), np.array([0.1, 0.0, 0.3]))(ctx)
        sim.Initialize()
        c = imu.GetMyContextFromRoot(ctx)
        out = {}
        for t in np.arange(1, 120) * 0.0025:
            sim.AdvanceTo(t)
            out[round(t, 6)] = imu.measurement_output.Eval(c).copy()
        return out

    now = outputs(imu_core.ImuConfig(rate_hz=RATE))
    late = outputs(imu_core.ImuConfig(rate_hz=RATE, delay_s=delay))
    checked = 0
    for t, shown in late.items():
        k = math.floor((t - delay) * RATE + 1e-6)
        if k < 0:
            np.testing.assert_array_equal(shown, 0.0)
            continue
        t_k = round(k / RATE + 0.0025, 6)  # just after sample k, undelayed
        np.testing.assert_array_equal(shown, now[t_k])
        checked += 1
    assert checked > 80


def test_star_tracker_system_tracks_attitude_with_configured_noise():
    rate = 20.0
    cfg = st_core.StarTrackerConfig(rate_hz=rate)
    diagram, plant, body, (st,) = _build(star_tracker=dict(seed=4, config=cfg))
    R0 = RollPitchYaw(0.1, 0.2, -0.7).ToRotationMatrix()
    w_W = np.array([0.0, 0.05, 0.3])
    n = 300
    (q,) = _run(diagram, [st], rate, n, _spinning(plant, body, R0, w_W))
    assert q.shape == (n, 4) and np.all(q[:, 0] >= 0)
    # truth: rotation about the fixed axis w_W (sphere, torque free)
    t = np.arange(n) / rate
    R_true = rot.rotation_exp(t[:, None] * w_W) @ R0.matrix()
    err_B = rot.rotation_log(np.swapaxes(R_true, 1, 2) @ rot.rotation_matrix_from_quaternion(q))
    std = err_B.std(axis=0) / ARCSEC
    np.testing.assert_allclose(std, [5.0, 5.0, 40.0], rtol=0.2)  # boresight = body z
    # 900 normal draws: P(any beyond 4.5 sigma) ~ 0.6 %, beyond 4 sigma it would be 6 %.
    assert np.all(np.abs(err_B).max(axis=0) < 4.5 * cfg.sigma_rad)


def test_wheel_encoders_on_plant_joints():
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, 0.0)
    inertia = SpatialInertia(1.0, np.zeros(3), UnitInertia.SolidCylinder(0.25, 0.1, [0, 1, 0]))
    joints = []
    for i in range(2):
        wheel = plant.AddRigidBody(f"wheel{i}", inertia)
        joints.append(
            plant.AddJoint(
                RevoluteJoint(f"axle{i}", plant.world_frame(), wheel.body_frame(), [0, 1, 0])
            )
        )
    plant.mutable_gravity_field().set_gravity_vector([0, 0, 0])
    plant.Finalize()
    cfg = enc_core.WheelEncoderConfig(counts_per_revolution=4096, rate_hz=20.0)
    enc = builder.AddSystem(WheelEncoders(n_wheels=2, seed=0, config=cfg))
    sel = builder.AddSystem(wheel_angle_selector(plant, joints[::-1]))  # reversed order
    builder.Connect(plant.get_state_output_port(), sel.get_input_port())
    builder.Connect(sel.get_output_port(), enc.wheel_angles_input)
    diagram = builder.Build()
    q0, w = np.array([0.3, -1.0]), np.array([1.5, -0.4])

    def setup(ctx):
        pc = plant.GetMyMutableContextFromRoot(ctx)
        for j, a, v in zip(joints, q0, w, strict=True):
            j.set_angle(pc, a)
            j.set_angular_rate(pc, v)

    (angles,) = _run(diagram, [enc], cfg.rate_hz, 40, setup)
    t = np.arange(40)[:, None] / cfg.rate_hz
    true = (q0 + w * t)[:, ::-1]
    res = 2 * math.pi / 4096
    np.testing.assert_allclose(angles / res, np.round(angles / res), atol=1e-9)
    assert np.all(np.abs(angles - true) <= res / 2 + 1e-9)


def test_attitude_propagation_matches_rotation_matrices():
    """The odometry's scalar quaternion step agrees with R_WB Exp(w dt) from Rodrigues'
    matrices (an independent formulation), small angles included; the batched and the
    one-quaternion matrix paths agree."""
    from lunar_drake.autonomy.odometry import propagate_attitude

    g = np.random.default_rng(5)
    for scale in (1e-9, 1e-3, 1.0, 3.0):
        q0 = rot.quaternion_from_rotation_matrix(rot.rotation_exp(g.normal(size=3)))
        w = g.normal(size=3) * scale
        q = propagate_attitude(q0, w, 0.02)
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1.0) < 1e-15
        expected = rot.rotation_matrix_from_quaternion(q0) @ rot.rotation_exp(w * 0.02)
        np.testing.assert_allclose(rot.rotation_matrix_from_quaternion(q), expected, atol=1e-12)
        batch = rot.rotation_matrix_from_quaternion(np.stack([q0, q]))
        np.testing.assert_allclose(rot.rotation_matrix_from_quaternion(q), batch[1], atol=1e-15)
