"""GroundPerception (ground "stereo, visual odometry and mapping"): the downlinked stereo
frames through :func:`~lunar_drake.perception.ground_pipeline.perception_step`."""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector

from lunar_drake.comms.images import decode_frame
from lunar_drake.perception.ground_pipeline import (
    PerceptionConfig,
    PerceptionState,
    perception_step,
    planar_correction,
)
from lunar_drake.systems.leaf import Leaf


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


class _Batch:
    """Frames in work on the ground's worker thread: when their result takes effect
    (``t_ready``, s), its future, the last message seq they hold. Kept in abstract
    state without copies."""

    __slots__ = ("future", "last_seq", "t_ready")

    def __init__(self, *, t_ready: float, future, last_seq: int):
        self.t_ready = float(t_ready)
        self.future = future
        self.last_seq = int(last_seq)

    def __deepcopy__(self, memo):
        return self


class GroundPerception(Leaf):
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
    lethal cells. State (abstract): the PerceptionState in effect, and the batches in
    work: ((t_ready, future, last seq), ...).

    With ``config.processing_s > 0`` a tick's frames are processed on this system's
    worker thread and the result takes effect at the first tick at or after ``t +
    processing_s`` (the outputs show the state in effect, never one in work); batches
    chain in order (each starts from the one before). The result is the same state a
    step in the tick would give, only later; it depends on simulated time alone, not on
    how fast the worker is.
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
        self._work = self.DeclareAbstractState(AbstractValue.Make(()))
        self._pool = None  # the worker thread, started by the first deferred batch
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
        return self.own_context(context).get_abstract_state(self._state).get_value()

    def _update(self, context, state):
        t = context.get_time()
        st = context.get_abstract_state(self._state).get_value()
        work = context.get_abstract_state(self._work).get_value()
        # batches due by now take effect, in order
        done = 0
        while done < len(work) and work[done].t_ready <= t:
            st = work[done].future.result()
            done += 1
        work = work[done:]
        last_seq = work[-1].last_seq if work else st.last_seq
        new = [(d.message.seq, d.message.payload) for d in self.images_input.Eval(context)
               if d.message.seq > last_seq]  # fmt: skip
        if new:
            step = functools.partial(self._step, new=new)
            delay = self._config.processing_s
            if delay > 0.0:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(1, thread_name_prefix="lunar_drake.ground")
                before = work[-1].future if work else None

                def chained(before=before, st=st):
                    return step(before.result() if before is not None else st)

                batch = _Batch(t_ready=t + delay, future=self._pool.submit(chained),
                               last_seq=new[-1][0])  # fmt: skip
                work = (*work, batch)
            else:
                st = step(st)
        state.get_mutable_abstract_state(self._state).set_value(st)
        state.get_mutable_abstract_state(self._work).set_value(work)

    def _step(self, st: PerceptionState, *, new) -> PerceptionState:
        """One batch of frames through the pipeline (touches no Context: it may run on
        the worker thread)."""

        def decode(buf, codec=new[0][1].codec):
            return decode_frame(buf, codec=codec, adc_bits=self._adc_bits)

        return perception_step(
            st, new, calib=self._calib, camera_in_chassis=self._X_BC, decode=decode,
            prior=self._prior, rover=self._rover, hazards=self._hazards, config=self._config,
        )  # fmt: skip
