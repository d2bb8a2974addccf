"""Ray casting against LOD terrain and moving meshes (DESIGN.md decision 3).

:class:`TerrainRaycaster` wraps two Open3D ``RaycastingScene`` s (Embree BVHs):

* a **static** scene holding the terrain LOD tiles (one geometry per tile) and any other
  fixed meshes; it is rebuilt only when the set of tiles changes (Open3D cannot remove
  geometry from a scene), i.e. when the rover's move changes a tile's level (check
  :meth:`TerrainLOD.changes_at` first: a rebuild of the BVH over ~1.2 M triangles takes
  0.5-1 s on 2 cores, a cast of a 1280 x 960 frame ~0.12 s);
* a **dynamic** scene holding moving meshes (the rover's visual geometry), given in
  their own frame G with a pose ``X_WG`` each; new poses rebuild only this small scene,
  lazily, at the next query.

:meth:`TerrainRaycaster.cast` queries both and keeps the nearer hit per ray. For the
dynamic scene, rays are culled against its bounding sphere in numpy, then an any-hit
pass (Embree ``test_occlusions``, cheap) finds the few rays that touch it, and only those
get a closest-hit cast (a rover-mounted camera sits inside the rover's bounding sphere,
so the sphere alone rarely culls much).

Frames and units: everything is in the world (site) frame W, metres: x east, y north,
z up. Cameras follow Drake's convention: camera frame C has +z forward (optical axis),
+x right and +y down in the image; pixel ``(u, v)`` (column, row) has its centre at
image coordinates ``(u, v)``, so the principal point of a centred ``W x H`` image is
``((W - 1) / 2, (H - 1) / 2)`` (as in ``pydrake.systems.sensors.CameraInfo``). Ray ``k``
of an image is pixel ``(u, v) = (k % width, k // width)``.

Precision: Embree works in float32, so positions carry ~1e-7 relative error (8 um at
100 m, 1 mm at 15 km from the site origin); shadow rays need a small origin bias.

Open3D is imported lazily (it takes about a second).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError

__all__ = [
    "DYNAMIC_ID_BASE",
    "INVALID_ID",
    "LABEL_ROVER",
    "LABEL_SKY",
    "LABEL_TERRAIN",
    "DynamicMesh",
    "PinholeCamera",
    "RayHits",
    "TerrainRaycaster",
    "as_pose_matrix",
    "camera_ray_directions",
    "pinhole_rays",
    "tune_malloc_for_large_arrays",
]

INVALID_ID = 0xFFFFFFFF
"""``geometry_id`` / ``primitive_id`` of a ray that hit nothing (Open3D's INVALID_ID)."""

DYNAMIC_ID_BASE = 1 << 24
"""``geometry_id`` of dynamic mesh ``j`` is ``DYNAMIC_ID_BASE + j``."""

LABEL_SKY = 0
LABEL_TERRAIN = 1
LABEL_ROVER = 2


def _o3d():
    import open3d  # slow (~1 s): deferred on purpose

    return open3d


def as_pose_matrix(X) -> np.ndarray:
    """A 4 x 4 float64 homogeneous matrix from a 4 x 4 array or a Drake ``RigidTransform``."""
    if hasattr(X, "GetAsMatrix4"):
        X = X.GetAsMatrix4()
    m = np.asarray(X, dtype=np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ConfigError(
            f"pose has shape {m.shape} or non-finite entries; a finite 4 x 4 homogeneous "
            "matrix or a pydrake RigidTransform is required"
        )
    return m


_MALLOC_TUNED: bool | None = None  # the process's answer, once asked


def tune_malloc_for_large_arrays() -> bool:
    """Keep freed large blocks in glibc's heap (process-wide; Linux only; once).

    Large arrays (1-30 MB: a camera frame's buffers, stereo images) are fresh ``mmap`` s
    under glibc's defaults, or heap top that was trimmed back, whose pages the kernel
    faults in and zeroes on first touch, again and again. This raises
    ``M_MMAP_THRESHOLD`` to its 32 MiB maximum and ``M_TRIM_THRESHOLD`` to 2 GiB so freed
    memory is recycled instead. It never changes results; the process keeps its peak heap
    (it is not handed back to the system). A process-wide choice, left to applications
    (``benchmarks/render.py --tune-malloc``): it speeds up every library in the process,
    Drake's VTK renderer most (``docs/lighting.md``, 2026-11-28: VTK frames 8-23 % less
    CPU in four of four pairs, Hapke frames within the noise). Equivalent to starting
    Python with ``MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=2147483647``;
    where either variable is already set, the environment's choice stands.

    Returns:
        True when the process runs with the tuning (set here, now or earlier); False
        where the environment chose its own thresholds or glibc's ``mallopt`` is
        unavailable.
    """
    global _MALLOC_TUNED
    if _MALLOC_TUNED is not None:
        return _MALLOC_TUNED
    import os

    if "MALLOC_MMAP_THRESHOLD_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        _MALLOC_TUNED = False
        return False
    import ctypes
    import ctypes.util

    _MALLOC_TUNED = False
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    m_trim_threshold, m_mmap_threshold = -1, -3
    ok = mallopt(m_mmap_threshold, 32 * 1024 * 1024) == 1
    _MALLOC_TUNED = bool(mallopt(m_trim_threshold, 2**31 - 1) == 1 and ok)
    return _MALLOC_TUNED


# ----------------------------------------------------------------------------------------
# Cameras
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole intrinsics (pixels), Drake convention (see module docstring).

    Attributes:
        width, height: image size (px), >= 1.
        fx, fy: focal lengths (px), > 0.
        cx, cy: principal point (px; pixel centres at integer coordinates).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or int(v) < 1:
                raise OutOfRangeError(f"{name} = {v!r} is invalid; must be an integer >= 1 (px)")
        for name in ("fx", "fy"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0.0):
                raise OutOfRangeError(f"{name} = {v!r} is invalid; must be > 0 (px)")
        for name in ("cx", "cy"):
            if not math.isfinite(float(getattr(self, name))):
                raise OutOfRangeError(
                    f"{name} = {getattr(self, name)!r} is invalid; must be finite"
                )

    @classmethod
    def from_fov(cls, *, width: int, height: int, fov_y_rad: float) -> PinholeCamera:
        """Centred principal point, square pixels, vertical field of view (rad), as Drake."""
        if not 0.0 < float(fov_y_rad) < math.pi:
            raise OutOfRangeError(f"fov_y_rad = {fov_y_rad!r} is invalid; allowed (0, pi) rad")
        f = 0.5 * height / math.tan(0.5 * float(fov_y_rad))
        return cls(width, height, f, f, 0.5 * width - 0.5, 0.5 * height - 0.5)

    def open3d_rays(self, X_WC) -> np.ndarray:
        """``(width * height, 6)`` float32 rays ``[origin, unit direction]`` in W (the
        fast path used by the renderer; same pixel order as :func:`pinhole_rays`)."""
        return self.world_rays(X_WC)[0]

    def world_rays(self, X_WC) -> tuple[np.ndarray, np.ndarray]:
        """``(rays (N, 6) float32, directions (3, N) float32)``: :meth:`open3d_rays` and
        the same unit directions in W stored per component."""
        d_C = camera_ray_directions(self.width, self.height, self.fx, self.fy, self.cx, self.cy)
        return _rays_world(d_C, as_pose_matrix(X_WC))

    def rays(self, X_WC) -> tuple[np.ndarray, np.ndarray]:
        """World-frame rays of every pixel; see :func:`pinhole_rays`."""
        return pinhole_rays(
            width=self.width,
            height=self.height,
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            X_WC=X_WC,
        )


@functools.lru_cache(maxsize=8)
def camera_ray_directions(
    width: int, height: int, fx: float, fy: float, cx: float, cy: float
) -> np.ndarray:
    """``(3, width * height)`` float32 unit ray directions in the camera frame C (cached,
    read-only), row-major pixel order; see :func:`pinhole_rays`."""
    u = ((np.arange(width, dtype=np.float64) - cx) / fx)[None, :]
    v = ((np.arange(height, dtype=np.float64) - cy) / fy)[:, None]
    inv = 1.0 / np.sqrt(u * u + v * v + 1.0)
    d = np.empty((3, height, width), dtype=np.float32)
    d[0] = u * inv
    d[1] = v * inv
    d[2] = inv
    d = d.reshape(3, -1)
    d.flags.writeable = False
    return d


def _rays_world(d_C: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 6)`` float32 Open3D rays ``[p_WC, R_WC d_C]`` from ``(3, N)`` directions, and
    the ``(3, N)`` world directions."""
    import cv2

    n = d_C.shape[1]
    R = X[:3, :3].astype(np.float32)
    d = np.empty((3, n), dtype=np.float32)
    tmp = np.empty(n, dtype=np.float32)
    for j in range(3):
        np.multiply(d_C[0], R[j, 0], out=d[j])
        np.multiply(d_C[1], R[j, 1], out=tmp)
        d[j] += tmp
        np.multiply(d_C[2], R[j, 2], out=tmp)
        d[j] += tmp
    o = [np.full(n, v, dtype=np.float32) for v in X[:3, 3].astype(np.float32)]
    if n <= 2**30:  # cv2.merge interleaves channels 2-3x faster than strided numpy writes
        rays = cv2.merge([*o, d[0], d[1], d[2]]).reshape(n, 6)
    else:  # pragma: no cover - beyond OpenCV's Mat size
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, :3] = np.stack(o, axis=1)
        rays[:, 3:] = d.T
    return rays, d


def pinhole_rays(
    *, width: int, height: int, fx: float, fy: float, cx: float, cy: float, X_WC
) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays through the pixel centres of a pinhole camera.

    Camera frame C (Drake): +z forward, +x right, +y down; pixel ``(u, v)`` centre at
    ``((u - cx) / fx, (v - cy) / fy, 1)`` in C. The ray of the principal point is the
    optical axis (C's +z).

    Args:
        width, height: image size (px). fx, fy, cx, cy: intrinsics (px).
        X_WC: pose of C in W (4 x 4 matrix or pydrake ``RigidTransform``).

    Returns:
        ``(origins, directions)``: ``(width * height, 3)`` float64, row-major pixel order
        (ray ``k`` is pixel ``(k % width, k // width)``); directions are unit vectors in W.
        ``origins`` is a read-only broadcast of the camera position ``p_WC``.
    """
    cam = PinholeCamera(int(width), int(height), float(fx), float(fy), float(cx), float(cy))
    X = as_pose_matrix(X_WC)
    u = (np.arange(cam.width, dtype=np.float64) - cam.cx) / cam.fx
    v = (np.arange(cam.height, dtype=np.float64) - cam.cy) / cam.fy
    d_C = np.empty((cam.height, cam.width, 3))
    d_C[..., 0] = u[None, :]
    d_C[..., 1] = v[:, None]
    d_C[..., 2] = 1.0
    d_C /= np.linalg.norm(d_C, axis=2, keepdims=True)
    d_W = d_C.reshape(-1, 3) @ X[:3, :3].T
    o = np.broadcast_to(X[:3, 3], d_W.shape)
    return o, d_W


# ----------------------------------------------------------------------------------------
# Hits and meshes
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RayHits:
    """First hits of N rays.

    Attributes:
        t_hit: ``(N,)`` float32 distance along the ray in units of the direction's length
            (m for unit directions); ``inf`` where nothing was hit.
        geometry_id: ``(N,)`` uint32: static geometry id, ``DYNAMIC_ID_BASE + j`` for
            dynamic mesh ``j``, :data:`INVALID_ID` for a miss.
        primitive_id: ``(N,)`` uint32 triangle index within the geometry.
        primitive_uvs: ``(N, 2)`` float32 barycentrics ``(u, v)``: the hit is
            ``(1 - u - v) p0 + u p1 + v p2``.
        normals: ``(N, 3)`` float32 unit geometric normals of the hit triangles (W),
            oriented by the triangle winding (``(p1 - p0) x (p2 - p0)``); zero on a miss.
    """

    t_hit: np.ndarray
    geometry_id: np.ndarray
    primitive_id: np.ndarray
    primitive_uvs: np.ndarray
    normals: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """``(N,)`` bool: the ray hit something."""
        return self.geometry_id != INVALID_ID

    @property
    def is_dynamic(self) -> np.ndarray:
        """``(N,)`` bool: the first hit is a dynamic mesh."""
        return (self.geometry_id >= DYNAMIC_ID_BASE) & (self.geometry_id != INVALID_ID)


@dataclass(frozen=True)
class DynamicMesh:
    """A moving triangle mesh in its own frame G.

    Attributes:
        vertices: ``(V, 3)`` positions in G (m).
        faces: ``(F, 3)`` vertex indices.
        label: label-image value of its pixels (default :data:`LABEL_ROVER`).
        albedo: Lambertian albedo used by the shader (default 0.5, an assumed mid-grey
            for painted/anodized rover surfaces).
    """

    vertices: np.ndarray
    faces: np.ndarray
    label: int = LABEL_ROVER
    albedo: float = 0.5

    def __post_init__(self) -> None:
        v, f = _check_mesh(self.vertices, self.faces, "DynamicMesh")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        if not 0.0 <= float(self.albedo) <= 1.0:
            raise OutOfRangeError(f"albedo = {self.albedo!r} is invalid; allowed [0, 1]")
        if not -32768 <= int(self.label) <= 32767:
            raise OutOfRangeError(f"label = {self.label!r} is invalid; must fit int16")


def _check_mesh(vertices, faces, what: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise ConfigError(f"{what} vertices have shape {v.shape}; finite (V, 3) required")
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
        raise ConfigError(
            f"{what} faces have shape {f.shape}, dtype {f.dtype}; int (F, 3) required"
        )
    if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
        raise ConfigError(
            f"{what} faces index vertices {int(f.min())}..{int(f.max())}; "
            f"allowed 0..{v.shape[0] - 1}"
        )
    return v, f.astype(np.uint32)


@dataclass
class _StaticGeom:
    vertices: np.ndarray  # float32 (V,3)
    faces: np.ndarray  # uint32 (F,3)
    label: int
    n_surface: int
    albedo: np.ndarray | None


# ----------------------------------------------------------------------------------------
# Raycaster
# ----------------------------------------------------------------------------------------
class TerrainRaycaster:
    """Static LOD terrain + dynamic meshes, cast with Embree through Open3D.

    Static geometry ids: extra static meshes (:meth:`add_static_mesh`) first, in the
    order added, then the terrain tiles in :attr:`TerrainLOD.tiles` order.
    """

    def __init__(self, *, nthreads: int = 0) -> None:
        if int(nthreads) < 0:
            raise OutOfRangeError(f"nthreads = {nthreads!r} is invalid; 0 (all cores) or more")
        self.nthreads = int(nthreads)
        self._extra: list[_StaticGeom] = []
        self._terrain: list[_StaticGeom] = []
        self._terrain_key: tuple | None = None
        self._terrain_hf = None
        self._terrain_albedo = None
        self._static_scene = None
        self._static_dirty = True
        self._dyn_meshes: list[DynamicMesh] = []
        self._dyn_poses: list[np.ndarray] = []
        self._dyn_scene = None
        self._dyn_dirty = True
        self._dyn_sphere: tuple[np.ndarray, float] | None = None
        self._attr_tables = None
        self.static_rebuilds = 0
        self.dynamic_rebuilds = 0

    # -- static geometry ----------------------------------------------------------------
    def set_terrain(self, lod) -> bool:
        """Use the tiles of a :class:`~lunar_drake.render.terrain_lod.TerrainLOD`.

        Returns True if the static scene must be rebuilt (the tile set changed), False if
        ``lod`` has the same tiles as the current one.
        """
        key = (lod.tile_px, lod.skirts, lod.skirt_margin_m, lod.tile_keys)
        if (
            key == self._terrain_key
            and lod.heightfield is self._terrain_hf
            and lod.albedo is self._terrain_albedo
        ):
            return False
        self._terrain = [
            _StaticGeom(
                vertices=t.vertices,
                faces=t.faces.view(np.uint32) if t.faces.dtype == np.int32 else t.faces,
                label=LABEL_TERRAIN,
                n_surface=t.n_surface_faces,
                albedo=t.albedo,
            )
            for t in lod.tiles
        ]
        self._terrain_key = key
        self._terrain_hf = lod.heightfield  # held: the identity checks stay meaningful
        self._terrain_albedo = lod.albedo
        self._static_dirty = True
        return True

    def add_static_mesh(self, vertices, faces, *, label: int = LABEL_TERRAIN) -> int:
        """Add a fixed mesh (W frame, m); returns its geometry id (stable)."""
        v, f = _check_mesh(vertices, faces, "static mesh")
        self._extra.append(
            _StaticGeom(
                vertices=v.astype(np.float32),
                faces=f,
                label=int(label),
                n_surface=int(f.shape[0]),
                albedo=None,
            )
        )
        self._static_dirty = True
        return len(self._extra) - 1

    @property
    def _static(self) -> list[_StaticGeom]:
        return self._extra + self._terrain

    @property
    def static_triangle_count(self) -> int:
        return sum(int(g.faces.shape[0]) for g in self._static)

    def _static_scene_ready(self):
        if self._static_dirty:
            o3d = _o3d()
            geoms = self._static
            scene = None
            if geoms:
                scene = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
                for g in geoms:
                    if g.faces.shape[0]:
                        scene.add_triangles(
                            o3d.core.Tensor.from_numpy(np.ascontiguousarray(g.vertices)),
                            o3d.core.Tensor.from_numpy(np.ascontiguousarray(g.faces)),
                        )
                    else:  # keep ids aligned: a degenerate placeholder triangle
                        scene.add_triangles(
                            o3d.core.Tensor.from_numpy(np.zeros((3, 3), np.float32)),
                            o3d.core.Tensor.from_numpy(np.array([[0, 1, 2]], np.uint32)),
                        )
            self._static_scene = scene
            self._static_labels = np.array([g.label for g in geoms] or [0], dtype=np.int16)
            self._static_nsurf = np.array([g.n_surface for g in geoms] or [0], dtype=np.int64)
            self._attr_tables = None
            self._static_dirty = False
            self.static_rebuilds += 1
        return self._static_scene

    # -- dynamic geometry ---------------------------------------------------------------
    def set_dynamic_meshes(self, meshes: Sequence, poses: Sequence | None = None) -> None:
        """Replace the dynamic meshes.

        Args:
            meshes: :class:`DynamicMesh` objects or ``(vertices, faces)`` pairs (frame G).
            poses: ``X_WG`` per mesh (4 x 4 or RigidTransform); default identity.
        """
        ms = [m if isinstance(m, DynamicMesh) else DynamicMesh(m[0], m[1]) for m in meshes]
        self._dyn_meshes = ms
        self._dyn_poses = [np.eye(4) for _ in ms]
        self._dyn_dirty = True
        if poses is not None:
            self.set_dynamic_poses(poses)

    def set_dynamic_poses(self, poses: Sequence) -> None:
        """New poses ``X_WG`` (one per dynamic mesh); the dynamic scene is rebuilt lazily,
        and only if a pose changed (a rover standing still while it images keeps its
        BVH; ``dynamic_rebuilds`` counts the builds)."""
        if len(poses) != len(self._dyn_meshes):
            raise ConfigError(
                f"got {len(poses)} poses for {len(self._dyn_meshes)} dynamic meshes; "
                "one pose per mesh is required"
            )
        new = [as_pose_matrix(X) for X in poses]
        if not all(np.array_equal(a, b) for a, b in zip(new, self._dyn_poses, strict=True)):
            self._dyn_dirty = True
        self._dyn_poses = new

    @property
    def dynamic_meshes(self) -> tuple[DynamicMesh, ...]:
        return tuple(self._dyn_meshes)

    @property
    def dynamic_triangle_count(self) -> int:
        return sum(int(m.faces.shape[0]) for m in self._dyn_meshes)

    def _dynamic_scene_ready(self):
        if self._dyn_dirty:
            scene, sphere = None, None
            if self._dyn_meshes:
                o3d = _o3d()
                scene = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
                allv = []
                for m, X in zip(self._dyn_meshes, self._dyn_poses, strict=True):
                    vw = m.vertices @ X[:3, :3].T + X[:3, 3]
                    allv.append(vw)
                    scene.add_triangles(
                        o3d.core.Tensor.from_numpy(vw.astype(np.float32)),
                        o3d.core.Tensor.from_numpy(np.ascontiguousarray(m.faces)),
                    )
                v = np.concatenate(allv)
                lo, hi = v.min(axis=0), v.max(axis=0)
                c = 0.5 * (lo + hi)
                r = float(np.sqrt(((v - c) ** 2).sum(axis=1).max())) * (1.0 + 1e-6) + 1e-6
                sphere = (c, r)
            self._dyn_scene = scene
            self._dyn_sphere = sphere
            self._dyn_labels = np.array([m.label for m in self._dyn_meshes] or [0], np.int16)
            self._dyn_albedo = np.array(
                [m.albedo for m in self._dyn_meshes] or [0.0], dtype=np.float32
            )
            self._dyn_dirty = False
            self.dynamic_rebuilds += 1
        return self._dyn_scene

    def dynamic_bounding_sphere(self) -> tuple[np.ndarray, float] | None:
        """``(center_W (3,), radius m)`` enclosing all dynamic meshes, or None."""
        self._dynamic_scene_ready()
        return self._dyn_sphere

    # -- queries ------------------------------------------------------------------------
    @staticmethod
    def _rays(origins, directions) -> np.ndarray:
        d = np.asarray(directions)
        o = np.asarray(origins)
        if d.ndim != 2 or d.shape[1] != 3:
            raise ConfigError(f"directions have shape {d.shape}; (N, 3) is required")
        if o.shape != d.shape:
            o = np.broadcast_to(o, d.shape)
        rays = np.empty((d.shape[0], 6), dtype=np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        return rays

    def _sphere_mask(self, rays: np.ndarray, tfar=None, *, common_origin=False) -> np.ndarray:
        """Rays that may touch the dynamic bounding sphere (conservative, float32)."""
        c, r = self._dyn_sphere  # type: ignore[misc]
        d = rays[:, 3:]
        if common_origin:
            w = (c - rays[0, :3].astype(np.float64)).astype(np.float32)
            wn = float(np.linalg.norm(w))
            if wn <= r * 1.0001 + 1e-6:
                m = np.ones(rays.shape[0], dtype=bool)
            else:
                dd = np.sqrt(np.einsum("ij,ij->i", d, d))
                cos_max = math.sqrt(max(0.0, 1.0 - (r / wn) ** 2)) - 1e-5
                m = (d @ w) >= np.float32(cos_max * wn) * dd
            if tfar is not None and math.isfinite(float(tfar)):
                dd = np.sqrt(np.einsum("ij,ij->i", d, d))
                m &= np.float32(wn - r) <= np.float32(tfar) * dd
            return m
        w = c.astype(np.float32) - rays[:, :3]
        dd = np.einsum("ij,ij->i", d, d)
        tp = np.einsum("ij,ij->i", w, d) / dd
        ww = np.einsum("ij,ij->i", w, w)
        dist2 = ww - tp * tp * dd
        # float32 cancellation in ww - tp^2 |d|^2: widen by a relative tolerance
        rr = np.float32(r * r * 1.0001 + 1e-6) + np.float32(1e-5) * ww
        m = (dist2 <= rr) & ((tp > 0) | (ww <= rr))
        if tfar is not None:
            m &= tp * np.sqrt(dd) - np.float32(r) <= tfar * np.sqrt(dd)
        return m

    def cast(self, origins, directions) -> RayHits:
        """First hits of rays ``origins + t * directions`` (W, m), ``t >= 0``.

        Args:
            origins: ``(N, 3)`` (or broadcastable) ray origins in W (m).
            directions: ``(N, 3)`` directions in W (need not be unit: ``t_hit`` is in
                units of their length).
        """
        return self.cast_rays(self._rays(origins, directions))

    def cast_rays(self, rays: np.ndarray, *, common_origin: bool = False) -> RayHits:
        """:meth:`cast` for an ``(N, 6)`` float32 array ``[origin, direction]`` (Open3D's
        layout); ``common_origin`` promises every ray starts at ``rays[0, :3]``."""
        rays = np.ascontiguousarray(rays, dtype=np.float32)
        if rays.ndim != 2 or rays.shape[1] != 6:
            raise ConfigError(f"rays have shape {rays.shape}; (N, 6) is required")
        n = rays.shape[0]
        o3d = _o3d()
        static = self._static_scene_ready()
        if static is not None:
            r = static.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self.nthreads)
            t = r["t_hit"].numpy()
            gid = r["geometry_ids"].numpy()
            pid = r["primitive_ids"].numpy()
            uv = r["primitive_uvs"].numpy()
            nrm = r["primitive_normals"].numpy()
        else:
            t = np.full(n, np.inf, np.float32)
            gid = np.full(n, INVALID_ID, np.uint32)
            pid = np.full(n, INVALID_ID, np.uint32)
            uv = np.zeros((n, 2), np.float32)
            nrm = np.zeros((n, 3), np.float32)
        dyn = self._dynamic_scene_ready()
        if dyn is not None and n:
            # bounding-sphere cull, then a cheap any-hit pass, then closest hits only for
            # the rays that touch a dynamic mesh (a rover camera sits inside the rover's
            # bounding sphere, so the cull alone rarely helps it)
            m = self._sphere_mask(rays, common_origin=common_origin)
            sel = None if m.all() else np.flatnonzero(m)
            sub = rays if sel is None else np.take(rays, sel, axis=0)
            if sub.shape[0]:
                occ = dyn.test_occlusions(
                    o3d.core.Tensor.from_numpy(sub), nthreads=self.nthreads
                ).numpy()
                k = np.flatnonzero(occ)
                if sel is not None:
                    k = sel[k]
                if k.size:
                    rd = dyn.cast_rays(
                        o3d.core.Tensor.from_numpy(np.take(rays, k, axis=0)),
                        nthreads=self.nthreads,
                    )
                    td = rd["t_hit"].numpy()
                    closer = td < t[k]
                    if closer.any():
                        kk = k[closer]
                        t, gid, pid, uv, nrm = (
                            a if a.flags.writeable else np.array(a) for a in (t, gid, pid, uv, nrm)
                        )
                        t[kk] = td[closer]
                        gid[kk] = rd["geometry_ids"].numpy()[closer] + np.uint32(DYNAMIC_ID_BASE)
                        pid[kk] = rd["primitive_ids"].numpy()[closer]
                        uv[kk] = rd["primitive_uvs"].numpy()[closer]
                        nrm[kk] = rd["primitive_normals"].numpy()[closer]
        return RayHits(t_hit=t, geometry_id=gid, primitive_id=pid, primitive_uvs=uv, normals=nrm)

    def occlusion(
        self,
        origins,
        directions,
        max_t=np.inf,
        *,
        static: bool = True,
        dynamic: bool = True,
        cull: bool = True,
    ) -> np.ndarray:
        """``(N,)`` bool: something lies on ``origins + t * directions``, ``0 < t < max_t``.

        For shadow rays: offset the origins off the surface yourself (e.g. along the
        normal by a few mm). ``max_t`` is a scalar or ``(N,)`` (in units of the direction
        length; per-ray limits are applied by scaling the directions, infinite entries
        are capped at 1e6 m). ``static`` / ``dynamic`` select which scenes occlude;
        ``cull=False`` skips the bounding-sphere pre-test of the dynamic scene (for rays
        already known to pass near it).
        """
        return self.occlusion_rays(
            self._rays(origins, directions), max_t, static=static, dynamic=dynamic, cull=cull
        )

    def occlusion_rays(
        self,
        rays: np.ndarray,
        max_t=np.inf,
        *,
        static: bool = True,
        dynamic: bool = True,
        cull: bool = True,
    ) -> np.ndarray:
        """:meth:`occlusion` for an ``(N, 6)`` float32 ray array (modified in place when
        ``max_t`` is per-ray)."""
        rays = np.ascontiguousarray(rays, dtype=np.float32)
        n = rays.shape[0]
        out = np.zeros(n, dtype=bool)
        if n == 0:
            return out
        mt = np.asarray(max_t, dtype=np.float64)
        if mt.ndim == 0:
            tfar = float(mt)
        else:
            if mt.shape != (n,):
                raise ConfigError(f"max_t has shape {mt.shape}; a scalar or ({n},) is required")
            rays[:, 3:] *= np.minimum(mt, 1e6).astype(np.float32)[:, None]
            tfar = 1.0
        o3d = _o3d()
        if static:
            s = self._static_scene_ready()
            if s is not None:
                out |= s.test_occlusions(
                    o3d.core.Tensor.from_numpy(rays), tfar=tfar, nthreads=self.nthreads
                ).numpy()
        if dynamic:
            d = self._dynamic_scene_ready()
            if d is not None:
                if not cull and not out.any():
                    out |= d.test_occlusions(
                        o3d.core.Tensor.from_numpy(rays), tfar=tfar, nthreads=self.nthreads
                    ).numpy()
                else:
                    m = ~out
                    if cull:
                        m &= self._sphere_mask(rays, np.float32(tfar))
                    sel = np.flatnonzero(m)
                    if sel.size:
                        out[sel] |= d.test_occlusions(
                            o3d.core.Tensor.from_numpy(rays[sel]),
                            tfar=tfar,
                            nthreads=self.nthreads,
                        ).numpy()
        return out

    # -- per-hit attributes ---------------------------------------------------------------
    def classify(
        self, geometry_id: np.ndarray, primitive_id: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(label int16, dynamic bool, skirt bool)`` of hits given by their ids (all
        entries must be hits, i.e. not :data:`INVALID_ID`)."""
        self._static_scene_ready()
        self._dynamic_scene_ready()
        gid = np.asarray(geometry_id)
        dyn = gid >= DYNAMIC_ID_BASE
        sg = np.minimum(gid, np.uint32(self._static_labels.size - 1))
        label = np.take(self._static_labels, sg)
        skirt = np.asarray(primitive_id) >= np.take(self._static_nsurf, sg)
        if dyn.any():
            k = np.flatnonzero(dyn)
            label[k] = np.take(self._dyn_labels, gid[k] - DYNAMIC_ID_BASE)
            skirt[k] = False
        return label, dyn, skirt

    def labels(self, hits: RayHits) -> np.ndarray:
        """``(N,)`` int16 label per ray: 0 sky, static geometry label (terrain 1), dynamic
        mesh label (rover 2)."""
        self._static_scene_ready()
        self._dynamic_scene_ready()
        gid = hits.geometry_id
        out = np.zeros(gid.shape, dtype=np.int16)
        dyn = hits.is_dynamic
        st = hits.hit & ~dyn
        if st.any():
            out[st] = self._static_labels[gid[st]]
        if dyn.any():
            out[dyn] = self._dyn_labels[gid[dyn] - DYNAMIC_ID_BASE]
        return out

    def skirt_mask(self, hits: RayHits) -> np.ndarray:
        """``(N,)`` bool: the hit is on a terrain skirt (crack filler) triangle."""
        self._static_scene_ready()
        st = hits.hit & ~hits.is_dynamic
        out = np.zeros(hits.t_hit.shape, dtype=bool)
        if st.any():
            out[st] = hits.primitive_id[st] >= self._static_nsurf[hits.geometry_id[st]]
        return out

    def dynamic_albedo(self, hits: RayHits) -> np.ndarray:
        """``(N,)`` float32 albedo of dynamic-mesh hits (0 elsewhere)."""
        self._dynamic_scene_ready()
        out = np.zeros(hits.t_hit.shape, dtype=np.float32)
        dyn = hits.is_dynamic
        if dyn.any():
            out[dyn] = self._dyn_albedo[hits.geometry_id[dyn] - DYNAMIC_ID_BASE]
        return out

    def vertex_albedo(self, hits: RayHits) -> np.ndarray:
        """``(N,)`` float32 per-vertex albedo of static hits, interpolated with the hit's
        barycentrics; NaN where the hit geometry has none (or for misses/dynamic hits)."""
        self._static_scene_ready()
        if self._attr_tables is None:
            geoms = self._static
            voff = np.cumsum([0] + [g.vertices.shape[0] for g in geoms])
            foff = np.cumsum([0] + [g.faces.shape[0] for g in geoms])
            faces = np.concatenate(
                [g.faces.astype(np.int64) + voff[i] for i, g in enumerate(geoms)]
                or [np.zeros((0, 3), np.int64)]
            )
            alb = np.concatenate(
                [
                    g.albedo if g.albedo is not None else np.full(g.vertices.shape[0], np.nan)
                    for g in geoms
                ]
                or [np.zeros(0)]
            ).astype(np.float32)
            self._attr_tables = (foff, faces, alb)
        foff, faces, alb = self._attr_tables
        out = np.full(hits.t_hit.shape, np.nan, dtype=np.float32)
        st = hits.hit & ~hits.is_dynamic
        if st.any() and faces.shape[0]:
            f = faces[foff[hits.geometry_id[st]] + hits.primitive_id[st]]
            uv = hits.primitive_uvs[st]
            u, v = uv[:, 0], uv[:, 1]
            out[st] = (1.0 - u - v) * alb[f[:, 0]] + u * alb[f[:, 1]] + v * alb[f[:, 2]]
        return out
