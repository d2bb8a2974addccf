"""Typed scenario for a whole run, loaded from YAML with Drake's ``yaml_load_typed``.

A scenario file holds named scenarios at its top level (see
``lunar_drake/scenarios/default.yaml``); ``load_scenario`` picks one by name, then
applies optional ``--scenario-text`` YAML overrides on top. Unknown keys are rejected,
and :func:`validate_scenario` checks every range after loading (``yaml_load_typed``
assigns fields without running ``__post_init__``).

Modelled on Drake's ``examples/hardware_sim/hardware_sim.py``.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import datetime
import math
import re
from importlib import resources
from pathlib import Path

from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.visualization import VisualizationConfig

from lunar_drake.errors import ConfigError, OutOfRangeError, check_range
from lunar_drake.models.rover_description import RoverDescription, krex2_rp

SFD_LAWS = ("trask", "viper", "powerlaw")


@dc.dataclass
class SiteConfig:
    """Where and when the mission happens.

    Attributes:
        name: human-readable site name.
        latitude_deg, longitude_deg: site centre on the IAU Moon sphere (deg; east lon).
        epoch_utc: UTC of simulation time 0 (ISO 8601).
    """

    name: str = "near Mons Mouton (approximate)"
    latitude_deg: float = -85.4
    longitude_deg: float = 31.6
    epoch_utc: str = "2027-11-15T00:00:00"


@dc.dataclass
class TerrainConfig:
    """The site raster: either a DEM file, or synthesized (paper section 4).

    Attributes:
        dem: path of a GeoTIFF DEM to use; empty to synthesize. With ``factor`` > 1 the
            DEM is fractally upscaled by ``factor`` first.
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
class RouteSegment:
    """One piece of an open-loop route: a body twist held for a duration.

    Attributes:
        duration_s: how long (s). vx_mps, vy_mps: chassis-frame velocity (m/s).
        wz_radps: yaw rate (rad/s).
    """

    duration_s: float = 1.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    wz_radps: float = 0.0


def _default_route() -> list:
    # About 100 m: straight, a gentle left arc, straight (0.2 m/s, RP-class speed).
    return [
        RouteSegment(duration_s=2.0),
        RouteSegment(duration_s=250.0, vx_mps=0.2),
        RouteSegment(duration_s=100.0, vx_mps=0.2, wz_radps=0.01),
        RouteSegment(duration_s=250.0, vx_mps=0.2),
    ]


@dc.dataclass
class RoverConfig:
    """The rover, its soil and its route.

    Attributes:
        enabled: add a rover to the mission diagram.
        description: the rover model (see lunar_drake/models/rover_description.py; the
            default is the explicit-steer RP/KRex2-class preset).
        soil: soil preset name (lunar_regolith, grc1).
        spawn_x_m, spawn_y_m, spawn_yaw_deg: start pose on the site (site frame).
        route: open-loop route (until the autonomy stack drives).
        log_period_s: period of the CSV logs (s).
    """

    enabled: bool = True
    description: RoverDescription = dc.field(default_factory=krex2_rp)
    soil: str = "lunar_regolith"
    spawn_x_m: float = 0.0
    spawn_y_m: float = 0.0
    spawn_yaw_deg: float = 0.0
    route: list[RouteSegment] = dc.field(default_factory=_default_route)
    log_period_s: float = 0.1


@dc.dataclass
class SpotlightConfig:
    """A rover spotlight rigidly attached to a rover body (paper: up to four lights).

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
class CameraConfig:
    """The mast stereo pair (Hapke camera; DESIGN.md decision 3).

    Attributes:
        enabled: render the stereo pair (``lunar-drake run --no-cameras`` turns it off).
        width, height: image size (px). fov_y_deg: vertical field of view (deg).
        rate_hz: frame rate (Hz). exposure_s, gain: sensor exposure (s) and analog gain.
        shadow_samples: rays toward the solar disk per rover-shadow penumbra pixel.
        lookahead_m: the gimbal points at the ground this far ahead of the rover (m).
        save_frames: write every frame into the run directory (frames/).
        spotlights: up to 4 rover lights.
        engine: ``heightfield`` (fast: DEM ray marching, tabulated Hapke, compiled
            shading) or ``raycast`` (reference: Embree over LOD triangles, exact Hapke);
            docs/lighting.md compares them.
    """

    enabled: bool = True
    width: int = 640
    height: int = 480
    fov_y_deg: float = 45.0
    rate_hz: float = 0.2
    exposure_s: float = 0.002
    gain: float = 1.0
    shadow_samples: int = 8
    lookahead_m: float = 6.0
    save_frames: bool = True
    spotlights: list[SpotlightConfig] = dc.field(default_factory=list)
    engine: str = "heightfield"


@dc.dataclass
class LightingConfig:
    """Sun, Earth and baked shadows.

    Attributes:
        ephemeris_update_s: how often Sun/Earth directions are recomputed (s).
        lightmap: bake terrain-shadow lightmaps for the camera.
        lightmap_interval_s: spacing of baked lightmaps (s; the paper planned hourly).
        lightmap_max_px: bake on the DEM decimated to at most this many pixels a side.
        extra_kernels: additional SPICE kernels (paths) furnished after the built-in ones.
    """

    ephemeris_update_s: float = 10.0
    lightmap: bool = True
    lightmap_interval_s: float = 3600.0
    lightmap_max_px: int = 2048
    extra_kernels: list[str] = dc.field(default_factory=list)


@dc.dataclass
class Scenario:
    """Everything a run needs. Field names are the YAML keys."""

    random_seed: int = 0
    simulation_duration: float = 5.0
    site: SiteConfig = dc.field(default_factory=SiteConfig)
    terrain: TerrainConfig = dc.field(default_factory=TerrainConfig)
    terrain_view: TerrainViewConfig = dc.field(default_factory=TerrainViewConfig)
    rover: RoverConfig = dc.field(default_factory=RoverConfig)
    camera: CameraConfig = dc.field(default_factory=CameraConfig)
    lighting: LightingConfig = dc.field(default_factory=LightingConfig)
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


def default_scenario_file() -> Path:
    """The scenario file shipped with the package."""
    return Path(str(resources.files("lunar_drake") / "scenarios" / "default.yaml"))


def _drake_error(exc: Exception, *, where: str) -> ConfigError:
    msg = str(exc)
    m = re.search(r"YAML key '([^']+)'", msg)
    hint = ""
    if m:
        hint = f" (unknown key {m.group(1)!r}; see Scenario in lunar_drake/scenario.py)"
    return ConfigError(f"invalid scenario in {where}: {msg}{hint}")


def scenario_names(*, filename: str | Path | None = None) -> list[str]:
    """Names of the scenarios in a scenario file."""
    import yaml

    path = Path(filename) if filename else default_scenario_file()
    with open(path) as f:
        data = yaml.safe_load(f) or {}
    return sorted(data)


def load_scenario(
    *, filename: str | Path | None = None, scenario_name: str = "default", scenario_text: str = "{}"
) -> Scenario:
    """Loads ``scenario_name`` from ``filename`` (default: the packaged file), applies the
    ``scenario_text`` YAML overrides and validates the result.

    Raises:
        ConfigError: unknown file, name or key, a malformed value, or a value out of range.
    """
    path = Path(filename) if filename else default_scenario_file()
    if not path.is_file():
        raise ConfigError(f"scenario file {str(path)!r} does not exist")
    names = scenario_names(filename=path)
    if scenario_name not in names:
        raise ConfigError(
            f"scenario {scenario_name!r} not found in {str(path)!r}; choose one of {names}"
        )
    try:
        result = yaml_load_typed(
            schema=Scenario, filename=str(path), child_name=scenario_name, defaults=Scenario()
        )
    except Exception as exc:  # Drake raises RuntimeError for schema mismatches.
        raise _drake_error(exc, where=f"{path}:{scenario_name}") from exc
    try:
        result = yaml_load_typed(schema=Scenario, data=scenario_text, defaults=result)
    except Exception as exc:
        raise _drake_error(exc, where="--scenario-text") from exc
    validate_scenario(result)
    return result


def scenario_from_text(text: str) -> Scenario:
    """A validated scenario from a YAML mapping (no name level), over the defaults."""
    try:
        result = yaml_load_typed(schema=Scenario, data=text, defaults=Scenario())
    except Exception as exc:
        raise _drake_error(exc, where="scenario text") from exc
    validate_scenario(result)
    return result


def dump_scenario(scenario: Scenario) -> str:
    """YAML text of a scenario (loads back to an equal scenario)."""
    return yaml_dump_typed(scenario)


_check = check_range


def _is_power_of_two(n: int) -> bool:
    return n >= 1 and (n & (n - 1)) == 0


def validate_scenario(s: Scenario) -> None:
    """Range-checks a loaded scenario; raises OutOfRangeError/ConfigError naming the field."""
    _check("random_seed", s.random_seed, 0, 2**63 - 1)
    _check("simulation_duration", s.simulation_duration, 0.0, 1.0e7, unit=" s")
    _check("site.latitude_deg", s.site.latitude_deg, -90.0, 90.0, unit=" deg")
    _check("site.longitude_deg", s.site.longitude_deg, -360.0, 360.0, unit=" deg")
    t = s.terrain
    if t.sfd not in SFD_LAWS:
        raise ConfigError(f"terrain.sfd = {t.sfd!r} is unknown; choose one of {list(SFD_LAWS)}")
    _check("terrain.size_px", t.size_px, 16, 65536)
    _check("terrain.resolution_m", t.resolution_m, 0.0, 1000.0, lo_open=True, unit=" m")
    if not _is_power_of_two(t.factor):
        raise ConfigError(f"terrain.factor = {t.factor!r} must be a power of two (1, 2, 4, ...)")
    if not t.dem and t.size_px % t.factor:
        raise ConfigError(
            f"terrain.size_px = {t.size_px} must be a multiple of terrain.factor = {t.factor}"
        )
    _check("terrain.min_crater_m", t.min_crater_m, 0.0, 1.0e5, lo_open=True, unit=" m")
    if t.max_crater_m and t.max_crater_m <= t.min_crater_m:
        raise OutOfRangeError(
            f"terrain.max_crater_m = {t.max_crater_m!r} must exceed terrain.min_crater_m = "
            f"{t.min_crater_m!r} (or be 0 for automatic)"
        )
    _check("terrain.powerlaw_coefficient", t.powerlaw_coefficient, 0.0, 1.0e6, lo_open=True)
    _check("terrain.powerlaw_exponent", t.powerlaw_exponent, -6.0, 0.0, hi_open=True)
    _check("terrain.rock_abundance", t.rock_abundance, 0.0, 1.0, hi_open=True)
    _check("terrain.min_rock_m", t.min_rock_m, 0.0, 100.0, lo_open=True, unit=" m")
    _check("terrain.tile_px", t.tile_px, 64, 16384)
    _check("terrain.workers", t.workers, 1, 256)
    _check("terrain_view.max_mesh_px", s.terrain_view.max_mesh_px, 8, 4096)
    _check("terrain_view.albedo_gain", s.terrain_view.albedo_gain, 0.0, 100.0, lo_open=True)
    _check(
        "simulator_config.max_step_size",
        s.simulator_config.max_step_size,
        0.0,
        10.0,
        lo_open=True,
        unit=" s",
    )
    _check("plant_config.time_step", s.plant_config.time_step, 0.0, 1.0, unit=" s")
    try:
        datetime.datetime.fromisoformat(s.site.epoch_utc)
    except ValueError as exc:
        raise ConfigError(
            f"site.epoch_utc = {s.site.epoch_utc!r} is not an ISO 8601 UTC time "
            "(e.g. 2027-11-15T00:00:00)"
        ) from exc
    r = s.rover
    try:
        r.description.validate()
    except ConfigError as exc:
        raise type(exc)(f"rover.description: {exc}") from exc
    from lunar_drake.dynamics.terramechanics import SOIL_PRESETS

    if r.soil not in SOIL_PRESETS:
        raise ConfigError(
            f"rover.soil = {r.soil!r} is unknown; choose one of {sorted(SOIL_PRESETS)}"
        )
    _check("rover.spawn_yaw_deg", r.spawn_yaw_deg, -360.0, 360.0, unit=" deg")
    _check("rover.log_period_s", r.log_period_s, 0.0, 100.0, lo_open=True, unit=" s")
    if r.description.steering == "skid" and any(seg.vy_mps for seg in r.route):
        raise ConfigError("rover.route has vy_mps != 0, which a skid-steer rover cannot do")
    for k, seg in enumerate(r.route):
        _check(f"rover.route[{k}].duration_s", seg.duration_s, 0.0, 1.0e6, unit=" s")
        _check(f"rover.route[{k}].vx_mps", seg.vx_mps, -5.0, 5.0, unit=" m/s")
        _check(f"rover.route[{k}].vy_mps", seg.vy_mps, -5.0, 5.0, unit=" m/s")
        _check(f"rover.route[{k}].wz_radps", seg.wz_radps, -2.0, 2.0, unit=" rad/s")
    c = s.camera
    _check("camera.width", c.width, 16, 8192, unit=" px")
    _check("camera.height", c.height, 16, 8192, unit=" px")
    _check("camera.fov_y_deg", c.fov_y_deg, 1.0, 170.0, unit=" deg")
    _check("camera.rate_hz", c.rate_hz, 0.0, 100.0, lo_open=True, unit=" Hz")
    _check("camera.exposure_s", c.exposure_s, 0.0, 10.0, lo_open=True, unit=" s")
    _check("camera.gain", c.gain, 0.0, 64.0, lo_open=True)
    _check("camera.shadow_samples", c.shadow_samples, 1, 64)
    _check("camera.lookahead_m", c.lookahead_m, 0.5, 1000.0, unit=" m")
    if c.engine not in ("heightfield", "raycast"):
        raise ConfigError(f"camera.engine = {c.engine!r}; allowed heightfield, raycast")
    if len(c.spotlights) > 4:
        raise OutOfRangeError(f"camera.spotlights has {len(c.spotlights)} lights; at most 4")
    for k, L in enumerate(c.spotlights):
        if len(L.xyz) != 3 or len(L.direction) != 3:
            raise ConfigError(f"camera.spotlights[{k}]: xyz and direction need 3 values")
        _check(f"camera.spotlights[{k}].intensity_W_per_sr", L.intensity_W_per_sr, 0.0, 1e6)
        _check(
            f"camera.spotlights[{k}].outer_half_angle_deg",
            L.outer_half_angle_deg,
            0.0,
            89.0,
            lo_open=True,
            unit=" deg",
        )
        _check(
            f"camera.spotlights[{k}].inner_half_angle_deg",
            L.inner_half_angle_deg,
            0.0,
            L.outer_half_angle_deg,
            hi_open=True,
            unit=" deg",
        )
    li = s.lighting
    _check(
        "lighting.ephemeris_update_s", li.ephemeris_update_s, 0.0, 86400.0, lo_open=True, unit=" s"
    )
    _check("lighting.lightmap_interval_s", li.lightmap_interval_s, 60.0, 1.0e6, unit=" s")
    _check("lighting.lightmap_max_px", li.lightmap_max_px, 64, 16384, unit=" px")
    for k in li.extra_kernels:
        if not Path(k).is_file():
            raise ConfigError(f"lighting.extra_kernels: {k!r} does not exist")
    if s.plant_config.time_step <= 0 and r.enabled:
        raise ConfigError("plant_config.time_step must be > 0 (a discrete SAP plant) with a rover")
    if not math.isfinite(s.simulation_duration):
        raise OutOfRangeError(f"simulation_duration = {s.simulation_duration!r} must be finite")
