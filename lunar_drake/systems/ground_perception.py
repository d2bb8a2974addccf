"""GroundPerception (ground "stereo, visual odometry and mapping"): the downlinked stereo
frames through :func:`~lunar_drake.perception.ground_pipeline.perception_step`."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.comms.images import decode_frame
from lunar_drake.perception.ground_pipeline import (
    PerceptionConfig,
    PerceptionState,
    perception_step,
    planar_correction,
)


def camera_in_chassis_fn(description):
    """``f(pan, tilt)`` -> ``X_BC`` (4 x 4): the left camera in the chassis frame at
    gimbal angles (rad), from the rover's own model (a private MultibodyPlant: the
    ground's copy of the kinematics)."""
    from pydrake.multibody.plant import MultibodyPlant

    from lunar_drake.models.rover_sdf import add_rover

    plant = MultibodyPlant(0.0)
    add_rover(plant, description=description)
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    pan = plant.GetJointByName("gimbal_pan")
    tilt = plant.GetJointByName("gimbal_tilt")
    chassis = plant.GetBodyByName("chassis").body_frame()
    cam = plant.GetFrameByName("left_camera")

    def X_BC(pan_rad: float, tilt_rad: float) -> np.ndarray:
        pan.set_angle(ctx, float(pan_rad))
        tilt.set_angle(ctx, float(tilt_rad))
        return cam.CalcPose(ctx, chassis).GetAsMatrix4()

    return X_BC


class GroundPerception(LeafSystem):
    """The ground's stereo, VO and mapping.

    .. pydrake_system::

        name: GroundPerception
        input_ports:
        - images
        output_ports:
        - pose_correction
        - pose_sigma
        - costmap

    ``images`` is the image downlink's inbox (deliveries of
    :class:`~lunar_drake.comms.images.StereoFrame` messages). Every 1 / ``rate_hz`` s the
    frames delivered since the last tick go through
    :func:`~lunar_drake.perception.ground_pipeline.perception_step`. Outputs:
    ``pose_correction`` (3,) = (dx, dy, dyaw) (m, rad): the planar map from the
    on-board estimate to the ground's (``p' = Rz(dyaw) p + d``); ``pose_sigma`` (1,) the
    ground's position sigma (m, per axis; :attr:`~lunar_drake.perception.
    ground_pipeline.PerceptionState.sigma_m`); ``costmap`` (abstract):
    (version, :class:`~lunar_drake.autonomy.costmap.Costmap`), the a-priori costmap
    with the stereo hazards merged in, ``version`` counting the keyframes that added
    lethal cells. State (abstract): the PerceptionState.
    """

    def __init__(self, *, config: PerceptionConfig, rate_hz: float, calib, description,
                 prior_costmap, prior_dem, rover, hazards, adc_bits: int = 12):  # fmt: skip
        super().__init__()
        config.validate()
        self._config = config
        self._calib = calib
        self._X_BC = camera_in_chassis_fn(description)
        self._prior = prior_dem
        self._rover = rover
        self._hazards = hazards
        self._adc_bits = int(adc_bits)
        self.images_input = self.DeclareAbstractInputPort("images", AbstractValue.Make(()))
        self._state = self.DeclareAbstractState(
            AbstractValue.Make(PerceptionState(costmap=prior_costmap))
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.pose_correction_output = self.DeclareVectorOutputPort(
            "pose_correction",
            BasicVector(3),
            lambda c, o: o.SetFromVector(planar_correction(self.perception_state(c).correction)),
            prerequisites_of_calc={self.all_state_ticket()},
        )
        self.pose_sigma_output = self.DeclareVectorOutputPort(
            "pose_sigma",
            BasicVector(1),
            lambda c, o: o.SetFromVector([self.perception_state(c).sigma_m]),
            prerequisites_of_calc={self.all_state_ticket()},
        )
        self.costmap_output = self.DeclareAbstractOutputPort(
            "costmap",
            lambda: AbstractValue.Make((0, prior_costmap)),
            lambda c, o: o.set_value(
                (self.perception_state(c).version, self.perception_state(c).costmap)
            ),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def perception_state(self, context) -> PerceptionState:
        """The PerceptionState (this system's context or the root's): keyframe records,
        the elevation map, the merged costmap."""
        try:
            own = self.GetMyContextFromRoot(context)
        except RuntimeError:
            self.ValidateContext(context)
            own = context
        return own.get_abstract_state(self._state).get_value()

    def _update(self, context, state):
        st = context.get_abstract_state(self._state).get_value()
        new = [(d.message.seq, d.message.payload) for d in self.images_input.Eval(context)
               if d.message.seq > st.last_seq]  # fmt: skip
        if not new:
            return

        def decode(buf, codec=new[0][1].codec):
            return decode_frame(buf, codec=codec, adc_bits=self._adc_bits)

        st = perception_step(
            st, new, calib=self._calib, camera_in_chassis=self._X_BC, decode=decode,
            prior=self._prior, rover=self._rover, hazards=self._hazards, config=self._config,
        )  # fmt: skip
        state.get_mutable_abstract_state(self._state).set_value(st)
