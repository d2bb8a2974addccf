"""MakeFlightDiagram: the rover's software. It reads only sensors and the uplink.

Wiring only. Ports (``<subsystem>.<signal>``):

* inputs -- sensors ``rover.imu``, ``rover.star_tracker``, ``rover.wheel_encoders`` and
  the uplink inbox ``uplink.commands`` and, when it sends frames down, the camera's
  ``camera.frame_index``, ``camera.left.raw``, ``camera.right.raw``; with the neutron
  spectrometer or NIRVSS, ``rover.nss`` / ``rover.nirvss``;
* outputs -- actuator commands ``rover.wheel_speed_command``,
  ``rover.steer_angle_command`` (explicit steer), ``rover.gimbal_command``,
  ``rover.brake_command`` (and ``rover.drill_command`` with the drill); the downlink
  outboxes ``downlink.telemetry`` (and
  ``downlink.images``: compressed stereo frames; ``downlink.science``: instrument
  records); and the on-board
  records ``flight.twist_command``, ``flight.brake_command``, ``flight.pose_estimate``,
  ``flight.pose_covariance``, ``flight.status`` (mode, command seq, safe reason, mode
  changes) and ``flight.bumper`` (the virtual bumper's trip) for logging.
"""

from __future__ import annotations

import dataclasses as dc
import math

from pydrake.systems.framework import DiagramBuilder

from lunar_drake.autonomy.follower import FollowerParams, HeadingConfig
from lunar_drake.scenario import Scenario
from lunar_drake.systems.command_executor import CommandExecutor
from lunar_drake.systems.drill import DrillController
from lunar_drake.systems.gimbal_pointing import GimbalPointing
from lunar_drake.systems.image_downlink import ImagePacketizer
from lunar_drake.systems.rover_kinematics import RoverKinematics
from lunar_drake.systems.science_downlink import TICK_S, Instrument, SciencePacketizer
from lunar_drake.systems.state_estimator import StateEstimator
from lunar_drake.systems.telemetry import TelemetryPacketizer
from lunar_drake.systems.virtual_bumper import VirtualBumper

#: Inputs the flight software reads: plant sensors and the uplink.
FLIGHT_INPUTS = ("rover.imu", "rover.star_tracker", "rover.wheel_encoders", "uplink.commands")
#: Camera sensor inputs, when it sends frames down (:func:`sends_images`).
IMAGE_INPUTS = ("camera.frame_index", "camera.left.raw", "camera.right.raw")
#: Values each science instrument reports (``rover.<name>`` sensor ports).
INSTRUMENT_VALUES = {"nss": 2, "nirvss": 8, "drill": 4}


def instruments(scenario: Scenario) -> list[Instrument]:
    """The science instruments the rover carries (``sensors.nss``, ``sensors.nirvss``,
    ``sensors.drill``: its records go when its sample count grows, ``rate_hz`` 0)."""
    out = []
    for name, n in INSTRUMENT_VALUES.items():
        cfg = getattr(scenario.sensors, name)
        if cfg.enabled:
            rate, delay = getattr(cfg, "rate_hz", 0.0), getattr(cfg, "delay_s", 0.0)
            out.append(Instrument(name=name, n_values=n, rate_hz=rate, delay_s=delay))
    return out


def sends_science(scenario: Scenario) -> bool:
    """True when the rover carries a science instrument and sends its records down."""
    return bool(instruments(scenario))


def science_timing(scenario: Scenario) -> tuple[float, float]:
    """(period, offset) s of the science packetizer's updates."""
    return TICK_S, 1e-6


def sends_images(scenario: Scenario) -> bool:
    """True when the flight software sends camera frames down (cameras on and
    ``flight.images.enabled``)."""
    return scenario.sensors.camera.enabled and scenario.flight.images.enabled


def flight_inputs(scenario: Scenario) -> tuple:
    """The flight diagram's inputs for ``scenario``."""
    return (
        FLIGHT_INPUTS
        + (IMAGE_INPUTS if sends_images(scenario) else ())
        + tuple(f"rover.{i.name}" for i in instruments(scenario))
        + (("rover.power",) if scenario.power.enabled else ())
    )


def image_timing(scenario: Scenario) -> tuple[float, float]:
    """(period, offset) s of the image packetizer: just after each frame is delivered."""
    cam = scenario.sensors.camera
    period = 1.0 / cam.rate_hz
    return period, (cam.delay_s % period) + 1e-6


def follower_params(description, heading: HeadingConfig | None = None) -> FollowerParams:
    """The on-board path follower's settings for a rover: explicit steer crabs back onto
    the path; skid steer cannot move sideways. ``heading`` (``flight.heading``; default
    ``path``) adds the heading policy, the panel's mount azimuth and the largest crab
    angle it drives: the steering limit, at most 90 deg less ``crab_margin_deg``."""
    skid = description.steering == "skid"
    params = FollowerParams(crab_gain_per_s=0.0 if skid else 0.3)
    if heading is None or heading.policy == "path":
        return params
    return dc.replace(
        params,
        heading=heading.policy,
        yaw_gain_per_s=float(heading.yaw_gain_per_s),
        panel_azimuth_rad=float(description.solar_panel_azimuth_rad),
        max_crab_rad=0.0 if skid else min(float(description.steering_limit_rad),
                                          math.radians(90.0 - heading.crab_margin_deg)),
    )


def flight_estimator_config(scenario: Scenario):
    """The on-board EKF's config: ``flight.estimator`` with its slip table and level
    prior from the pre-flight slip calibration when it names one
    (:func:`~lunar_drake.autonomy.slip_calibration.calibrated_estimator`)."""
    from lunar_drake.autonomy.slip_calibration import calibrated_estimator

    config, _ = calibrated_estimator(scenario.flight.estimator,
                                     description=scenario.rover.description)  # fmt: skip
    return config


def MakeFlightDiagram(*, scenario: Scenario):
    """Builds the flight-software diagram (named ``flight``): the command executor (runs
    the uplinked commands, keeps the mode, safes on a bumper trip or the loss of the
    uplink, brakes when parked), the virtual bumper (tilt, stall, yaw slip), the rover
    kinematics, the on-board EKF (wheel odometry, IMU gyro and accelerometer, star
    tracker: pose with covariance), gimbal pointing (from the estimate and the
    operator's mast commands, never truth) and the telemetry packetizer.

    It knows the rover only from ``scenario.rover.description`` and the start point
    from ``scenario.rover.spawn_*`` (what operations tell the rover).
    """
    f = scenario.flight
    d = scenario.rover.description
    builder = DiagramBuilder()
    executor = builder.AddNamedSystem(
        "flight.executor",
        CommandExecutor(
            rate_hz=f.rate_hz,
            brake_delay_s=f.brake_delay_s,
            uplink_timeout_s=f.safety.uplink_timeout_s,
            follower=follower_params(d, f.heading),
        ),
    )
    power = scenario.power.enabled
    bumper = builder.AddNamedSystem("flight.bumper", VirtualBumper(description=d, config=f.safety,
                                                                   power=power))  # fmt: skip
    kinematics = builder.AddNamedSystem(
        "flight.kinematics", RoverKinematics(description=d, rate_hz=f.rate_hz)
    )
    odometry = builder.AddNamedSystem(
        "flight.estimator",
        StateEstimator(
            description=d,
            config=flight_estimator_config(scenario),
            start_xy_m=(scenario.rover.spawn_x_m, scenario.rover.spawn_y_m),
            start_yaw_rad=math.radians(scenario.rover.spawn_yaw_deg),
        ),
    )
    gimbal = builder.AddNamedSystem(
        "flight.gimbal_pointing", GimbalPointing(description=d, config=f.gimbal)
    )
    telemetry = builder.AddNamedSystem(
        "flight.telemetry", TelemetryPacketizer(rate_hz=f.telemetry_rate_hz, power=power)
    )
    builder.ExportInput(executor.commands_input, "uplink.commands")
    builder.Connect(executor.twist_output, kinematics.twist_input)
    builder.ExportInput(odometry.wheel_angles_input, "rover.wheel_encoders")
    builder.ConnectInput("rover.wheel_encoders", bumper.wheel_angles_input)
    builder.Connect(kinematics.wheel_speed_output, bumper.wheel_speed_input)
    builder.Connect(odometry.pose_estimate_output, bumper.pose_input)
    builder.Connect(executor.status_output, bumper.status_input)
    builder.Connect(bumper.trip_output, executor.trip_input)
    builder.Connect(executor.mast_output, gimbal.hold_input)
    builder.ExportInput(odometry.q_WB_input, "rover.star_tracker")
    if kinematics.steer_angle_output is not None:
        builder.Connect(kinematics.steer_angle_output, odometry.steer_input)
        builder.Connect(kinematics.steer_angle_output, bumper.steer_input)
        builder.ExportOutput(kinematics.steer_angle_output, "rover.steer_angle_command")
    builder.Connect(odometry.p_WB_output, gimbal.p_WB_input)
    builder.Connect(odometry.q_WB_output, gimbal.q_WB_input)
    builder.Connect(odometry.pose_estimate_output, telemetry.pose_estimate_input)
    builder.Connect(odometry.pose_estimate_output, executor.pose_input)
    builder.Connect(executor.twist_output, telemetry.twist_input)
    builder.Connect(executor.brake_output, telemetry.brake_input)
    builder.Connect(executor.status_output, telemetry.status_input)
    builder.ExportInput(odometry.imu_input, "rover.imu")
    builder.ConnectInput("rover.imu", bumper.imu_input)
    if power:  # the power sensor: low-SOC safing and SOC in telemetry
        builder.ExportInput(bumper.power_input, "rover.power")
        builder.ConnectInput("rover.power", telemetry.power_input)
    builder.ExportOutput(kinematics.wheel_speed_output, "rover.wheel_speed_command")
    builder.ExportOutput(gimbal.gimbal_command_output, "rover.gimbal_command")
    builder.ExportOutput(executor.brake_output, "rover.brake_command")
    builder.ExportOutput(telemetry.telemetry_output, "downlink.telemetry")
    if sends_images(scenario):
        period, offset = image_timing(scenario)
        images = builder.AddNamedSystem(
            "flight.images", ImagePacketizer(config=f.images, period_s=period, offset_s=offset)
        )
        builder.ExportInput(images.frame_index_input, "camera.frame_index")
        builder.ExportInput(images.left_input, "camera.left.raw")
        builder.ExportInput(images.right_input, "camera.right.raw")
        builder.Connect(odometry.pose_estimate_output, images.pose_input)
        builder.Connect(gimbal.gimbal_command_output, images.gimbal_input)
        builder.ExportOutput(images.images_output, "downlink.images")
    if sends_science(scenario):
        science = builder.AddNamedSystem(
            "flight.science", SciencePacketizer(instruments=instruments(scenario))
        )
        for name, port in science.values_inputs.items():
            builder.ExportInput(port, f"rover.{name}")
        builder.Connect(odometry.pose_estimate_output, science.pose_input)
        builder.ExportOutput(science.science_output, "downlink.science")
    if scenario.sensors.drill.enabled:
        drill = builder.AddNamedSystem("flight.drill", DrillController(rate_hz=f.rate_hz))
        builder.ConnectInput("uplink.commands", drill.commands_input)
        builder.Connect(executor.status_output, drill.status_input)
        builder.ExportOutput(drill.drill_command_output, "rover.drill_command")
    builder.ExportOutput(executor.twist_output, "flight.twist_command")
    builder.ExportOutput(odometry.pose_estimate_output, "flight.pose_estimate")
    builder.ExportOutput(odometry.pose_covariance_output, "flight.pose_covariance")
    builder.ExportOutput(executor.brake_output, "flight.brake_command")
    builder.ExportOutput(executor.status_output, "flight.status")
    builder.ExportOutput(bumper.trip_output, "flight.bumper")
    diagram = builder.Build()
    diagram.set_name("flight")
    return diagram
