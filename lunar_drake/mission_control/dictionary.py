"""The telemetry dictionary: every point mission control shows, and the conversion of
what the ground received into datums ``(key, t_s, value)``.

Times are simulation seconds of reception on the ground; displays show them as UTC
(``site.epoch_utc`` + t). Nothing here reads truth.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lunar_drake.autonomy.commands import MODES, SAFE_REASONS
from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS


@dc.dataclass(frozen=True)
class Point:
    """One telemetry point: ``key`` (dotted), display ``name``, ``units``, ``format``
    (``float``, ``int``, ``enum`` with ``enum`` names by index, or ``string``) and the
    ``group`` it is listed under."""

    key: str
    name: str
    units: str = ""
    format: str = "float"
    enum: tuple = ()
    group: str = "rover"

    def to_json(self) -> dict:
        d = {"key": self.key, "name": self.name, "units": self.units,
             "format": self.format, "group": self.group}  # fmt: skip
        if self.enum:
            d["enum"] = list(self.enum)
        return d


#: Cautions and warnings (the ``cw.*`` points): 0 nominal, 1 active.
CAUTIONS = {
    "cw.safed": "Rover safed",
    "cw.uplink_loss": "Uplink loss (safed on board)",
    "cw.loss_of_signal": "No telemetry for 3 periods (LOS: Earth below the horizon or link)",
    "cw.low_soc": "Low state of charge",
    "cw.earth_below_horizon": "Earth predicted below the horizon (ground's map; LOS expected)",
}

POINTS: tuple[Point, ...] = (
    Point("mission.time", "Mission elapsed time (the displays' clock)", "s", group="mission"),
    Point("rover.x", "Estimated x (on board)", "m"),
    Point("rover.y", "Estimated y (on board)", "m"),
    Point("rover.z", "Estimated height change (on board)", "m"),
    Point("rover.roll", "Roll (on board)", "deg"),
    Point("rover.pitch", "Pitch (on board)", "deg"),
    Point("rover.yaw", "Heading (on board)", "deg"),
    Point("rover.speed", "Speed (from the downlinked estimates)", "m/s"),
    Point("rover.slip", "Estimated slip (1 - speed / commanded)", "%"),
    Point("rover.cmd_vx", "Commanded speed", "m/s"),
    Point("rover.cmd_vy", "Commanded sideways speed (crab)", "m/s"),
    Point("rover.cmd_wz", "Commanded turn rate", "deg/s"),
    Point("rover.brake", "Brakes", "", "enum", ("released", "applied")),
    Point("rover.mode", "Mode", "", "enum", MODES),
    Point("rover.safe_reason", "Safe reason", "", "enum", ("none", *SAFE_REASONS[1:])),
    Point("rover.command_seq", "Newest command handled", "", "int"),
    Point("rover.motion_seq", "Newest drive command accepted", "", "int"),
    Point("rover.mode_changes", "Mode changes on board", "", "int"),
    Point("rover.soc", "Battery state of charge", "%"),
    Point("rover.array_power", "Solar array power", "W"),
    Point("link.delay", "Telemetry latency (sent to received)", "s", group="link"),
    Point("link.lost", "Telemetry packets lost (seq gaps)", "", "int", group="link"),
    Point("link.received", "Telemetry packets received", "", "int", group="link"),
    Point("link.packet_age", "Age of the newest telemetry packet", "s", group="link"),
    Point("link.commands_sent", "Commands sent up", "", "int", group="link"),
    Point("link.uplink_queue", "Commands sent, not yet handled on board", "", "int",
          group="link"),
    Point("link.frames", "Stereo frames received", "", "int", group="link"),
    Point("link.frame_delay", "Stereo frame latency (capture to received)", "s", group="link"),
    Point("ground.x", "Ground estimate x (with VO)", "m", group="ground"),
    Point("ground.y", "Ground estimate y (with VO)", "m", group="ground"),
    Point("ground.z", "Ground estimate height change", "m", group="ground"),
    Point("ground.yaw", "Ground estimate heading", "deg", group="ground"),
    Point("ground.sigma", "Ground position sigma (per axis, since the first keyframe)", "m",
          group="ground"),
    Point("ground.keyframes", "Stereo keyframes processed", "", "int", group="ground"),
    Point("ground.vo_accepted", "VO alignments fused", "", "int", group="ground"),
    Point("ground.vo_rejected", "VO alignments rejected or gated", "", "int", group="ground"),
    Point("ground.stereo_lethal", "Costmap cells stereo made lethal", "", "int",
          group="ground"),
    Point("ground.map_version", "Costmap version", "", "int", group="ground"),
    Point("ground.active_goal", "Goal being driven (1-based; 0 none)", "", "int",
          group="ground"),
    Point("ground.goal_distance", "Ground estimate to the active goal", "m", group="ground"),
    Point("ground.plan_left", "Planned path left to drive", "m", group="ground"),
    Point("ground.replans", "Replans of the active goal", "", "int", group="ground"),
    Point("ground.resends", "Gotos sent again for want of an acknowledgement", "", "int",
          group="ground"),
    Point("ground.auto_resumes", "Automatic resumes", "", "int", group="ground"),
    Point("ground.goals_reached", "Goals reached (ground's judgement)", "", "int", group="ground"),
    Point("ground.goals", "Goals given", "", "int", group="ground"),
    Point("ground.event", "Ground event", "", "string", group="ground"),
    Point("nss.weh", "NSS water-equivalent hydrogen (ground estimate)", "wt%", group="science"),
    Point("nss.epithermal", "NSS epithermal counts", "counts", group="science"),
    Point("nss.thermal", "NSS thermal counts", "counts", group="science"),
    Point("nirvss.ice", "NIRVSS ice band depth", "-", group="science"),
    Point("nirvss.oh", "NIRVSS OH band depth", "-", group="science"),
    Point("lcs.temperature", "LCS surface temperature", "K", group="science"),
    Point("sky.sun_elevation", "Sun elevation (predicted)", "deg", group="sky"),
    Point("sky.sun_azimuth", "Sun azimuth from true north (predicted)", "deg", group="sky"),
    Point("sky.earth_elevation", "Earth elevation (predicted)", "deg", group="sky"),
    Point("sky.earth_azimuth", "Earth azimuth from true north (predicted)", "deg", group="sky"),
    Point("sky.earth_margin", "Earth above the map's horizon at the ground's estimate "
          "(predicted)", "deg", group="sky"),
    *(Point(k, n, "", "enum", ("nominal", "ACTIVE"), group="cw") for k, n in CAUTIONS.items()),
)

BY_KEY = {p.key: p for p in POINTS}
#: The points stamped with a telemetry packet's reception (:meth:`Converter.packet`);
#: the others are stamped at the ground's tick or a product's reception.
PACKET_KEYS = frozenset({k for k in BY_KEY if k.startswith("rover.")}
                        | {"link.delay", "link.lost", "link.received"})  # fmt: skip
_F = {name: k for k, name in enumerate(TELEMETRY_FIELDS)}


@dc.dataclass
class Converter:
    """Turns telemetry packets into datums, packet after packet (it remembers the one
    before for speed, slip and lost packets).

    Attributes: ``telemetry_period_s`` (the rover's telemetry period: three without a
    packet raise ``cw.loss_of_signal``), ``min_soc`` (the low-SOC caution, 0-1).
    """

    telemetry_period_s: float = 1.0
    min_soc: float = 0.2
    prev: tuple | None = None  # (seq, t_sent, x, y, vx_cmd)
    lost: int = 0
    received: int = 0
    los: bool = False

    def packet(self, *, seq: int, t_sent: float, t_received: float, packet) -> list:
        """The datums of one received packet, all stamped ``t_received`` (s)."""
        p = np.asarray(packet, np.float64)
        t = float(t_received)
        deg = math.degrees
        out = [
            ("rover.x", t, float(p[_F["x_m"]])),
            ("rover.y", t, float(p[_F["y_m"]])),
            ("rover.z", t, float(p[_F["z_rel_m"]])),
            ("rover.roll", t, deg(p[_F["roll_rad"]])),
            ("rover.pitch", t, deg(p[_F["pitch_rad"]])),
            ("rover.yaw", t, deg(p[_F["yaw_rad"]])),
            ("rover.cmd_vx", t, float(p[_F["vx_cmd_mps"]])),
            ("rover.cmd_vy", t, float(p[_F["vy_cmd_mps"]])),
            ("rover.cmd_wz", t, deg(p[_F["wz_cmd_radps"]])),
            ("rover.brake", t, int(p[_F["brake"]] > 0.5)),
            ("rover.mode", t, int(p[_F["mode"]])),
            ("rover.safe_reason", t, int(p[_F["safe_reason"]])),
            ("rover.command_seq", t, int(p[_F["command_seq"]])),
            ("rover.motion_seq", t, int(p[_F["motion_seq"]])),
            ("rover.mode_changes", t, int(p[_F["mode_changes"]])),
            ("link.delay", t, float(t_received - t_sent)),
        ]
        soc, array = float(p[_F["soc"]]), float(p[_F["array_W"]])
        if math.isfinite(soc):
            out.append(("rover.soc", t, 100.0 * soc))
            out.append(("cw.low_soc", t, int(soc < self.min_soc)))
        if math.isfinite(array):
            out.append(("rover.array_power", t, array))
        x, y, vx = float(p[_F["x_m"]]), float(p[_F["y_m"]]), float(p[_F["vx_cmd_mps"]])
        if self.prev is not None:
            pseq, pt, px, py, pvx = self.prev
            self.lost += max(0, int(seq) - pseq - 1)
            dt = float(t_sent) - pt
            if dt > 0 and int(seq) == pseq + 1:
                speed = math.hypot(x - px, y - py) / dt
                out.append(("rover.speed", t, speed))
                if abs(pvx) > 0.01 and abs(vx) > 0.01:
                    out.append(("rover.slip", t, 100.0 * (1.0 - speed / abs(pvx))))
        self.prev = (int(seq), float(t_sent), x, y, vx)
        self.received += 1
        out.append(("link.lost", t, self.lost))
        out.append(("link.received", t, self.received))
        mode = MODES[int(p[_F["mode"]])] if 0 <= int(p[_F["mode"]]) < len(MODES) else ""
        reason = int(p[_F["safe_reason"]])
        out.append(("cw.safed", t, int(mode == "safed")))
        out.append(("cw.uplink_loss", t, int(mode == "safed" and 0 <= reason < len(SAFE_REASONS)
                                             and SAFE_REASONS[reason] == "uplink_loss")))
        if self.los:
            self.los = False
            out.append(("cw.loss_of_signal", t, 0))
        return out

    def tick(self, *, now_s: float, last_received_s: float | None) -> list:
        """``cw.loss_of_signal`` when no packet came for three telemetry periods."""
        if self.los or last_received_s is None:
            return []
        if now_s - last_received_s > 3.0 * self.telemetry_period_s:
            self.los = True
            return [("cw.loss_of_signal", float(now_s), 1)]
        return []


def ground_pose_datums(t_s: float, pose) -> list:
    """Datums of the ground's pose estimate (x, y, z, roll, pitch, yaw; m, rad) at ``t_s``."""
    t = float(t_s)
    return [("ground.x", t, float(pose[0])), ("ground.y", t, float(pose[1])),
            ("ground.z", t, float(pose[2])),
            ("ground.yaw", t, math.degrees(float(pose[5])))]  # fmt: skip


def _tel(packet, name: str, default: float = math.nan) -> float:
    return default if packet is None else float(np.asarray(packet)[_F[name]])


def operator_datums(t_s: float, ops, pose) -> list:
    """Datums of the ground operator's state ``ops`` (an
    :class:`~lunar_drake.autonomy.operations.OperatorState`) at ``t_s`` with the
    ground's ``pose`` (x, y, ...; m): goal driving, replans, the uplink's commands."""
    t = float(t_s)
    x, y = float(pose[0]), float(pose[1])
    out = [("ground.active_goal", t, int(ops.active) + 1),
           ("ground.replans", t, int(ops.replans)),
           ("ground.resends", t, int(ops.resends)),
           ("ground.auto_resumes", t, int(ops.resumes)),
           ("link.commands_sent", t, int(ops.next_seq))]  # fmt: skip
    handled = _tel(ops.packet, "command_seq", -1.0)
    out.append(("link.uplink_queue", t, max(0, int(ops.next_seq) - 1 - int(handled))))
    if math.isfinite(ops.t_received):
        out.append(("link.packet_age", t, max(0.0, t - float(ops.t_received))))
    if 0 <= ops.active < len(ops.goals):
        gx, gy = ops.goals[ops.active][:2]
        out.append(("ground.goal_distance", t, math.hypot(float(gx) - x, float(gy) - y)))
    if ops.path:
        pts = np.asarray([p[:2] for p in ops.path], np.float64)
        k = int(np.argmin(np.hypot(pts[:, 0] - x, pts[:, 1] - y)))  # nearest waypoint on
        rest = np.vstack([[x, y], pts[k:]])
        out.append(("ground.plan_left", t,
                    float(np.sum(np.hypot(*np.diff(rest, axis=0).T)))))  # fmt: skip
    return out


@dc.dataclass
class KeyframeCounter:
    """Counts the ground perception's keyframes as they come (``ground.keyframes``,
    ``ground.vo_accepted``, ``ground.vo_rejected``, ``ground.stereo_lethal``)."""

    keyframes: int = 0
    accepted: int = 0
    rejected: int = 0
    lethal: int = 0

    def datums(self, t_s: float, new_records, *, sigma_m: float, version: int) -> list:
        """Datums at ``t_s`` after the records ``new_records`` (KeyframeRecords)."""
        for r in new_records:
            self.keyframes += 1
            self.accepted += r.vo == "accepted"
            self.rejected += r.vo in ("rejected", "gated")
            self.lethal += int(r.new_lethal)
        t = float(t_s)
        out = [("ground.keyframes", t, self.keyframes), ("ground.vo_accepted", t, self.accepted),
               ("ground.vo_rejected", t, self.rejected), ("ground.stereo_lethal", t, self.lethal),
               ("ground.map_version", t, int(version))]  # fmt: skip
        if math.isfinite(sigma_m):
            out.append(("ground.sigma", t, float(sigma_m)))
        return out


def event_datum(event) -> tuple:
    """The ``ground.event`` datum of a ground :class:`~lunar_drake.autonomy.operations.Event`."""
    text = event.kind + (f": {event.detail}" if event.detail else "")
    return ("ground.event", float(event.t_s), text)


def goal_datums(t_s: float, status) -> list:
    """``ground.goals`` and ``ground.goals_reached`` from the goals' status tuple."""
    t = float(t_s)
    return [("ground.goals", t, len(status)),
            ("ground.goals_reached", t, sum(s == "reached" for s in status))]  # fmt: skip


#: Heat layers of the site map: name -> (the science record's instrument, what it shows).
HEAT_LAYERS = {"nss_weh": ("nss", "NSS water-equivalent hydrogen (wt%)"),
               "nirvss_ice": ("nirvss", "NIRVSS ice band depth"),
               "lcs_temperature": ("nirvss", "LCS surface temperature (K)")}  # fmt: skip


def science_datums(t_received_s: float, record, *, nss_config=None) -> tuple[list, dict]:
    """Datums of one received science record and its heat-map samples
    ``{layer: (x, y, value)}`` at the on-board estimate carried with it."""
    from lunar_drake.science.nirvss import BANDS

    t = float(t_received_s)
    x, y = float(record.pose_estimate[0]), float(record.pose_estimate[1])
    v = record.values
    if record.instrument == "nss" and nss_config is not None:
        from lunar_drake.science.nss import weh_from_epithermal

        weh = float(weh_from_epithermal(v[0], record.integration_s, config=nss_config))
        if not math.isfinite(weh):  # no counts: no estimate
            return [("nss.epithermal", t, float(v[0])), ("nss.thermal", t, float(v[1]))], {}
        return ([("nss.weh", t, weh), ("nss.epithermal", t, float(v[0])),
                 ("nss.thermal", t, float(v[1]))], {"nss_weh": (x, y, weh)})  # fmt: skip
    if record.instrument == "nirvss":
        ice, oh, temp = float(v[BANDS.index("ice")]), float(v[BANDS.index("oh")]), float(v[-1])
        return ([("nirvss.ice", t, ice), ("nirvss.oh", t, oh), ("lcs.temperature", t, temp)],
                {"nirvss_ice": (x, y, ice), "lcs_temperature": (x, y, temp)})  # fmt: skip
    return [], {}
