"""The typed scenario: everything one run needs, section by section.

A scenario is a YAML mapping onto :class:`Scenario` (Drake's ``yaml_load_typed``; see
:mod:`lunar_drake.scenario_files` for loading, overrides and error reporting). Its
sections follow the mission's seams (docs/design.md):

* the plant -- ``site``, ``terrain``, ``soil``, ``rover`` (with its lights), ``sensors``
  (IMU, star tracker, wheel encoders, cameras: rates, delays, noise), ``lighting`` and
  ``power`` (solar array, battery, loads);
* ``flight`` (rover software), ``ground`` (operations software: the route it sends) and
  ``comms`` (the uplink and downlink);
* ``logging``, ``terrain_view`` and Drake's own ``simulator_config``, ``plant_config``
  and ``visualization``.

Each concept has one config class, defined next to the code that uses it (``ImuConfig``
in :mod:`lunar_drake.sensors.imu`, ``CameraConfig`` in :mod:`lunar_drake.render.camera`,
``SoilParams`` in :mod:`lunar_drake.dynamics.terramechanics`, ...). ``yaml_load_typed``
assigns fields without running ``__post_init__``, so :func:`validate_scenario` checks
every section after loading; its messages name the scenario key
(``sensors.imu.rate_hz``).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import datetime
import math
from pathlib import Path

from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.visualization import VisualizationConfig

from lunar_drake.autonomy.costmap import HazardConfig, MapConfig
from lunar_drake.autonomy.ekf import EstimatorConfig
from lunar_drake.autonomy.follower import HeadingConfig
from lunar_drake.autonomy.safety import SafetyConfig
from lunar_drake.comms.images import ImageDownlinkConfig
from lunar_drake.comms.link import ChannelConfig, LinkConfig
from lunar_drake.dynamics.terramechanics import SoilParams
from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError, check_range
from lunar_drake.models.rover_description import RoverDescription, krex2_rp
from lunar_drake.perception.ground_pipeline import PerceptionConfig
from lunar_drake.power.config import PowerConfig
from lunar_drake.render.camera import CameraConfig
from lunar_drake.science.config import WorldConfig
from lunar_drake.science.drill import DrillConfig, check_drill_request
from lunar_drake.science.nirvss import NIRVSSConfig
from lunar_drake.science.nss import NSSConfig
from lunar_drake.sensors.imu import ImuConfig
from lunar_drake.sensors.star_tracker import StarTrackerConfig
from lunar_drake.sensors.wheel_encoders import WheelEncoderConfig
from lunar_drake.systems.gimbal_pointing import GimbalPointingConfig

SFD_LAWS = ("trask", "viper", "powerlaw")


@dc.dataclass
class SiteConfig:
    """Where and when the mission happens.

    Attributes:
        name: human-readable site name.
        latitude_deg, longitude_deg: site centre on the IAU Moon sphere (deg; east lon).
        epoch_utc: UTC of simulation time 0 (ISO 8601).
        seed: the site's seed: terrain synthesis (craters, rocks, fractal detail), the
            world model's seeded layers and the orbital map's noise -- everything that
            exists before the mission. ``random_seed`` drives the run itself, so
            replicates over noise share one site.
    """

    name: str = "near Mons Mouton (approximate)"
    latitude_deg: float = -85.4
    longitude_deg: float = 31.6
    epoch_utc: str = "2027-11-15T00:00:00"
    seed: int = 0


@dc.dataclass
class TerrainConfig:
    """The site raster: either a DEM file, or synthesized (paper section 4).

    Attributes:
        dem: path of a GeoTIFF DEM to use (relative paths are relative to the scenario
            file); empty to synthesize. With ``factor`` > 1 the DEM is fractally
            upscaled by ``factor`` first.
        size_px: synthesized site side (pixels).
        resolution_m: synthesized pixel size (m).
        factor: fractal upscaling factor (power of two); the coarse grid is
            ``size_px / factor`` pixels at ``resolution_m * factor`` metres.
        sfd: crater size-frequency law: trask, viper or powerlaw.
        powerlaw_coefficient, powerlaw_exponent: N(>=D) = c D^e per m^2 for ``powerlaw``.
        min_crater_m, max_crater_m: crater diameter range (m); max 0 = automatic.
        rock_abundance: Golombek-Rapp cumulative fractional area k of background rocks.
        min_rock_m: smallest rock diameter placed (m).
        tile_px: tile side for tiled synthesis (pixels); never changes the result.
        workers: worker threads for tiled synthesis; never changes the result.
    """

    dem: str = ""
    size_px: int = 2048
    resolution_m: float = 0.1
    factor: int = 32
    sfd: str = "trask"
    powerlaw_coefficient: float = 0.08
    powerlaw_exponent: float = -2.0
    min_crater_m: float = 0.5
    max_crater_m: float = 0.0
    rock_abundance: float = 0.005
    min_rock_m: float = 0.1
    tile_px: int = 1024
    workers: int = 2


@dc.dataclass
class TerrainViewConfig:
    """How the terrain is shown in Meshcat.

    Attributes:
        max_mesh_px: the LOD mesh is decimated so its larger side has at most this many
            vertices.
        albedo_gain: display gain applied to albedo for vertex colours.
    """

    max_mesh_px: int = 384
    albedo_gain: float = 3.0


@dc.dataclass
class SpotlightConfig:
    """A rover lamp rigidly attached to a rover body (paper: up to four lights).

    Attributes:
        body: rover body name (e.g. chassis, mast_head).
        xyz: lamp position in the body frame (m). direction: beam axis in the body frame.
        intensity_W_per_sr: on-axis radiant intensity in the camera band (W/sr).
        outer_half_angle_deg, inner_half_angle_deg: cone edge and full-intensity core.
        cast_shadows: ray-cast the light's shadows (slower).
    """

    body: str = "chassis"
    xyz: list[float] = dc.field(default_factory=lambda: [0.75, 0.0, 0.0])
    direction: list[float] = dc.field(default_factory=lambda: [1.0, 0.0, -0.35])
    intensity_W_per_sr: float = 20.0
    outer_half_angle_deg: float = 35.0
    inner_half_angle_deg: float = 20.0
    cast_shadows: bool = False


@dc.dataclass
class RoverConfig:
    """The rover hardware and where it starts.

    Attributes:
        description: the rover model (lunar_drake/models/rover_description.py; the
            default is the explicit-steer RP/KRex2-class preset).
        spawn_x_m, spawn_y_m, spawn_yaw_deg: start pose on the site (site frame).
        lights: up to 4 lamps (they light the camera images).
    """

    description: RoverDescription = dc.field(default_factory=krex2_rp)
    spawn_x_m: float = 0.0
    spawn_y_m: float = 0.0
    spawn_yaw_deg: float = 0.0
    lights: list[SpotlightConfig] = dc.field(default_factory=list)


@dc.dataclass
class SensorsConfig:
    """The rover's sensors; each has ``rate_hz``, ``delay_s`` and a noise model.

    Attributes:
        imu: chassis IMU. star_tracker: chassis star tracker (boresight up).
        wheel_encoders: drive-joint encoders. camera: the mast stereo pair.
        nss: the neutron spectrometer (science; reads the world model, ``science``).
        nirvss: the near-infrared volatiles spectrometer and its LCS (same).
        drill: the drill (its samples are read by NIRVSS; ground action ``drill``).
    """

    imu: ImuConfig = dc.field(default_factory=ImuConfig)
    star_tracker: StarTrackerConfig = dc.field(default_factory=StarTrackerConfig)
    wheel_encoders: WheelEncoderConfig = dc.field(default_factory=WheelEncoderConfig)
    camera: CameraConfig = dc.field(default_factory=CameraConfig)
    nss: NSSConfig = dc.field(default_factory=NSSConfig)
    nirvss: NIRVSSConfig = dc.field(default_factory=NIRVSSConfig)
    drill: DrillConfig = dc.field(default_factory=DrillConfig)


@dc.dataclass
class LightingConfig:
    """Sun, Earth and baked shadows.

    Attributes:
        ephemeris_update_s: how often Sun/Earth directions are recomputed (s).
        lightmap: bake terrain-shadow lightmaps for the camera.
        lightmap_interval_s: spacing of baked lightmaps (s; the paper planned hourly).
        lightmap_max_px: bake on the DEM decimated to at most this many pixels a side.
        extra_kernels: additional SPICE kernels (paths, relative to the scenario file)
            furnished after the built-in ones.
    """

    ephemeris_update_s: float = 10.0
    lightmap: bool = True
    lightmap_interval_s: float = 3600.0
    lightmap_max_px: int = 2048
    extra_kernels: list[str] = dc.field(default_factory=list)


@dc.dataclass
class FlightConfig:
    """The rover's software (reads only sensors and the uplink).

    Attributes:
        rate_hz: tick of the command executor, kinematics and odometry (Hz).
        brake_delay_s: how long the rover stands still before its wheel brakes engage
            (s); they are on from the start.
        telemetry_rate_hz: rate of the housekeeping telemetry sent down (Hz).
        gimbal: mast camera pointing.
        estimator: the on-board EKF's assumptions
            (:class:`~lunar_drake.autonomy.ekf.EstimatorConfig`).
        safety: the virtual bumper and the uplink timeout
            (:class:`~lunar_drake.autonomy.safety.SafetyConfig`).
        images: the camera frames sent down the ``images`` topic when the cameras are
            on (:class:`~lunar_drake.comms.images.ImageDownlinkConfig`).
        heading: how the path follower points the chassis: ``path`` (face the way it
            drives) or ``sun`` (explicit steer: crab along the path, the solar panel
            turned to the Sun; :class:`~lunar_drake.autonomy.follower.HeadingConfig`).
    """

    rate_hz: float = 50.0
    brake_delay_s: float = 0.5
    telemetry_rate_hz: float = 1.0
    gimbal: GimbalPointingConfig = dc.field(default_factory=GimbalPointingConfig)
    estimator: EstimatorConfig = dc.field(default_factory=EstimatorConfig)
    safety: SafetyConfig = dc.field(default_factory=SafetyConfig)
    images: ImageDownlinkConfig = dc.field(default_factory=ImageDownlinkConfig)
    heading: HeadingConfig = dc.field(default_factory=HeadingConfig)


@dc.dataclass
class RouteSegment:
    """One drive command: a chassis twist held for a duration.

    Attributes:
        duration_s: how long (s). vx_mps, vy_mps: chassis-frame velocity (m/s).
        wz_radps: yaw rate (rad/s).
    """

    duration_s: float = 1.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    wz_radps: float = 0.0


def _default_route() -> list:
    # About 100 m: stand still, straight, a gentle left arc, straight (0.2 m/s, RP class).
    return [
        RouteSegment(duration_s=2.0),
        RouteSegment(duration_s=250.0, vx_mps=0.2),
        RouteSegment(duration_s=100.0, vx_mps=0.2, wz_radps=0.01),
        RouteSegment(duration_s=250.0, vx_mps=0.2),
    ]


@dc.dataclass
class Goal:
    """An operator goal: a point in the site frame (m)."""

    x_m: float = 0.0
    y_m: float = 0.0


#: Operator actions a scenario may schedule (``ground.actions``).
ACTIONS = ("goal", "stop", "resume", "drive_arc", "point_mast", "drill")


@dc.dataclass
class OperatorAction:
    """An operator request at a set time (what a Python call on the ground operator does
    in a notebook, written down so that ``scenario.yaml`` reproduces the run).

    Attributes:
        t_s: when the ground sends it (s).
        action: goal, stop, resume, drive_arc, point_mast or drill.
        x_m, y_m: the goal (site frame, m).
        speed_mps, curvature_per_m, distance_m: the arc (m/s, 1/m positive left, m).
        pan_deg, tilt_deg: the mast pointing (deg); auto: back to automatic pointing.
        depth_m, step_m: the drill's depth and sample spacing (m; at most 1 m).
    """

    t_s: float = 0.0
    action: str = "stop"
    x_m: float = 0.0
    y_m: float = 0.0
    speed_mps: float = 0.2
    curvature_per_m: float = 0.0
    distance_m: float = 1.0
    pan_deg: float = 0.0
    tilt_deg: float = 0.0
    auto: bool = False
    depth_m: float = 0.5
    step_m: float = 0.1


@dc.dataclass
class GroundConfig:
    """Operations software on Earth (reads only what the downlink delivers).

    Attributes:
        rate_hz: tick of the ground software (Hz); one command is sent per tick.
        route: the operator's drive commands, sent in order from t = 0 and run one
            after the other on board.
        goals: operator goals; when given, they replace the route: the ground drives
            them one at a time, planning a hazard-free path on its map from its pose
            estimate and replanning (:mod:`lunar_drake.autonomy.operations`).
        actions: scheduled operator requests (:class:`OperatorAction`).
        goal_tolerance_m: a goal is reached when the true position comes within this
            distance (m; scoring); the ground judges its own goals done when its
            estimate is this close less its position sigma (at least
            ``goto_tolerance_m`` + 0.1 m; :func:`~lunar_drake.autonomy.operations.
            reach_radius_m`), else it plans a final approach.
        goto_tolerance_m: on board, a goto ends when the *estimate* is this close to
            its goal (m); smaller than ``goal_tolerance_m`` so that the estimate's drift
            has room.
        drive_speed_mps: goto driving speed (m/s).
        heartbeat_s: send a keep-alive when nothing else went up for this long (s).
        auto_resume: resume a safed rover (and replan) without waiting for a person.
        max_resumes: at most this many automatic resumes in a run.
        max_replans: replans of one goal before the ground gives it up.
        replan_deviation_m: stop and replan when the ground's estimate is this far off
            the planned path (m).
        max_extrapolation_s: the ground carries the downlinked pose forward along the
            commanded twist for at most this long (s).
        ack_timeout_s: a goto (or resume) that telemetry has not acknowledged after this
            long plus the round trip (twice the measured telemetry latency) is taken as
            lost and sent again, replanned (s).
        max_resends: at most this many times per goal (or resume).
        resume_soc: after a ``low_soc`` safing the rover stays parked, charging, until
            telemetry reports this state of charge; then the automatic resume.
        map: the a-priori map (:class:`~lunar_drake.autonomy.costmap.MapConfig`).
        hazards: how the map becomes a costmap
            (:class:`~lunar_drake.autonomy.costmap.HazardConfig`).
        perception: stereo, visual odometry and mapping on the downlinked frames
            (:class:`~lunar_drake.perception.ground_pipeline.PerceptionConfig`; runs
            when frames come down: cameras on and ``flight.images.enabled``).
    """

    rate_hz: float = 10.0
    route: list[RouteSegment] = dc.field(default_factory=_default_route)
    goals: list[Goal] = dc.field(default_factory=list)
    actions: list[OperatorAction] = dc.field(default_factory=list)
    goal_tolerance_m: float = 1.0
    goto_tolerance_m: float = 0.2
    drive_speed_mps: float = 0.2
    heartbeat_s: float = 5.0
    auto_resume: bool = True
    max_resumes: int = 3
    max_replans: int = 3
    replan_deviation_m: float = 2.0
    max_extrapolation_s: float = 10.0
    ack_timeout_s: float = 20.0
    max_resends: int = 5
    resume_soc: float = 0.5
    map: MapConfig = dc.field(default_factory=MapConfig)
    hazards: HazardConfig = dc.field(default_factory=HazardConfig)
    perception: PerceptionConfig = dc.field(default_factory=PerceptionConfig)


@dc.dataclass
class LineOfSightConfig:
    """Direct-to-Earth line of sight (:class:`~lunar_drake.systems.earth_line_of_sight.
    EarthLineOfSight`): while the Earth is below the terrain horizon at the rover's
    antenna, both links lose every message (``no_line_of_sight``).

    Attributes:
        enabled: model it (False: always in view, e.g. through a relay orbiter).
        period_s: how often the horizon is checked (s), (0, 600].
        antenna_height_m: antenna above the chassis origin (m), [0, 10].
        min_margin_deg: the Earth's centre must clear the horizon by this much (deg).
    """

    enabled: bool = True
    period_s: float = 1.0
    antenna_height_m: float = 1.0
    min_margin_deg: float = 0.0

    def validate(self) -> None:
        check_range("period_s", self.period_s, 0.0, 600.0, lo_open=True, unit=" s")
        check_range("antenna_height_m", self.antenna_height_m, 0.0, 10.0, unit=" m")
        check_range("min_margin_deg", self.min_margin_deg, -90.0, 90.0, unit=" deg")


def _default_downlink() -> LinkConfig:
    # Housekeeping on one channel, camera frames on their own (a 1280 x 960 16-bit PNG
    # is about 1.5 MB: the bucket must hold the largest message). Placeholder figures.
    return LinkConfig(
        channels=[
            ChannelConfig(name="main"),
            ChannelConfig(
                name="images",
                bandwidth_bps=2.0e6,
                bucket_bytes=8_000_000,
                queue_limit_bytes=32_000_000,
                topics=["images"],
            ),
        ]
    )


@dc.dataclass
class CommsConfig:
    """The Earth-Moon link, one config per direction, and the line of sight to Earth.
    The downlink's default has a ``main`` channel and an ``images`` channel."""

    uplink: LinkConfig = dc.field(default_factory=LinkConfig)
    downlink: LinkConfig = dc.field(default_factory=_default_downlink)
    line_of_sight: LineOfSightConfig = dc.field(default_factory=LineOfSightConfig)


@dc.dataclass
class LoggingConfig:
    """What a run records.

    Attributes:
        period_s: sample period of the CSV logs of truth and sensors (s).
        save_frames: write every camera frame into the run directory (frames/).
    """

    period_s: float = 0.1
    save_frames: bool = True


MAX_DURATION_S = 1.0e7
"""The longest ``simulation_duration`` a scenario may ask for (s)."""


@dc.dataclass
class Scenario:
    """Everything a run needs. Field names are the YAML keys.

    Attributes:
        name: a label for the run (summaries carry it); the loader sets it to the named
            scenario's name when the file does not.
        random_seed: the run's seed (DESIGN.md decision 6): sensor noise, link losses
            and delays' jitter, IMU biases, instrument counts -- every random stream of
            the mission. The site (terrain, world model, orbital map) has its own,
            ``site.seed``: changing ``random_seed`` never moves the ground.
        simulation_duration: simulated time (s).
        science: the world model science instruments read (:mod:`lunar_drake.science`;
            built on demand for the site and the epoch, and cached).
        power: the rover's solar array, battery and loads
            (:class:`~lunar_drake.power.config.PowerConfig`; the panel's size and mount
            are the rover description's).
    """

    name: str = ""
    random_seed: int = 0
    simulation_duration: float = 5.0
    site: SiteConfig = dc.field(default_factory=SiteConfig)
    terrain: TerrainConfig = dc.field(default_factory=TerrainConfig)
    soil: SoilParams = dc.field(default_factory=SoilParams)
    rover: RoverConfig = dc.field(default_factory=RoverConfig)
    sensors: SensorsConfig = dc.field(default_factory=SensorsConfig)
    lighting: LightingConfig = dc.field(default_factory=LightingConfig)
    flight: FlightConfig = dc.field(default_factory=FlightConfig)
    ground: GroundConfig = dc.field(default_factory=GroundConfig)
    comms: CommsConfig = dc.field(default_factory=CommsConfig)
    logging: LoggingConfig = dc.field(default_factory=LoggingConfig)
    terrain_view: TerrainViewConfig = dc.field(default_factory=TerrainViewConfig)
    science: WorldConfig = dc.field(default_factory=WorldConfig)
    power: PowerConfig = dc.field(default_factory=PowerConfig)
    simulator_config: SimulatorConfig = dc.field(
        default_factory=lambda: SimulatorConfig(
            max_step_size=0.01, accuracy=1.0e-3, use_error_control=False, target_realtime_rate=0.0
        )
    )
    plant_config: MultibodyPlantConfig = dc.field(
        default_factory=lambda: MultibodyPlantConfig(
            time_step=0.01, discrete_contact_approximation="sap"
        )
    )
    visualization: VisualizationConfig = dc.field(
        default_factory=lambda: VisualizationConfig(publish_contacts=False, publish_inertia=False)
    )


# ------------------------------------------------------------------------------ validation


def _section(prefix: str, check) -> None:
    """Runs ``check()``; re-raises its error with the scenario key ``prefix.`` in front
    of the field it names."""
    try:
        check()
    except LunarDrakeError as exc:
        raise type(exc)(f"{prefix}.{exc}") from None


def _is_power_of_two(n: int) -> bool:
    return n >= 1 and (n & (n - 1)) == 0


def validate_scenario(s: Scenario) -> None:
    """Range-checks a loaded scenario; raises OutOfRangeError/ConfigError naming the key."""
    check_range("random_seed", s.random_seed, 0, 2**63 - 1)
    check_range("simulation_duration", s.simulation_duration, 0.0, MAX_DURATION_S, unit=" s")
    if not math.isfinite(s.simulation_duration):
        raise OutOfRangeError(f"simulation_duration = {s.simulation_duration!r} must be finite")
    check_range("site.seed", s.site.seed, 0, 2**63 - 1)
    check_range("site.latitude_deg", s.site.latitude_deg, -90.0, 90.0, unit=" deg")
    check_range("site.longitude_deg", s.site.longitude_deg, -360.0, 360.0, unit=" deg")
    try:
        epoch = datetime.datetime.fromisoformat(s.site.epoch_utc)
    except ValueError:
        raise ConfigError(
            f"site.epoch_utc = {s.site.epoch_utc!r} is not an ISO 8601 UTC time "
            "(e.g. 2027-11-15T00:00:00)"
        ) from None
    offset_min = round(epoch.utcoffset().total_seconds() / 60) if epoch.utcoffset() else 0
    if offset_min:
        h, m = divmod(abs(offset_min), 60)
        raise ConfigError(
            f"site.epoch_utc = {s.site.epoch_utc!r} is {'+-'[offset_min < 0]}{h:02d}:{m:02d} "
            "off UTC; give the time in UTC (e.g. 2027-11-15T00:00:00 or ...Z)"
        )
    _validate_terrain(s.terrain)
    check_range("terrain_view.max_mesh_px", s.terrain_view.max_mesh_px, 8, 4096)
    check_range("terrain_view.albedo_gain", s.terrain_view.albedo_gain, 0.0, 100.0, lo_open=True)
    _section("soil", s.soil.validate)
    _section("rover.description", s.rover.description.validate)
    check_range("rover.spawn_yaw_deg", s.rover.spawn_yaw_deg, -360.0, 360.0, unit=" deg")
    _validate_lights(s.rover.lights)
    _section("sensors.imu", s.sensors.imu.validate)
    _section("sensors.star_tracker", s.sensors.star_tracker.validate)
    _section("sensors.wheel_encoders", s.sensors.wheel_encoders.validate)
    _section("sensors.camera", s.sensors.camera.validate)
    _section("sensors.nss", s.sensors.nss.validate)
    _section("sensors.nirvss", s.sensors.nirvss.validate)
    _section("sensors.drill", s.sensors.drill.validate)
    if s.sensors.drill.enabled and not s.sensors.nirvss.enabled:
        raise ConfigError("sensors.drill.enabled needs sensors.nirvss.enabled (NIRVSS reads "
                          "the drill's samples)")  # fmt: skip
    _section("science", s.science.validate)
    _section("power", s.power.validate)
    li = s.lighting
    check_range(
        "lighting.ephemeris_update_s", li.ephemeris_update_s, 0.0, 86400.0, lo_open=True, unit=" s"
    )
    check_range("lighting.lightmap_interval_s", li.lightmap_interval_s, 60.0, 1.0e6, unit=" s")
    check_range("lighting.lightmap_max_px", li.lightmap_max_px, 64, 16384, unit=" px")
    for k in li.extra_kernels:
        if not Path(k).is_file():
            raise ConfigError(f"lighting.extra_kernels: {k!r} does not exist")
    f = s.flight
    check_range("flight.rate_hz", f.rate_hz, 1.0, 1000.0, unit=" Hz")
    check_range("flight.brake_delay_s", f.brake_delay_s, 0.0, 60.0, unit=" s")
    check_range("flight.telemetry_rate_hz", f.telemetry_rate_hz, 0.001, 100.0, unit=" Hz")
    _section("flight.gimbal", f.gimbal.validate)
    _section("flight.estimator", f.estimator.validate)
    if f.estimator.slip_calibration:
        from lunar_drake.dynamics.soil_io import load_soil

        try:
            load_soil(f.estimator.slip_calibration)
        except ConfigError as exc:
            raise ConfigError(f"flight.estimator.slip_calibration: {exc}") from None
    _section("flight.safety", f.safety.validate)
    _section("flight.images", f.images.validate)
    _section("flight.heading", f.heading.validate)
    if f.heading.policy == "sun" and s.rover.description.steering == "skid":
        raise ConfigError(
            "flight.heading.policy = 'sun' needs an explicit-steer rover (it crabs along "
            "the path while its panel faces the Sun); a skid-steer rover allows only 'path'"
        )
    check_range("ground.rate_hz", s.ground.rate_hz, 0.01, 1000.0, unit=" Hz")
    _validate_route(s)
    check_range("ground.goal_tolerance_m", s.ground.goal_tolerance_m, 0.05, 100.0, unit=" m")
    check_range("ground.goto_tolerance_m", s.ground.goto_tolerance_m, 0.05, 100.0, unit=" m")
    check_range("ground.drive_speed_mps", s.ground.drive_speed_mps, 0.01, 2.0, unit=" m/s")
    for k, g in enumerate(s.ground.goals):
        check_range(f"ground.goals[{k}].x_m", g.x_m, -1e6, 1e6, unit=" m")
        check_range(f"ground.goals[{k}].y_m", g.y_m, -1e6, 1e6, unit=" m")
    _validate_ground(s.ground)
    for k, a in enumerate(s.ground.actions):
        if a.action == "drill":
            if not s.sensors.drill.enabled:
                raise ConfigError(f"ground.actions[{k}].action = 'drill' needs "
                                  "sensors.drill.enabled")  # fmt: skip
            check_drill_request(a.depth_m, a.step_m, max_depth_m=s.sensors.drill.max_depth_m,
                                what=f"ground.actions[{k}].")  # fmt: skip
    timeout = s.flight.safety.uplink_timeout_s
    if timeout > 0 and s.ground.heartbeat_s > 0.5 * timeout:
        raise OutOfRangeError(
            f"ground.heartbeat_s = {s.ground.heartbeat_s:g} s must be at most half of "
            f"flight.safety.uplink_timeout_s = {timeout:g} s (the rover safes when the "
            "uplink is silent that long)"
        )
    _section("ground.map", s.ground.map.validate)
    _section("ground.hazards", s.ground.hazards.validate)
    _section("ground.perception", s.ground.perception.validate)
    _section("comms.uplink", s.comms.uplink.validate)
    _section("comms.downlink", s.comms.downlink.validate)
    _section("comms.line_of_sight", s.comms.line_of_sight.validate)
    check_range("logging.period_s", s.logging.period_s, 0.0, 100.0, lo_open=True, unit=" s")
    check_range(
        "simulator_config.max_step_size",
        s.simulator_config.max_step_size,
        0.0,
        10.0,
        lo_open=True,
        unit=" s",
    )
    check_range(
        "plant_config.time_step", s.plant_config.time_step, 0.0, 1.0, lo_open=True, unit=" s"
    )


def _validate_ground(g: GroundConfig) -> None:
    check_range("ground.heartbeat_s", g.heartbeat_s, 0.1, 3600.0, unit=" s")
    check_range("ground.max_resumes", g.max_resumes, 0, 1000)
    check_range("ground.max_replans", g.max_replans, 0, 1000)
    check_range("ground.replan_deviation_m", g.replan_deviation_m, 0.1, 1000.0, unit=" m")
    check_range("ground.max_extrapolation_s", g.max_extrapolation_s, 0.0, 3600.0, unit=" s")
    check_range("ground.ack_timeout_s", g.ack_timeout_s, 1.0, 3600.0, unit=" s")
    check_range("ground.max_resends", g.max_resends, 0, 1000)
    check_range("ground.resume_soc", g.resume_soc, 0.0, 1.0)
    for k, a in enumerate(g.actions):
        key = f"ground.actions[{k}]"
        if a.action not in ACTIONS:
            raise ConfigError(f"{key}.action = {a.action!r} is unknown; choose one of {ACTIONS}")
        check_range(f"{key}.t_s", a.t_s, 0.0, 1.0e7, unit=" s")
        if a.action == "goal":
            check_range(f"{key}.x_m", a.x_m, -1e6, 1e6, unit=" m")
            check_range(f"{key}.y_m", a.y_m, -1e6, 1e6, unit=" m")
        if a.action == "drive_arc":
            check_range(f"{key}.speed_mps", abs(a.speed_mps), 0.0, 1.0, lo_open=True,
                        unit=" m/s (absolute)")  # fmt: skip
            check_range(f"{key}.curvature_per_m", a.curvature_per_m, -10.0, 10.0, unit=" 1/m")
            check_range(f"{key}.distance_m", a.distance_m, 0.0, 1000.0, lo_open=True, unit=" m")
        if a.action == "point_mast":
            check_range(f"{key}.pan_deg", a.pan_deg, -360.0, 360.0, unit=" deg")
            check_range(f"{key}.tilt_deg", a.tilt_deg, -180.0, 180.0, unit=" deg")


def _validate_terrain(t: TerrainConfig) -> None:
    if t.sfd not in SFD_LAWS:
        raise ConfigError(f"terrain.sfd = {t.sfd!r} is unknown; choose one of {list(SFD_LAWS)}")
    check_range("terrain.size_px", t.size_px, 16, 65536)
    check_range("terrain.resolution_m", t.resolution_m, 0.0, 1000.0, lo_open=True, unit=" m")
    if not _is_power_of_two(t.factor):
        raise ConfigError(f"terrain.factor = {t.factor!r} must be a power of two (1, 2, 4, ...)")
    if not t.dem and t.size_px % t.factor:
        raise ConfigError(
            f"terrain.size_px = {t.size_px} must be a multiple of terrain.factor = {t.factor}"
        )
    check_range("terrain.min_crater_m", t.min_crater_m, 0.0, 1.0e5, lo_open=True, unit=" m")
    if t.max_crater_m and t.max_crater_m <= t.min_crater_m:
        raise OutOfRangeError(
            f"terrain.max_crater_m = {t.max_crater_m:g} must exceed terrain.min_crater_m = "
            f"{t.min_crater_m:g} (or be 0 for automatic)"
        )
    check_range("terrain.powerlaw_coefficient", t.powerlaw_coefficient, 0.0, 1.0e6, lo_open=True)
    check_range("terrain.powerlaw_exponent", t.powerlaw_exponent, -6.0, 0.0, hi_open=True)
    check_range("terrain.rock_abundance", t.rock_abundance, 0.0, 1.0, hi_open=True)
    check_range("terrain.min_rock_m", t.min_rock_m, 0.0, 100.0, lo_open=True, unit=" m")
    check_range("terrain.tile_px", t.tile_px, 64, 16384)
    check_range("terrain.workers", t.workers, 1, 256)


def _validate_lights(lights) -> None:
    if len(lights) > 4:
        raise OutOfRangeError(f"rover.lights has {len(lights)} lights; at most 4")
    for k, L in enumerate(lights):
        key = f"rover.lights[{k}]"
        if len(L.xyz) != 3 or len(L.direction) != 3:
            raise ConfigError(f"{key}: xyz and direction need 3 values each")
        check_range(f"{key}.intensity_W_per_sr", L.intensity_W_per_sr, 0.0, 1e6)
        check_range(
            f"{key}.outer_half_angle_deg",
            L.outer_half_angle_deg,
            0.0,
            89.0,
            lo_open=True,
            unit=" deg",
        )
        check_range(
            f"{key}.inner_half_angle_deg",
            L.inner_half_angle_deg,
            0.0,
            L.outer_half_angle_deg,
            hi_open=True,
            unit=" deg",
        )


def _validate_route(s: Scenario) -> None:
    route = s.ground.route
    if s.rover.description.steering == "skid":
        for k, seg in enumerate(route):
            if seg.vy_mps:
                raise ConfigError(
                    f"ground.route[{k}].vy_mps = {seg.vy_mps:g}: a skid-steer rover cannot "
                    "move sideways (use 0, or an explicit-steer rover)"
                )
    for k, seg in enumerate(route):
        check_range(f"ground.route[{k}].duration_s", seg.duration_s, 0.0, 1.0e6, unit=" s")
        check_range(f"ground.route[{k}].vx_mps", seg.vx_mps, -5.0, 5.0, unit=" m/s")
        check_range(f"ground.route[{k}].vy_mps", seg.vy_mps, -5.0, 5.0, unit=" m/s")
        check_range(f"ground.route[{k}].wz_radps", seg.wz_radps, -2.0, 2.0, unit=" rad/s")


def section_fields(obj, prefix: str = "") -> dict:
    """Every leaf field of a scenario (or section) as ``{"a.b.c": value}``; lists of
    dataclasses are entered as ``a[0].b``. Used to compare scenarios key by key."""
    out = {}
    if dc.is_dataclass(obj):
        for f in dc.fields(obj):
            out.update(section_fields(getattr(obj, f.name), f"{prefix}{f.name}."))
        return out
    if hasattr(obj, "__fields__") and not isinstance(obj, (list, dict)):
        # Drake's configs (SimulatorConfig, ...) are pybind classes with __fields__.
        for f in obj.__fields__:
            out.update(section_fields(getattr(obj, f.name), f"{prefix}{f.name}."))
        return out
    if isinstance(obj, list) and obj and dc.is_dataclass(obj[0]):
        for k, item in enumerate(obj):
            out.update(section_fields(item, f"{prefix[:-1]}[{k}]."))
        return out
    out[prefix[:-1]] = obj
    return out
