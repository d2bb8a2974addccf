"""Compiled forward kinematics of the rover's joint tree against Drake's MultibodyPlant,
and the contact fed by it against the contact fed by the plant's body ports."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.tree_kinematics import body_kinematics
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
    x = rng.normal(size=plant.num_multibody_states())
    x[:4] /= np.linalg.norm(x[:4])  # the chassis' floating joint comes first
    if not unit_quaternion:
        x[:4] *= 1.7
    x[4:7] *= 20.0
    return x


@pytest.mark.parametrize("preset", ["explicit", "skid"])
def test_poses_and_velocities_match_drake(preset):
    _, plant, _ = _plant(preset)
    tree = tree_kinematics_from_plant(plant)
    ctx = plant.CreateDefaultContext()
    bodies = np.arange(plant.num_bodies())
    X = np.empty((len(bodies), 3, 4))
    V = np.empty((len(bodies), 6))
    rng = np.random.default_rng(7)
    for trial in range(20):
        x = _random_state(plant, rng, unit_quaternion=trial % 2 == 0)
        plant.SetPositionsAndVelocities(ctx, x)
        body_kinematics(tree, x, bodies, X, V)
        for b in bodies:
            body = plant.get_body(BodyIndex(int(b)))
            X_ref = plant.EvalBodyPoseInWorld(ctx, body).GetAsMatrix34()
            V_ref = plant.EvalBodySpatialVelocityInWorld(ctx, body).get_coeffs()
            np.testing.assert_allclose(X[b], X_ref, rtol=0, atol=1e-12)
            np.testing.assert_allclose(V[b], V_ref, rtol=0, atol=1e-11)


def test_a_wrong_state_size_is_refused():
    _, plant, _ = _plant("skid")
    tree = tree_kinematics_from_plant(plant)
    with pytest.raises(ConfigError, match=r"state has shape \(3,\)"):
        body_kinematics(tree, np.zeros(3), [1], np.empty((1, 3, 4)), np.empty((1, 6)))


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


def test_a_joint_the_kernel_does_not_model_is_refused():
    from pydrake.multibody.tree import PrismaticJoint, SpatialInertia

    b = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), b)
    body = plant.AddRigidBody("slider", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.AddJoint(PrismaticJoint("rail", plant.world_frame(), body.body_frame(), [1, 0, 0]))
    plant.Finalize()
    with pytest.raises(ConfigError, match="'rail' is 'prismatic'"):
        tree_kinematics_from_plant(plant)
