"""RoverKinematics (flight "Rover Kinematics") and TwistSchedule (an open-loop route)."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.dynamics.kinematics import (
    WheelGeometry,
    explicit_steer_commands,
    skid_steer_wheel_speeds,
)


def wheel_geometry_for(description) -> WheelGeometry:
    """Kinematic wheel geometry of a rover description (body frame = chassis frame C).

    Skid: wheel centres, no steering. Explicit: steering axes ``steering_offset_m``
    inboard of the wheel centres; offsets signed along each wheel's left axis.
    """
    wc = np.asarray(description.wheel_centres_C(), dtype=float)[:, :2]
    if description.steering == "skid":
        return WheelGeometry(
            p_BS=wc,
            wheel_radius=description.wheel_radius_m,
            steering_offset=0.0,
            steering_limit=0.0,
            steerable=False,
        )
    o = float(description.steering_offset_m)
    side = np.sign(wc[:, 1])
    p = wc.copy()
    p[:, 1] -= side * o
    return WheelGeometry(
        p_BS=p,
        wheel_radius=description.wheel_radius_m,
        steering_offset=side * o,
        steering_limit=float(description.steering_limit_rad),
        steerable=True,
    )


class RoverKinematics(LeafSystem):
    """Body twist -> wheel speed and steering set-points for the plant's PD servos.

    .. pydrake_system::

        name: RoverKinematics
        input_ports:
        - twist_command
        - gimbal_command
        output_ports:
        - desired_state

    ``twist_command`` is (vx, vy, wz) in the chassis frame (m/s, m/s, rad/s);
    ``gimbal_command`` is (pan, tilt) in rad. ``desired_state`` is the plant's
    per-model-instance desired state ``[q_d; v_d]`` in actuator order: drive joints get
    v_d = wheel speed (rad/s), steering joints q_d = angle (rad), gimbal joints q_d =
    command. Updated periodically at ``rate_hz`` (flight-software rate) and held;
    steering angles are kept through zero-twist commands (no spurious flips). Steering
    angles beyond a joint's limit are saturated (``clip=True``).

    Args:
        rover: a RoverModel. plant: the finalized MultibodyPlant. rate_hz: update rate.
    """

    def __init__(self, *, rover, plant, rate_hz: float = 50.0):
        super().__init__()
        self._desc = rover.description
        self._geometry = wheel_geometry_for(self._desc)
        self._skid = self._desc.steering == "skid"
        acts = plant.GetJointActuatorIndices(rover.model_instance)
        names = [plant.get_joint_actuator(a).joint().name() for a in acts]
        self._nu = len(names)
        drive = [j.name() for j in rover.drive_joints]
        steer = [j.name() for j in rover.steer_joints]
        self._drive_slots = [names.index(n) for n in drive]
        self._steer_slots = [names.index(n) for n in steer]
        self._gimbal_slots = [
            names.index(rover.gimbal_pan.name()),
            names.index(rover.gimbal_tilt.name()),
        ]
        self.twist_input = self.DeclareVectorInputPort("twist_command", 3)
        self.gimbal_input = self.DeclareVectorInputPort("gimbal_command", 2)
        n_steer = len(self._steer_slots)
        # State: [desired q (nu), desired v (nu), previous steering angles (n_steer)].
        self._state = self.DeclareDiscreteState(2 * self._nu + n_steer)
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.desired_state_output = self.DeclareVectorOutputPort(
            "desired_state",
            BasicVector(2 * self._nu),
            self._calc_output,
            prerequisites_of_calc={self.xd_ticket()},
        )

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).get_value().copy()
        twist = (
            self.twist_input.Eval(context) if self.twist_input.HasValue(context) else np.zeros(3)
        )
        gimbal = (
            self.gimbal_input.Eval(context) if self.gimbal_input.HasValue(context) else np.zeros(2)
        )
        nu = self._nu
        if self._skid:
            omega = skid_steer_wheel_speeds(
                np.array([twist[0], 0.0, twist[2]]), geometry=self._geometry
            )
        else:
            prev = x[2 * nu :]
            cmd = explicit_steer_commands(
                np.asarray(twist, float), geometry=self._geometry, previous_delta=prev, clip=True
            )
            omega = cmd.omega
            for k, slot in enumerate(self._steer_slots):
                x[slot] = cmd.delta[k]
            x[2 * nu :] = cmd.delta
        for k, slot in enumerate(self._drive_slots):
            x[nu + slot] = omega[k]
        x[self._gimbal_slots[0]] = gimbal[0]
        x[self._gimbal_slots[1]] = gimbal[1]
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)

    def _calc_output(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        output.SetFromVector(x[: 2 * self._nu])


class TwistSchedule(LeafSystem):
    """An open-loop route: piecewise-constant body twists.

    .. pydrake_system::

        name: TwistSchedule
        output_ports:
        - twist_command

    Args:
        segments: sequence of (duration_s, vx, vy, wz); after the last segment the
            command is zero (the rover stops).
    """

    def __init__(self, *, segments):
        super().__init__()
        seg = np.asarray(segments, dtype=float).reshape(-1, 4)
        if (seg[:, 0] < 0).any():
            raise ValueError(f"segment durations must be >= 0, got {seg[:, 0].tolist()}")
        self._ends = np.cumsum(seg[:, 0])
        self._twists = seg[:, 1:]
        self.twist_output = self.DeclareVectorOutputPort(
            "twist_command", BasicVector(3), self._calc, prerequisites_of_calc={self.time_ticket()}
        )

    def _calc(self, context, output):
        t = context.get_time()
        k = int(np.searchsorted(self._ends, t, side="right"))
        output.SetFromVector(self._twists[k] if k < len(self._twists) else np.zeros(3))

    @property
    def duration_s(self) -> float:
        return float(self._ends[-1]) if len(self._ends) else 0.0
