"""Compiled forward kinematics and generalized forces of the rover's joint tree against
Drake's MultibodyPlant, and the contact fed by it against the contact fed by the plant's
body ports."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import (
    BodyIndex,
    FixedOffsetFrame,
    MultibodyForces,
    PrismaticJoint,
    RevoluteJoint,
    SpatialInertia,
)
from pydrake.systems.framework import DiagramBuilder

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.tree_kinematics import body_kinematics, generalized_forces
from lunar_drake.errors import ConfigError
from lunar_drake.models.plant_tree import tree_kinematics_from_plant
from lunar_drake.models.rover_description import rover_preset
from lunar_drake.models.rover_sdf import add_rover
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.wheel_regolith_contact import WheelRegolithContact
from lunar_drake.terrain.heightfield import Heightfield


def _plant(preset, builder=None):
    builder = builder or DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=0.01, discrete_contact_approximation="sap"), builder
    )
    rover = add_rover(plant, description=rover_preset(preset))
    plant.Finalize()
    return builder, plant, rover


def _random_state(plant, rng, *, unit_quaternion=True):
    """Random [q, v] with each floating body's quaternion unit (or 1.7 x unit)."""
    x = rng.normal(size=plant.num_multibody_states())
    for i in plant.GetJointIndices():
        j = plant.get_joint(i)
        if j.type_name() == "quaternion_floating":
            k = j.position_start()
            x[k : k + 4] *= (1.0 if unit_quaternion else 1.7) / np.linalg.norm(x[k : k + 4])
            x[k + 4 : k + 7] *= 20.0
    return x


def _drake_generalized_forces(plant, ctx, bodies, F_W):
    """Drake's J^T F of spatial forces F_W[k] (moment, force; W) at each body's origin."""
    forces = MultibodyForces(plant)
    for b, F in zip(bodies, F_W, strict=True):
        plant.get_body(BodyIndex(int(b))).AddInForceInWorld(ctx, SpatialForce(F), forces)
    return plant.CalcGeneralizedForces(ctx, forces)


def _assert_matches_drake(plant, tree, rng, trials=20):
    ctx = plant.CreateDefaultContext()
    bodies = np.arange(plant.num_bodies())
    X = np.empty((len(bodies), 3, 4))
    V = np.empty((len(bodies), 6))
    for trial in range(trials):
        x = _random_state(plant, rng, unit_quaternion=trial % 2 == 0)
        plant.SetPositionsAndVelocities(ctx, x)
        body_kinematics(tree, x, bodies, X, V)
        for b in bodies:
            body = plant.get_body(BodyIndex(int(b)))
            X_ref = plant.EvalBodyPoseInWorld(ctx, body).GetAsMatrix34()
            V_ref = plant.EvalBodySpatialVelocityInWorld(ctx, body).get_coeffs()
            np.testing.assert_allclose(X[b], X_ref, rtol=0, atol=1e-12)
            np.testing.assert_allclose(V[b], V_ref, rtol=0, atol=1e-11)
        # every body but the world pushed at once, and each body alone
        moving = bodies[1:]
        F_W = 100.0 * rng.normal(size=(len(moving), 6))
        tau = np.full(plant.num_velocities(), np.nan)
        for sel in [slice(None), *(slice(k, k + 1) for k in range(len(moving)))]:
            generalized_forces(tree, x, moving[sel], F_W[sel], tau)
            ref = _drake_generalized_forces(plant, ctx, moving[sel], F_W[sel])
            np.testing.assert_allclose(tau, ref, rtol=0, atol=1e-10 * max(1.0, abs(ref).max()))


@pytest.mark.parametrize("preset", ["explicit", "skid"])
def test_poses_and_velocities_match_drake(preset):
    _, plant, _ = _plant(preset)
    _assert_matches_drake(plant, tree_kinematics_from_plant(plant), np.random.default_rng(7))


def test_other_bodies_and_offset_frames_match_drake():
    """Beside the rover: a second free body, a body welded off the world's origin and a
    pendulum whose joint frames are offset and rotated, about an oblique axis."""
    b = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), b)
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.1)
    plant.AddRigidBody("rock", inertia)  # free: a floating joint after the rover's
    add_rover(plant, description=rover_preset("explicit"))
    extra = plant.AddModelInstance("extra")
    post = plant.AddRigidBody("post", extra, inertia)
    X_WP = RigidTransform(RollPitchYaw(0.1, -0.2, 0.3), [1.0, 2.0, 0.5])
    plant.WeldFrames(plant.world_frame(), post.body_frame(), X_WP)
    bob = plant.AddRigidBody("bob", extra, inertia)
    F = plant.AddFrame(
        FixedOffsetFrame(
            "F", post.body_frame(), RigidTransform(RollPitchYaw(0.3, 0.0, -0.1), [0.2, 0, 0])
        )
    )
    M = plant.AddFrame(
        FixedOffsetFrame(
            "M", bob.body_frame(), RigidTransform(RollPitchYaw(0.0, 0.4, 0.2), [0, 0, -0.5])
        )
    )
    plant.AddJoint(RevoluteJoint("hinge", F, M, np.array([1.0, 2.0, 2.0]) / 3.0))
    plant.Finalize()
    _assert_matches_drake(plant, tree_kinematics_from_plant(plant), np.random.default_rng(11))


def test_wrong_sizes_and_bodies_are_refused():
    _, plant, rover = _plant("skid")
    tree = tree_kinematics_from_plant(plant)
    x = np.zeros(tree.nq + tree.nv)
    X, V = np.empty((1, 3, 4)), np.empty((1, 6))
    with pytest.raises(ConfigError, match=r"state has shape \(3,\)"):
        body_kinematics(tree, np.zeros(3), [1], X, V)
    with pytest.raises(ConfigError, match=r"state has 1 non-finite value"):
        body_kinematics(tree, np.where(np.arange(x.size) == 5, np.nan, x), [1], X, V)
    with pytest.raises(ConfigError, match=r"bodies \[99\]: a body index is 0\.\."):
        body_kinematics(tree, x, [99], X, V)
    with pytest.raises(ConfigError, match=r"2 bodies need \(2, 3, 4\)"):
        body_kinematics(tree, x, [1, 2], X, V)
    tau = np.empty(tree.nv)
    with pytest.raises(ConfigError, match=rf"2 bodies need \(2, 6\) and \({tree.nv},\)"):
        generalized_forces(tree, x, [1, 2], np.zeros((3, 6)), tau)
    with pytest.raises(ConfigError, match=r"output of shape \(2,\)"):
        generalized_forces(tree, x, [1], np.zeros((1, 6)), np.empty(2))
    with pytest.raises(ConfigError, match=r"bodies \[99\]: a body index is 0\.\."):
        generalized_forces(tree, x, [99], np.zeros((1, 6)), tau)
    with pytest.raises(ConfigError, match=r"forces have 1 non-finite value"):
        generalized_forces(tree, x, [1], np.array([[0, 0, 0, np.nan, 0, 0.0]]), tau)
    d = rover.description
    with pytest.raises(ConfigError, match=r"bodies \[\d+, -1\]: a BodyIndex of the tree"):
        WheelRegolithContact(
            wheel_bodies=[rover.wheels[0].index(), -1],
            wheel=tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m),
            soil=tm.soil_preset("lunar_regolith"),
            tree=tree,
        )


def test_contact_from_the_state_equals_contact_from_the_body_ports():
    """The same plant state through both input modes: the same forces and wheel states."""
    b = DiagramBuilder()
    b, plant, rover = _plant("explicit", b)
    z = np.zeros((64, 64))
    hf = Heightfield.from_array(z, resolution_m=0.1)
    terrain = b.AddSystem(TerrainSource(heightfield=hf))
    d = rover.description
    kw = dict(
        wheel_bodies=[w.index() for w in rover.wheels],
        wheel=tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m),
        soil=tm.soil_preset("lunar_regolith"),
        belly_body=rover.chassis.index(),
        belly_points_B=rover.belly_points_C,
    )
    ports = b.AddSystem(WheelRegolithContact(**kw))
    state = b.AddSystem(WheelRegolithContact(**kw, tree=tree_kinematics_from_plant(plant)))
    assert state.body_poses_input is None and ports.plant_state_input is None
    b.Connect(plant.get_body_poses_output_port(), ports.body_poses_input)
    b.Connect(plant.get_body_spatial_velocities_output_port(), ports.body_spatial_velocities_input)
    b.Connect(plant.get_state_output_port(), state.plant_state_input)
    for c in (ports, state):
        b.Connect(terrain.heightfield_output, c.heightfield_input)
    diagram = b.Build()
    ctx = diagram.CreateDefaultContext()
    plant_ctx = plant.GetMyMutableContextFromRoot(ctx)
    rng = np.random.default_rng(3)
    for sink_m in (0.01, 0.03):  # chassis low enough that the wheels sink in
        X_WC = RigidTransform([0.1, -0.2, d.nominal_chassis_height_m() - sink_m])
        plant.SetFreeBodyPose(plant_ctx, rover.chassis, X_WC)
        v = 0.05 * rng.normal(size=plant.num_velocities())
        plant.SetVelocities(plant_ctx, v)
        a = ports.wheel_state_output.Eval(ports.GetMyContextFromRoot(ctx))
        s = state.wheel_state_output.Eval(state.GetMyContextFromRoot(ctx))
        assert np.abs(a).max() > 0
        np.testing.assert_allclose(s, a, rtol=1e-9, atol=1e-9)
        fa = ports.spatial_forces_output.Eval(ports.GetMyContextFromRoot(ctx))
        fs = state.spatial_forces_output.Eval(state.GetMyContextFromRoot(ctx))
        for ea, es in zip(fa, fs, strict=True):
            assert ea.body_index == es.body_index
            np.testing.assert_allclose(
                es.F_Bq_W.get_coeffs(), ea.F_Bq_W.get_coeffs(), rtol=1e-9, atol=1e-7
            )
        # the generalized forces the plant's diagram applies: Drake's J^T F of the list
        assert ports.generalized_force_output is None
        tau = state.generalized_force_output.Eval(state.GetMyContextFromRoot(ctx))
        ref = _drake_generalized_forces(
            plant, plant_ctx, [e.body_index for e in fa], [e.F_Bq_W.get_coeffs() for e in fa]
        )
        assert np.abs(ref).max() > 1.0
        np.testing.assert_allclose(tau, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize(
    "make_joint, message",
    [
        # a joint type the kernel does not model
        (lambda w, b: PrismaticJoint("rail", w, b, [1, 0, 0]), r"'rail' is 'prismatic'"),
        # a joint whose child is the world (its parent farther from the world)
        (
            lambda w, b: RevoluteJoint("reversed", b, w, [0, 0, 1]),
            r"joint 'reversed': body 'world'.*exactly one joint",
        ),
    ],
    ids=["prismatic", "reversed"],
)
def test_a_tree_the_kernel_cannot_follow_is_refused(make_joint, message):
    b = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), b)
    body = plant.AddRigidBody("link", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.AddJoint(make_joint(plant.world_frame(), body.body_frame()))
    plant.Finalize()
    with pytest.raises(ConfigError, match=message):
        tree_kinematics_from_plant(plant)
