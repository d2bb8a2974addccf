"""Flight software cores and systems: command executor, odometry, gimbal pointing, and the
flight diagram alone (fed sensor values and uplink deliveries by hand)."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from lunar_drake.autonomy.commands import (
    MODES,
    DriveCommand,
    ExecutorState,
    StopCommand,
    executor_step,
)
from lunar_drake.autonomy.odometry import body_displacement, odometry_step, propagate_attitude
from lunar_drake.comms.messages import Delivery, Message
from lunar_drake.dynamics.kinematics import (
    explicit_steer_commands,
    skid_steer_wheel_speeds,
    wheel_geometry_for,
)
from lunar_drake.models.rover_description import rover_preset
from lunar_drake.rotations import (
    quaternion_from_rotation_matrix,
    rotation_exp,
    rotation_matrix_from_quaternion,
)

RATE = 50.0


def _deliveries(cmds, t=0.0):
    return tuple(
        Delivery(Message("commands", k, t, c, c.size_bytes()), t) for k, c in enumerate(cmds)
    )


def _run(state, deliveries, ticks, brake_delay_s=0.5):
    out = []
    for tick in ticks:
        state, o = executor_step(
            state, deliveries, tick=tick, rate_hz=RATE, brake_delay_s=brake_delay_s
        )
        out.append(o)
    return state, out


def test_executor_runs_commands_in_order_for_their_durations():
    cmds = [DriveCommand(0.1), DriveCommand(0.2, vx_mps=0.3), DriveCommand(0.1, wz_radps=0.05)]
    state, out = _run(ExecutorState(), _deliveries(cmds), range(30))
    vx = np.array([o.twist[0] for o in out])
    wz = np.array([o.twist[2] for o in out])
    # ticks 0-4 still, 5-14 vx 0.3, 15-19 wz, then nothing left
    np.testing.assert_array_equal(vx, [0.0] * 5 + [0.3] * 10 + [0.0] * 15)
    np.testing.assert_array_equal(wz, [0.0] * 15 + [0.05] * 5 + [0.0] * 10)
    # A zero-twist drive command still runs (driving, standing still); then waiting.
    assert [o.mode for o in out[:1] + out[5:6] + out[29:]] == ["driving", "driving", "waiting"]
    assert [(m.before, m.after) for m in state.transitions.items()] == [
        ("idle", "driving"),
        ("driving", "waiting"),
    ]
    assert state.last_seq == 2 and state.queue == ()


def test_executor_brakes_from_the_start_releases_to_drive_and_rebrakes_after_the_delay():
    cmds = [DriveCommand(0.2, vx_mps=0.1)]
    _, out = _run(ExecutorState(), (), range(3))
    assert all(o.brake for o in out)  # parked from the start
    _, out = _run(ExecutorState(), _deliveries(cmds), range(60))
    brake = [o.brake for o in out]
    # driving ticks 0-9 unbraked; stand-still from tick 10; brakes after 0.5 s = 25 ticks
    assert brake[:35] == [False] * 35 and all(brake[35:])


def test_stop_clears_the_queue_and_old_messages_are_ignored():
    d = _deliveries([DriveCommand(10.0, vx_mps=0.2), DriveCommand(5.0, vx_mps=0.1)])
    state, out = _run(ExecutorState(), d, range(3))
    assert out[-1].twist[0] == 0.2 and len(state.queue) == 1
    stop = (Delivery(Message("commands", 2, 0.1, StopCommand(), 4), 0.1),)
    state, out = _run(state, d + stop, range(3, 5))
    assert out[-1].twist[0] == 0.0 and state.queue == () and state.active is None
    state, out = _run(state, d + stop, range(5, 7))  # redelivered: not run again
    assert out[-1].twist[0] == 0.0 and state.last_seq == 2
    assert MODES.index(out[-1].mode) == MODES.index("waiting")


@pytest.mark.parametrize("preset", ["krex2_rp", "husky_rp"])
def test_odometry_inverts_the_kinematics_of_a_straight_and_turning_drive(preset):
    d = rover_preset(preset)
    g = wheel_geometry_for(d)
    skid = d.steering == "skid"
    for twist in ([0.2, 0.0, 0.0], [0.15, 0.0, 0.03]):
        dt = 0.02
        if skid:
            omega, steer = skid_steer_wheel_speeds(twist, geometry=g), np.zeros(4)
        else:
            steer, omega = explicit_steer_commands(twist, geometry=g, previous_delta=np.zeros(4))
        disp = body_displacement(omega * dt, steer, geometry=g, skid=skid)
        np.testing.assert_allclose(disp, np.array(twist) * dt, atol=1e-12)
    # Straight along a heading rotated 30 deg about z: the displacement turns with it.
    R = rotation_exp([0.0, 0.0, math.radians(30)])
    omega = np.full(4, 0.2 / d.wheel_radius_m)
    p = odometry_step(np.zeros(3), omega * 1.0, np.zeros(4), R, geometry=g, skid=skid)
    np.testing.assert_allclose(p, [0.2 * math.cos(math.radians(30)), 0.1, 0.0], atol=1e-12)


def test_gyro_propagation_matches_the_closed_form_rotation():
    q0 = quaternion_from_rotation_matrix(rotation_exp([0.1, -0.2, 0.3]))
    w = np.array([0.01, 0.02, -0.05])
    q = q0
    for _ in range(100):
        q = propagate_attitude(q, w, 0.01)
    expected = rotation_matrix_from_quaternion(q0) @ rotation_exp(w * 1.0)
    np.testing.assert_allclose(rotation_matrix_from_quaternion(q), expected, atol=1e-12)


def test_gimbal_lookahead_points_the_cameras_at_the_ground_ahead():
    """The flight gimbal's pan/tilt from the description put the plant's camera axis on
    the ground point lookahead_m ahead (checked on the plant's own frames)."""
    from pydrake.multibody.plant import MultibodyPlant

    from lunar_drake.models.rover_sdf import add_rover
    from lunar_drake.systems.gimbal_pointing import GimbalPointing, GimbalPointingConfig

    d = rover_preset("krex2_rp")
    cfg = GimbalPointingConfig(lookahead_m=6.0)
    gp = GimbalPointing(description=d, config=cfg)
    pan, tilt = gp.gimbal_command_output.Eval(gp.CreateDefaultContext())
    plant = MultibodyPlant(0.0)
    rover = add_rover(plant, description=d)
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    rover.gimbal_pan.set_angle(ctx, pan)
    rover.gimbal_tilt.set_angle(ctx, tilt)
    # Chassis at its nominal height over level ground z = 0 (the default pose puts C at 0).
    X_WH = plant.EvalBodyPoseInWorld(ctx, rover.left_camera.body())
    p = X_WH.translation()
    axis = X_WH.rotation().matrix()[:, 0]  # the head looks along its +x
    ground = -d.nominal_chassis_height_m()
    s = (ground - p[2]) / axis[2]
    hit = p + s * axis
    assert hit[0] == pytest.approx(6.0, abs=0.01) and abs(hit[1]) < 0.01


def test_flight_diagram_reads_sensors_and_uplink_and_commands_the_wheels():
    from lunar_drake.diagrams.flight import FLIGHT_INPUTS, MakeFlightDiagram
    from lunar_drake.scenario import Scenario

    s = Scenario()
    s.flight.telemetry_rate_hz = 10.0
    flight = MakeFlightDiagram(scenario=s)
    names = {flight.get_input_port(k).get_name() for k in range(flight.num_input_ports())}
    assert names == {*FLIGHT_INPUTS, "rover.power"}
    sim = Simulator(flight)
    ctx = sim.get_mutable_context()
    flight.GetInputPort("rover.imu").FixValue(ctx, np.zeros(6))
    flight.GetInputPort("rover.star_tracker").FixValue(ctx, [1.0, 0.0, 0.0, 0.0])
    flight.GetInputPort("rover.wheel_encoders").FixValue(ctx, np.zeros(4))
    flight.GetInputPort("rover.power").FixValue(ctx, [0.8, 120.0, 90.0])
    cmd = DriveCommand(1.0, vx_mps=0.25)
    flight.GetInputPort("uplink.commands").FixValue(ctx, _deliveries([cmd]))
    sim.AdvanceTo(0.5)
    w = flight.GetOutputPort("rover.wheel_speed_command").Eval(ctx)
    np.testing.assert_allclose(w, 0.25 / s.rover.description.wheel_radius_m, rtol=1e-12)
    assert flight.GetOutputPort("rover.brake_command").Eval(ctx)[0] == 0.0
    (msg,) = flight.GetOutputPort("downlink.telemetry").Eval(ctx)
    assert msg.topic == "telemetry" and msg.payload[6] == 0.25  # vx_cmd_mps
    assert tuple(msg.payload[-2:]) == (0.8, 120.0)  # soc, array_W
    sim.AdvanceTo(2.0)
    assert flight.GetOutputPort("rover.brake_command").Eval(ctx)[0] == 1.0
