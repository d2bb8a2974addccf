"""The Hapke terrain camera core: ray-cast LOD terrain + rover geometry, deferred Hapke
shading, and the sensor model (no Drake; the LeafSystem is systems/hapke_camera.py).

Per frame (reference ``raycast`` engine): centre the level-of-detail terrain on the camera
position rounded to ``lod_recenter_m`` (cached tiles are reused), cast one ray per pixel (Open3D /
Embree), shade with the Hapke (2012, Sato et al. 2014 form) bidirectional reflectance
blended with Lunar-Lambert near grazing emission, scaled per pixel by the albedo map,
lit by the Sun (times the baked lightmap and a soft ray-cast rover shadow), an indirect
fill opposing the Sun, Earthshine and rover spotlights; then the sensor: exposure and
gain, shot and read noise, 12-bit ADC into uint16.

Units: the shaded image is the radiance factor I/F for a unit solar irradiance at 1 au;
Sun and Earth irradiances are scaled by distance. Earthshine irradiance on a surface
facing Earth is ``A_E (R_E / d)^2 k(phase)`` of the solar irradiance, with Earth's
Bond albedo A_E = 0.3 and k the illuminated fraction (a Lambert-sphere simplification).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import functools
import math

import numpy as np

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError, check_range
from lunar_drake.render import hapke as hapke_mod
from lunar_drake.render import sensor as sensor_mod
from lunar_drake.render.raycast import DynamicMesh, PinholeCamera, TerrainRaycaster
from lunar_drake.render.regolith import RegolithTextureConfig
from lunar_drake.render.shading import (
    Illumination,
    RasterSampler,
    ShadedImage,
    ShadingConfig,
    SpotLight,
    brdf_from_reflectance,
    shade,
    trace,
)
from lunar_drake.render.terrain_lod import TerrainLOD

ENGINES = ("heightfield", "raycast")
"""Camera engines: the fast DEM ray-marching engine and the Embree reference engine."""

AU_KM = 149_597_870.7
EARTH_RADIUS_KM = 6371.0
EARTH_BOND_ALBEDO = 0.3


@dc.dataclass
class CameraConfig:
    """The mast stereo cameras: timing, optics, sensor settings and render engine (one
    config for the scenario's ``sensors.camera`` section and the renderer).

    Attributes:
        enabled: render the stereo pair (``lunar-drake run --no-cameras`` turns it off).
        rate_hz: frame rate (Hz). delay_s: delivery delay of each frame (s).
        width, height: image size (px). fov_y_deg: vertical field of view (deg).
        exposure_s, gain: exposure time (s) and analog gain.
        shadow_samples: rays toward the solar disk per penumbra pixel (soft rover shadow).
        engine: ``"heightfield"`` -- the fast engine (:mod:`lunar_drake.render.
            fast_engine`: DEM ray marching, tabulated BRDF, one compiled shading pass)
            -- or ``"raycast"`` -- the reference engine (Embree over LOD triangle tiles,
            exact BRDF, numpy shading); docs/lighting.md compares them.
        near_radius_m: full-resolution terrain radius around the camera (m; raycast).
        tile_px: LOD tile size (px; raycast). lod_recenter_m: the LOD terrain is centred
            on the camera position rounded to this grid (m; raycast), so it depends on
            the camera pose only, never on the history of frames.
        fill_fraction: indirect fill as a fraction of the direct sunlight (paper: ~3%).
        fill_fraction_sun_down: fill fraction when the Sun is below the horizon (light
            scattered from sunlit distant terrain; an assumption).
        earthshine_min_fraction: earthshine fainter than this fraction of the solar
            irradiance is left out (near new Earth, where it is at most a few hundredths
            of a code on sunlit terrain; at full Earth it is about 8e-5).
        limb_blend_deg: [start, end] emission angles (deg) over which Hapke blends into
            Lunar-Lambert.
        normal_map_max_px: the smooth-shading normal map is built from the DEM decimated
            to at most this many pixels a side (0: use the LOD triangles' flat normals;
            the heightfield engine then uses 4096).
        dem_max_px: the heightfield engine's DEM is decimated to at most this many
            pixels a side.
        sensor: the image sensor and optics: full well, read noise, ADC, QE, dark
            current, f-number (:class:`~lunar_drake.render.sensor.SensorParams`; default
            the CMV4000-class navigation camera).
    """

    enabled: bool = False
    rate_hz: float = 0.2
    delay_s: float = 0.0
    width: int = 640
    height: int = 480
    fov_y_deg: float = 45.0
    exposure_s: float = 0.002
    gain: float = 1.0
    shadow_samples: int = 8
    engine: str = "heightfield"
    near_radius_m: float = 20.0
    tile_px: int = 256
    lod_recenter_m: float = 10.0
    fill_fraction: float = 0.03
    fill_fraction_sun_down: float = 0.003
    earthshine_min_fraction: float = 1e-5
    limb_blend_deg: list[float] = dc.field(default_factory=lambda: [84.0, 89.0])
    normal_map_max_px: int = 4096
    dem_max_px: int = 8192
    sensor: sensor_mod.SensorParams = dc.field(default_factory=sensor_mod.SensorParams)

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        if self.engine not in ENGINES:
            raise ConfigError(f"engine = {self.engine!r} is unknown; allowed {', '.join(ENGINES)}")
        check_range("rate_hz", self.rate_hz, 0.0, 100.0, lo_open=True, unit=" Hz")
        check_range("delay_s", self.delay_s, 0.0, 3600.0, unit=" s")
        check_range("width", self.width, 16, 8192, unit=" px")
        check_range("height", self.height, 16, 8192, unit=" px")
        check_range("fov_y_deg", self.fov_y_deg, 1.0, 170.0, unit=" deg")
        check_range("exposure_s", self.exposure_s, 0.0, 10.0, lo_open=True, unit=" s")
        check_range("gain", self.gain, 0.0, 64.0, lo_open=True)
        check_range("shadow_samples", self.shadow_samples, 1, 64)
        check_range("near_radius_m", self.near_radius_m, 1.0, 10000.0, unit=" m")
        if self.tile_px < 4 or self.tile_px > 4096 or self.tile_px & (self.tile_px - 1):
            raise OutOfRangeError(
                f"tile_px = {self.tile_px!r} is out of range; allowed powers of two in [4, 4096] px"
            )
        check_range("lod_recenter_m", self.lod_recenter_m, 0.0, 10000.0, lo_open=True, unit=" m")
        check_range("fill_fraction", self.fill_fraction, 0.0, 1.0)
        check_range("fill_fraction_sun_down", self.fill_fraction_sun_down, 0.0, 1.0)
        check_range("earthshine_min_fraction", self.earthshine_min_fraction, 0.0, 1.0)
        lb = self.limb_blend_deg
        if len(lb) != 2 or not 0.0 <= lb[0] < lb[1] <= 90.0:
            raise OutOfRangeError(
                f"limb_blend_deg = {list(lb)!r} is out of range; need [start, end] with "
                "0 <= start < end <= 90 deg"
            )
        check_range("normal_map_max_px", self.normal_map_max_px, 0, 65536, unit=" px")
        check_range("dem_max_px", self.dem_max_px, 64, 65536, unit=" px")

        try:
            self.sensor.validate()
        except LunarDrakeError as exc:
            raise type(exc)(f"sensor.{exc}") from None

    def pinhole(self) -> PinholeCamera:
        return PinholeCamera.from_fov(
            width=self.width, height=self.height, fov_y_rad=math.radians(self.fov_y_deg)
        )


def earthshine_fraction(*, earth_distance_km: float, earth_phase: float) -> float:
    """Earthshine irradiance as a fraction of the solar irradiance (see module doc)."""
    return EARTH_BOND_ALBEDO * (EARTH_RADIUS_KM / earth_distance_km) ** 2 * float(earth_phase)


def _normal_samplers(heightfield, *, max_px: int):
    """Bilinear samplers of the DEM's unit-normal x and y components (site frame)."""
    if max_px <= 0:
        return None
    from lunar_drake.terrain.surface import normals_from_dem

    z, res = heightfield.decimated(max_size=max_px)
    z = np.asarray(z, np.float32)
    if np.isnan(z).any():
        z = np.where(np.isnan(z), np.float32(np.nanmean(z)), z)
    n = normals_from_dem(np.pad(z, 1, mode="edge"), resolution_m=res)
    return (
        RasterSampler.on_heightfield(n[0], heightfield, outside=0.0),
        RasterSampler.on_heightfield(n[1], heightfield, outside=0.0),
    )


class TerrainCameraRenderer:
    """Renders frames of one site for any number of cameras (they share the scene).

    Args:
        heightfield: the site terrain. albedo: normal-albedo grid covering the site (any
            resolution) or None (0.15 everywhere).
        model: CameraConfig (optics, sensor settings, engine). hapke: HapkeParams.
        dynamic_meshes: the rover's meshes (DynamicMesh, in their geometry frames).
        texture: the sub-cell regolith texture (:class:`~lunar_drake.render.regolith.
            RegolithTextureConfig`; None = the default, on with a fixed seed).
        soft_shadows: smooth (quadratic B-spline) lightmap reconstruction.
    """

    def __init__(
        self,
        *,
        heightfield,
        albedo=None,
        model: CameraConfig | None = None,
        hapke: hapke_mod.HapkeParams = hapke_mod.HIGHLANDS_643NM,
        dynamic_meshes=(),
        texture: RegolithTextureConfig | None = None,
        soft_shadows: bool = True,
    ):
        model = CameraConfig() if model is None else model
        model.validate()
        self.heightfield = heightfield
        self.model = model
        self.sensor = model.sensor
        self._albedo = (
            None
            if albedo is None
            else RasterSampler.on_heightfield(np.asarray(albedo, np.float32), heightfield)
        )
        self._brdf = brdf_from_reflectance(
            functools.partial(
                hapke_mod.blended_reflectance,
                params=hapke,
                start_deg=model.limb_blend_deg[0],
                end_deg=model.limb_blend_deg[1],
            )
        )
        self._config = ShadingConfig(
            shadow_samples=model.shadow_samples,
            texture=RegolithTextureConfig() if texture is None else texture,
            soft_shadows=soft_shadows,
        )
        self._normals = _normal_samplers(heightfield, max_px=model.normal_map_max_px)
        self._hapke = hapke
        self._fast = None
        self._camera = model.pinhole()
        self._raycaster = TerrainRaycaster()
        self._lod = None
        self._lod_centre = None
        self._meshes = list(dynamic_meshes)
        if self._meshes:
            self._raycaster.set_dynamic_meshes(self._meshes, [np.eye(4)] * len(self._meshes))

    @property
    def raycaster(self) -> TerrainRaycaster:
        return self._raycaster

    def fast_engine(self):
        """The heightfield engine's per-site state (DEM pyramid, reflectance table),
        built on first use (about a second for a 2048^2 site)."""
        if self._fast is None:
            from lunar_drake.render.fast_engine import FastTerrainEngine

            normals = self._normals or _normal_samplers(self.heightfield, max_px=4096)
            reflectance = functools.partial(
                hapke_mod.blended_reflectance,
                params=self._hapke,
                start_deg=self.model.limb_blend_deg[0],
                end_deg=self.model.limb_blend_deg[1],
                dtype=np.float64,
            )
            self._fast = FastTerrainEngine.build(
                heightfield=self.heightfield,
                reflectance=reflectance,
                normals=normals,
                albedo=self._albedo,
                config=self._config,
                max_px=self.model.dem_max_px,
            )
        return self._fast

    def _ensure_lod(self, p_WC):
        # The LOD centre is the camera position rounded to a lod_recenter_m grid: the
        # terrain a frame sees depends on its pose only, never on earlier frames (the
        # tiles are a cache, not state).
        g = self.model.lod_recenter_m
        b = self.heightfield.bounds
        c = (
            min(max(round(float(p_WC[0]) / g) * g, b.left), b.right),
            min(max(round(float(p_WC[1]) / g) * g, b.bottom), b.top),
        )
        if self._lod is None:
            self._lod = TerrainLOD.build(
                self.heightfield,
                center_xy=c,
                tile_px=self.model.tile_px,
                near_radius_m=self.model.near_radius_m,
            )
            self._raycaster.set_terrain(self._lod)
        elif c != self._lod_centre and self._lod.changes_at(c):
            self._lod.recenter(c)
            self._raycaster.set_terrain(self._lod)
        self._lod_centre = c

    def illumination(
        self,
        *,
        sun_dir_W,
        sun_distance_km=AU_KM,
        earth_dir_W=None,
        earth_distance_km=384_400.0,
        earth_phase=0.0,
        spotlights=(),
    ):
        """``(Illumination, sun_up)`` for one instant (site-frame unit vectors, km).

        Sun above the horizontal: direct sunlight (the lightmap adds terrain horizons)
        plus the fill. Sun below it: no direct light; a weak fill
        (``fill_fraction_sun_down``) from sunlit distant terrain, arriving from the
        opposite azimuth at 5 deg elevation, unshadowed by the lightmap. Earthshine when
        Earth is above the horizontal and its irradiance at least
        ``earthshine_min_fraction`` of the Sun's.
        """
        sun = np.asarray(sun_dir_W, float)
        sun = sun / np.linalg.norm(sun)
        e_sun = (AU_KM / float(sun_distance_km)) ** 2
        earth, e_earth = None, 0.0
        if earth_dir_W is not None and float(np.asarray(earth_dir_W)[2]) > 0.0:
            f_earth = earthshine_fraction(
                earth_distance_km=earth_distance_km, earth_phase=earth_phase
            )
            if f_earth >= self.model.earthshine_min_fraction:
                earth = tuple(float(v) for v in earth_dir_W)
                e_earth = e_sun * f_earth
        spots = tuple(spotlights)
        if sun[2] > 0.0:
            return Illumination(
                sun_direction_W=tuple(sun),
                sun_irradiance=e_sun,
                fill_fraction=self.model.fill_fraction,
                earth_direction_W=earth,
                earth_irradiance=e_earth,
                spotlights=spots,
            ), True
        h = np.array([-sun[0], -sun[1], 0.0])
        h = (
            h / max(np.linalg.norm(h), 1e-12)
            if np.linalg.norm(h) > 1e-9
            else np.array([1.0, 0.0, 0.0])
        )
        el = math.radians(5.0)
        fill_dir = (h[0] * math.cos(el), h[1] * math.cos(el), math.sin(el))
        return Illumination(
            sun_direction_W=fill_dir,
            sun_irradiance=self.model.fill_fraction_sun_down * e_sun,
            fill_fraction=0.0,
            earth_direction_W=earth,
            earth_irradiance=e_earth,
            spotlights=spots,
        ), False

    def shade(
        self, *, X_WC, illumination: Illumination, dynamic_poses=(), lightmap=None, track_depth=None
    ) -> ShadedImage:
        """Ray-casts and shades one frame (I/F-like radiance, depth, label). Pass
        ``lightmap=None`` when :meth:`illumination` says the Sun is down."""
        X = np.asarray(X_WC.GetAsMatrix4() if hasattr(X_WC, "GetAsMatrix4") else X_WC, float)
        if self._meshes:
            self._raycaster.set_dynamic_poses(list(dynamic_poses))
        if self.model.engine == "heightfield":
            return self.fast_engine().render(
                camera=self._camera,
                X_WC=X,
                illumination=illumination,
                raycaster=self._raycaster,
                brdf=self._brdf,
                lightmap=lightmap,
                track_depth=track_depth,
            )
        self._ensure_lod(X[:3, 3])
        gb = trace(self._raycaster, self._camera, X)
        if self._normals is not None and gb.index.size:
            # Smooth shading: terrain normals from the DEM's normal map (bilinear), not
            # the flat LOD triangles (which show as facets under a grazing Sun).
            t = gb.terrain
            x, y = gb.position[0, t], gb.position[1, t]
            nx = self._normals[0](x, y)
            ny = self._normals[1](x, y)
            nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 1e-6, 1.0))
            n = gb.normal.copy()
            n[0, t], n[1, t], n[2, t] = nx, ny, nz
            gb = dc.replace(gb, normal=n)
        return shade(
            gb,
            self._raycaster,
            illumination,
            brdf=self._brdf,
            albedo=self._albedo,
            lightmap=lightmap,
            track_depth=track_depth,
            config=self._config,
        )

    def expose(
        self,
        shaded: ShadedImage,
        *,
        exposure_s: float,
        gain: float,
        key: int,
        frame_index: int,
    ) -> np.ndarray:
        """The sensor's raw uint16 frame (12-bit codes) from a shaded image.

        The shaded image is already in units of the solar irradiance at 1 au (the Sun's
        distance is applied in :meth:`illumination`), so it converts at 1 au here.
        """
        # L = (I/F) E_band / pi (sensor.radiance_from_i_over_f at 1 au), applied inside
        # the sensor kernel: the same bytes without a float64 copy of the frame
        return sensor_mod.expose(
            shaded.radiance,
            radiance_scale=self.sensor.band_solar_irradiance_W_m2 / math.pi,
            clamp_negative=True,
            exposure_s=exposure_s,
            gain=gain,
            params=self.sensor,
            key=key,
            frame_index=frame_index,
        )


__all__ = [
    "CameraConfig",
    "DynamicMesh",
    "SpotLight",
    "TerrainCameraRenderer",
    "earthshine_fraction",
]
