"""The simulation side of a live mission: :class:`LiveObserver` runs between the
simulator's steps (an :data:`~lunar_drake.simulation.Observer`), publishes what the
ground received since the last call and applies the commands that came from the network.

It talks to the server through two queues (``multiprocessing`` ones across processes):
``outbox`` gets messages ``{"kind": ..., ...}`` (``site`` once, then ``batch``,
``reply`` and finally ``done``); ``inbox`` holds requests ``{"id", "op", ...}`` with
``op`` one of ``command`` (a :func:`~lunar_drake.mission_control.commands.parse_command`
body), ``preview`` (plan a goal without sending it) and ``end`` (stop the mission).
"""

from __future__ import annotations

import io
import math
import queue
import time

import numpy as np

from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS
from lunar_drake.errors import LunarDrakeError
from lunar_drake.mission_control import dictionary as dic
from lunar_drake.mission_control.commands import (
    apply_command,
    as_action,
    next_tick_s,
    parse_command,
)

#: The stop reason of a mission ended from mission control.
ENDED = "ended from mission control"
#: Costmap cell classes sent to displays: free, lethal on the a-priori map, lethal until
#: stereo confirms it (an unconfirmed orbital slope), lethal found by stereo.
COSTMAP_CLASSES = ("free", "lethal_prior", "unconfirmed", "lethal_stereo")


def costmap_classes(costmap, prior=None) -> np.ndarray:
    """(rows, cols) uint8 of :data:`COSTMAP_CLASSES` for ``costmap`` (lethal cells of
    ``prior``, the a-priori costmap on the same grid, are ``lethal_prior``)."""
    lethal = ~np.isfinite(costmap.cost)
    out = np.zeros(costmap.cost.shape, np.uint8)
    if prior is not None and prior.cost.shape == costmap.cost.shape:
        was = ~np.isfinite(prior.cost)
        out[lethal & was] = 1
        out[lethal & ~was] = 3
    else:
        out[lethal] = 1
    if costmap.unconfirmed is not None:
        out[lethal & costmap.unconfirmed.astype(bool)] = 2
    return out


def png_bytes(image: np.ndarray) -> bytes:
    """PNG of a uint8 (rows, cols) or (rows, cols, 3|4) array."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def hillshade_u8(z: np.ndarray, resolution_m: float) -> np.ndarray:
    """A uint8 hillshade (Sun from the north-west, 35 deg up) of heights ``z`` (m)."""
    from lunar_drake.science.world import hillshade

    return (255.0 * np.clip(hillshade(np.asarray(z, np.float64), resolution_m), 0, 1)).astype(
        np.uint8
    )


class LiveObserver:
    """Publishes the ground's news and applies network commands (module docstring).

    Args:
        outbox, inbox: the queues (``put`` / ``get_nowait``).
        frame_width_px: stereo previews are scaled to this width.
        pose_period_s: how often the ground's pose estimate is published (s, sim time).
        costmap_period_s: the costmap is sent at most this often (s, sim time).
        alive: ``alive()`` -> whether the server is still there (None: assume so); when
            it has gone, nothing more is published and the run goes on.
        instructor: also publish the plant's ``truth.pose`` (x, y, yaw) every
            ``pose_period_s`` for the instructor overlay (an oracle, marked so on the
            page; never in the telemetry dictionary or to the ground).
    """

    def __init__(self, *, outbox, inbox, frame_width_px: int = 320,
                 pose_period_s: float = 0.5, costmap_period_s: float = 2.0,
                 alive=None, instructor: bool = False):  # fmt: skip
        self.outbox, self.inbox = outbox, inbox
        self.alive, self._gone = alive, False
        self.instructor = bool(instructor)
        self.ended_s: float | None = None
        self.frame_width_px = int(frame_width_px)
        self.pose_period_s = float(pose_period_s)
        self.costmap_period_s = float(costmap_period_s)
        self.actions: list = []  # the commands applied, as OperatorActions
        self._started = False
        self._n_tel = self._n_events = self._n_images = self._n_science = 0
        self._next_pose = 0.0
        self._next_costmap = 0.0
        self._costmap_version = -1
        self._goals = None
        self._plan = None
        self._last_rx = None
        self._conv = None
        self._sky = None
        self._kf = dic.KeyframeCounter()
        self._n_kf = 0

    # ----------------------------------------------------------------------- observer

    def __call__(self, run) -> str | None:
        if self.alive is not None and not self.alive():
            if not self._gone:
                self._gone = True
                print("mission control: the server process has gone; the run goes on",
                      flush=True)  # fmt: skip
            return None
        root = run.root
        now = run.time_s
        if not self._started:
            self._start(run)
        why = self._handle_requests(run, root, now)
        if why is not None:
            self.ended_s = now
        datums, extra = self._news(run, root, now)
        datums.append(("mission.time", now, now))
        if datums or extra:
            self.outbox.put({"kind": "batch", "t_s": now, "wall": time.time(),
                             "datums": datums, **extra})  # fmt: skip
        return why

    def _start(self, run) -> None:
        self._started = True
        sc = run.scenario
        self._conv = dic.Converter(telemetry_period_s=1.0 / sc.flight.telemetry_rate_hz,
                                   min_soc=sc.flight.safety.min_soc)  # fmt: skip
        mp = run.map_product
        try:
            from lunar_drake.mission_control.sky import SkyPrediction

            self._sky = SkyPrediction(scenario=sc, map_product=mp)
        except LunarDrakeError as exc:  # no ephemeris for this epoch: no sky points
            print(f"mission control: no sky prediction ({exc})", flush=True)
        site = {"kind": "site", "epoch_utc": sc.site.epoch_utc, "name": sc.name or "",
                "duration_s": float(sc.simulation_duration), "map_source": mp.source,
                "extent_m": [mp.x0_m, mp.x0_m + mp.shape[1] * mp.resolution_m,
                             mp.y1_m - mp.shape[0] * mp.resolution_m, mp.y1_m],
                "hillshade_png": png_bytes(hillshade_u8(mp.z, mp.resolution_m)),
                "spawn_xy": [sc.rover.spawn_x_m, sc.rover.spawn_y_m],
                "ground_rate_hz": float(sc.ground.rate_hz),
                "instructor": self.instructor}  # fmt: skip
        self.outbox.put(site)

    def _handle_requests(self, run, root, now: float) -> str | None:
        why = None
        while True:
            try:
                req = self.inbox.get_nowait()
            except queue.Empty:
                return why
            rid, op = req.get("id"), req.get("op")
            if req.get("expires") is not None and time.time() > req["expires"]:
                self._reply(rid, ok=False, error="the request expired before the mission "
                                                 "could take it; nothing was sent")  # fmt: skip
                continue
            try:
                if why is not None:
                    self._reply(rid, ok=False, error="the mission is ending")
                elif op == "end":
                    why = "ended from mission control"
                    self._reply(rid, ok=True, t_s=now)
                elif op == "preview":
                    path = self._preview(run, root, float(req["x_m"]), float(req["y_m"]))
                    self._reply(rid, ok=True, t_s=now, path=path)
                elif op == "command":
                    cmd = parse_command(req.get("command"))
                    apply_command(run.operator, root, cmd)
                    t_up = next_tick_s(now, run.scenario.ground.rate_hz)
                    self.actions.append(as_action(cmd, t_s=t_up))
                    self._reply(rid, ok=True, t_s=t_up, command=cmd,
                                warning=self._safed_warning(run, root, cmd))  # fmt: skip
                else:
                    self._reply(rid, ok=False, error=f"unknown request {op!r}")
            except LunarDrakeError as exc:
                self._reply(rid, ok=False, error=str(exc))
            except Exception as exc:  # a request must never end the mission
                self._reply(rid, ok=False, error=f"{type(exc).__name__}: {exc}")

    def _safed_warning(self, run, root, cmd) -> str:
        """A warning for a drive command while the newest telemetry says safed."""
        from lunar_drake.autonomy.commands import MODES, SAFE_REASONS

        packet = run.operator.operator_state(root).packet
        if packet is None or cmd["action"] not in ("goal", "drive_arc"):
            return ""
        mode = int(packet[TELEMETRY_FIELDS.index("mode")])
        if MODES[mode] != "safed":
            return ""
        why = SAFE_REASONS[int(packet[TELEMETRY_FIELDS.index("safe_reason")])]
        return (f"the rover reports safed ({why}): it ignores driving until a resume "
                "(the ground resumes on its own when auto_resume allows)")

    def _reply(self, rid, **kw) -> None:
        self.outbox.put({"kind": "reply", "id": rid, **kw})

    def _costmap(self, run, root):
        gp = run.ground_system("ground.perception")
        if gp is not None:
            st = gp.perception_state(root)
            if st.costmap is not None:
                return st.version, st.costmap
        return 0, run.operator.prior_costmap

    def _prior_costmap(self, run):
        """The a-priori costmap on the grid of the ground's merged costmap (what stereo
        changed shows against it)."""
        if not hasattr(self, "_prior"):
            gp = run.ground_system("ground.perception")
            self._prior = (gp.costmap_output.Allocate().get_value()[1] if gp is not None
                           else run.operator.prior_costmap)  # fmt: skip
        return self._prior

    def _preview(self, run, root, x: float, y: float) -> list:
        """The path the ground would plan to (x, y) from its estimate now."""
        from lunar_drake.autonomy.operations import goal_shift_limit_m
        from lunar_drake.systems.ground_operator import plan_waypoints

        _, costmap = self._costmap(run, root)
        if costmap is None:
            return []
        pose = run.mission.GetOutputPort("ground.pose_estimate").Eval(
            run.mission.GetMyContextFromRoot(root)
        )
        plan = plan_waypoints(costmap, goal_free_radius_m=goal_shift_limit_m(run.operator.params))
        return [list(p) for p in plan((float(pose[0]), float(pose[1])), (x, y))]

    def _news(self, run, root, now: float):
        datums: list = []
        extra: dict = {}
        rx = run.ground_system("ground.telemetry")
        rctx = rx.GetMyContextFromRoot(root)
        packets = []
        for d in rx.received_since(rctx, self._n_tel):
            m = d.message
            datums += self._conv.packet(seq=m.seq, t_sent=m.t_sent_s,
                                        t_received=d.t_received_s, packet=m.payload)  # fmt: skip
            packets.append({"seq": int(m.seq), "t_sent_s": float(m.t_sent_s),
                            "t_received_s": float(d.t_received_s),
                            "fields": dict(zip(TELEMETRY_FIELDS, map(float, m.payload),
                                               strict=True))})  # fmt: skip
            self._last_rx = d.t_received_s
            self._n_tel += 1
        if packets:
            extra["packets"] = packets
        datums += self._conv.tick(now_s=now, last_received_s=self._last_rx)
        ops = run.operator.operator_state(root)
        events = ops.events.since(self._n_events)
        self._n_events += len(events)
        datums += [dic.event_datum(ev) for ev in events]
        if events:
            extra["events"] = [(float(ev.t_s), ev.kind, ev.detail) for ev in events]
        if now >= self._next_pose - 1e-9:
            self._next_pose = now + self.pose_period_s
            pose = run.mission.GetOutputPort("ground.pose_estimate").Eval(
                run.mission.GetMyContextFromRoot(root)
            )
            datums += dic.ground_pose_datums(now, pose)
            datums += dic.operator_datums(now, ops, pose)
            extra["ground_pose"] = (now, [float(v) for v in pose])
            if (gp := run.ground_system("ground.perception")) is not None:
                st = gp.perception_state(root)
                new = st.records.since(self._n_kf)
                self._n_kf += len(new)
                datums += self._kf.datums(now, new, sigma_m=st.sigma_m, version=st.version)
            if self.instructor:  # the oracle: the page marks it as truth
                truth = run.mission.GetOutputPort("truth.pose").Eval(
                    run.mission.GetMyContextFromRoot(root)
                )
                extra["truth_pose"] = [now, float(truth[0]), float(truth[1]), float(truth[5])]
            if self._sky is not None and self._sky.due(now):
                datums += self._sky.datums(now, pose)
            # states that change seldom, repeated so a display opened later has them
            datums += dic.goal_datums(now, ops.status)
            datums.append(("cw.loss_of_signal", now, int(self._conv.los)))
        goals = (ops.goals, ops.status)
        if goals != self._goals:
            self._goals = goals
            datums += dic.goal_datums(now, ops.status)
            extra["goals"] = [[float(g[0]), float(g[1]), s]
                              for g, s in zip(ops.goals, ops.status, strict=True)]  # fmt: skip
        plan = (ops.goto_seq, ops.path)
        if plan != self._plan:
            self._plan = plan
            extra["plan"] = {"seq": int(ops.goto_seq),
                             "path": [[float(x), float(y)] for x, y in ops.path]}  # fmt: skip
        if now >= self._next_costmap - 1e-9:
            version, costmap = self._costmap(run, root)
            if costmap is not None and version != self._costmap_version:
                self._costmap_version = version
                self._next_costmap = now + self.costmap_period_s
                cls = costmap_classes(costmap, self._prior_costmap(run))
                res = costmap.resolution_m
                extra["costmap"] = {
                    "version": int(version), "classes": list(COSTMAP_CLASSES),
                    "extent_m": [costmap.x0_m, costmap.x0_m + cls.shape[1] * res,
                                 costmap.y1_m - cls.shape[0] * res, costmap.y1_m],
                    "png": png_bytes(_classes_rgba(cls)),
                }  # fmt: skip
        if (ix := run.ground_system("ground.images")) is not None:
            got = ix.received_since(ix.GetMyContextFromRoot(root), self._n_images)
            self._n_images += len(got)
            for d in got:
                datums.append(("link.frame_delay", float(d.t_received_s),
                               float(d.t_received_s - d.message.payload.t_capture_s)))
            if got:
                datums.append(("link.frames", now, self._n_images))
                d = got[-1]
                f = d.message.payload
                extra["frame"] = {"t_received_s": d.t_received_s,
                                  "frame_index": int(f.frame_index),
                                  "png": png_bytes(self._preview_image(f))}
        if (sx := run.ground_system("ground.science")) is not None:
            got = sx.received_since(sx.GetMyContextFromRoot(root), self._n_science)
            self._n_science += len(got)
            heat: dict = {}
            for d in got:
                more, samples = dic.science_datums(d.t_received_s, d.message.payload,
                                                   nss_config=run.scenario.sensors.nss)  # fmt: skip
                datums += more
                for layer, xyv in samples.items():
                    heat.setdefault(layer, []).append(list(xyv))
            if heat:
                extra["science"] = heat
        return datums, extra

    def _preview_image(self, frame) -> np.ndarray:
        """The left image of a received StereoFrame, decoded, 8-bit, ``frame_width_px``
        wide at most."""
        from lunar_drake.comms.images import decode_frame

        a = decode_frame(frame.left, codec=frame.codec)
        if a.dtype != np.uint8:  # 12/16-bit codes: scale by the frame's own range
            a = a.astype(np.float64)
            hi = float(np.percentile(a, 99.5)) or 1.0
            a = np.clip(a / hi * 255.0, 0, 255).astype(np.uint8)
        step = max(1, math.ceil(a.shape[1] / self.frame_width_px))
        return a[::step, ::step]

    def finish(self, *, simulated_s: float) -> None:
        """Tells the server the mission has ended (at ``simulated_s``; not why: a stop
        reason may name the true pose)."""
        if self.alive is None or self.alive():
            self.outbox.put({"kind": "done",
                             "stop_reason": f"the mission ended at t = {simulated_s:.1f} s"})


def _classes_rgba(cls: np.ndarray) -> np.ndarray:
    colors = np.array([[0, 0, 0, 0], [220, 40, 40, 150], [240, 170, 30, 150],
                       [230, 40, 230, 200]], np.uint8)  # fmt: skip
    return colors[np.minimum(cls, 3)]
