"""WheelRegolithContact: terramechanics wheel-soil forces on the Heightfield (DESIGN.md
decision 2), applied through the plant's applied-spatial-force input."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce, SpatialVelocity
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import BasicVector, LeafSystem, ValueProducer

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.contact_geometry import (
    FootprintSampling,
    _cross,
    belly_penetration,
    wheel_contact_geometry,
)
from lunar_drake.terrain.heightfield import Heightfield

#: Columns of the ``wheel_state`` output, per wheel.
WHEEL_STATE_FIELDS = (
    "sinkage_m",
    "normal_force_N",
    "slip",
    "slip_angle_rad",
    "drawbar_pull_N",
    "off_terrain",
)


class WheelRegolithContact(LeafSystem):
    """Per-wheel soil contact from the Heightfield: Bekker sinkage and normal force,
    Wong-Reece/Janosi-Hanamoto traction versus slip, lateral force versus slip angle,
    compaction resistance; plus stiff penalty contact at chassis belly points (rock and
    belly strikes, from the same raster).

    .. pydrake_system::

        name: WheelRegolithContact
        input_ports:
        - body_poses
        - body_spatial_velocities
        - heightfield
        output_ports:
        - spatial_forces
        - wheel_state
        - off_terrain

    Forces are computed from the plant state at the start of each step and held over
    it (explicit); the soil law is soft enough (Bekker, lunar parameters) that a 5 ms
    step is stable. Each wheel's force acts at its contact point, with a torque that
    sets the soil moment about the axle to the Wong-Reece value. Wheels whose footprint
    leaves the raster (or touches nodata) get no force and raise ``off_terrain`` (1.0),
    which a simulator monitor turns into a clean stop.

    Args:
        wheel_bodies: BodyIndex of each wheel (axle = body +y, origin at the centre).
        wheel: wheel radius and width. soil: soil parameters.
        belly_body: BodyIndex of the chassis; belly_points_B: (k, 3) points in it (m).
        belly_stiffness_N_per_m, belly_damping_Ns_per_m, belly_friction: penalty law
            per belly point.
        sampling: footprint sampling. v_eps: slip regularization speed (m/s).
    """

    def __init__(
        self,
        *,
        wheel_bodies,
        wheel: tm.WheelParams,
        soil: tm.SoilParams,
        belly_body=None,
        belly_points_B=None,
        belly_stiffness_N_per_m: float = 1.0e5,
        belly_damping_Ns_per_m: float = 3.0e3,
        belly_friction: float = 0.6,
        sampling: FootprintSampling | None = None,
        v_eps: float = 0.08,
        direction_eps: float = 0.02,
    ):
        super().__init__()
        self._wheels = [int(b) for b in wheel_bodies]
        if not self._wheels:
            raise ValueError("wheel_bodies must be a non-empty list of BodyIndex")
        self._wheel = wheel
        self._soil = soil
        self._belly = None if belly_body is None else int(belly_body)
        self._belly_pts = (
            np.zeros((0, 3)) if belly_points_B is None else np.asarray(belly_points_B, float)
        )
        self._k_belly = float(belly_stiffness_N_per_m)
        self._c_belly = float(belly_damping_Ns_per_m)
        self._mu_belly = float(belly_friction)
        self._sampling = sampling or FootprintSampling()
        self._v_eps = float(v_eps)
        self._dir_eps = float(direction_eps)
        self._wheel_index_objs = [BodyIndex(int(b)) for b in wheel_bodies]
        self._belly_obj = None if belly_body is None else BodyIndex(int(belly_body))
        n = len(self._wheels)
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.body_spatial_velocities_input = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self.heightfield_input = self.DeclareAbstractInputPort(
            "heightfield",
            AbstractValue.Make(Heightfield.from_array(np.zeros((4, 4)), resolution_m=1.0)),
        )
        # One contact evaluation per context change, shared by the three outputs.
        self._cache = self.DeclareCacheEntry(
            description="wheel-soil contact",
            value_producer=ValueProducer(
                allocate=lambda: AbstractValue.Make(None),
                calc=lambda context, out: out.set_value(self._compute(context)),
            ),
            prerequisites_of_calc={
                self.input_port_ticket(self.body_poses_input.get_index()),
                self.input_port_ticket(self.body_spatial_velocities_input.get_index()),
                self.input_port_ticket(self.heightfield_input.get_index()),
            },
        )
        self.spatial_forces_output = self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            self._calc_forces,
        )
        self.wheel_state_output = self.DeclareVectorOutputPort(
            "wheel_state", BasicVector(len(WHEEL_STATE_FIELDS) * n), self._calc_wheel_state
        )
        self.off_terrain_output = self.DeclareVectorOutputPort(
            "off_terrain", BasicVector(1), self._calc_off_terrain
        )

    # -- core ---------------------------------------------------------------------------
    def _compute(self, context):
        poses = self.body_poses_input.Eval(context)
        vels = self.body_spatial_velocities_input.Eval(context)
        hf = self.heightfield_input.Eval(context)
        w = self._wheel
        X = [poses[i] for i in self._wheels]
        p = np.array([x.translation() for x in X])
        axle = np.array([x.rotation().col(1) for x in X])
        V = [vels[i] for i in self._wheels]
        v = np.array([x.translational() for x in V])
        wv = np.array([x.rotational() for x in V])
        g = wheel_contact_geometry(
            heightfield=hf,
            p_WWo=p,
            axle_W=axle,
            radius_m=w.radius_m,
            width_m=w.width_m,
            sampling=self._sampling,
        )
        on = ~g.off_terrain
        z = np.where(on, np.clip(g.sinkage, -1.0, w.radius_m), -1.0)
        v_x = np.einsum("ij,ij->i", v, g.forward_W)
        v_y = np.einsum("ij,ij->i", v, g.lateral_W)
        z_dot = -np.einsum("ij,ij->i", v, g.n_W)
        # Absolute spin about the axle: the rim's slip against the ground does not care
        # which body the wheel hangs from (a pitching rocker must not look like slip).
        spin = np.einsum("ij,ij->i", wv, axle)
        slip = tm.slip_ratio(omega_r=spin * w.radius_m, v=v_x, v_eps=self._v_eps)
        beta = tm.slip_angle(v_x=v_x, v_y=v_y, v_eps=self._v_eps)
        N = tm.normal_force(z, z_dot, wheel=w, soil=self._soil) * on
        f = tm.wheel_forces(
            slip=slip,
            slip_angle=beta,
            W=N,
            z=z,
            wheel=w,
            soil=self._soil,
            # The soil is compacted by a wheel that translates or spins (digging in when
            # immobilized): the resistance follows v + r omega, faded out near rest.
            direction=tm.travel_direction(v_x + spin * w.radius_m, v_eps=self._dir_eps),
        )
        F = (
            N[:, None] * g.n_W
            + f.drawbar_pull[:, None] * g.forward_W
            + f.lateral[:, None] * g.lateral_W
        ) * on[:, None]
        # Moment about the centre of F at the contact point, corrected so its axle
        # component is the soil moment -torque (Wong-Reece) rather than the lever arm.
        r_c = g.p_WC - p
        M = _cross(r_c, F)
        m_axle = np.einsum("ij,ij->i", M, axle)
        tau = M + ((-f.torque * on) - m_axle)[:, None] * axle
        state = np.stack(
            [np.where(on, g.sinkage, 0.0), N, slip, beta, f.drawbar_pull * on, (~on).astype(float)],
            axis=1,
        )
        belly = None
        off = bool((~on).any())
        if self._belly is not None and len(self._belly_pts):
            X = poses[self._belly]
            V = vels[self._belly]
            Rb = X.rotation().matrix()
            p_pts = X.translation() + self._belly_pts @ Rb.T
            pen, n_t, off_b = belly_penetration(heightfield=hf, p_WP=p_pts)
            off = off or bool(off_b.any())
            touching = pen > 0
            if touching.any():
                r_b = p_pts - X.translation()
                v_pts = V.translational() + np.cross(V.rotational(), r_b)
                vn = np.einsum("ij,ij->i", v_pts, n_t)
                fn = np.maximum(self._k_belly * np.clip(pen, 0, None) - self._c_belly * vn, 0)
                fn = fn * touching
                vt = v_pts - vn[:, None] * n_t
                vt_norm = np.linalg.norm(vt, axis=1)
                ft = -self._mu_belly * fn[:, None] * vt / np.maximum(vt_norm, 0.01)[:, None]
                Fb = fn[:, None] * n_t + ft
                belly = (Fb.sum(axis=0), np.cross(r_b, Fb).sum(axis=0))
        return p, F, tau, state, belly, off

    def _cached(self, context):
        return self._cache.Eval(context)

    def _calc_forces(self, context, output):
        _p, F, tau, _, belly, _ = self._cached(context)
        forces = []
        for k, b in enumerate(self._wheel_index_objs):
            e = ExternallyAppliedSpatialForce()
            e.body_index = b
            e.p_BoBq_B = np.zeros(3)
            # Applied at the centre: the force plus its moment about the centre.
            e.F_Bq_W = SpatialForce(tau[k], F[k])
            forces.append(e)
        if belly is not None:
            e = ExternallyAppliedSpatialForce()
            e.body_index = self._belly_obj
            e.p_BoBq_B = np.zeros(3)
            e.F_Bq_W = SpatialForce(belly[1], belly[0])
            forces.append(e)
        output.set_value(forces)

    def _calc_wheel_state(self, context, output):
        _, _, _, state, _, _ = self._cached(context)
        output.SetFromVector(state.ravel())

    def _calc_off_terrain(self, context, output):
        *_, off = self._cached(context)
        output.SetFromVector([1.0 if off else 0.0])
