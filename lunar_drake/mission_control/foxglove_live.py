"""Foxglove live: the foxglove-sdk WebSocket server fed with what the ground received,
so Foxglove (``ws://127.0.0.1:8765``) can connect while a mission runs. The same topics
and schemas as ``run.mcap`` (:mod:`.recording`), stamped with reception time."""

from __future__ import annotations

import json

from lunar_drake.mission_control.recording import ns_since_epoch, pose_in_frame, pose_messages


class FoxgloveLive:
    """A foxglove-sdk server on ``host:port`` with the live topics; :meth:`batch` logs a
    live mission's batch (``packets``, ``events``, ``ground_pose``, ``frame``)."""

    def __init__(self, *, host: str = "127.0.0.1", port: int = 8765, epoch_utc: str):
        import foxglove
        from foxglove.channels import (
            CompressedImageChannel,
            FrameTransformChannel,
            LogChannel,
            PoseInFrameChannel,
        )

        self.ctx = foxglove.Context()
        self.server = foxglove.start_server(name="lunar_drake", host=host, port=int(port),
                                            context=self.ctx)  # fmt: skip
        self.epoch_utc = epoch_utc
        self.est = PoseInFrameChannel("/rover/pose_estimate", context=self.ctx)
        self.ground = PoseInFrameChannel("/ground/pose", context=self.ctx)
        self.tf = FrameTransformChannel("/tf", context=self.ctx)
        self.events = LogChannel("/ground/events", context=self.ctx)
        self.images = CompressedImageChannel("/camera/left/compressed", context=self.ctx)
        self.telemetry = foxglove.Channel("/telemetry", message_encoding="json", context=self.ctx)

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.server.port}"

    def batch(self, msg: dict) -> None:
        from foxglove.messages import CompressedImage, Log, LogLevel

        from lunar_drake.mission_control.recording import WARN_EVENTS, stamp

        e = self.epoch_utc
        for row in msg.get("packets", ()):
            t = row["t_received_s"]
            p = row["fields"]
            pose = pose_in_frame(e, t, p["x_m"], p["y_m"], p["z_rel_m"], p["roll_rad"],
                                 p["pitch_rad"], p["yaw_rad"])  # fmt: skip
            self.est.log(pose, log_time=ns_since_epoch(e, t))
            self.telemetry.log(json.dumps({**row["fields"], "t_received_s": t,
                                           "t_sent_s": row["t_sent_s"], "seq": row["seq"]})
                               .encode(), log_time=ns_since_epoch(e, t))  # fmt: skip
        if (g := msg.get("ground_pose")) is not None:
            t, pose6 = g
            pose, transform = pose_messages(e, t, pose6)
            self.ground.log(pose, log_time=ns_since_epoch(e, t))
            self.tf.log(transform, log_time=ns_since_epoch(e, t))
        for t, kind, detail in msg.get("events", ()):
            level = LogLevel.Warning if kind in WARN_EVENTS else LogLevel.Info
            self.events.log(Log(timestamp=stamp(e, t), level=level, name="ground", file="",
                                line=0, message=kind + (f": {detail}" if detail else "")),
                            log_time=ns_since_epoch(e, t))  # fmt: skip
        if (f := msg.get("frame")) is not None:
            t = f["t_received_s"]
            self.images.log(CompressedImage(timestamp=stamp(e, t), frame_id="left_camera",
                                            data=f["png"], format="png"),
                            log_time=ns_since_epoch(e, t))  # fmt: skip

    def close(self) -> None:
        self.server.stop()
