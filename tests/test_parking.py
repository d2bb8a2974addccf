"""Parking: the static shear patch of the wheel-soil contact and the wheel brakes hold a
parked rover on a slope (and let it slide where the soil cannot hold it).

The diagrams are built here from the systems (plant, TerrainSource, WheelRegolithContact,
WheelBrakes, constant or piecewise-constant sources), not from lunar_drake.diagrams.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.models.rover_description import (
    RoverDescription,
    husky_rp,
    krex2_rp,
    rover_description_from_yaml,
    rover_preset,
)
from lunar_drake.models.rover_sdf import add_rover
from lunar_drake.moon import GRAVITY_MPS2
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.wheel_brakes import (
    WheelBrakes,
    brake_stiffness,
    brake_torque,
    brake_update,
)
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS, WheelRegolithContact
from lunar_drake.terrain.heightfield import Heightfield

DT = 0.01
SOIL = tm.LUNAR_REGOLITH


# ----------------------------------------------------------------------------- helpers
def _slope(*, side_deg: float, along_deg: float, n: int = 160, res: float = 0.05) -> Heightfield:
    """Planar terrain z = x tan(along) + y tan(side) (rising ahead and to the left)."""
    yy, xx = np.mgrid[0:n, 0:n]
    x = (xx + 0.5 - n / 2) * res
    y = (n / 2 - yy - 0.5) * res
    z = x * math.tan(math.radians(along_deg)) + y * math.tan(math.radians(side_deg))
    return Heightfield.from_array(z.astype(np.float32), resolution_m=res)


def _spawn(rover, *, side_deg: float, along_deg: float) -> RigidTransform:
    """Chassis pose on the plane through the origin, heading +x (uphill along track), with
    the wheels at their static Bekker sinkage."""
    d = rover.description
    ta, ts = math.tan(math.radians(along_deg)), math.tan(math.radians(side_deg))
    n = np.array([-ta, -ts, 1.0]) / math.sqrt(1.0 + ta * ta + ts * ts)
    fwd = np.array([1.0, 0.0, ta]) / math.sqrt(1.0 + ta * ta)
    R = RotationMatrix(np.column_stack([fwd, np.cross(n, fwd), n]))
    wheel = tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m)
    sink = float(tm.equilibrium_sinkage(max(rover.static_wheel_load_N), wheel=wheel, soil=SOIL))
    h = -d.wheel_centres_C()[:, 2].min() + d.wheel_radius_m - sink
    return RigidTransform(R, h * n)


def _steps(times, values):
    """A piecewise-constant source: values[k] from times[k] on."""
    v = np.asarray(values, dtype=float)
    return TrajectorySource(PiecewisePolynomial.ZeroOrderHold(list(times), v))


class _Rig:
    """A rover on a planar slope: plant, terrain, contact, brakes and servo set-points."""

    def __init__(
        self,
        preset: str,
        *,
        side_deg: float = 0.0,
        along_deg: float = 0.0,
        brake_on_s: float | None = 0.0,
        drive_mps: float = 0.0,
        drive_until_s: float = 0.0,
        holding_torque_nm: float | None = None,
    ):
        b = DiagramBuilder()
        plant, _ = AddMultibodyPlant(
            MultibodyPlantConfig(time_step=DT, discrete_contact_approximation="sap"), b
        )
        plant.mutable_gravity_field().set_gravity_vector([0, 0, -GRAVITY_MPS2])
        rover = add_rover(plant, description=rover_preset(preset))
        plant.Finalize()
        d = rover.description
        terrain = b.AddSystem(
            TerrainSource(heightfield=_slope(side_deg=side_deg, along_deg=along_deg))
        )
        contact = b.AddSystem(
            WheelRegolithContact(
                wheel_bodies=[w.index() for w in rover.wheels],
                wheel=tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m),
                soil=SOIL,
                belly_body=rover.chassis.index(),
                belly_points_B=rover.belly_points_C,
                time_step_s=DT,
            )
        )
        b.Connect(plant.get_body_poses_output_port(), contact.body_poses_input)
        b.Connect(
            plant.get_body_spatial_velocities_output_port(),
            contact.body_spatial_velocities_input,
        )
        b.Connect(terrain.heightfield_output, contact.heightfield_input)
        b.Connect(contact.spatial_forces_output, plant.get_applied_spatial_force_input_port())
        # Servo set-points [q_d; v_d] in actuator order: drives at drive_mps until
        # drive_until_s, then zero (wheels held by the velocity servos).
        nu = plant.num_actuated_dofs(rover.model_instance)
        names = [
            plant.get_joint_actuator(a).joint().name()
            for a in plant.GetJointActuatorIndices(rover.model_instance)
        ]
        xd = np.zeros(2 * nu)
        for j in rover.drive_joints:
            xd[nu + names.index(j.name())] = drive_mps / d.wheel_radius_m
        if drive_until_s > 0.0:
            servo = b.AddSystem(_steps([0.0, drive_until_s, 1e4], np.c_[xd, 0 * xd, 0 * xd]))
        else:
            servo = b.AddSystem(ConstantVectorSource(np.zeros(2 * nu)))
        b.Connect(servo.get_output_port(), plant.get_desired_state_input_port(rover.model_instance))
        zero = b.AddSystem(ConstantVectorSource(np.zeros(nu)))
        b.Connect(zero.get_output_port(), plant.get_actuation_input_port(rover.model_instance))
        brakes = b.AddSystem(
            WheelBrakes(
                plant=plant, rover=rover, time_step_s=DT, holding_torque_nm=holding_torque_nm
            )
        )
        if brake_on_s is None or brake_on_s <= 0.0:
            cmd = b.AddSystem(ConstantVectorSource([0.0 if brake_on_s is None else 1.0]))
        else:
            cmd = b.AddSystem(_steps([0.0, brake_on_s, 1e4], [[0.0, 1.0, 1.0]]))
        b.Connect(cmd.get_output_port(), brakes.brake_command_input)
        b.Connect(plant.get_state_output_port(), brakes.state_input)
        b.Connect(brakes.generalized_force_output, plant.get_applied_generalized_force_input_port())
        self.diagram = b.Build()
        self.sim = Simulator(self.diagram)
        self.ctx = self.sim.get_mutable_context()
        self.plant, self.rover, self.contact, self.brakes = plant, rover, contact, brakes
        self.pc = plant.GetMyMutableContextFromRoot(self.ctx)
        plant.SetFloatingBaseBodyPoseInWorldFrame(
            self.pc, rover.chassis, _spawn(rover, side_deg=side_deg, along_deg=along_deg)
        )
        self.sim.Initialize()

    def advance(self, t: float):
        self.sim.AdvanceTo(t)
        return self.position(), self.speed()

    def position(self) -> np.ndarray:
        return self.plant.EvalBodyPoseInWorld(self.pc, self.rover.chassis).translation().copy()

    def speed(self) -> float:
        v = self.plant.EvalBodySpatialVelocityInWorld(self.pc, self.rover.chassis)
        return float(np.linalg.norm(v.translational()))

    def wheel_spin(self) -> np.ndarray:
        v = self.plant.GetVelocities(self.pc)
        return np.array([v[j.velocity_start()] for j in self.rover.drive_joints])

    def brake_torques(self) -> np.ndarray:
        bc = self.brakes.GetMyContextFromRoot(self.ctx)
        f = self.brakes.generalized_force_output.Eval(bc)
        return np.array([f[j.velocity_start()] for j in self.rover.drive_joints])

    def state_bytes(self) -> bytes:
        x = self.ctx.get_discrete_state()
        return b"".join(x.get_vector(i).value().tobytes() for i in range(x.num_groups()))


# --------------------------------------------------------------------- (a) holding
@pytest.mark.parametrize(
    "preset, side_deg, along_deg",
    [
        ("krex2_rp", 8.0, 0.0),
        ("krex2_rp", 0.0, 10.0),
        ("husky_rp", 8.0, 0.0),
        ("husky_rp", 0.0, 10.0),
    ],
)
def test_braked_rover_holds_within_1_cm_for_30_s(preset, side_deg, along_deg):
    # Drive 1 s at 0.1 m/s (along the contour on the side slope, uphill on the along-track
    # one), stop, brake at 1.5 s; once at rest (t = 3 s) the chassis origin must stay put.
    rig = _Rig(
        preset,
        side_deg=side_deg,
        along_deg=along_deg,
        brake_on_s=1.5,
        drive_mps=0.1,
        drive_until_s=1.0,
    )
    p0, v0 = rig.advance(3.0)
    assert v0 < 1e-3  # at rest
    p1, v1 = rig.advance(33.0)
    drift = float(np.linalg.norm(p1 - p0))
    print(f"{preset} side {side_deg} along {along_deg}: drift over 30 s = {drift * 1e3:.3f} mm")
    assert drift < 0.01  # the requirement: within 1 cm over 30 s (measured: < 0.1 mm)
    assert v1 < 1e-4
    # The brakes hold below their holding torque (they do not slip).
    assert np.all(np.abs(rig.brake_torques()) < rig.brakes.holding_torque_nm)


# ------------------------------------------------------------- (b) not a glue
@pytest.mark.parametrize("brake_on_s", [0.0, None], ids=["braked", "released"])
def test_rover_slides_on_a_slope_steeper_than_the_soil_holds(brake_on_s):
    # Patch strength c b L + N tan(phi): with phi = 35 deg the 300 kg rover can be held up
    # to ~36 deg (tan = 0.70 + cohesion). At 40 deg it slides, braked or not.
    rig = _Rig("krex2_rp", along_deg=40.0, brake_on_s=brake_on_s)
    p0, _ = rig.advance(0.5)
    p1, v1 = rig.advance(3.0)
    slid = float(np.linalg.norm(p1 - p0))
    assert slid > 0.2 and v1 > 0.1  # sliding and accelerating, not held
    assert p1[0] < p0[0]  # downhill
    if brake_on_s is not None:
        # The brakes hold the wheels (below their torque): the soil gives way, not them.
        assert np.all(np.abs(rig.wheel_spin()) < 0.02)
        assert np.all(np.abs(rig.brake_torques()) < rig.brakes.holding_torque_nm)


def test_braked_rover_holds_on_its_rated_slope():
    # 25 deg (krex2_rp's max_rated_slope_deg): the soil and the brakes hold.
    rig = _Rig("krex2_rp", along_deg=25.0, brake_on_s=0.0)
    p0, v0 = rig.advance(3.0)
    assert v0 < 1e-3
    p1, _ = rig.advance(8.0)
    assert np.linalg.norm(p1 - p0) < 1e-3


# ----------------------------------------------------------- (c) brake torque cap
def test_weak_brake_slips_at_its_holding_torque():
    # krex2_rp on 10 deg needs ~5 N m per wheel; a 0.2 N m brake slips and the rover
    # rolls away (held only by the drive servos' damping).
    rig = _Rig("krex2_rp", along_deg=10.0, brake_on_s=0.0, holding_torque_nm=0.2)
    bc = rig.brakes.GetMyContextFromRoot(rig.ctx)
    p0, _ = rig.advance(2.0)
    latch0 = rig.brakes.latched_angles(bc)
    p1, _ = rig.advance(8.0)
    assert rig.brakes.is_engaged(bc)
    np.testing.assert_allclose(np.abs(rig.brake_torques()), 0.2, rtol=1e-12)
    # The latches were dragged along: the wheels turned (rolling downhill, q decreasing).
    assert np.all(rig.brakes.latched_angles(bc) - latch0 < -0.01)
    assert p0[0] - p1[0] > 3e-3  # moved downhill (the strong brake: < 0.1 mm)


def test_brake_pure_functions():
    k, T = 1000.0, 2.0
    # Engaged spring, capped at the holding torque.
    np.testing.assert_allclose(
        brake_torque([0.001, -0.001, 0.01, -0.5], np.zeros(4), stiffness=k, holding_torque=T),
        [-1.0, 1.0, -2.0, 2.0],
    )
    # Engagement latches q; a held brake keeps its latch; a slipping one drags it to
    # within T / k = 2 mrad; release follows q.
    q = np.array([0.1, 0.2])
    latch, on = brake_update(q, np.zeros(2), False, 1.0, stiffness=k, holding_torque=T)
    assert on and np.array_equal(latch, q)
    latch2, on = brake_update(
        q + np.array([0.001, 0.5]), latch, True, 1.0, stiffness=k, holding_torque=T
    )
    np.testing.assert_allclose(latch2, [0.1, 0.7 - 0.002])
    assert on
    latch3, on = brake_update(q, latch2, True, 0.2, stiffness=k, holding_torque=T)
    assert not on and np.array_equal(latch3, q)
    # k = kd / h: half the explicit-application stability bound.
    assert brake_stiffness(drive_kd=2000.0, time_step_s=0.01) == pytest.approx(2.0e5)
    with pytest.raises(ValueError, match="time_step_s"):
        brake_stiffness(drive_kd=2000.0, time_step_s=0.0)


def test_wheel_brakes_system_ports_defaults_and_state():
    b = DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=DT, discrete_contact_approximation="sap"), b
    )
    rover = add_rover(plant, description=husky_rp())
    plant.Finalize()
    brakes = WheelBrakes(plant=plant, rover=rover)
    d = rover.description
    assert brakes.holding_torque_nm == pytest.approx(d.brake_holding_torque_nm())
    assert brakes.stiffness_nm_per_rad == pytest.approx(d.drive_kd / DT)
    assert brakes.generalized_force_output.size() == plant.num_velocities()
    assert brakes.state_input.size() == plant.num_positions() + plant.num_velocities()
    # The output depends on the state, not directly on the command.
    assert not brakes.HasDirectFeedthrough(
        brakes.brake_command_input.get_index(), brakes.generalized_force_output.get_index()
    )
    ctx = brakes.CreateDefaultContext()
    x = np.zeros(plant.num_positions() + plant.num_velocities())
    x[: plant.num_positions()] = np.arange(plant.num_positions()) * 0.01
    brakes.state_input.FixValue(ctx, x)
    brakes.brake_command_input.FixValue(ctx, [0.0])
    assert not np.any(brakes.generalized_force_output.Eval(ctx))
    # Released: the update leaves the state alone.
    xd = brakes.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).value()
    assert not np.any(xd)
    # Engage: latches the drive angles.
    brakes.brake_command_input.FixValue(ctx, [1.0])
    xd = brakes.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).value().copy()
    q_drive = np.array([x[j.position_start()] for j in rover.drive_joints])
    np.testing.assert_array_equal(xd, np.append(q_drive, 1.0))
    ctx.SetDiscreteState(xd)
    assert brakes.is_engaged(ctx)
    # The wheels turn 1 mrad forward: torque -k * 1e-3 = -300 N m, capped at T, on the
    # drive joints' velocity slots only.
    x2 = x.copy()
    for j in rover.drive_joints:
        x2[j.position_start()] += 1e-3
    brakes.state_input.FixValue(ctx, x2)
    f = brakes.generalized_force_output.Eval(ctx)
    slots = [j.velocity_start() for j in rover.drive_joints]
    np.testing.assert_allclose(f[slots], -brakes.holding_torque_nm)
    assert not np.any(np.delete(f, slots))
    with pytest.raises(ValueError, match="time_step_s"):
        WheelBrakes(plant=plant, rover=rover, time_step_s=0.0)


# --------------------------------------------------- brake torque in the description
def test_automatic_brake_torque_and_validation():
    # krex2_rp: 2 * 300 kg * 1.62 m/s^2 * sin(25 deg) * 0.25 m / 4
    #   = 2 * 486 * 0.42261826 * 0.0625 = 25.674059 N m.
    assert krex2_rp().max_rated_slope_deg == 25.0
    assert krex2_rp().brake_holding_torque_nm() == pytest.approx(25.674059, rel=1e-7)
    # husky_rp: 2 * 60 * 1.62 * sin(20 deg) * 0.165 / 4 = 194.4 * 0.34202014 * 0.04125
    #   = 2.742660 N m.
    assert husky_rp().brake_holding_torque_nm() == pytest.approx(2.742660, rel=1e-6)
    # It holds the rover on its rated slope with any two wheels.
    for d in (krex2_rp(), husky_rp()):
        demand = d.total_mass_kg() * 1.62 * math.sin(math.radians(d.max_rated_slope_deg))
        assert 2 * d.brake_holding_torque_nm() / d.wheel_radius_m == pytest.approx(demand)
    assert dc.replace(krex2_rp(), brake_torque_nm=40.0).brake_holding_torque_nm() == 40.0
    d = rover_description_from_yaml(data="{max_rated_slope_deg: 15.0}", preset="husky_rp")
    assert d.brake_holding_torque_nm() < husky_rp().brake_holding_torque_nm()
    for field, value in (
        ("max_rated_slope_deg", 0.0),
        ("max_rated_slope_deg", 75.0),
        ("brake_torque_nm", -1.0),
    ):
        with pytest.raises(OutOfRangeError, match=field):
            dc.replace(krex2_rp(), **{field: value})
    with pytest.raises(ConfigError, match="max_rated_slope_deg"):
        RoverDescription(max_rated_slope_deg="steep")


# ------------------------------------------------ contact: patch state and soil parameter
R_W = 0.25
WHEEL = tm.WheelParams(radius_m=R_W, width_m=0.2)


def _contact(*, v=(0.0, 0.0, 0.0), w_spin=0.0, z=0.012, soil=SOIL):
    sys = WheelRegolithContact(wheel_bodies=[1], wheel=WHEEL, soil=soil, time_step_s=DT)
    ctx = sys.CreateDefaultContext()
    sys.body_poses_input.FixValue(ctx, [RigidTransform(), RigidTransform([0, 0, R_W - z])])
    sys.body_spatial_velocities_input.FixValue(
        ctx,
        [
            SpatialVelocity(np.zeros(3), np.zeros(3)),
            SpatialVelocity(np.array([0.0, w_spin, 0.0]), np.asarray(v, float)),
        ],
    )
    sys.heightfield_input.FixValue(ctx, _slope(side_deg=0.0, along_deg=0.0, n=100))
    return sys, ctx


def _eval(sys, ctx):
    F = sys.spatial_forces_output.Eval(ctx)[0].F_Bq_W
    state = dict(zip(WHEEL_STATE_FIELDS, sys.wheel_state_output.Eval(ctx), strict=True))
    return F, state


def test_contact_at_rest_applies_the_static_patch_force():
    sys, ctx = _contact()
    F, st = _eval(sys, ctx)
    assert F.translational()[0] == 0.0 and F.translational()[1] == 0.0  # j = 0: no shear
    sys.set_patch_displacement(ctx, [[0.018, -0.009]])
    F, st = _eval(sys, ctx)
    # Independent of the system: strength from the reported load and sinkage.
    L = R_W * math.sin(math.acos(1.0 - st["sinkage_m"] / R_W))
    fmax = SOIL.c * 0.2 * L + st["normal_force_N"] * math.tan(SOIL.phi)
    rho = math.hypot(1.0, 0.5)
    expected = -fmax * (1.0 - math.exp(-rho)) / rho * np.array([1.0, -0.5])
    np.testing.assert_allclose(F.translational()[:2], expected, rtol=1e-9)
    assert st["drawbar_pull_N"] == pytest.approx(expected[0], rel=1e-9)
    # The patch force acts at the rim, r below the centre: its moment about the axle (+y)
    # is the lever arm's, -r F_x.
    assert F.rotational()[1] == pytest.approx(-R_W * expected[0], rel=1e-9)
    # A creeping wheel integrates the creep into the patch (j + u dt).
    sys2, ctx2 = _contact(v=(1e-3, -2e-3, 0.0))
    j = sys2.EvalUniquePeriodicDiscreteUpdate(ctx2).get_vector(0).value()
    np.testing.assert_allclose(j, [1e-3 * DT, -2e-3 * DT], rtol=1e-12)
    assert sys2.GetUniquePeriodicDiscreteUpdateAttribute().period_sec() == DT


def test_contact_at_driving_speed_ignores_the_patch_state():
    # Rolling at 0.1 m/s with 20 % slip: the static weight is exactly 0, so the forces
    # are the Wong-Reece ones whatever the patch holds (driving is unchanged).
    v = 0.1
    sys, ctx = _contact(v=(v, 0.01, 0.0), w_spin=1.25 * v / R_W)
    F0, st0 = _eval(sys, ctx)
    sys.set_patch_displacement(ctx, [[0.05, -0.03]])
    F1, st1 = _eval(sys, ctx)
    assert F0.translational().tobytes() == F1.translational().tobytes()
    assert F0.rotational().tobytes() == F1.rotational().tobytes()
    assert st0 == st1
    f = tm.wheel_forces(
        slip=st0["slip"],
        slip_angle=st0["slip_angle_rad"],
        z=st0["sinkage_m"],
        wheel=WHEEL,
        soil=SOIL,
        direction=1.0,
    )
    assert F0.translational()[0] == pytest.approx(float(f.drawbar_pull), rel=1e-9)
    # While driving the patch relaxes towards u L / |r omega| (bounded, small).
    j = sys.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).value()
    assert np.all(np.abs(j) < np.abs([0.05, 0.03]))


def test_soil_is_a_context_parameter():
    sys, ctx = _contact()
    assert sys.get_soil(ctx) == SOIL
    sys.set_patch_displacement(ctx, [[0.01, 0.0]])
    F_lunar = _eval(sys, ctx)[0].translational().copy()
    other = sys.CreateDefaultContext()
    sys.set_soil(ctx, tm.GRC1)
    assert sys.get_soil(ctx) == tm.GRC1 and sys.get_soil(other) == SOIL
    F_grc = _eval(sys, ctx)[0].translational()
    # GRC-1: phi = 33 deg, K = 1.5 cm: a different strength and stiffness, and sinkage.
    assert abs(F_grc[0] - F_lunar[0]) > 0.5
    sys.set_soil(ctx, SOIL)
    np.testing.assert_array_equal(_eval(sys, ctx)[0].translational(), F_lunar)
    with pytest.raises(TypeError, match="SoilParams"):
        sys.set_soil(ctx, "grc1")
    with pytest.raises(TypeError, match="SoilParams"):
        WheelRegolithContact(wheel_bodies=[1], wheel=WHEEL, soil="grc1")


# ------------------------------------------------------------------ (e) determinism
def test_contact_with_patch_state_is_deterministic():
    outs = []
    for _ in range(2):
        sys, ctx = _contact(v=(3e-3, -1e-3, 0.0), w_spin=0.004)
        sys.set_patch_displacement(ctx, [[0.004, -0.002]])
        F, _ = _eval(sys, ctx)
        j = sys.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).value()
        outs.append(
            F.translational().tobytes()
            + F.rotational().tobytes()
            + sys.wheel_state_output.Eval(ctx).tobytes()
            + j.tobytes()
        )
    assert outs[0] == outs[1]
    # A whole braked rover: same inputs, same bytes (plant, patch and brake states).
    runs = []
    for _ in range(2):
        rig = _Rig("husky_rp", side_deg=8.0, brake_on_s=0.3)
        rig.advance(1.0)
        runs.append(rig.state_bytes())
    assert runs[0] == runs[1]
