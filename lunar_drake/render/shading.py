"""Deferred shading of a ray-cast G-buffer (paper section 5; DESIGN.md decision 3).

Pipeline: :func:`trace` casts one ray per pixel (:class:`~lunar_drake.render.raycast.
TerrainRaycaster`) into a :class:`GBuffer` (hit position, normal, view direction,
label, depth); :func:`shade` evaluates the lights per hit pixel in numpy;
:func:`render` does both.

Output units -- "I/F-like relative radiance": each pixel holds

    I = pi * sum_k E_k * f_r(cos_i_k, cos_e, g_k) * cos_i_k

with ``E_k`` the irradiance of light k on a surface facing it, in the units the caller
uses for :attr:`Illumination.sun_irradiance`. With ``sun_irradiance = 1`` (the solar
irradiance at the Moon as the unit) ``I`` is the radiance factor I/F; with irradiances
in W m^-2 it is pi times the radiance in W m^-2 sr^-1. Sky pixels are 0.

Lights and terms (per hit point p, unit normal n, unit direction v to the camera):

* **Sun**: ``E_sun * lit(x, y) * S(p)`` with ``lit`` the baked terrain lightmap
  (terrain self-shadowing, a callable / :class:`RasterSampler`; default 1) and ``S`` the
  soft shadow of the dynamic (rover) geometry: the fraction of ``shadow_samples`` rays
  toward points of the solar disk (a fixed Vogel-spiral pattern, angular radius
  0.2666 deg -- the Sun's mean apparent radius at 1 au) that reach the Sun unoccluded.
  Rover pixels use the lightmap at their own (x, y) (the terrain shadow they stand in).
* **Indirect fill** (paper: "an average of 3% of the direct illumination reflects into
  shadows in polar scenes ... approximated by ... a low-intensity virtual source
  opposing the sun in azimuth"): a directional source of irradiance
  ``fill_fraction * E_sun`` at the Sun's azimuth + 180 deg and the Sun's elevation
  (or ``fill_elevation_rad``), never shadowed. On level ground it adds
  ``fill_fraction`` of the unshadowed direct level to every pixel, shadowed or not.
* **Earthshine**: a directional source (direction, irradiance), not shadowed.
* **Spotlights** (up to 4): point sources with a cone (full intensity inside
  ``inner_half_angle_rad``, smoothstep to 0 at ``outer_half_angle_rad``), inverse-square
  falloff, an optional projected pattern (a 2-D texture in the light's frame) and
  optional ray-cast shadows.

Materials: static geometry (terrain) uses the regolith BRDF ``brdf(cos_i, cos_e,
phase) -> f_r (1/sr)`` (the bidirectional reflectance *distribution* function, i.e.
Hapke's bidirectional reflectance r divided by cos_i; wrap an ``r`` function with
:func:`brdf_from_reflectance`) scaled by ``albedo(x, y) / albedo_reference``;
dynamic meshes are Lambertian with their own albedo (``f_r = albedo / pi``).

Normals: terrain hits use the geometric normal of the hit triangle (faceted at coarse
levels), skirt triangles an upward normal; with ``track_depth`` (wheel-track groove
depth, m, positive down; a callable or :class:`RasterSampler`) they are bump mapped
as the surface ``z = Z(x, y) - depth(x, y)``: ``n' ~ (n_x/n_z + d_x, n_y/n_z + d_y, 1)``
with ``d_x, d_y`` the depth gradient (the paper's track texture: 255 = untouched,
lower = groove; use ``depth = (255 - texel) / 255 * groove_depth_m``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render.raycast import (
    INVALID_ID,
    PinholeCamera,
    RayHits,
    TerrainRaycaster,
    as_pose_matrix,
    camera_ray_directions,
)
from lunar_drake.render.regolith import (
    RegolithTextureConfig,
    apply_texture,
    build_texture,
    inverse_footprint,
)
from lunar_drake.render.soft_shadow import soft_lightmap

__all__ = [
    "SUN_ANGULAR_RADIUS_RAD",
    "GBuffer",
    "Illumination",
    "RasterSampler",
    "ShadedImage",
    "ShadingConfig",
    "SpotLight",
    "brdf_from_reflectance",
    "fill_direction",
    "lommel_seeliger",
    "render",
    "rover_shadow_factor",
    "shade",
    "sun_disk_directions",
    "trace",
]

_NO_TEXTURE = RegolithTextureConfig(enabled=False)

SUN_ANGULAR_RADIUS_RAD = math.radians(0.2666)
"""Mean apparent angular radius of the Sun at 1 au (959.6 arcsec, IAU nominal R_sun)."""

BRDF = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
Field2D = Callable[[np.ndarray, np.ndarray], np.ndarray]


# ----------------------------------------------------------------------------------------
# BRDFs
# ----------------------------------------------------------------------------------------
def lommel_seeliger(cos_i, cos_e, phase=None, *, normal_albedo: float = 0.15) -> np.ndarray:
    """Lommel-Seeliger BRDF ``f_r = 2 A_n / (pi (cos_i + cos_e))`` (1/sr).

    Normalized so the radiance factor at ``i = e = g = 0`` equals the normal albedo
    ``A_n`` (0.15: highland normal albedo, as ``terrain.albedo``'s default). No phase
    dependence (``phase`` is ignored) and no opposition surge; the default BRDF for tests.
    """
    ci = np.asarray(cos_i, dtype=np.float32)
    ce = np.asarray(cos_e, dtype=np.float32)
    s = np.maximum(ci + ce, np.float32(1e-6))
    return np.float32(2.0 * normal_albedo / math.pi) / s


def brdf_from_reflectance(reflectance: BRDF) -> BRDF:
    """A BRDF ``f_r = r / cos_i`` from a bidirectional-reflectance function ``r`` (1/sr)
    (Hapke's ``r(i, e, g)`` includes the ``cos_i`` factor; the shader multiplies by it)."""

    def brdf(cos_i, cos_e, phase):
        ci = np.asarray(cos_i, dtype=np.float32)
        return np.asarray(reflectance(ci, cos_e, phase), dtype=np.float32) / np.maximum(
            ci, np.float32(1e-6)
        )

    return brdf


# ----------------------------------------------------------------------------------------
# Rasters in site coordinates
# ----------------------------------------------------------------------------------------
_REMAP_COLS = 1024
_SHRT_MAX = 32767


def _bilinear(values: np.ndarray, row, col, outside: float | None) -> np.ndarray:
    """Bilinear sample of ``values`` at fractional pixel-centre coordinates (float32).

    Edge values are clamped (replicated); with ``outside`` points beyond the half-pixel
    band around the raster get that value. OpenCV's ``remap`` (exact float weights for
    float maps, multi-threaded, per-point so deterministic) when the raster fits its
    limits, else numpy.
    """
    h, w = values.shape
    row = np.asarray(row, dtype=np.float32).reshape(-1)
    col = np.asarray(col, dtype=np.float32).reshape(-1)
    m = row.size
    if h < _SHRT_MAX and w < _SHRT_MAX and m:
        import cv2

        nr = -(-m // _REMAP_COLS)
        pad = nr * _REMAP_COLS - m
        mr = np.concatenate([row, np.zeros(pad, np.float32)]) if pad else row
        mc = np.concatenate([col, np.zeros(pad, np.float32)]) if pad else col
        src = np.ascontiguousarray(values, dtype=np.float32)
        out = cv2.remap(
            src,
            mc.reshape(nr, _REMAP_COLS),
            mr.reshape(nr, _REMAP_COLS),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        ).reshape(-1)[:m]
    else:
        rc = np.clip(row, 0.0, h - 1.0)
        cc = np.clip(col, 0.0, w - 1.0)
        r0 = np.minimum(rc.astype(np.int64), max(h - 2, 0))
        c0 = np.minimum(cc.astype(np.int64), max(w - 2, 0))
        fr = rc - r0
        fc = cc - c0
        r1 = np.minimum(r0 + 1, h - 1)
        c1 = np.minimum(c0 + 1, w - 1)
        flat = values.reshape(-1)
        v00 = flat[r0 * w + c0]
        v01 = flat[r0 * w + c1]
        v10 = flat[r1 * w + c0]
        v11 = flat[r1 * w + c1]
        top = v00 + fc * (v01 - v00)
        bot = v10 + fc * (v11 - v10)
        out = (top + fr * (bot - top)).astype(np.float32, copy=False)
    if outside is not None:
        bad = (row < -0.5) | (row > h - 0.5) | (col < -0.5) | (col > w - 0.5)
        if bad.any():
            out = np.where(bad, np.float32(outside), out)
    return out


class RasterSampler:
    """Bilinear lookup of a raster in site coordinates (callable ``f(x, y)``).

    ``values[row, col]`` is a north-up, pixel-is-area grid over ``bounds = (left,
    bottom, right, top)`` (site m), pixel centres as in :mod:`lunar_drake.terrain`.
    Bilinear between pixel centres; in the half-pixel band inside the edge values are
    clamped; beyond the extent either clamped too (``outside=None``) or ``outside``.
    Arithmetic in float32.
    """

    def __init__(self, values, *, bounds, outside: float | None = None) -> None:
        v = np.asarray(values, dtype=np.float32)
        if v.ndim != 2 or v.shape[0] < 1 or v.shape[1] < 1:
            raise ConfigError(f"values have shape {v.shape}; a non-empty 2-D raster is required")
        try:
            left, bottom, right, top = (float(b) for b in bounds)
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                f"bounds = {bounds!r} is invalid; expected (left, bottom, right, top) in m"
            ) from exc
        if not (right > left and top > bottom):
            raise OutOfRangeError(f"bounds = {bounds!r} is empty; need right > left, top > bottom")
        self.values = v
        self.bounds = (left, bottom, right, top)
        self.outside = outside
        h, w = v.shape
        self._sx = w / (right - left)
        self._sy = h / (top - bottom)
        self._grad: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def on_heightfield(cls, values, heightfield, *, outside: float | None = None):
        """A raster covering ``heightfield.bounds`` (any resolution)."""
        return cls(values, bounds=tuple(heightfield.bounds), outside=outside)

    def _rc(self, x, y):
        left, _, _, top = self.bounds
        col = (np.asarray(x, np.float32) - np.float32(left)) * np.float32(self._sx) - 0.5
        row = (np.float32(top) - np.asarray(y, np.float32)) * np.float32(self._sy) - 0.5
        return row, col

    def __call__(self, x, y) -> np.ndarray:
        row, col = self._rc(x, y)
        return _bilinear(self.values, row, col, self.outside)

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """``(d/dx, d/dy)`` (units per m, x east, y north): bilinear interpolation of the
        central-difference gradient at the pixel centres (0 outside with ``outside``)."""
        if self._grad is None:
            # np.gradient's differences (central inside, one-sided at the edges) in
            # float32: the wheel-track window is millions of cells, rebuilt every frame.
            v = np.asarray(self.values, np.float32)
            h, w = v.shape
            gx = np.zeros_like(v)
            gy = np.zeros_like(v)
            sx, sy = np.float32(self._sx), np.float32(self._sy)
            if w > 1:
                np.multiply(v[:, 2:] - v[:, :-2], np.float32(0.5) * sx, out=gx[:, 1:-1])
                gx[:, 0] = (v[:, 1] - v[:, 0]) * sx
                gx[:, -1] = (v[:, -1] - v[:, -2]) * sx
            if h > 1:  # row index grows southwards
                np.multiply(v[:-2] - v[2:], np.float32(0.5) * sy, out=gy[1:-1])
                gy[0] = (v[0] - v[1]) * sy
                gy[-1] = (v[-2] - v[-1]) * sy
            self._grad = (gx, gy)
        row, col = self._rc(x, y)
        o = None if self.outside is None else 0.0
        return _bilinear(self._grad[0], row, col, o), _bilinear(self._grad[1], row, col, o)


# ----------------------------------------------------------------------------------------
# Configuration
# ----------------------------------------------------------------------------------------
def _unit3(v, name: str) -> tuple[float, float, float]:
    try:
        a = np.asarray(v, dtype=np.float64).reshape(3)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} = {v!r} is invalid; a 3-vector is required") from exc
    n = float(np.linalg.norm(a))
    if not (math.isfinite(n) and n > 0.0):
        raise OutOfRangeError(f"{name} = {v!r} is invalid; a finite non-zero 3-vector")
    return tuple(float(c) for c in a / n)  # type: ignore[return-value]


@dataclass(frozen=True)
class SpotLight:
    """A rover spotlight (paper section 5, "Rover Lights").

    Attributes:
        position_W: light position in W (m).
        direction_W: beam axis in W (normalized here).
        intensity: radiant intensity on the axis, in irradiance units x m^2 (so the
            irradiance at distance d on the axis, facing the light, is intensity / d^2).
        outer_half_angle_rad: cone half-angle (rad) where the beam reaches 0, in (0, pi/2).
        inner_half_angle_rad: full intensity inside this half-angle (rad), smoothstep
            falloff to the outer angle; < outer.
        pattern: optional 2-D texture (>= 0) projected in the light frame L: +z the beam
            axis, +x right, +y down (image rows), so its corners are at ``tan`` of the
            outer half-angle on both axes; bilinear, 0 outside.
        up_W: W vector that points "up" in the pattern (its -y axis); default +z,
            must not be parallel to the axis.
        cast_shadows: ray-cast shadows (against terrain and dynamic meshes); the light
            must then sit outside the rover's meshes (e.g. 1 cm in front of the lamp).
        min_distance_m: distances below this are clamped in the inverse-square law (m).
    """

    position_W: tuple[float, float, float]
    direction_W: tuple[float, float, float]
    intensity: float
    outer_half_angle_rad: float = math.radians(30.0)
    inner_half_angle_rad: float = math.radians(20.0)
    pattern: np.ndarray | None = field(default=None, compare=False, repr=False)
    up_W: tuple[float, float, float] = (0.0, 0.0, 1.0)
    cast_shadows: bool = False
    min_distance_m: float = 0.05

    def __post_init__(self) -> None:
        p = np.asarray(self.position_W, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ConfigError(f"position_W = {self.position_W!r} is invalid; a finite 3-vector")
        object.__setattr__(self, "position_W", tuple(float(c) for c in p))
        object.__setattr__(self, "direction_W", _unit3(self.direction_W, "direction_W"))
        object.__setattr__(self, "up_W", _unit3(self.up_W, "up_W"))
        if not (math.isfinite(self.intensity) and self.intensity >= 0.0):
            raise OutOfRangeError(f"intensity = {self.intensity!r} is invalid; must be >= 0")
        if not 0.0 < self.outer_half_angle_rad < 0.5 * math.pi:
            raise OutOfRangeError(
                f"outer_half_angle_rad = {self.outer_half_angle_rad!r} is invalid; "
                "allowed (0, pi/2)"
            )
        if not 0.0 <= self.inner_half_angle_rad < self.outer_half_angle_rad:
            raise OutOfRangeError(
                f"inner_half_angle_rad = {self.inner_half_angle_rad!r} is invalid; allowed "
                f"[0, outer_half_angle_rad = {self.outer_half_angle_rad!r})"
            )
        if abs(float(np.dot(self.direction_W, self.up_W))) > 1.0 - 1e-9:
            raise ConfigError(
                f"up_W = {self.up_W!r} is parallel to direction_W = {self.direction_W!r}"
            )
        if self.pattern is not None:
            pt = np.asarray(self.pattern, dtype=np.float32)
            if pt.ndim != 2 or pt.size == 0 or not np.isfinite(pt).all() or (pt < 0).any():
                raise ConfigError(
                    f"pattern has shape {pt.shape}; a non-empty finite 2-D array >= 0 is required"
                )
            object.__setattr__(self, "pattern", pt)
        if not self.min_distance_m > 0.0:
            raise OutOfRangeError(f"min_distance_m = {self.min_distance_m!r}; must be > 0 (m)")

    def frame_W(self) -> np.ndarray:
        """Rotation ``R_WL`` (3 x 3): columns are L's x (right), y (down), z (beam) in W."""
        z = np.asarray(self.direction_W)
        x = np.cross(z, np.asarray(self.up_W))
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        return np.stack([x, y, z], axis=1)


@dataclass(frozen=True)
class Illumination:
    """Light sources of one frame (W = site frame; irradiances in one consistent unit).

    Attributes:
        sun_direction_W: unit vector toward the Sun (normalized here).
        sun_irradiance: solar irradiance ``E_sun`` (1 = output is I/F).
        sun_angular_radius_rad: apparent solar radius (rad) for soft rover shadows.
        fill_fraction: indirect-fill irradiance as a fraction of ``E_sun`` (paper: ~3%
            in polar scenes).
        fill_elevation_rad: elevation of the fill source (rad); None = the Sun's.
        earth_direction_W: unit vector toward the Earth, or None.
        earth_irradiance: Earthshine irradiance (same unit as ``sun_irradiance``).
        spotlights: up to 4 :class:`SpotLight`.
    """

    sun_direction_W: tuple[float, float, float] = (0.0, 0.0, 1.0)
    sun_irradiance: float = 1.0
    sun_angular_radius_rad: float = SUN_ANGULAR_RADIUS_RAD
    fill_fraction: float = 0.03
    fill_elevation_rad: float | None = None
    earth_direction_W: tuple[float, float, float] | None = None
    earth_irradiance: float = 0.0
    spotlights: tuple[SpotLight, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "sun_direction_W", _unit3(self.sun_direction_W, "sun_direction_W"))
        if self.earth_direction_W is not None:
            object.__setattr__(
                self, "earth_direction_W", _unit3(self.earth_direction_W, "earth_direction_W")
            )
        for name in ("sun_irradiance", "earth_irradiance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise OutOfRangeError(f"{name} = {v!r} is invalid; must be >= 0")
        if not 0.0 <= self.sun_angular_radius_rad < 0.1:
            raise OutOfRangeError(
                f"sun_angular_radius_rad = {self.sun_angular_radius_rad!r}; allowed [0, 0.1) rad"
            )
        if not 0.0 <= self.fill_fraction <= 1.0:
            raise OutOfRangeError(f"fill_fraction = {self.fill_fraction!r}; allowed [0, 1]")
        if self.fill_elevation_rad is not None and not (
            -0.5 * math.pi <= self.fill_elevation_rad <= 0.5 * math.pi
        ):
            raise OutOfRangeError(
                f"fill_elevation_rad = {self.fill_elevation_rad!r}; allowed [-pi/2, pi/2]"
            )
        spots = tuple(self.spotlights)
        if len(spots) > 4 or not all(isinstance(s, SpotLight) for s in spots):
            raise ConfigError(
                f"spotlights has {len(spots)} entries; at most 4 SpotLight objects are allowed"
            )
        object.__setattr__(self, "spotlights", spots)


@dataclass(frozen=True)
class ShadingConfig:
    """Shader settings.

    Attributes:
        shadow_samples: rays per pixel toward the solar disk for the rover shadow (1 =
            hard shadow), 1..64.
        shadow_bias_m: shadow-ray origin offset along the normal (m).
        albedo_reference: normal albedo at which ``brdf`` holds; a pixel's BRDF is
            scaled by ``albedo(x, y) / albedo_reference``. Default 0.15 (highland soil,
            as the terrain albedo model's ``A0``).
        bump_step_m: central-difference step (m) for a callable ``track_depth``.
        max_penumbra_px: widest rover-shadow penumbra (px, each side of the hard edge)
            sampled with ``shadow_samples`` rays; beyond it the shadow is hard (see
            :func:`rover_shadow_factor`). Under a low Sun penumbrae stretch by
            ``1 / cos_i`` and dominate the shading cost: lower this or
            ``shadow_samples`` to trade accuracy for speed.
        texture: the sub-cell regolith texture on terrain pixels (albedo and bump
            detail from 5 mm to 8 cm, band-limited by the pixel footprint;
            :class:`~lunar_drake.render.regolith.RegolithTextureConfig`). Off here, so
            :func:`shade` stays the plain BRDF model; the camera
            (:class:`~lunar_drake.render.camera.TerrainCameraRenderer`) turns it on.
        soft_shadows: a :class:`RasterSampler` lightmap is reconstructed smoothly
            (quadratic B-spline, :mod:`lunar_drake.render.soft_shadow`) instead of
            bilinearly, so sub-cell shadow edges do not staircase; other lightmap
            callables are called as they are. Off here, on in the camera.
    """

    shadow_samples: int = 8
    shadow_bias_m: float = 1e-3
    albedo_reference: float = 0.15
    bump_step_m: float = 0.01
    max_penumbra_px: int = 16
    texture: RegolithTextureConfig = field(default_factory=lambda: _NO_TEXTURE)
    soft_shadows: bool = False

    def __post_init__(self) -> None:
        if not 1 <= int(self.shadow_samples) <= 64:
            raise OutOfRangeError(f"shadow_samples = {self.shadow_samples!r}; allowed 1..64")
        if not (math.isfinite(self.shadow_bias_m) and self.shadow_bias_m >= 0.0):
            raise OutOfRangeError(f"shadow_bias_m = {self.shadow_bias_m!r}; must be >= 0 (m)")
        if not 0.0 < self.albedo_reference <= 1.0:
            raise OutOfRangeError(f"albedo_reference = {self.albedo_reference!r}; allowed (0, 1]")
        if not self.bump_step_m > 0.0:
            raise OutOfRangeError(f"bump_step_m = {self.bump_step_m!r}; must be > 0 (m)")
        if not 1 <= int(self.max_penumbra_px) <= 256:
            raise OutOfRangeError(f"max_penumbra_px = {self.max_penumbra_px!r}; allowed 1..256")
        if not isinstance(self.texture, RegolithTextureConfig):
            raise ConfigError(f"texture = {self.texture!r} is invalid; a RegolithTextureConfig")
        if not isinstance(self.soft_shadows, bool):
            raise ConfigError(f"soft_shadows = {self.soft_shadows!r} is invalid; a bool")


# ----------------------------------------------------------------------------------------
# G-buffer
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GBuffer:
    """Per-pixel ray-cast results; per-hit arrays are compact (one entry per hit pixel).

    Attributes:
        width, height: image size (px).
        index: ``(M,)`` int64 flat pixel index (row-major) of each hit.
        position: ``(3, M)`` float32 hit points in W (m).
        normal: ``(3, M)`` float32 unit normals in W, facing the camera (skirts: +z).
        view: ``(3, M)`` float32 unit vectors from the hit toward the camera.
        dynamic: ``(M,)`` bool: hit a dynamic mesh.
        terrain: ``(M,)`` bool: hit static geometry (terrain) on a surface triangle.
        hits: the raw :class:`RayHits` of all ``width * height`` rays.
        label: ``(height, width)`` int16 (0 sky, 1 terrain, 2 rover, ...).
        depth: ``(height, width)`` float32 distance along the optical axis (m), inf = sky.
        pixel_angle_rad: angular size of a pixel, ``1 / max(fx, fy)`` (rad).
        hits_compact: ``hits`` holds one entry per hit pixel (aligned with ``index``)
            instead of one per image pixel.
    """

    width: int
    height: int
    index: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    dynamic: np.ndarray
    terrain: np.ndarray
    hits: RayHits
    label: np.ndarray
    depth: np.ndarray
    pixel_angle_rad: float = 0.0
    hits_compact: bool = False

    def per_hit(self, a: np.ndarray) -> np.ndarray:
        """A per-ray array of :attr:`hits` as one entry per hit pixel."""
        return a if self.hits_compact else a[self.index]


@dataclass(frozen=True)
class ShadedImage:
    """A rendered frame.

    Attributes:
        radiance: ``(height, width)`` float32 I/F-like relative radiance (module
            docstring); 0 for sky.
        depth: ``(height, width)`` float32 depth along the optical axis (m), inf = sky.
        label: ``(height, width)`` int16: 0 sky, 1 terrain, 2 rover (dynamic mesh label).
    """

    radiance: np.ndarray
    depth: np.ndarray
    label: np.ndarray


def trace(raycaster: TerrainRaycaster, camera: PinholeCamera, X_WC) -> GBuffer:
    """Cast one ray per pixel of ``camera`` at pose ``X_WC`` and build the G-buffer."""
    X = as_pose_matrix(X_WC)
    d_C = camera_ray_directions(
        camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy
    )
    rays, d_W = camera.world_rays(X)
    hits = raycaster.cast_rays(rays, common_origin=True)
    n = rays.shape[0]
    idx = np.flatnonzero(hits.geometry_id != INVALID_ID)
    d = np.take(d_W, idx, axis=1)  # (3, M) unit, W
    t = np.take(hits.t_hit, idx)
    pos = X[:3, 3].astype(np.float32)[:, None] + t[None, :] * d
    nrm = np.ascontiguousarray(np.take(hits.normals, idx, axis=0).T)
    lab, dyn, skirt = raycaster.classify(
        np.take(hits.geometry_id, idx), np.take(hits.primitive_id, idx)
    )
    if skirt.any():
        nrm[:, skirt] = np.array([[0.0], [0.0], [1.0]], np.float32)
    flip = _dot3(nrm, d) > 0  # face the camera
    if flip.any():
        nrm[:, flip] *= np.float32(-1.0)
    depth = np.full(n, np.inf, dtype=np.float32)
    depth[idx] = t * np.take(d_C[2], idx)
    label = np.zeros(n, dtype=np.int16)
    label[idx] = lab
    np.negative(d, out=d)
    return GBuffer(
        width=camera.width,
        height=camera.height,
        index=idx,
        position=pos,
        normal=nrm,
        view=d,
        dynamic=dyn,
        terrain=~dyn & ~skirt,
        hits=hits,
        label=label.reshape(camera.height, camera.width),
        depth=depth.reshape(camera.height, camera.width),
        pixel_angle_rad=1.0 / max(camera.fx, camera.fy),
    )


# ----------------------------------------------------------------------------------------
# Lights
# ----------------------------------------------------------------------------------------
def sun_disk_directions(sun_direction_W, angular_radius_rad: float, n: int) -> np.ndarray:
    """``(n, 3)`` unit directions spread over the solar disk (Vogel spiral, fixed)."""
    s = np.asarray(_unit3(sun_direction_W, "sun_direction_W"))
    if n == 1 or angular_radius_rad == 0.0:
        return np.repeat(s[None, :], n, axis=0)
    a = np.array([1.0, 0.0, 0.0]) if abs(s[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(s, a)
    u /= np.linalg.norm(u)
    w = np.cross(s, u)
    k = np.arange(n, dtype=np.float64)
    r = np.sqrt((k + 0.5) / n) * math.tan(angular_radius_rad)
    th = k * (math.pi * (3.0 - math.sqrt(5.0)))
    d = s[None, :] + r[:, None] * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * w)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def fill_direction(sun_direction_W, elevation_rad: float | None = None) -> np.ndarray:
    """Unit direction of the indirect-fill source: the Sun's azimuth + 180 deg, at the
    Sun's elevation (or ``elevation_rad``). The Sun at the zenith/nadir: the Sun's own."""
    s = np.asarray(_unit3(sun_direction_W, "sun_direction_W"))
    h = math.hypot(s[0], s[1])
    if h < 1e-12:
        return s.copy()
    e = math.asin(max(-1.0, min(1.0, s[2]))) if elevation_rad is None else float(elevation_rad)
    return np.array([-s[0] / h * math.cos(e), -s[1] / h * math.cos(e), math.sin(e)])


def rover_shadow_factor(
    raycaster: TerrainRaycaster,
    points_W,
    normals_W,
    sun_direction_W,
    *,
    angular_radius_rad: float = SUN_ANGULAR_RADIUS_RAD,
    samples: int = 8,
    bias_m: float = 1e-3,
    image_shape: tuple[int, int] | None = None,
    pixel_index=None,
    pixel_footprint_m=None,
    max_penumbra_px: int = 16,
    active=None,
) -> np.ndarray:
    """``(N,)`` float32 fraction of the solar disk visible past the dynamic meshes.

    Shadow rays start at the point offset by ``bias_m`` along its normal and are
    tested against the dynamic scene only (terrain shadows come from the lightmap).
    Points whose rays cannot come near the dynamic bounding sphere are 1 without
    casting.

    Without image information every remaining point casts ``samples`` rays toward
    :func:`sun_disk_directions` (exact up to the sampling). With ``image_shape``,
    ``pixel_index`` (flat row-major pixel of each point) and ``pixel_footprint_m``
    (pixel size on the surface, m) it casts one central ray per point (hard shadow),
    then ``samples`` rays only for pixels within the penumbra half-width of a
    hard-shadow edge pixel in the image -- ``D tan(angular radius) / cos_i`` on the
    surface, ``D`` bounded by the distance to the far side of the dynamic bounding
    sphere, over the pixel footprint, plus one pixel, capped at ``max_penumbra_px`` --
    and keeps the hard result elsewhere. Exact (equal to casting every sample at every
    pixel) unless a penumbra is wider than the cap (long shadows under a low Sun: the
    outer penumbra is then cut to a hard edge) or an occluder is thinner than a pixel's
    footprint (missed by the hard pass).

    Args:
        points_W, normals_W: ``(N, 3)`` (or ``(3, N)`` when N != 3) points and unit
            normals in W (m).
        active: optional ``(N,)`` bool; inactive points are returned as 1 untested.
    """
    p = _as_3n(points_W)
    nrm = _as_3n(normals_W)
    n = p.shape[1]
    out = np.ones(n, dtype=np.float32)
    sphere = raycaster.dynamic_bounding_sphere()
    if sphere is None or n == 0:
        return out
    k = int(samples)
    dirs = sun_disk_directions(sun_direction_W, angular_radius_rad, k).astype(np.float32)
    s = np.asarray(_unit3(sun_direction_W, "sun_direction_W"))
    c, r = sphere
    tan_a = math.tan(angular_radius_rad)
    # cull: the ray from p toward the Sun passes the sphere within the disk spread
    c32 = c.astype(np.float32)
    q0, q1, q2 = p[0] - c32[0], p[1] - c32[1], p[2] - c32[2]
    s32 = s.astype(np.float32)
    tp = q0 * -s32[0]
    tp -= q1 * s32[1]
    tp -= q2 * s32[2]  # distance along s from p to the sphere centre
    qq = q0 * q0
    qq += q1 * q1
    qq += q2 * q2
    reach = np.maximum(tp, np.float32(0.0))
    reach += np.float32(r)
    reach *= np.float32(1.01 * tan_a)
    reach += np.float32(r + 2.0 * bias_m)
    ok = tp > np.float32(-r - 2.0 * bias_m)
    ok &= qq - tp * tp <= reach * reach + np.float32(1e-5) * qq + np.float32(1e-6)
    if active is not None:
        ok &= np.asarray(active, dtype=bool)
    cand = np.flatnonzero(ok)
    if cand.size == 0:
        return out
    oc = (p[:, cand] + np.float32(bias_m) * nrm[:, cand]).T  # (C, 3)

    def cast_samples(sel: np.ndarray) -> np.ndarray:
        rays = np.empty((sel.size, k, 6), dtype=np.float32)
        rays[:, :, 0:3] = oc[sel][:, None, :]
        rays[:, :, 3:6] = dirs[None, :, :]
        occ = raycaster.occlusion_rays(rays.reshape(-1, 6), static=False, cull=False)
        return 1.0 - occ.reshape(sel.size, k).sum(axis=1).astype(np.float32) / np.float32(k)

    adaptive = (
        image_shape is not None
        and pixel_index is not None
        and pixel_footprint_m is not None
        and k > 1
        and tan_a > 0.0
    )
    if not adaptive:
        out[cand] = cast_samples(np.arange(cand.size))
        return out
    import cv2

    rays = np.empty((cand.size, 6), dtype=np.float32)
    rays[:, 0:3] = oc
    rays[:, 3:6] = s.astype(np.float32)
    hard = raycaster.occlusion_rays(rays, static=False, cull=False)
    out[cand] = np.where(hard, np.float32(0.0), np.float32(1.0))
    h, wd = image_shape
    pix = np.asarray(pixel_index)[cand]
    img = np.zeros(h * wd, dtype=np.uint8)
    img[pix] = hard.view(np.uint8)
    img = img.reshape(h, wd)
    k3 = np.ones((3, 3), np.uint8)
    e = np.flatnonzero((cv2.dilate(img, k3) != cv2.erode(img, k3)).reshape(-1)[pix])
    if e.size == 0:
        return out
    # penumbra half-width (px) around each hard-edge pixel: occluder distance
    # <= tp + r, stretched by 1 / cos_i on the surface, over the smallest pixel footprint
    ce = np.maximum(nrm[:, cand[e]].T @ s.astype(np.float32), np.float32(0.05))
    foot = np.maximum(np.asarray(pixel_footprint_m, np.float32)[cand[e]], np.float32(1e-6))
    pen = (np.maximum(tp[cand[e]], 0.0) + np.float32(r)) * np.float32(tan_a) / (ce * foot)
    rad = np.clip(np.ceil(pen) + 1.0, 1.0, float(max_penumbra_px))
    region = np.zeros(h * wd, dtype=np.uint8)
    lo = 0.0
    for b in sorted({*(2**j for j in range(16) if 2**j < max_penumbra_px), max_penumbra_px}):
        m = (rad > lo) & (rad <= b)
        lo = float(b)
        if not m.any():
            continue
        seed = np.zeros(h * wd, dtype=np.uint8)
        seed[pix[e[m]]] = 1
        kern = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * b + 1, 2 * b + 1))
        region |= cv2.dilate(seed.reshape(h, wd), kern).reshape(-1)
    sel = np.flatnonzero(region[pix])
    if sel.size:
        out[cand[sel]] = cast_samples(sel)
    return out


def _as_3n(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    if a.ndim != 2 or 3 not in a.shape:
        raise ConfigError(f"array has shape {a.shape}; (N, 3) or (3, N) is required")
    if a.shape[1] == 3 and a.shape[0] != 3:
        return np.ascontiguousarray(a.T)
    return a


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - np.float32(e0)) / np.float32(e1 - e0), 0.0, 1.0)
    return t * t * (np.float32(3.0) - np.float32(2.0) * t)


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Column-wise dot of (3, M) arrays, or of a (3, M) array with a 3-vector."""
    if b.ndim == 1:
        b = b.astype(np.float32)
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _phase(cos_g: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(cos_g, -1.0, 1.0))


# ----------------------------------------------------------------------------------------
# Shading
# ----------------------------------------------------------------------------------------
def bumped_normals(gb: GBuffer, track_depth, step: float) -> np.ndarray:
    n = gb.normal
    sel = np.flatnonzero(gb.terrain & (n[2] > 1e-3))
    if sel.size == 0:
        return n
    x, y = gb.position[0, sel], gb.position[1, sel]
    if isinstance(track_depth, RasterSampler):
        gx, gy = track_depth.gradient(x, y)
    else:
        h = np.float32(step)
        gx = (np.asarray(track_depth(x + h, y), np.float32) - track_depth(x - h, y)) / (2 * h)
        gy = (np.asarray(track_depth(x, y + h), np.float32) - track_depth(x, y - h)) / (2 * h)
    nz = n[2, sel]
    bx = n[0, sel] / nz + gx
    by = n[1, sel] / nz + gy
    inv = 1.0 / np.sqrt(bx * bx + by * by + 1.0)
    out = n.copy()
    out[0, sel] = bx * inv
    out[1, sel] = by * inv
    out[2, sel] = inv
    return out


def shade(
    gbuffer: GBuffer,
    raycaster: TerrainRaycaster,
    illumination: Illumination,
    *,
    brdf: BRDF = lommel_seeliger,
    albedo: Field2D | RasterSampler | str | None = None,
    lightmap: Field2D | RasterSampler | None = None,
    track_depth: Field2D | RasterSampler | None = None,
    config: ShadingConfig = ShadingConfig(),
    secondary_brdf: BRDF | None = None,
) -> ShadedImage:
    """Shade a G-buffer (see the module docstring for the model and units).

    Args:
        gbuffer: from :func:`trace` (with the same ``raycaster``).
        raycaster: used for rover/spotlight shadow rays and per-geometry attributes.
        illumination: the light sources.
        brdf: regolith BRDF ``f_r(cos_i, cos_e, phase_rad)`` (1/sr), vectorized.
        albedo: terrain normal albedo: a callable ``(x, y) -> A`` / :class:`RasterSampler`
            in site coordinates, ``"vertex"`` for the LOD tiles' per-vertex albedo, or
            None (``albedo_reference`` everywhere).
        lightmap: terrain lit fraction ``(x, y) -> [0, 1]`` (baked terrain shadows);
            None = 1.
        track_depth: wheel-track groove depth ``(x, y) -> m`` (positive down) for bump
            normals; None = no bump.
        config: :class:`ShadingConfig`.
        secondary_brdf: a cheaper BRDF for the indirect fill and Earthshine (both weak,
            broad sources); None = ``brdf``.
    """
    gb = gbuffer
    m = gb.index.size
    rad = np.zeros(gb.width * gb.height, dtype=np.float32)
    if m == 0:
        return ShadedImage(rad.reshape(gb.height, gb.width), gb.depth, gb.label)
    n = (
        bumped_normals(gb, track_depth, config.bump_step_m)
        if track_depth is not None
        else gb.normal
    )
    v = gb.view
    x, y = gb.position[0], gb.position[1]
    cos_e = _dot3(n, v)
    np.maximum(cos_e, np.float32(0.0), out=cos_e)
    tex = build_texture(config.texture)
    tsel = np.flatnonzero(gb.terrain) if tex.enabled else np.zeros(0, np.int64)
    if tsel.size:
        # sub-cell regolith texture: bump the terrain normals, scale the albedo below
        ifoot = inverse_footprint(gb.per_hit(gb.hits.t_hit)[tsel], gb.pixel_angle_rad, cos_e[tsel])
        n_t, tex_fac = apply_texture(tex, x[tsel], y[tsel], ifoot, n[:, tsel], None)
        n = n.copy()
        n[:, tsel] = n_t
        cos_e[tsel] = np.maximum(_dot3(n_t, v[:, tsel]), np.float32(0.0))

    # material: regolith BRDF x albedo factor; Lambertian for dynamic meshes
    afac = None
    if albedo is not None:
        if isinstance(albedo, str):
            if albedo != "vertex":
                raise ConfigError(f"albedo = {albedo!r} is invalid; a callable, 'vertex' or None")
            a = gb.per_hit(raycaster.vertex_albedo(gb.hits))
            a = np.where(np.isnan(a), np.float32(config.albedo_reference), a)
        else:
            a = np.asarray(albedo(x, y), dtype=np.float32)
        afac = a * np.float32(1.0 / config.albedo_reference)
    if tsel.size:
        if afac is None:
            afac = np.ones(m, np.float32)
        afac[tsel] *= tex_fac
    dyn_idx = np.flatnonzero(gb.dynamic)
    lam = None  # Lambertian f_r of dynamic-mesh pixels, (M,)
    if dyn_idx.size:
        lam = gb.per_hit(raycaster.dynamic_albedo(gb.hits)) * np.float32(1.0 / math.pi)

    def radiance_term(cos_i, cos_g, sel=None, fn=None):
        """f_r * cos_i for one light at pixels ``sel`` (all when None); cos_i >= 0."""
        ce = cos_e if sel is None else cos_e[sel]
        np.clip(cos_g, -1.0, 1.0, out=cos_g)
        f = np.asarray((fn or brdf)(cos_i, ce, np.arccos(cos_g)), dtype=np.float32)
        if f.shape != cos_i.shape or not f.flags.writeable:
            f = np.array(np.broadcast_to(f, cos_i.shape), dtype=np.float32)
        if afac is not None:
            f = f * (afac if sel is None else afac[sel])
        if lam is not None:
            if sel is None:
                f[dyn_idx] = lam[dyn_idx]
            else:
                f = np.where(gb.dynamic[sel], lam[sel], f)
        f *= cos_i
        return f

    total = np.zeros(m, dtype=np.float32)
    il = illumination

    if il.sun_irradiance > 0.0:
        s = np.asarray(il.sun_direction_W, dtype=np.float32)
        cos_i = _dot3(n, s)
        lit = cos_i > 0
        if lit.any():
            np.maximum(cos_i, np.float32(0.0), out=cos_i)
            term = radiance_term(cos_i, _dot3(v, s))
            term *= np.float32(il.sun_irradiance)
            if lightmap is not None:
                if config.soft_shadows and isinstance(lightmap, RasterSampler):
                    lm = soft_lightmap(lightmap, x, y)
                else:
                    lm = np.clip(np.asarray(lightmap(x, y), np.float32), 0.0, 1.0)
                term *= lm
                lit &= lm > 0
            if raycaster.dynamic_bounding_sphere() is not None:
                # the geometric normal offsets shadow rays (bumps do not move the surface)
                term *= rover_shadow_factor(
                    raycaster,
                    gb.position,
                    gb.normal,
                    il.sun_direction_W,
                    angular_radius_rad=il.sun_angular_radius_rad,
                    samples=config.shadow_samples,
                    bias_m=config.shadow_bias_m,
                    image_shape=(gb.height, gb.width),
                    pixel_index=gb.index,
                    pixel_footprint_m=gb.per_hit(gb.hits.t_hit) * np.float32(gb.pixel_angle_rad),
                    max_penumbra_px=int(config.max_penumbra_px),
                    active=lit,
                )
            total += term

    if il.fill_fraction > 0.0 and il.sun_irradiance > 0.0:
        fdir = fill_direction(il.sun_direction_W, il.fill_elevation_rad).astype(np.float32)
        _add_directional(
            total, n, v, fdir, il.fill_fraction * il.sun_irradiance, radiance_term, secondary_brdf
        )

    if il.earth_direction_W is not None and il.earth_irradiance > 0.0:
        edir = np.asarray(il.earth_direction_W, dtype=np.float32)
        _add_directional(total, n, v, edir, il.earth_irradiance, radiance_term, secondary_brdf)

    for spot in il.spotlights:
        add_spotlight(total, gb, n, v, spot, radiance_term, raycaster, config)

    total *= np.float32(math.pi)
    rad[gb.index] = total
    return ShadedImage(rad.reshape(gb.height, gb.width), gb.depth, gb.label)


def _add_directional(total, n, v, ldir, irradiance: float, radiance_term, fn=None) -> None:
    cos_i = _dot3(n, ldir)
    if not (cos_i > 0).any():
        return
    np.maximum(cos_i, np.float32(0.0), out=cos_i)
    term = radiance_term(cos_i, _dot3(v, ldir), None, fn)
    term *= np.float32(irradiance)
    total += term


def add_spotlight(total, gb: GBuffer, n, v, spot: SpotLight, radiance_term, raycaster, config):
    if spot.intensity == 0.0:
        return
    m = total.size
    pl = np.asarray(spot.position_W, dtype=np.float32)
    axis = np.asarray(spot.direction_W, dtype=np.float32)
    p = gb.position
    # cone cull without square roots: light->hit along the axis vs. its length
    t0, t1, t2 = p[0] - pl[0], p[1] - pl[1], p[2] - pl[2]
    along = t0 * axis[0]
    along += t1 * axis[1]
    along += t2 * axis[2]
    d2 = t0 * t0
    d2 += t1 * t1
    d2 += t2 * t2
    co = np.float32(math.cos(spot.outer_half_angle_rad))
    inside = (along > 0) & (along * along > co * co * d2)
    sel = np.flatnonzero(inside)
    if sel.size == 0:
        return
    if sel.size > 0.6 * m:  # a wide beam: full arrays beat gathers (the cone zeroes the rest)
        sel = None

    def take(a):
        return a if sel is None else np.take(a, sel, axis=-1)

    tv = np.stack([take(t0), take(t1), take(t2)])  # light -> hit, (3, S)
    d2s = take(d2)
    dist = np.sqrt(d2s)
    inv = np.float32(-1.0) / np.maximum(dist, np.float32(1e-9))
    lvec = tv * inv  # hit -> light, unit
    cos_i = _dot3(take(n) if sel is not None else n, lvec)
    if not (cos_i > 0).any():
        return
    cone = _smoothstep(
        math.cos(spot.outer_half_angle_rad),
        math.cos(spot.inner_half_angle_rad),
        -take(along) * inv,
    )
    if spot.pattern is not None:
        R = spot.frame_W().astype(np.float32)  # columns: x, y, z of L in W
        q = R.T @ tv  # hit in L
        q2 = np.where(q[2] > 0, q[2], np.float32(1.0))
        tan_o = np.float32(math.tan(spot.outer_half_angle_rad))
        h, wd = spot.pattern.shape
        col = (q[0] / q2 / tan_o + 1.0) * np.float32(0.5 * wd) - 0.5
        row = (q[1] / q2 / tan_o + 1.0) * np.float32(0.5 * h) - 0.5
        cone = cone * _bilinear(spot.pattern, row, col, 0.0)
    e = np.float32(spot.intensity) * cone / np.maximum(d2s, np.float32(spot.min_distance_m**2))
    if spot.cast_shadows:
        k = np.flatnonzero((e > 0) & (cos_i > 0))
        if k.size:
            bias = np.float32(config.shadow_bias_m)
            pk = k if sel is None else sel[k]
            o = np.take(p, pk, axis=1) + bias * np.take(gb.normal, pk, axis=1)
            occ = raycaster.occlusion(
                o.T, np.take(lvec, k, axis=1).T, np.maximum(dist[k] - 2 * bias, 0.0)
            )
            e[k[occ]] = 0.0
    np.maximum(cos_i, np.float32(0.0), out=cos_i)
    term = radiance_term(cos_i, _dot3(take(v) if sel is not None else v, lvec), sel)
    term *= e
    if sel is None:
        total += term
    else:
        total[sel] += term


def render(
    raycaster: TerrainRaycaster,
    camera: PinholeCamera,
    X_WC,
    illumination: Illumination,
    **shade_kwargs,
) -> ShadedImage:
    """:func:`trace` then :func:`shade` (keyword arguments go to :func:`shade`)."""
    return shade(trace(raycaster, camera, X_WC), raycaster, illumination, **shade_kwargs)
