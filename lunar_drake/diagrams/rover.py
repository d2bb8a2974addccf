"""AddRover: a rover on the terrain — plant model, wheel-soil contact, kinematics, sensors.

Used by MakeMissionDiagram and by the slip study; only wires systems together.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.errors import ConfigError, NoDataError, OutOfBoundsError
from lunar_drake.models.rover_sdf import RoverModel, add_rover
from lunar_drake.systems.imu import Imu
from lunar_drake.systems.rover_kinematics import RoverKinematics
from lunar_drake.systems.star_tracker import StarTracker
from lunar_drake.systems.wheel_encoders import WheelEncoders, wheel_angle_selector
from lunar_drake.systems.wheel_regolith_contact import WheelRegolithContact


class BodyPoseVector(LeafSystem):
    """Ground truth of one body as a vector.

    .. pydrake_system::

        name: BodyPoseVector
        input_ports:
        - body_poses
        - body_spatial_velocities
        output_ports:
        - pose

    ``pose`` = [x, y, z (m), roll, pitch, yaw (rad), vx, vy, vz (m/s, world),
    wx, wy, wz (rad/s, world)] of the body frame in the world (site) frame.
    """

    FIELDS = (
        "x_m",
        "y_m",
        "z_m",
        "roll_rad",
        "pitch_rad",
        "yaw_rad",
        "vx_mps",
        "vy_mps",
        "vz_mps",
        "wx_radps",
        "wy_radps",
        "wz_radps",
    )

    def __init__(self, *, body_index):
        super().__init__()
        self._b = int(body_index)
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        from pydrake.multibody.math import SpatialVelocity

        self.body_spatial_velocities_input = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self.pose_output = self.DeclareVectorOutputPort("pose", BasicVector(12), self._calc)

    def _calc(self, context, output):
        X = self.body_poses_input.Eval(context)[self._b]
        V = self.body_spatial_velocities_input.Eval(context)[self._b]
        rpy = RollPitchYaw(X.rotation()).vector()
        output.SetFromVector(
            np.concatenate([X.translation(), rpy, V.translational(), V.rotational()])
        )


@dc.dataclass
class RoverHandles:
    """Systems and model handles of one rover in a diagram."""

    model: RoverModel
    contact: WheelRegolithContact
    kinematics: RoverKinematics
    imu: Imu
    star_tracker: StarTracker
    encoders: WheelEncoders
    truth: BodyPoseVector
    wheel: tm.WheelParams
    soil: tm.SoilParams


def add_rover_model(plant, *, description, model_name: str = "rover") -> RoverModel:
    """Adds the rover model to an unfinalized plant (step 1 of 2)."""
    return add_rover(plant, description=description, model_name=model_name)


def wire_rover(
    builder,
    *,
    plant,
    rover: RoverModel,
    heightfield_port,
    soil: tm.SoilParams,
    seed: int,
    name: str = "rover",
) -> RoverHandles:
    """Adds contact, kinematics and sensors for a rover in a finalized plant (step 2 of 2).

    Exports nothing; the caller connects ``kinematics.twist_input`` and
    ``kinematics.gimbal_input`` (or leaves them to default zero) and logs what it needs.
    """
    d = rover.description
    wheel = tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m)
    contact = builder.AddNamedSystem(
        f"{name}.contact",
        WheelRegolithContact(
            wheel_bodies=[b.index() for b in rover.wheels],
            wheel=wheel,
            soil=soil,
            belly_body=rover.chassis.index(),
            belly_points_B=rover.belly_points_C,
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), contact.body_poses_input)
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), contact.body_spatial_velocities_input
    )
    builder.Connect(heightfield_port, contact.heightfield_input)
    builder.Connect(contact.spatial_forces_output, plant.get_applied_spatial_force_input_port())

    kin = builder.AddNamedSystem(f"{name}.kinematics", RoverKinematics(rover=rover, plant=plant))
    builder.Connect(
        kin.desired_state_output, plant.get_desired_state_input_port(rover.model_instance)
    )
    # PD servos provide all actuation; feed-forward torques are zero.
    from pydrake.systems.primitives import ConstantVectorSource

    zero = builder.AddNamedSystem(
        f"{name}.zero_actuation",
        ConstantVectorSource(np.zeros(plant.num_actuated_dofs(rover.model_instance))),
    )
    builder.Connect(zero.get_output_port(), plant.get_actuation_input_port(rover.model_instance))

    gravity = plant.gravity_field().gravity_vector()
    imu = builder.AddNamedSystem(
        f"{name}.imu",
        Imu(body_index=rover.chassis.index(), seed=seed, name=f"{name}.imu", gravity_W=gravity),
    )
    builder.Connect(plant.get_body_poses_output_port(), imu.body_poses_input)
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), imu.body_spatial_velocities_input
    )
    builder.Connect(
        plant.get_body_spatial_accelerations_output_port(), imu.body_spatial_accelerations_input
    )
    st = builder.AddNamedSystem(
        f"{name}.star_tracker",
        StarTracker(body_index=rover.chassis.index(), seed=seed, name=f"{name}.star_tracker"),
    )
    builder.Connect(plant.get_body_poses_output_port(), st.body_poses_input)
    sel = builder.AddNamedSystem(
        f"{name}.wheel_angles", wheel_angle_selector(plant, list(rover.drive_joints))
    )
    enc = builder.AddNamedSystem(
        f"{name}.encoders",
        WheelEncoders(n_wheels=len(rover.drive_joints), seed=seed, name=f"{name}.encoders"),
    )
    builder.Connect(plant.get_state_output_port(), sel.get_input_port())
    builder.Connect(sel.get_output_port(), enc.wheel_angles_input)
    truth = builder.AddNamedSystem(
        f"{name}.truth", BodyPoseVector(body_index=rover.chassis.index())
    )
    builder.Connect(plant.get_body_poses_output_port(), truth.body_poses_input)
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), truth.body_spatial_velocities_input
    )
    return RoverHandles(
        model=rover,
        contact=contact,
        kinematics=kin,
        imu=imu,
        star_tracker=st,
        encoders=enc,
        truth=truth,
        wheel=wheel,
        soil=soil,
    )


def spawn_pose(
    *, heightfield, rover: RoverModel, x_m: float, y_m: float, yaw_rad: float, soil: tm.SoilParams
) -> RigidTransform:
    """Chassis pose that sets the rover on the terrain at (x, y) with heading ``yaw``.

    The chassis is pitched/rolled to the plane through the terrain under the four wheel
    centres and raised so the lowest wheel rests at its static Bekker sinkage.

    Raises:
        OutOfBoundsError: a wheel would be off the raster. NoDataError: over a NaN hole.
    """
    d = rover.description
    wc = np.asarray(d.wheel_centres_C(), dtype=float)
    Rz = RotationMatrix.MakeZRotation(yaw_rad)
    pts = (Rz.matrix() @ wc.T).T[:, :2] + [x_m, y_m]
    try:
        zt = heightfield.height(pts[:, 0], pts[:, 1])
    except OutOfBoundsError as exc:
        raise OutOfBoundsError(f"rover spawn at ({x_m:.2f}, {y_m:.2f}) m: {exc}") from exc
    except NoDataError as exc:
        raise NoDataError(
            f"rover spawn at ({x_m:.2f}, {y_m:.2f}) m is over a nodata hole: {exc}"
        ) from exc
    # Least-squares plane z = a + bx*X + by*Y through the wheel contact points.
    A = np.c_[np.ones(len(pts)), pts - [x_m, y_m]]
    a, bx, by = np.linalg.lstsq(A, zt, rcond=None)[0]
    n = np.array([-bx, -by, 1.0])
    n /= np.linalg.norm(n)
    heading = Rz.matrix()[:, 0]
    fwd = heading - n * heading.dot(n)
    fwd /= np.linalg.norm(fwd)
    R = RotationMatrix(np.column_stack([fwd, np.cross(n, fwd), n]))
    wheel = tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m)
    load = float(np.max(rover.static_wheel_load_N)) if len(rover.static_wheel_load_N) else 0.0
    sink = float(tm.static_sinkage(load, wheel=wheel, soil=soil)) if load > 0 else 0.0
    # Chassis origin above the plane so the wheels touch at static sinkage.
    wc_z = wc[:, 2].min()
    h = -wc_z + d.wheel_radius_m - sink
    p = np.array([x_m, y_m, a]) + h * n
    # Wheels over bumps: raise so no wheel centre is below its terrain + radius - sink.
    R_m = R.matrix()
    centres = p + wc @ R_m.T
    z_need = heightfield.height(centres[:, 0], centres[:, 1]) + d.wheel_radius_m - sink
    p[2] += max(0.0, float(np.max(z_need - centres[:, 2])))
    return RigidTransform(R, p)


def check_soil_name(name: str) -> tm.SoilParams:
    """The soil preset named in a scenario (ConfigError listing the presets if unknown)."""
    try:
        return tm.soil_preset(name)
    except Exception as exc:
        raise ConfigError(str(exc)) from exc
