"""WheelRegolithContact: terramechanics wheel-soil forces on the Heightfield (DESIGN.md
decision 2), applied through the plant's applied-spatial-force input."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce, SpatialVelocity
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import (
    AbstractParameterIndex,
    BasicVector,
    DiscreteStateIndex,
    ValueProducer,
)

from lunar_drake.dynamics import contact_kernels as ck
from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics import tree_kinematics as tk
from lunar_drake.dynamics.contact_geometry import (
    FootprintSampling,
    belly_penetration,
    footprint_pattern,
    wheel_contact_geometry,
)
from lunar_drake.dynamics.tree_kinematics import TreeKinematics
from lunar_drake.errors import ConfigError
from lunar_drake.systems.leaf import Leaf
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


class _Kinematics(NamedTuple):
    """Stage 1 of a contact evaluation: everything that does not depend on the patch state
    (footprint geometry, loads, slip, the Wong-Reece forces, belly contact)."""

    values: np.ndarray  # contact_kernels.pack_stage1's blocks (wheel_state: drawbar pull 0)
    on: np.ndarray  # (n,) wheel on the raster
    const: np.ndarray  # the soil's kernel constants (contact_kernels.soil_constants)
    belly: tuple | None  # (force, moment about the chassis origin), world
    off: bool  # any wheel or belly point off the raster


class _Contact(NamedTuple):
    """Stage 2: the forces with the patch state (what the outputs are computed from)."""

    F6: np.ndarray  # (n, 6) [moment about each wheel centre, force on it], world
    state: np.ndarray  # (n, len(WHEEL_STATE_FIELDS)) wheel_state rows
    belly: tuple | None
    off: bool


class WheelRegolithContact(Leaf):
    """Per-wheel soil contact from the Heightfield: one Wong-Reece wheel per wheel (normal
    and Janosi-Hanamoto shear stresses over the contact angle give the load carried at
    the current sinkage and slip, the traction, compaction resistance and torque, and
    lateral shear plus bulldozing versus slip angle), a static shear patch that holds a
    wheel at rest; plus stiff penalty contact at chassis belly points (rock and belly
    strikes, from the same raster).

    .. pydrake_system::

        name: WheelRegolithContact
        input_ports:
        - body_poses (without tree)
        - body_spatial_velocities (without tree)
        - plant_state (with tree)
        - heightfield
        output_ports:
        - spatial_forces
        - generalized_force (with tree)
        - wheel_state
        - off_terrain

    Forces are computed from the plant state at the start of each step and held over
    it (explicit); the soil law is soft enough (lunar parameters) that a 5 ms
    step is stable. Each wheel's force acts at its contact point, with a torque that
    sets the soil moment about the axle to the Wong-Reece value. Wheels whose footprint
    leaves the raster (or touches nodata) get no force and raise ``off_terrain`` (1.0),
    which a simulator monitor turns into a clean stop.

    Static shear patch (module docstring of :mod:`lunar_drake.dynamics.terramechanics`):
    each wheel's patch shear displacement ``j = (j_x, j_y)`` (m, contact frame) is
    discrete state, ``2 n`` values ordered ``[j_x0, j_y0, j_x1, ...]``, advanced every
    ``time_step_s`` (the plant's time step) by a periodic discrete update,
    :func:`~lunar_drake.dynamics.terramechanics.update_patch_displacement`. Below a
    rolling speed ``|r omega|`` of ``patch.static_speed_mps`` the tangential force is the
    patch's static (Mohr-Coulomb / Janosi-Hanamoto) force, above
    ``patch.dynamic_speed_mps`` the Wong-Reece forces, blended smoothly in between; the
    ``drawbar_pull_N`` column is the blended net force along the wheel heading.

    The evaluation is split in two stages so that the footprint geometry and the
    Wong-Reece forces are computed once per step: the kinematics (everything but the
    patch force; from the inputs and the soil), cached and read by the patch update and
    the outputs, and the forces (kinematics plus patch state), computed by each output
    (the plant reads one of them each step). Drake's discrete MultibodyPlant
    (with sampled output ports, the default) steps in an unrestricted update, which the
    Simulator applies before discrete updates; so the patch update sees the plant's new
    state (a semi-implicit step of ``j``) and evaluates the kinematics that the next
    step's forces reuse, and only the cheap second stage is redone for the new ``j``.
    Both stages and the patch update are compiled
    (:mod:`lunar_drake.dynamics.contact_kernels`: terramechanics' formulas, one call each).

    The bodies' poses and spatial velocities come from the plant's ``body_poses`` and
    ``body_spatial_velocities`` ports, or, given ``tree`` (the plant's joint tree,
    :func:`~lunar_drake.models.plant_tree.tree_kinematics_from_plant`), from its state
    port ``plant_state`` (``[q, v]``) through the compiled forward kinematics of
    :mod:`lunar_drake.dynamics.tree_kinematics` (the same values to round-off, without
    converting two lists of every body to Python each step). With ``tree`` the same
    forces are also offered as ``generalized_force`` (nv,), the plant's generalized
    forces ``J^T F`` of them (:func:`~lunar_drake.dynamics.tree_kinematics.
    generalized_forces`), for the plant's ``applied_generalized_force`` port: the same
    dynamics to round-off, without building ``ExternallyAppliedSpatialForce`` objects.

    The soil is an abstract *parameter* (default: the ``soil`` argument), so a Context
    may carry another soil without rebuilding the diagram (:meth:`get_soil`,
    :meth:`set_soil`).

    Args:
        wheel_bodies: BodyIndex of each wheel (axle = body +y, origin at the centre).
        wheel: wheel radius and width. soil: default soil parameters.
        belly_body: BodyIndex of the chassis; belly_points_B: (k, 3) points in it (m).
        belly_stiffness_N_per_m, belly_damping_Ns_per_m, belly_friction: penalty law
            per belly point.
        sampling: footprint sampling. v_eps: slip regularization speed (m/s).
        direction_eps: speed (m/s) over which the compaction resistance fades in.
        time_step_s: period of the patch update (s); the plant's time step.
        patch: static shear patch parameters (default :class:`ShearPatchParams()
            <lunar_drake.dynamics.terramechanics.ShearPatchParams>`).
        tree: the plant's joint tree: read the bodies from a ``plant_state`` port
            instead of the two list ports (``body_poses_input`` and
            ``body_spatial_velocities_input`` are then None).
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
        time_step_s: float = 0.01,
        patch: tm.ShearPatchParams | None = None,
        tree: TreeKinematics | None = None,
    ):
        super().__init__()
        self._wheels = [int(b) for b in wheel_bodies]
        if not self._wheels:
            raise ValueError("wheel_bodies must be a non-empty list of BodyIndex")
        if not isinstance(soil, tm.SoilParams):
            raise TypeError(f"soil must be a SoilParams, got {type(soil).__name__}")
        self._wheel = wheel
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
        self._dt = float(time_step_s)
        if not (np.isfinite(self._dt) and self._dt > 0.0):
            raise ValueError(f"time_step_s = {time_step_s!r} must be a positive number")
        self._patch = tm.ShearPatchParams() if patch is None else patch
        if not isinstance(self._patch, tm.ShearPatchParams):
            raise TypeError(f"patch must be a ShearPatchParams, got {type(patch).__name__}")
        self._wheel_index_objs = [BodyIndex(int(b)) for b in wheel_bodies]
        self._belly_obj = None if belly_body is None else BodyIndex(int(belly_body))
        self._force_buffer = []
        for b in self._wheel_index_objs + ([self._belly_obj] if self._belly_obj else []):
            e = ExternallyAppliedSpatialForce()
            e.body_index = b
            e.p_BoBq_B = np.zeros(3)
            self._force_buffer.append(e)
        n = len(self._wheels)
        self._n = n
        self._bodies = self._wheels + ([] if self._belly is None else [self._belly])
        self._memo = None  # (soil, kernel parameters) of the last soil seen
        # (heightfield, its kernel arguments, the footprint pattern) of the last raster seen
        self._raster_memo = None
        self._radius = float(wheel.radius_m)
        self._X = np.empty((len(self._bodies), 3, 4))  # scratch of _compute_kinematics
        self._V = np.empty((len(self._bodies), 6))
        self._soil_index = self.DeclareAbstractParameter(AbstractValue.Make(soil))
        self._patch_index = self.DeclareDiscreteState(2 * n)
        self.DeclarePeriodicDiscreteUpdateEvent(
            period_sec=self._dt, offset_sec=0.0, update=self._update_patch
        )
        self._tree = None  # (kernel arguments, bodies) of the compiled kinematics
        self.body_poses_input = self.body_spatial_velocities_input = self.plant_state_input = None
        if tree is None:
            self.body_poses_input = self.DeclareAbstractInputPort(
                "body_poses", AbstractValue.Make([RigidTransform()])
            )
            self.body_spatial_velocities_input = self.DeclareAbstractInputPort(
                "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
            )
            kinematic_inputs = (self.body_poses_input, self.body_spatial_velocities_input)
        else:
            if min(self._bodies) < 0 or max(self._bodies) >= tree.n_bodies:
                raise ConfigError(
                    f"bodies {self._bodies}: a BodyIndex of the tree is 0..{tree.n_bodies - 1}"
                )
            self._tree = (tk.kernel_args(tree), np.asarray(self._bodies, np.int64))
            self.plant_state_input = self.DeclareVectorInputPort("plant_state", tree.nq + tree.nv)
            kinematic_inputs = (self.plant_state_input,)
        self.heightfield_input = self.DeclareAbstractInputPort(
            "heightfield",
            AbstractValue.Make(Heightfield.from_array(np.zeros((4, 4)), resolution_m=1.0)),
        )
        # One contact evaluation per step, in two stages: the kinematics (geometry, loads,
        # slip, Wong-Reece forces; from the inputs and the soil), cached and shared by the
        # patch update and the outputs, and the forces (kinematics + patch state).
        # Drake's discrete plant (sampled output ports) steps in an unrestricted update,
        # which the Simulator applies before discrete updates: the patch update therefore
        # sees the plant's new state and computes the kinematics that the next step's
        # forces reuse; only stage 2 is recomputed after the patch state changes.
        soil_ticket = self.abstract_parameter_ticket(AbstractParameterIndex(self._soil_index))
        self._kinematics = self.DeclareCacheEntry(
            description="wheel-soil contact kinematics",
            value_producer=ValueProducer(
                allocate=lambda: AbstractValue.Make(None),
                calc=lambda context, out: out.set_value(self._compute_kinematics(context)),
            ),
            prerequisites_of_calc={
                *(self.input_port_ticket(p.get_index()) for p in kinematic_inputs),
                self.input_port_ticket(self.heightfield_input.get_index()),
                soil_ticket,
            },
        )
        # Stage 2 (the forces with the patch state) is cheap and each output computes it
        # from the cached stage 1: the plant reads one force output per step, the rest
        # (wheel_state for logs) far less often.
        cached = {
            self._kinematics.ticket(),
            self.discrete_state_ticket(DiscreteStateIndex(self._patch_index)),
            soil_ticket,
        }
        self.spatial_forces_output = self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            self._calc_forces,
            prerequisites_of_calc=cached,
        )
        self.wheel_state_output = self.DeclareVectorOutputPort(
            "wheel_state",
            BasicVector(len(WHEEL_STATE_FIELDS) * n),
            self._calc_wheel_state,
            prerequisites_of_calc=cached,
        )
        self.off_terrain_output = self.DeclareVectorOutputPort(
            "off_terrain",
            BasicVector(1),
            self._calc_off_terrain,
            prerequisites_of_calc={self._kinematics.ticket()},
        )
        self.generalized_force_output = None
        if tree is not None:
            self._F_W = np.zeros((len(self._bodies), 6))  # scratch of _calc_generalized_force
            self._gf_args = tk.kernel_args(tree)
            self.generalized_force_output = self.DeclareVectorOutputPort(
                "generalized_force",
                BasicVector(tree.nv),
                self._calc_generalized_force,
                prerequisites_of_calc={
                    *cached,
                    self.input_port_ticket(self.plant_state_input.get_index()),
                },
            )

    # -- parameters and state -------------------------------------------------------------
    def get_soil(self, context) -> tm.SoilParams:
        """The soil in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._soil_index).get_value()

    def set_soil(self, context, soil: tm.SoilParams) -> None:
        """Replaces the soil in ``context``."""
        if not isinstance(soil, tm.SoilParams):
            raise TypeError(f"soil must be a SoilParams, got {type(soil).__name__}")
        context.get_mutable_abstract_parameter(self._soil_index).set_value(soil)

    def get_patch_displacement(self, context) -> np.ndarray:
        """(n, 2) patch shear displacement ``(j_x, j_y)`` (m, contact frame) in ``context``."""
        return context.get_discrete_state(self._patch_index).value().reshape(self._n, 2)

    def set_patch_displacement(self, context, j) -> None:
        """Sets the (n, 2) patch shear displacement (m) in ``context``."""
        j = np.asarray(j, dtype=float)
        if j.shape != (self._n, 2):
            raise ValueError(f"patch displacement must have shape ({self._n}, 2), got {j.shape}")
        context.get_mutable_discrete_state(self._patch_index).SetFromVector(j.ravel())

    # -- core ---------------------------------------------------------------------------
    def _compute_kinematics(self, context) -> _Kinematics:
        hf = self.heightfield_input.Eval(context)
        par, const = self._constants(self.get_soil(context))
        n = self._n
        # the wheels' and the chassis' poses and velocities, one array each (scratch:
        # the kernel copies what the cache value keeps)
        X, V = self._X, self._V  # (n [+1], 3, 4), (n [+1], 6): [w, v]
        if self._tree is not None:
            args, bodies = self._tree
            tk.body_kinematics_kernel(*args, self.plant_state_input.Eval(context), bodies, X, V)
        else:
            poses = self.body_poses_input.Eval(context)
            vels = self.body_spatial_velocities_input.Eval(context)
            for k, i in enumerate(self._bodies):
                X[k] = poses[i].GetAsMatrix34()
                V[k] = vels[i].get_coeffs()
        belly_B = self._belly_pts if self._belly is not None else np.zeros((0, 3))
        memo = self._raster_memo
        if memo is None or memo[0] is not hf:
            w = self._wheel
            memo = self._raster_memo = (
                hf, hf.within_kernel_args(margin_m=hf.resolution_m),
                footprint_pattern(self._sampling, w.radius_m, w.width_m),
            )  # fmt: skip
        raster = memo[1]
        if raster is None:  # a file-backed raster: the functions one by one
            return self._kinematics_file_backed(hf, X.copy(), V.copy(), par, const, belly_B)
        values, flags, p_pts, off, touch = ck.step_kinematics(
            X, V, n, *raster, *memo[2], self._radius, par, const, belly_B
        )
        belly = None
        if touch:
            belly = self._belly_contact(hf, X, V, p_pts, values[33 * n :], flags[n:])
        return _Kinematics(values, flags[:n], const, belly, off)

    def _kinematics_file_backed(self, hf, X, V, par, const, belly_B) -> _Kinematics:
        """Stage 1 on a file-backed raster (no compiled height lookups)."""
        n = self._n
        w = self._wheel
        p = np.ascontiguousarray(X[:n, :, 3])
        axle = np.ascontiguousarray(X[:n, :, 1])  # the wheel body's +y
        v = np.ascontiguousarray(V[:n, 3:])
        wv = np.ascontiguousarray(V[:n, :3])
        g = wheel_contact_geometry(
            heightfield=hf,
            p_WWo=p,
            axle_W=axle,
            radius_m=w.radius_m,
            width_m=w.width_m,
            sampling=self._sampling,
        )
        on = ~g.off_terrain
        state, N, slip_velocity, omega_r, length, ws, fx, fy, m_soil = ck.kinematics(
            v, wv, axle, g.sinkage, g.n_W, g.forward_W, g.lateral_W, on, par, const
        )
        belly = None
        off = bool((~on).any())
        pen = np.zeros(0)
        if len(belly_B):
            p_pts = ck.points_in_world(X[n], belly_B)
            pen, n_t, off_b = belly_penetration(heightfield=hf, p_WP=p_pts)
            off = off or bool(off_b.any())
            belly = self._belly_contact(hf, X, V, p_pts, pen, ~off_b, n_t=n_t)
        values = ck.pack_stage1(
            p, axle, g.n_W, g.forward_W, g.lateral_W, g.p_WC - p, state, N, slip_velocity,
            omega_r, length, ws, fx, fy, m_soil, np.asarray(pen, float),
        )  # fmt: skip
        return _Kinematics(values, on, const, belly, off)

    def _belly_contact(self, hf, X, V, p_pts, pen, ok, *, n_t=None):
        """(force, moment about the chassis origin) in W of the penalty contact at the
        belly points below the terrain (penetration ``pen`` (k,) m, ``ok`` on the
        raster; terrain normals ``n_t`` (k, 3) where already known), or None when none
        touches."""
        touching = pen > 0
        if not touching.any():
            return None
        n = self._n
        if n_t is None:  # as belly_penetration: the terrain's normal where touching
            n_t = np.zeros((len(p_pts), 3))
            n_t[:, 2] = 1.0
            hit = ok & touching
            n_t[hit] = hf.normal(p_pts[hit, 0], p_pts[hit, 1])
        p_Bo = X[n, :, 3]
        r_b = p_pts - p_Bo
        v_pts = V[n, 3:] + np.cross(V[n, :3], r_b)
        vn = np.einsum("ij,ij->i", v_pts, n_t)
        fn = np.maximum(self._k_belly * np.clip(pen, 0, None) - self._c_belly * vn, 0)
        fn = fn * touching
        vt = v_pts - vn[:, None] * n_t
        vt_norm = np.linalg.norm(vt, axis=1)
        ft = -self._mu_belly * fn[:, None] * vt / np.maximum(vt_norm, 0.01)[:, None]
        Fb = fn[:, None] * n_t + ft
        return (Fb.sum(axis=0), np.cross(r_b, Fb).sum(axis=0))

    def _constants(self, soil: tm.SoilParams):
        """The compiled kernels' parameters of ``soil`` (remembered for the last soil
        seen: a pure function of it, not state)."""
        memo = self._memo
        if memo is None or memo[0] is not soil:
            memo = self._memo = (soil, *ck.soil_constants(
                wheel=self._wheel, soil=soil, patch=self._patch, v_eps=self._v_eps,
                direction_eps=self._dir_eps))  # fmt: skip
        return memo[1], memo[2]

    def _compute(self, context) -> _Contact:
        k = self._kinematics.Eval(context)
        j = context.get_discrete_state(self._patch_index).value().reshape(self._n, 2)
        F6, state = ck.step_forces(k.values, self._n, k.on, j, k.const)
        return _Contact(F6, state, k.belly, k.off)

    def _update_patch(self, context, discrete_state):
        k = self._kinematics.Eval(context)
        j = context.get_discrete_state(self._patch_index).value().reshape(self._n, 2)
        jn = ck.step_patch(k.values, self._n, j, self._dt, k.const,
                           self._patch.saturation_moduli)  # fmt: skip
        discrete_state.get_mutable_vector(self._patch_index).SetFromVector(jn.ravel())

    def _calc_forces(self, context, output):
        c = self._compute(context)
        # The ExternallyAppliedSpatialForce objects are scratch: set_value copies them.
        forces = self._force_buffer
        for k, e in enumerate(forces[: self._n]):
            # Applied at the centre: the force plus its moment about the centre.
            e.F_Bq_W = SpatialForce(c.F6[k])
        if c.belly is None:
            output.set_value(forces[: self._n])
            return
        forces[-1].F_Bq_W = SpatialForce(c.belly[1], c.belly[0])
        output.set_value(forces)

    def _calc_generalized_force(self, context, output):
        c = self._compute(context)
        F = self._F_W
        F[: self._n] = c.F6
        if self._belly is not None:
            if c.belly is None:
                F[self._n] = 0.0
            else:
                F[self._n, :3] = c.belly[1]
                F[self._n, 3:] = c.belly[0]
        tk.generalized_forces_kernel(
            *self._gf_args, self.plant_state_input.Eval(context), self._tree[1], F,
            output.get_mutable_value(),
        )  # fmt: skip

    def _calc_wheel_state(self, context, output):
        output.SetFromVector(self._compute(context).state.ravel())

    def _calc_off_terrain(self, context, output):
        output.SetFromVector([1.0 if self._kinematics.Eval(context).off else 0.0])
