"""``run.mcap``: a run as Foxglove opens it (the ``mcap`` container through
foxglove-sdk, Foxglove's standard schemas), written from the run directory's files so
that older runs convert the same way (``lunar-drake export-mcap RUN``).

Every message is stamped with the time the ground received it (``site.epoch_utc`` +
simulation time, ns): what mission control saw, when it saw it. Channels:

==========================  =================  =============================================
topic                       schema             from
==========================  =================  =============================================
``/rover/pose_estimate``    PoseInFrame        telemetry: the on-board estimate, downlinked
``/ground/pose``            PoseInFrame        the ground's estimate (with VO), 2 Hz
``/tf``                     FrameTransform     ``site`` -> ``rover`` (the ground's estimate)
``/telemetry``              JSON               every telemetry packet's fields
``/ground/events``          Log                the ground's events (safings as warnings)
``/camera/left/compressed`` CompressedImage    stereo frames the ground received (JPEG)
``/ground/keyframes``       PointCloud         where the ground's VO placed each keyframe
``/ground/points``          PointCloud         each keyframe's stereo points, as the ground
                                               mapped them (``keyframe_points.npy``)
``/ground/costmap``         Grid               the ground's final costmap (uint8 classes)
``/science/nss``            JSON               NSS records as received, with the WEH estimate
==========================  =================  =============================================
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
from pathlib import Path

import numpy as np

from lunar_drake.errors import ConfigError

#: The channels' topics, for tests and the README.
TOPICS = ("/rover/pose_estimate", "/ground/pose", "/tf", "/telemetry", "/ground/events",
          "/camera/left/compressed", "/ground/keyframes", "/ground/points", "/ground/costmap",
          "/science/nss")  # fmt: skip

def ns_since_epoch(epoch_utc: str, t_s: float) -> int:
    """Unix nanoseconds of simulation time ``t_s`` (s after ``site.epoch_utc``)."""
    epoch = _dt.datetime.fromisoformat(epoch_utc)
    if epoch.tzinfo is None:
        epoch = epoch.replace(tzinfo=_dt.timezone.utc)
    return round(epoch.timestamp()) * 1_000_000_000 + round(float(t_s) * 1e9)


def stamp(epoch_utc: str, t_s: float):
    """A foxglove Timestamp of simulation time ``t_s``."""
    from foxglove.messages import Timestamp

    n = ns_since_epoch(epoch_utc, t_s)
    return Timestamp(sec=n // 1_000_000_000, nsec=n % 1_000_000_000)


def pose_in_frame(epoch_utc: str, t_s: float, x, y, z, roll, pitch, yaw):
    """A foxglove PoseInFrame in the ``site`` frame (m, rad)."""
    return pose_messages(epoch_utc, t_s, (x, y, z, roll, pitch, yaw))[0]


def pose_messages(epoch_utc: str, t_s: float, pose6) -> tuple:
    """(PoseInFrame in ``site``, FrameTransform ``site`` -> ``rover``) of a pose (x, y,
    z, roll, pitch, yaw; m, rad) at simulation time ``t_s``."""
    from foxglove.messages import FrameTransform, Pose, PoseInFrame, Vector3

    x, y, z, roll, pitch, yaw = (float(v) for v in pose6)

    def parts():
        return stamp(epoch_utc, t_s), Vector3(x=x, y=y, z=z), _quat(roll, pitch, yaw)

    ts, p, q = parts()
    pif = PoseInFrame(timestamp=ts, frame_id="site", pose=Pose(position=p, orientation=q))
    ts, p, q = parts()
    tf = FrameTransform(timestamp=ts, parent_frame_id="site", child_frame_id="rover",
                        translation=p, rotation=q)  # fmt: skip
    return pif, tf


#: JPEG quality of the stereo frames in ``run.mcap`` (the 8-bit previews the run saved).
JPEG_QUALITY = 85
_POSE6 = ("x_m", "y_m", "z_rel_m", "roll_rad", "pitch_rad", "yaw_rad")
#: Ground events logged as warnings.
WARN_EVENTS = ("safed", "goal_failed", "no_ack", "left_safed", "charging")


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _jpeg(png: Path, quality: int = JPEG_QUALITY) -> bytes:
    """A saved 8-bit preview frame re-encoded as JPEG (a quarter of the PNG's bytes)."""
    import cv2

    image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ConfigError(f"could not encode {str(png)!r} as JPEG")
    return buf.tobytes()


def _quat(roll: float, pitch: float, yaw: float):
    from foxglove.messages import Quaternion

    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return Quaternion(x=sr * cp * cy - cr * sp * sy, y=cr * sp * cy + sr * cp * sy,
                      z=cr * cp * sy - sr * sp * cy, w=cr * cp * cy + sr * sp * sy)  # fmt: skip


def _point_cloud(epoch_utc: str, t_s: float, points):
    """A foxglove PointCloud in the ``site`` frame: ``points`` (N, 3; m) as x, y, z
    float32."""
    from foxglove.messages import (
        PackedElementField,
        PackedElementFieldNumericType,
        PointCloud,
        Pose,
        Vector3,
    )

    f32 = PackedElementFieldNumericType.Float32
    pts = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3))
    return PointCloud(timestamp=stamp(epoch_utc, t_s), frame_id="site",
                      pose=Pose(position=Vector3(x=0, y=0, z=0), orientation=_quat(0, 0, 0)),
                      point_stride=12,
                      fields=[PackedElementField(name=n, offset=4 * k, type=f32)
                              for k, n in enumerate("xyz")],
                      data=pts.tobytes())  # fmt: skip


def _keyframe_points(d: Path, kf: list[dict]) -> list[tuple[float, np.ndarray]]:
    """Per row of ``keyframes.csv`` (``kf``), the time the ground received its frame
    (``images.csv``; its capture time if not listed; s) and the points it mapped from it
    (``keyframe_points.npy``: (N, 3) float32, m, site frame); none without that file."""
    path = d / "keyframe_points.npy"
    if not path.is_file():
        return []
    rows = np.load(path, allow_pickle=False)
    if rows.dtype.names is None or not {"frame_index", "x", "y", "z"} <= set(rows.dtype.names):
        raise ConfigError(f"{str(path)!r} holds no (frame_index, x, y, z) rows")
    received = {}
    for r in _rows(d / "images.csv"):
        received.setdefault(int(r["frame_index"]), float(r["t_received_s"]))
    out = []
    for r in kf:
        k = int(float(r["frame_index"]))
        sel = rows[rows["frame_index"] == k]
        pts = np.stack([sel["x"], sel["y"], sel["z"]], axis=1).astype(np.float32)
        out.append((received.get(k, float(r["t_capture_s"])), pts))
    return out


def check_run_dir(run_dir: str | Path) -> Path:
    """``run_dir`` as a Path if it holds a run (``scenario.yaml`` and ``telemetry.csv``),
    else :class:`~lunar_drake.errors.ConfigError`."""
    d = Path(run_dir)
    if not (d / "scenario.yaml").is_file() or not (d / "telemetry.csv").is_file():
        raise ConfigError(f"{str(d)!r} is not a run directory (no scenario.yaml and "
                          "telemetry.csv; lunar-drake run writes them)")  # fmt: skip
    return d


def write_run_mcap(run_dir: str | Path, *, out: str | Path | None = None,
                   costmap=None, prior_costmap=None) -> Path:  # fmt: skip
    """Writes ``run.mcap`` (or ``out``) from the files of ``run_dir``; ``costmap`` (the
    run's final ground costmap, when at hand) adds ``/ground/costmap``. Returns its path.

    Raises:
        ConfigError: ``run_dir`` is not a run directory.
    """
    import foxglove
    from foxglove.channels import (
        CompressedImageChannel,
        FrameTransformChannel,
        GridChannel,
        LogChannel,
        PointCloudChannel,
        PoseInFrameChannel,
    )
    from foxglove.messages import (
        CompressedImage,
        Grid,
        Log,
        LogLevel,
        PackedElementField,
        PackedElementFieldNumericType,
        Pose,
        Vector2,
        Vector3,
    )

    from lunar_drake.scenario_files import load_scenario

    d = check_run_dir(run_dir)
    e = load_scenario(filename=d / "scenario.yaml").site.epoch_utc

    def ns(t_s: float) -> int:
        return ns_since_epoch(e, t_s)

    path = Path(out) if out is not None else d / "run.mcap"
    tmp = path.with_name(path.name + ".partial")
    tmp.unlink(missing_ok=True)
    ctx = foxglove.Context()
    writer = foxglove.open_mcap(tmp, context=ctx)
    try:
        messages = []  # (log_time ns, order, channel, message): written in time order

        def add(t_s, channel, msg):
            messages.append((ns(t_s), len(messages), channel, msg))

        est = PoseInFrameChannel("/rover/pose_estimate", context=ctx)
        telemetry = foxglove.Channel("/telemetry", message_encoding="json", context=ctx)
        for r in _rows(d / "telemetry.csv"):
            t = float(r["t_received_s"])
            pose6 = [float(r[k]) for k in _POSE6]
            add(t, est, pose_in_frame(e, t, *pose6))
            add(t, telemetry, {k: (float(v) if v not in ("", None) else None)
                               for k, v in r.items()})  # fmt: skip
        ground = PoseInFrameChannel("/ground/pose", context=ctx)
        tf = FrameTransformChannel("/tf", context=ctx)
        last = -math.inf
        for r in _rows(d / "ground_pose.csv"):
            t = float(r["t_s"])
            if t - last < 0.5 - 1e-9:
                continue
            last = t
            pose, transform = pose_messages(e, t, [float(r[k]) for k in _POSE6])
            add(t, ground, pose)
            add(t, tf, transform)
        events = LogChannel("/ground/events", context=ctx)
        for r in _rows(d / "ground_events.csv"):
            t = float(r["t_s"])
            level = LogLevel.Warning if r["event"] in WARN_EVENTS else LogLevel.Info
            text = r["event"] + (f": {r['detail']}" if r["detail"] else "")
            add(t, events, Log(timestamp=stamp(e, t), level=level, message=text, name="ground",
                               file="", line=0))  # fmt: skip
        images = CompressedImageChannel("/camera/left/compressed", context=ctx)
        for r in _rows(d / "images.csv"):
            f = d / "frames" / f"left_{int(r['frame_index']):06d}_preview.png"
            if f.is_file():
                t = float(r["t_received_s"])
                add(t, images, CompressedImage(timestamp=stamp(e, t), frame_id="left_camera",
                                               data=_jpeg(f), format="jpeg"))  # fmt: skip
        kf = [r for r in _rows(d / "keyframes.csv") if r.get("x_m") not in (None, "")]
        if kf:
            cloud = PointCloudChannel("/ground/keyframes", context=ctx)
            pts = np.array([[float(r["x_m"]), float(r["y_m"]), 0.0] for r in kf], np.float32)
            t = float(kf[-1]["t_capture_s"])
            add(t, cloud, _point_cloud(e, t, pts))
        mapped = _keyframe_points(d, kf)
        if mapped:
            points = PointCloudChannel("/ground/points", context=ctx)
            for t, pts in mapped:
                add(t, points, _point_cloud(e, t, pts))
        if costmap is not None:
            from lunar_drake.mission_control.live import costmap_classes

            cls = costmap_classes(costmap, prior_costmap)[::-1]  # row 0 south: +y up
            grid = GridChannel("/ground/costmap", context=ctx)
            res = float(costmap.resolution_m)
            y0 = costmap.y1_m - cls.shape[0] * res
            t_s = max((m[0] for m in messages), default=ns(0.0))
            t_s = (t_s - ns(0.0)) / 1e9
            add(t_s, grid, Grid(
                timestamp=stamp(e, t_s), frame_id="site",
                pose=Pose(position=Vector3(x=costmap.x0_m, y=y0, z=0), orientation=_quat(0, 0, 0)),
                column_count=cls.shape[1], cell_size=Vector2(x=res, y=res),
                row_stride=cls.shape[1], cell_stride=1,
                fields=[PackedElementField(name="class", offset=0,
                                           type=PackedElementFieldNumericType.Uint8)],
                data=np.ascontiguousarray(cls).tobytes()))  # fmt: skip
        nss = _rows(d / "nss.csv")
        if nss:
            ch = foxglove.Channel("/science/nss", message_encoding="json", context=ctx)
            for r in nss:
                add(float(r["t_received_s"]), ch, {k: float(v) for k, v in r.items()})
        messages.sort(key=lambda m: (m[0], m[1]))
        for t, _, channel, msg in messages:
            if isinstance(msg, dict):
                channel.log(json.dumps(msg, sort_keys=True).encode(), log_time=t)
            else:
                channel.log(msg, log_time=t)
    finally:
        writer.close()
    tmp.replace(path)
    return path
