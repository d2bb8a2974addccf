"""MakeFlightDiagram: the rover's software. It reads only sensors and the uplink.

Wiring only. Ports (``<subsystem>.<signal>``):

* inputs -- sensors ``rover.imu``, ``rover.star_tracker``, ``rover.wheel_encoders`` and
  the uplink inbox ``uplink.commands``;
* outputs -- actuator commands ``rover.wheel_speed_command``,
  ``rover.steer_angle_command`` (explicit steer), ``rover.gimbal_command``,
  ``rover.brake_command``; the downlink outbox ``downlink.telemetry``; and the on-board
  records ``flight.twist_command``, ``flight.brake_command``, ``flight.pose_estimate``,
  ``flight.pose_covariance``, ``flight.status`` (for logging).
"""

from __future__ import annotations

import math

from pydrake.systems.framework import DiagramBuilder

from lunar_drake.scenario import Scenario
from lunar_drake.systems.command_executor import CommandExecutor
from lunar_drake.systems.gimbal_pointing import GimbalPointing
from lunar_drake.systems.rover_kinematics import RoverKinematics
from lunar_drake.systems.state_estimator import StateEstimator
from lunar_drake.systems.telemetry import TelemetryPacketizer

#: Inputs the flight software reads: plant sensors and the uplink.
FLIGHT_INPUTS = ("rover.imu", "rover.star_tracker", "rover.wheel_encoders", "uplink.commands")


def MakeFlightDiagram(*, scenario: Scenario):
    """Builds the flight-software diagram (named ``flight``): the command executor (runs
    the uplinked drive commands, brakes when parked), the rover kinematics, the on-board
    EKF (wheel odometry, IMU gyro and accelerometer, star tracker: pose with
    covariance), gimbal pointing
    (from the estimate and commands, never truth) and the telemetry packetizer.

    It knows the rover only from ``scenario.rover.description`` and the start point
    from ``scenario.rover.spawn_*`` (what operations tell the rover).
    """
    f = scenario.flight
    d = scenario.rover.description
    builder = DiagramBuilder()
    executor = builder.AddNamedSystem(
        "flight.executor", CommandExecutor(rate_hz=f.rate_hz, brake_delay_s=f.brake_delay_s)
    )
    kinematics = builder.AddNamedSystem(
        "flight.kinematics", RoverKinematics(description=d, rate_hz=f.rate_hz)
    )
    odometry = builder.AddNamedSystem(
        "flight.estimator",
        StateEstimator(
            description=d,
            config=f.estimator,
            start_xy_m=(scenario.rover.spawn_x_m, scenario.rover.spawn_y_m),
            start_yaw_rad=math.radians(scenario.rover.spawn_yaw_deg),
        ),
    )
    gimbal = builder.AddNamedSystem(
        "flight.gimbal_pointing", GimbalPointing(description=d, config=f.gimbal)
    )
    telemetry = builder.AddNamedSystem(
        "flight.telemetry", TelemetryPacketizer(rate_hz=f.telemetry_rate_hz)
    )
    builder.ExportInput(executor.commands_input, "uplink.commands")
    builder.Connect(executor.twist_output, kinematics.twist_input)
    builder.ExportInput(odometry.wheel_angles_input, "rover.wheel_encoders")
    builder.ExportInput(odometry.q_WB_input, "rover.star_tracker")
    if kinematics.steer_angle_output is not None:
        builder.Connect(kinematics.steer_angle_output, odometry.steer_input)
        builder.ExportOutput(kinematics.steer_angle_output, "rover.steer_angle_command")
    builder.Connect(odometry.p_WB_output, gimbal.p_WB_input)
    builder.Connect(odometry.q_WB_output, gimbal.q_WB_input)
    builder.Connect(odometry.pose_estimate_output, telemetry.pose_estimate_input)
    builder.Connect(odometry.pose_estimate_output, executor.pose_input)
    builder.Connect(executor.twist_output, telemetry.twist_input)
    builder.Connect(executor.brake_output, telemetry.brake_input)
    builder.Connect(executor.status_output, telemetry.status_input)
    builder.ExportInput(odometry.imu_input, "rover.imu")
    builder.ExportOutput(kinematics.wheel_speed_output, "rover.wheel_speed_command")
    builder.ExportOutput(gimbal.gimbal_command_output, "rover.gimbal_command")
    builder.ExportOutput(executor.brake_output, "rover.brake_command")
    builder.ExportOutput(telemetry.telemetry_output, "downlink.telemetry")
    builder.ExportOutput(executor.twist_output, "flight.twist_command")
    builder.ExportOutput(odometry.pose_estimate_output, "flight.pose_estimate")
    builder.ExportOutput(odometry.pose_covariance_output, "flight.pose_covariance")
    builder.ExportOutput(executor.brake_output, "flight.brake_command")
    builder.ExportOutput(executor.status_output, "flight.status")
    diagram = builder.Build()
    diagram.set_name("flight")
    return diagram
