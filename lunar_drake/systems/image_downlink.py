"""ImagePacketizer (flight) and ImageReceiver (ground): camera frames over the downlink
(:mod:`lunar_drake.comms.images`)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue

from lunar_drake.comms.images import ImageDownlinkConfig, StereoFrame, encode_frames
from lunar_drake.comms.messages import Message
from lunar_drake.systems.leaf import Leaf
from lunar_drake.systems.receiver import TopicReceiver

TOPIC = "images"


class ImagePacketizer(Leaf):
    """Flight: compresses each selected stereo frame into an ``images`` message.

    .. pydrake_system::

        name: ImagePacketizer
        input_ports:
        - frame_index
        - left.raw
        - right.raw
        - pose_estimate
        - gimbal_command
        output_ports:
        - images

    Every ``period_s`` from ``offset_s`` (just after a frame is delivered) it checks the
    camera's ``frame_index``; a new frame whose index is a multiple of
    ``config.every_n_frames`` is encoded (:func:`~lunar_drake.comms.images.encode_frames`)
    and published: ``images`` is an outbox (a tuple with the newest message; topic
    ``images``, seq = frames sent so far, payload a
    :class:`~lunar_drake.comms.images.StereoFrame`). Inputs are camera sensor outputs
    and, for the frame header, the flight EKF's ``pose_estimate`` (6,) and the
    ``gimbal_command`` (pan, tilt; rad), both latched every ``period_s`` from 0 (the
    capture instants); left unconnected they go down as NaN. State (abstract): (last
    frame index seen, frames sent, outbox), and the latched (pose, pan/tilt).
    """

    def __init__(self, *, config: ImageDownlinkConfig, period_s: float, offset_s: float):
        super().__init__()
        config.validate()
        self._config = config
        self._period = float(period_s)
        self.frame_index_input = self.DeclareVectorInputPort("frame_index", 1)
        blank = AbstractValue.Make(np.zeros((1, 1), np.uint16))
        self.left_input = self.DeclareAbstractInputPort("left.raw", blank)
        self.right_input = self.DeclareAbstractInputPort("right.raw", blank.Clone())
        self.pose_input = self.DeclareVectorInputPort("pose_estimate", 6)
        self.gimbal_input = self.DeclareVectorInputPort("gimbal_command", 2)
        self._state = self.DeclareAbstractState(AbstractValue.Make((-1, 0, ())))
        nan = (math.nan,) * 6, (math.nan, math.nan), 0.0
        self._latched = self.DeclareAbstractState(AbstractValue.Make(nan))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._latch)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, offset_s, self._update)
        self.images_output = self.DeclareAbstractOutputPort(
            TOPIC,
            lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(c.get_abstract_state(self._state).get_value()[2]),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def _latch(self, context, state):
        def read(port, n):
            return (
                tuple(float(v) for v in port.Eval(context))
                if port.HasValue(context)
                else ((math.nan,) * n)
            )

        _, old, t_changed = context.get_abstract_state(self._latched).get_value()
        pan_tilt = read(self.gimbal_input, 2)
        if any(abs(a - b) > 1e-4 for a, b in zip(pan_tilt, old, strict=True)):
            t_changed = context.get_time() if math.isfinite(old[0]) else t_changed
        value = (read(self.pose_input, 6), pan_tilt, t_changed)
        state.get_mutable_abstract_state(self._latched).set_value(value)

    def _update(self, context, state):
        last, sent, previous = context.get_abstract_state(self._state).get_value()
        k = int(self.frame_index_input.Eval(context)[0])
        if k < 0 or k == last:
            if previous:  # the outbox holds only what the latest update made
                state.get_mutable_abstract_state(self._state).set_value((last, sent, ()))
            return
        outbox = ()
        pose, pan_tilt, t_changed = context.get_abstract_state(self._latched).get_value()
        if k % self._config.every_n_frames == 0:
            left, right = encode_frames(
                [self.left_input.Eval(context), self.right_input.Eval(context)],
                config=self._config,
            )
            frame = StereoFrame(
                frame_index=k,
                t_capture_s=k * self._period,
                codec=self._config.codec,
                left=left,
                right=right,
                pose_estimate=pose,
                pan_tilt_rad=pan_tilt,
                gimbal_steady_s=k * self._period - t_changed,
            )
            msg = Message(topic=TOPIC, seq=sent, t_sent_s=context.get_time(), payload=frame,
                          size_bytes=frame.size_bytes())  # fmt: skip
            outbox, sent = (msg,), sent + 1
        state.get_mutable_abstract_state(self._state).set_value((k, sent, outbox))


class ImageReceiver(TopicReceiver):
    """Ground: takes in the stereo frames the downlink delivered, in order, once each
    (:class:`~lunar_drake.systems.receiver.TopicReceiver` of ``images``;
    ``frames_received`` (1,) counts them)."""

    def __init__(self, *, rate_hz: float):
        super().__init__(topic=TOPIC, count_name="frames_received", rate_hz=rate_hz)
        self.images_input = self.inbox_input
        self.frames_received_output = self.count_output
