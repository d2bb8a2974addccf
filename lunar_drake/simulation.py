"""simulate(): build the mission diagram, run it, and return what it recorded.

The CLI, notebooks, the slip study, trade sweeps and the mission-control server all
make the same three calls::

    logs = simulate(scenario=scenario, site=site)        # this module
    summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
    outputs.write_run(out_dir, scenario=scenario, logs=logs, summary=summary)

``simulate`` writes no files except camera frames (into ``frames_dir``, when given: they
are too large to hold in memory). Its result holds plain numpy arrays and dataclasses,
so it pickles (sweeps run it in worker processes).
"""

from __future__ import annotations

import dataclasses as dc
import math
import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lunar_drake import interrupts
from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS
from lunar_drake.errors import SimulationError
from lunar_drake.scenario import Scenario
from lunar_drake.site import SiteData
from lunar_drake.systems.body_pose_vector import BodyPoseVector
from lunar_drake.systems.command_executor import STATUS_FIELDS
from lunar_drake.systems.power_system import TRUTH_FIELDS as POWER_FIELDS
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS

_WHEELS = ("fl", "fr", "rl", "rr")
_AXES6 = ("gyro_x_radps", "gyro_y_radps", "gyro_z_radps")
_AXES6 += ("accel_x_mps2", "accel_y_mps2", "accel_z_mps2")

#: Mission output ports logged every ``logging.period_s``, with their columns (those the
#: mission has: ``truth.power`` only when ``power.enabled``).
LOGGED_PORTS = {
    "truth.pose": BodyPoseVector.FIELDS,
    "truth.wheel_state": tuple(f"{w}_{f}" for w in _WHEELS for f in WHEEL_STATE_FIELDS),
    "truth.drive_energy": ("energy_J",),
    "truth.imu_bias": tuple(f"bias_{a}" for a in _AXES6),
    "truth.power": POWER_FIELDS,
    "rover.imu": _AXES6,
    "rover.star_tracker": ("qw", "qx", "qy", "qz"),
    "rover.wheel_encoders": tuple(f"{w}_angle_rad" for w in _WHEELS),
    "flight.twist_command": ("vx_mps", "vy_mps", "wz_radps"),
    "flight.brake_command": ("brake",),
    "flight.status": STATUS_FIELDS,
    "flight.bumper": ("trip",),
    "flight.pose_estimate": ("x_m", "y_m", "z_rel_m", "roll_rad", "pitch_rad", "yaw_rad"),
    # Row-major 6 x 6 covariance of [position (m), world-frame attitude error (rad)].
    "flight.pose_covariance": tuple(
        f"cov_{a}_{b}"
        for a in ("x", "y", "z", "rx", "ry", "rz")
        for b in ("x", "y", "z", "rx", "ry", "rz")
    ),
    "ground.pose_estimate": ("x_m", "y_m", "z_rel_m", "roll_rad", "pitch_rad", "yaw_rad"),
}


@dc.dataclass
class VectorLog:
    """Samples of one vector port: ``times`` (n,) s and ``data`` (n, len(columns))."""

    times: np.ndarray
    data: np.ndarray
    columns: tuple

    def column(self, name: str) -> np.ndarray:
        """One column's samples."""
        return self.data[:, self.columns.index(name)]


@dc.dataclass
class ReceivedTelemetry:
    """Telemetry as the ground received it: per packet its seq, send and reception times
    (s) and the packet (rows of :data:`~lunar_drake.autonomy.telemetry.TELEMETRY_FIELDS`)."""

    seq: np.ndarray
    t_sent: np.ndarray
    t_received: np.ndarray
    packets: np.ndarray
    columns: tuple = TELEMETRY_FIELDS


@dc.dataclass
class SimulationLogs:
    """What one simulation recorded.

    Attributes:
        simulated_s: simulated time reached (s).
        stop_reason: "duration reached", or why the run stopped early.
        systems: names of the mission's subsystems, recursively (sorted).
        vectors: port name -> :class:`VectorLog` (see :data:`LOGGED_PORTS`; the ports
            the mission has).
        telemetry: what the ground received (:class:`ReceivedTelemetry`).
        link: every message over the uplink and downlink
            (:class:`~lunar_drake.comms.link.LinkRecord`).
        transitions: every on-board mode change
            (:class:`~lunar_drake.autonomy.commands.Transition`).
        ground_events: what the ground did and saw
            (:class:`~lunar_drake.autonomy.operations.Event`).
        ground_goals: every goal the ground was given ((x, y) m) and its status on the
            ground (:data:`~lunar_drake.autonomy.operations.GOAL_STATUS`).
        images_received: the stereo frames the ground received, (t_received_s,
            t_sent_s, frame_index, codec, bytes) each.
        science_received: the instrument records the ground received, (t_received_s,
            :class:`~lunar_drake.comms.science.ScienceRecord`) each, in sample order.
        keyframes: the ground perception's processed keyframes
            (:class:`~lunar_drake.perception.ground_pipeline.KeyframeRecord`).
        keyframe_clouds: the points the ground mapped from each keyframe, in its own
            site frame (:class:`~lunar_drake.perception.ground_pipeline.KeyframeCloud`;
            none with ``ground.perception.cloud_voxel_m`` 0).
        ground_costmap: the ground's final costmap (a-priori + stereo hazards; the
            a-priori one without ground perception), or None when it had no map.
        ground_prior_costmap: the ground's a-priori costmap on the grid of
            ``ground_costmap`` (the stereo hazards are where they differ), or None.
        ground_first_lethal_s: per cell of ``ground_costmap``, the capture time (s) of
            the keyframe whose stereo first made it lethal (NaN: never), or None.
        preflight: what the mission had before launch
            (:func:`lunar_drake.preflight.describe`: the ground's map and its source, the
            flight's slip calibration).
        frames_written: camera frames written to ``frames_dir``.
        wall: wall-clock timing (s; not deterministic).
    """

    simulated_s: float
    stop_reason: str
    systems: list
    vectors: dict
    telemetry: ReceivedTelemetry
    link: list
    frames_written: int
    wall: dict
    transitions: list = dc.field(default_factory=list)
    ground_events: list = dc.field(default_factory=list)
    ground_goals: list = dc.field(default_factory=list)
    images_received: list = dc.field(default_factory=list)
    science_received: list = dc.field(default_factory=list)
    keyframes: list = dc.field(default_factory=list)
    keyframe_clouds: list = dc.field(default_factory=list)
    ground_costmap: object = None
    ground_prior_costmap: object = None
    ground_first_lethal_s: object = None
    preflight: dict = dc.field(default_factory=dict)


StopCheck = Callable[[float, np.ndarray], "str | None"]


def _system_names(system) -> list[str]:
    out = []
    for s in system.GetSystems():
        out.append(re.sub(r"@[0-9a-f]+$", "", s.get_name()))
        if hasattr(s, "GetSystems"):
            out += _system_names(s)
    return out


@dc.dataclass
class MissionRun:
    """A built mission ready to run (:func:`build_mission`), then run
    (:func:`run_mission`) and read (:func:`collect_logs`).

    Attributes:
        scenario, site: what it was built from.
        mission: the mission diagram (``MakeMissionDiagram``).
        diagram: the root diagram (the mission, its logger and the frame writer).
        simulator: the Drake Simulator on ``diagram``.
        map_product: the ground's pre-flight map product.
        log_sink: one VectorLogSink of the logged ports side by side (a Multiplexer of
            the :data:`LOGGED_PORTS` the mission has; one sink, not one a port: 15 sinks'
            events cost 9 % of a no-camera step); None when it has none.
        log_slices: each logged port's columns in the sink's samples.
        build_s: wall time spent building (s).
        wall: wall-clock timing of the run so far (s; not deterministic).
    """

    scenario: Scenario
    site: SiteData
    mission: object
    diagram: object
    simulator: object
    map_product: object
    log_sink: object
    log_slices: dict
    writer: object = None
    meshcat: object = None
    build_s: float = 0.0
    wall: dict = dc.field(default_factory=dict)

    @property
    def root(self):
        """The simulator's root context (mutable: the operator API takes it)."""
        return self.simulator.get_mutable_context()

    @property
    def time_s(self) -> float:
        """Simulated time reached (s)."""
        return float(self.simulator.get_context().get_time())

    @property
    def operator(self):
        """The ground's operator API (:class:`~lunar_drake.systems.ground_operator.
        GroundOperator`: ``send_goal(run.root, ...)``, ``stop``, ``resume``, ...)."""
        return self.mission.GetSubsystemByName("ground").GetSubsystemByName("ground.operator")

    def ground_system(self, name: str):
        """The ground subsystem ``name`` (e.g. ``ground.telemetry``), or None."""
        ground = self.mission.GetSubsystemByName("ground")
        return ground.GetSubsystemByName(name) if ground.HasSubsystemNamed(name) else None


#: ``observer(run)`` is called between ``AdvanceTo`` calls of a run with observers (every
#: ``observe_period_s`` of simulated time); it may read the run, queue operator requests
#: on ``run.root`` and return a reason to stop the run (or None).
Observer = Callable[[MissionRun], "str | None"]


def build_mission(*, scenario: Scenario, site: SiteData, meshcat=None,
                  frames_dir: str | Path | None = None) -> MissionRun:  # fmt: skip
    """Builds ``scenario``'s mission on ``site`` with its loggers (and a frame writer into
    ``frames_dir`` when given and the cameras are on) under a configured Simulator."""
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput, Multiplexer

    from lunar_drake import preflight
    from lunar_drake.diagrams.mission import MakeMissionDiagram

    t0 = time.perf_counter()
    map_product = preflight.ground_map_product(scenario, site)
    mission = MakeMissionDiagram(scenario=scenario, site=site, meshcat=meshcat,
                                 map_product=map_product)  # fmt: skip
    builder = DiagramBuilder()
    builder.AddSystem(mission)
    logged = [name for name in LOGGED_PORTS if mission.HasOutputPort(name)]
    sizes = [mission.GetOutputPort(name).size() for name in logged]
    starts = np.cumsum([0, *sizes])
    log_slices = {name: slice(int(starts[i]), int(starts[i + 1])) for i, name in enumerate(logged)}
    log_sink = None
    if logged:
        mux = builder.AddNamedSystem("logged_ports", Multiplexer(input_sizes=sizes))
        for i, name in enumerate(logged):
            builder.Connect(mission.GetOutputPort(name), mux.get_input_port(i))
        log_sink = LogVectorOutput(mux.get_output_port(0), builder, scenario.logging.period_s)
    writer = None
    cam = scenario.sensors.camera
    if frames_dir is not None and cam.enabled:
        from pydrake.systems.sensors import ImageGrey8U

        from lunar_drake.systems.frame_writer import FrameWriter

        camera_period = 1.0 / cam.rate_hz
        writer = builder.AddNamedSystem(
            "frame_writer",
            FrameWriter(
                names=["left", "right"],
                out_dir=frames_dir,
                period_s=camera_period,
                offset_s=(cam.delay_s % camera_period) + 1e-6,
                preview_image_type=ImageGrey8U,
            ),
        )
        builder.Connect(mission.GetOutputPort("camera.frame_index"), writer.frame_index_input)
        for n in ("left", "right"):
            builder.Connect(mission.GetOutputPort(f"camera.{n}.raw"), writer.raw_inputs[n])
            builder.Connect(mission.GetOutputPort(f"camera.{n}.preview"), writer.preview_inputs[n])
    diagram = builder.Build()
    diagram.set_name("run")
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    return MissionRun(scenario=scenario, site=site, mission=mission, diagram=diagram,
                      simulator=simulator, map_product=map_product, log_sink=log_sink,
                      log_slices=log_slices,
                      writer=writer, meshcat=meshcat,
                      build_s=time.perf_counter() - t0)  # fmt: skip


def run_mission(
    run: MissionRun,
    *,
    progress: bool = False,
    stop_when: StopCheck | None = None,
    stop_check_period_s: float = 0.5,
    stop_after_goals_s: float | None = None,
    realtime_rate: float | None = None,
    observers: tuple = (),
    observe_period_s: float = 0.1,
    observe_offset_s: float = 0.0,
) -> str:
    """Runs ``run`` to ``scenario.simulation_duration`` (or an earlier stop) and returns
    why it stopped ("duration reached", or the reason).

    The run stops early, cleanly, when the rover leaves the terrain, when
    ``stop_when(t, truth_pose)`` (checked every ``stop_check_period_s`` of simulated
    time; ``truth_pose`` as ``truth.pose``) returns a reason, with
    ``stop_after_goals_s`` that many seconds after the ground has judged every one of its
    goals (reached or failed), or when an observer returns a reason.

    Args:
        realtime_rate: pace the run to this multiple of real time (Drake's target
            realtime rate; 0: as fast as it can); None keeps the scenario's.
        observers: :data:`Observer` callables; with any, the run advances to the times
            ``observe_offset_s + k * observe_period_s`` (s) and calls each at those times
            (an offset just after a software tick sees what that tick did). Pacing and
            steps change when things happen on the wall clock, never what happens.

    Raises:
        SimulationError: the integrator failed; the message has the simulated time.
    """
    from pydrake.systems.framework import EventStatus

    scenario, mission, diagram, simulator = run.scenario, run.mission, run.diagram, run.simulator
    if realtime_rate is not None:
        simulator.set_target_realtime_rate(float(realtime_rate))
    root = simulator.get_mutable_context()
    mctx = mission.GetMyContextFromRoot(root)
    off_port = mission.GetOutputPort("truth.off_terrain")
    pose_port = mission.GetOutputPort("truth.pose")
    hf = run.site.heightfield
    end = float(scenario.simulation_duration)
    stop_reason = ["duration reached"]
    bar = _progress_bar(end, progress)
    clock = {"next_check": 0.0, "next_bar": 0.0, "wall0": None, "goals_done": None}
    operator = run.operator
    op_ctx = operator.GetMyContextFromRoot(root)

    def monitor(context):
        if interrupts.requested():  # Ctrl-C whose KeyboardInterrupt something swallowed
            raise KeyboardInterrupt
        t = context.get_time()
        if off_port.Eval(mctx)[0] > 0.5:
            x, y = pose_port.Eval(mctx)[:2]
            b = hf.bounds
            stop_reason[0] = (
                f"rover left the terrain at t = {t:.2f} s, chassis at ({x:.2f}, {y:.2f}) m; "
                f"site x in [{b.left:g}, {b.right:g}], y in [{b.bottom:g}, {b.top:g}] m"
            )
            return EventStatus.ReachedTermination(diagram, stop_reason[0])
        check = stop_when is not None or stop_after_goals_s is not None
        if check and t >= clock["next_check"]:
            clock["next_check"] = t + stop_check_period_s
            why = stop_when(t, pose_port.Eval(mctx)) if stop_when is not None else None
            if stop_after_goals_s is not None and not why:
                status = operator.operator_state(op_ctx).status
                done = bool(status) and all(g in ("reached", "failed") for g in status)
                if not done:
                    clock["goals_done"] = None
                elif clock["goals_done"] is None:
                    clock["goals_done"] = t
                elif t - clock["goals_done"] >= stop_after_goals_s:
                    why = f"the ground's goals done at t = {clock['goals_done']:.1f} s"
            if why:
                stop_reason[0] = why
                return EventStatus.ReachedTermination(diagram, why)
        if bar is not None and clock["wall0"] is not None and t >= clock["next_bar"]:
            clock["next_bar"] = t + max(end / 200.0, 0.25)
            _update_bar(bar, t, time.perf_counter() - clock["wall0"])
        return EventStatus.DidNothing()

    def advance() -> None:
        if not observers:
            simulator.AdvanceTo(end)
            return
        step, offset = float(observe_period_s), float(observe_offset_s)
        k = -1
        while True:
            for observe in observers:
                why = observe(run)
                if why:
                    stop_reason[0] = why
                    return
            t = root.get_time()
            if t >= end or stop_reason[0] != "duration reached":
                return
            k = max(k + 1, math.floor((t - offset) / step + 1e-9) + 1)
            status = simulator.AdvanceTo(min(offset + k * step, end))
            if status.reason() == status.ReturnReason.kReachedTerminationCondition:
                return

    simulator.set_monitor(monitor)
    if run.meshcat is not None:
        run.meshcat.StartRecording(set_visualizations_while_recording=True)
    sigint = interrupts.LatchedSigint()
    t_sim = t_start = time.perf_counter()
    try:
        if interrupts.requested():  # Ctrl-C while building, its exception swallowed
            raise KeyboardInterrupt
        clock["wall0"] = t_start - 1e-9
        try:
            simulator.Initialize()
            advance()
        except (KeyboardInterrupt, SimulationError):
            raise
        except Exception as exc:  # Drake raises RuntimeError on integrator failures.
            if interrupts.requested():
                # Ctrl-C inside a system's Python callback reaches us through C++ as a
                # RuntimeError ("initialization failed", ...): it is still an interrupt.
                raise KeyboardInterrupt from None
            raise SimulationError(
                f"simulation failed at t = {root.get_time():.3f} s: " + " ".join(str(exc).split())
            ) from exc
        t_sim = time.perf_counter()
        if bar is not None:
            _update_bar(bar, root.get_time(), t_sim - t_start)
    finally:
        sigint.restore()
        if bar is not None:
            bar.close()
        simulator.clear_monitor()
    if run.meshcat is not None:
        run.meshcat.StopRecording()
        run.meshcat.PublishRecording()
    simulated = float(root.get_time())
    run.wall = {
        "build_s": run.build_s,
        "simulate_s": t_sim - t_start,
        "realtime_factor": simulated / (t_sim - t_start) if t_sim > t_start else None,
    }
    return stop_reason[0]


def collect_logs(run: MissionRun, *, stop_reason: str) -> SimulationLogs:
    """What ``run`` recorded so far, as plain arrays and dataclasses."""
    from lunar_drake import preflight

    mission, root = run.mission, run.simulator.get_context()
    vectors = {}
    if run.log_sink is not None:
        log = run.log_sink.FindLog(root)
        times = np.array(log.sample_times())
        data = np.array(log.data())
        for name, cols in run.log_slices.items():
            vectors[name] = VectorLog(
                times=times.copy(), data=data[cols].T.copy(), columns=LOGGED_PORTS[name]
            )
    receiver = run.ground_system("ground.telemetry")
    received = receiver.received(receiver.GetMyContextFromRoot(root))
    telemetry = ReceivedTelemetry(
        seq=np.array([d.message.seq for d in received], dtype=np.int64),
        t_sent=np.array([d.message.t_sent_s for d in received], dtype=np.float64),
        t_received=np.array([d.t_received_s for d in received], dtype=np.float64),
        packets=np.array([d.message.payload for d in received], dtype=np.float64).reshape(
            -1, len(TELEMETRY_FIELDS)
        ),
    )
    link = []
    for name in ("uplink", "downlink"):
        sys = mission.GetSubsystemByName(name)
        link += sys.records(sys.GetMyContextFromRoot(root))
    writer = run.writer
    frames = writer.frames_written(writer.GetMyContextFromRoot(root)) if writer else 0
    executor = mission.GetSubsystemByName("flight").GetSubsystemByName("flight.executor")
    transitions = executor.executor_state(executor.GetMyContextFromRoot(root)).transitions.items()
    operator = run.operator
    ops = operator.operator_state(root)
    images = []
    if (rx := run.ground_system("ground.images")) is not None:
        images = [
            (d.t_received_s, d.message.t_sent_s, d.message.payload.frame_index,
             d.message.payload.codec, d.message.size_bytes)
            for d in rx.received(rx.GetMyContextFromRoot(root))
        ]  # fmt: skip
    science = []
    if (rx := run.ground_system("ground.science")) is not None:
        science = [(d.t_received_s, d.message.payload)
                   for d in rx.received(rx.GetMyContextFromRoot(root))]  # fmt: skip
    keyframes, costmap, prior = [], operator.prior_costmap, operator.prior_costmap
    clouds = []
    first_lethal = None
    if (gp := run.ground_system("ground.perception")) is not None:
        pst = gp.perception_state(root)
        keyframes, costmap = pst.records.items(), pst.costmap
        clouds = pst.clouds.items()
        first_lethal = pst.first_lethal_s
        prior = gp.costmap_output.Allocate().get_value()[1]  # the prior, refined
    return SimulationLogs(
        simulated_s=float(root.get_time()),
        stop_reason=stop_reason,
        systems=sorted(_system_names(mission)),
        vectors=vectors,
        telemetry=telemetry,
        link=link,
        frames_written=frames,
        transitions=transitions,
        ground_events=ops.events.items(),
        ground_goals=[(g, st) for g, st in zip(ops.goals, ops.status, strict=True)],
        images_received=images,
        science_received=science,
        keyframes=keyframes,
        keyframe_clouds=clouds,
        ground_costmap=costmap,
        ground_prior_costmap=prior,
        ground_first_lethal_s=first_lethal,
        preflight=preflight.describe(run.scenario, map_product=run.map_product),
        wall=dict(run.wall),
    )


def simulate(
    *,
    scenario: Scenario,
    site: SiteData,
    meshcat=None,
    progress: bool = False,
    frames_dir: str | Path | None = None,
    stop_when: StopCheck | None = None,
    stop_check_period_s: float = 0.5,
    stop_after_goals_s: float | None = None,
    realtime_rate: float | None = None,
    observers: tuple = (),
    observe_period_s: float = 0.1,
    observe_offset_s: float = 0.0,
) -> SimulationLogs:
    """Simulates ``scenario`` on ``site`` for ``scenario.simulation_duration`` seconds:
    :func:`build_mission`, :func:`run_mission` (see it for the stop conditions, pacing
    and observers), :func:`collect_logs`.

    Args:
        meshcat: a pydrake Meshcat to draw in (and record), or None (headless).
        progress: show a progress bar in simulated seconds with the real-time factor.
        frames_dir: write camera frames there (when the cameras are enabled).

    Raises:
        SimulationError: the integrator failed; the message has the simulated time.
    """
    run = build_mission(scenario=scenario, site=site, meshcat=meshcat, frames_dir=frames_dir)
    why = run_mission(run, progress=progress, stop_when=stop_when,
                      stop_check_period_s=stop_check_period_s,
                      stop_after_goals_s=stop_after_goals_s, realtime_rate=realtime_rate,
                      observers=observers, observe_period_s=observe_period_s,
                      observe_offset_s=observe_offset_s)  # fmt: skip
    return collect_logs(run, stop_reason=why)


def _progress_bar(total: float, enabled: bool):
    if not enabled or total <= 0:
        return None
    from tqdm.auto import tqdm

    return tqdm(
        total=round(total, 3),
        unit="sim s",
        desc="simulating",
        bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} sim s [{elapsed}<{remaining}{postfix}]",
    )


def _update_bar(bar, t: float, wall_s: float) -> None:
    bar.n = round(min(t, bar.total), 3)
    if wall_s > 0:
        bar.set_postfix_str(f"{t / wall_s:.1f}x real time", refresh=False)
    bar.refresh()
