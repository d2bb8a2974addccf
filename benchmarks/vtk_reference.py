"""A Drake RenderEngineVtk reference camera for the same terrain (benchmarks, comparisons).

:func:`write_terrain_obj` writes a terrain triangle mesh (e.g. ``TerrainLOD.merged()``)
as a Wavefront OBJ, optionally textured with an albedo raster draped in site
coordinates (``vt`` from the vertex x, y over the raster bounds; an 8-bit PNG named by
an MTL ``map_Kd``). :class:`VtkReferenceCamera` registers that mesh, welded to the
world, in a MultibodyPlant/SceneGraph (the caller may add more models, e.g. the rover,
before :meth:`~VtkReferenceCamera.finalize`), adds a ``RenderEngineVtk`` and an
``RgbdSensor`` with Drake's pinhole intrinsics (the same as
:class:`lunar_drake.render.raycast.PinholeCamera.from_fov`), and renders colour images
at any camera pose ``X_WC`` (Drake camera frame: +z forward, +x right, +y down).

The VTK image is lit by one directional "Sun" light (Lambertian diffuse, no terrain or
rover shadows unless ``cast_shadows``); it is a rendering-speed reference, not a
photometric one. pydrake is imported lazily (the pure-numpy writer needs none).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError

__all__ = ["VtkReferenceCamera", "albedo_texture", "vertex_normals", "write_terrain_obj"]


def _format_rows(row: str, a: np.ndarray) -> str:
    """``row`` (a %-format taking one table row) applied to every row of ``a``."""
    a = np.ascontiguousarray(a)
    if a.size == 0:
        return ""
    return (row * a.shape[0]) % tuple(a.ravel().tolist())


def vertex_normals(vertices, faces, *, face_mask=None) -> np.ndarray:
    """``(V, 3)`` unit vertex normals: area-weighted sums of the normals of the adjacent
    counter-clockwise faces (only those where ``face_mask`` is True, e.g. leaving out LOD
    skirts); +z for vertices without such faces or with a zero sum."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if face_mask is not None:
        f = f[np.asarray(face_mask, dtype=bool)]
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # 2 x area
    nv = v.shape[0]
    idx = f.ravel()
    n = np.stack(
        [np.bincount(idx, weights=np.repeat(fn[:, c], 3), minlength=nv) for c in range(3)],
        axis=1,
    )
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-12
    n[ok] /= length[ok, None]
    n[~ok] = (0.0, 0.0, 1.0)
    return n


def albedo_texture(albedo, *, gain: float = 3.0) -> np.ndarray:
    """8-bit grey texture ``clip(gain * albedo, 0, 1) * 255`` of an albedo raster (NaN = 0).

    ``gain`` (default 3, as the Meshcat terrain view) maps typical lunar normal albedos
    (0.1-0.3) into the displayable range.
    """
    a = np.asarray(albedo, dtype=np.float64)
    if a.ndim != 2 or a.size == 0:
        raise ConfigError(f"albedo has shape {a.shape}; a non-empty 2-D raster is required")
    if not (math.isfinite(gain) and gain > 0):
        raise OutOfRangeError(f"gain = {gain!r}; must be > 0")
    t = np.clip(np.nan_to_num(a, nan=0.0) * gain, 0.0, 1.0)
    return np.round(t * 255.0).astype(np.uint8)


def write_terrain_obj(
    path,
    vertices,
    faces,
    *,
    albedo=None,
    bounds=None,
    albedo_gain: float = 3.0,
    diffuse=(0.6, 0.6, 0.6),
    normal_faces=None,
) -> Path:
    """Writes a triangle mesh (site frame, m) as an OBJ with an MTL (and a PNG texture).

    Args:
        path: the ``.obj`` path; ``<stem>.mtl`` (and ``<stem>_albedo.png``) go beside it.
        vertices: ``(V, 3)`` positions (m). faces: ``(F, 3)`` zero-based vertex indices.
        albedo: optional 2-D albedo raster covering ``bounds`` (north-up; row 0 at the
            top); draped as a texture with ``u = (x - left) / (right - left)``,
            ``v = (y - bottom) / (top - bottom)``.
        bounds: ``(left, bottom, right, top)`` of the raster in site m (needed with
            ``albedo``). albedo_gain: see :func:`albedo_texture`.
        diffuse: MTL ``Kd`` (RGB in [0, 1]) when there is no texture.
        normal_faces: optional ``(F,)`` bool mask of the faces that define the vertex
            normals (``vn``, see :func:`vertex_normals`), e.g. the LOD surface faces
            without the skirts (which would otherwise tilt the tile-edge normals).

    Returns:
        The OBJ path.

    Raises:
        ConfigError: bad shapes, out-of-range face indices, or ``albedo`` without
            ``bounds``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
        raise ConfigError(f"vertices have shape {v.shape}; (V >= 3, 3) is required")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1 or not np.issubdtype(f.dtype, np.integer):
        raise ConfigError(f"faces have shape {f.shape} ({f.dtype}); (F >= 1, 3) ints required")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ConfigError(
            f"face indices span [{f.min()}, {f.max()}]; allowed [0, {v.shape[0] - 1}]"
        )
    if not np.isfinite(v).all():
        raise ConfigError("vertices contain non-finite values")
    path = Path(path)
    mtl = path.with_suffix(".mtl")
    lines = [f"mtllib {mtl.name}\n"]
    mtl_text = "newmtl terrain\nKa 0 0 0\nKs 0 0 0\nNs 1\n"
    textured = albedo is not None
    if textured:
        if bounds is None:
            raise ConfigError("albedo given without bounds = (left, bottom, right, top) in m")
        left, bottom, right, top = (float(b) for b in bounds)
        if not (right > left and top > bottom):
            raise OutOfRangeError(f"bounds = {bounds!r} is empty; need right > left, top > bottom")
        import cv2

        png = path.with_name(f"{path.stem}_albedo.png")
        if not cv2.imwrite(str(png), albedo_texture(albedo, gain=albedo_gain)):
            raise ConfigError(f"could not write the albedo texture {str(png)!r}")
        mtl_text += f"Kd 1 1 1\nmap_Kd {png.name}\n"
    else:
        r, g, b = (float(c) for c in diffuse)
        mtl_text += f"Kd {r:.4f} {g:.4f} {b:.4f}\n"
    lines.append(_format_rows("v %.4f %.4f %.4f\n", v))
    if textured:
        uv = np.stack([(v[:, 0] - left) / (right - left), (v[:, 1] - bottom) / (top - bottom)], 1)
        lines.append(_format_rows("vt %.6f %.6f\n", uv))
    lines.append(_format_rows("vn %.4f %.4f %.4f\n", vertex_normals(v, f, face_mask=normal_faces)))
    lines.append("usemtl terrain\n")
    f1 = f.astype(np.int64) + 1
    if textured:
        lines.append(_format_rows("f %d/%d/%d %d/%d/%d %d/%d/%d\n", np.repeat(f1, 3, axis=1)))
    else:
        lines.append(_format_rows("f %d//%d %d//%d %d//%d\n", np.repeat(f1, 2, axis=1)))
    mtl.write_text(mtl_text)
    with open(path, "w") as fh:
        fh.writelines(lines)
    return path


class VtkReferenceCamera:
    """A MultibodyPlant + SceneGraph + RenderEngineVtk + RgbdSensor around a terrain mesh.

    Use: construct (terrain registered), optionally add models to :attr:`plant`, call
    :meth:`finalize`, then :meth:`render` (or :meth:`set_pose` and :meth:`eval_color`).

    Args:
        obj_path: terrain mesh file (from :func:`write_terrain_obj`), site frame (m).
        width, height: image size (px). fov_y_deg: vertical field of view (deg).
        sun_dir_W: unit vector toward the Sun in the site frame, or None for Drake's
            default head light.
        near_m, far_m: clipping range (m).
        cast_shadows: RenderEngineVtk shadow mapping for the Sun light.
        background_rgb: clear colour (RGB in [0, 1]; black sky by default).
        backend: RenderEngineVtkParams.backend ("" = Drake's default).
        plant_time_step: the MultibodyPlant's time step (s).
    """

    def __init__(
        self,
        *,
        obj_path,
        width: int = 1280,
        height: int = 960,
        fov_y_deg: float = 45.0,
        sun_dir_W=None,
        near_m: float = 0.05,
        far_m: float = 1000.0,
        cast_shadows: bool = False,
        background_rgb=(0.0, 0.0, 0.0),
        backend: str = "",
        plant_time_step: float = 0.0,
    ):
        from pydrake.geometry import (
            GeometryInstance,
            LightParameter,
            MakeRenderEngineVtk,
            Mesh,
            RenderEngineVtkParams,
        )
        from pydrake.math import RigidTransform
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
        from pydrake.systems.framework import DiagramBuilder

        if not (16 <= int(width) <= 8192 and 16 <= int(height) <= 8192):
            raise OutOfRangeError(f"camera size {width}x{height} px; allowed 16..8192 each")
        if not 1.0 <= float(fov_y_deg) <= 170.0:
            raise OutOfRangeError(f"fov_y_deg = {fov_y_deg!r}; allowed [1, 170] deg")
        if not 0.0 < float(near_m) < float(far_m):
            raise OutOfRangeError(f"clipping range ({near_m!r}, {far_m!r}) m; need 0 < near < far")
        if not Path(obj_path).exists():
            raise ConfigError(f"obj_path = {str(obj_path)!r} does not exist")
        self.width, self.height, self.fov_y_deg = int(width), int(height), float(fov_y_deg)
        self._near, self._far = float(near_m), float(far_m)
        params = RenderEngineVtkParams()
        params.default_clear_color = list(background_rgb)
        params.backend = backend
        if sun_dir_W is not None:
            s = np.asarray(sun_dir_W, dtype=float).reshape(3)
            s = s / np.linalg.norm(s)
            params.lights = [
                LightParameter(
                    type="directional", direction=(-s).tolist(), frame="world", intensity=1.0
                )
            ]
            params.cast_shadows = bool(cast_shadows)
            if cast_shadows:
                params.shadow_map_size = 2048
        self.builder = DiagramBuilder()
        self.plant, self.scene_graph = AddMultibodyPlantSceneGraph(
            self.builder, float(plant_time_step)
        )
        self.scene_graph.AddRenderer("vtk", MakeRenderEngineVtk(params))
        # No diffuse property: the mesh's own MTL material (and texture) is used.
        self.terrain_geometry_id = self.plant.RegisterVisualGeometry(
            self.plant.world_body(),
            GeometryInstance(RigidTransform(), Mesh(str(obj_path)), "terrain_mesh"),
        )
        self.diagram = None
        self.sensor = None

    def finalize(self) -> None:
        """Finalizes the plant, adds the RgbdSensor, builds the diagram and its context."""
        from pydrake.geometry import (
            ClippingRange,
            ColorRenderCamera,
            DepthRange,
            DepthRenderCamera,
            RenderCameraCore,
        )
        from pydrake.math import RigidTransform
        from pydrake.systems.sensors import CameraInfo, RgbdSensor

        if self.diagram is not None:
            raise ConfigError("VtkReferenceCamera.finalize() was already called")
        if not self.plant.is_finalized():
            self.plant.Finalize()
        info = CameraInfo(width=self.width, height=self.height, fov_y=math.radians(self.fov_y_deg))
        core = RenderCameraCore("vtk", info, ClippingRange(self._near, self._far), RigidTransform())
        self.sensor = self.builder.AddNamedSystem(
            "vtk_camera",
            RgbdSensor(
                parent_id=self.scene_graph.world_frame_id(),
                X_PB=RigidTransform(),
                color_camera=ColorRenderCamera(core, False),
                depth_camera=DepthRenderCamera(core, DepthRange(self._near, self._far * 0.999)),
            ),
        )
        self.builder.Connect(
            self.scene_graph.get_query_output_port(), self.sensor.query_object_input_port()
        )
        self.diagram = self.builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.sensor_context = self.sensor.GetMyMutableContextFromRoot(self.context)
        self.plant_context = self.plant.GetMyMutableContextFromRoot(self.context)

    def hide(self, geometry_ids) -> None:
        """Removes the perception role of the given plant geometries (before
        :meth:`finalize`), e.g. the camera head the camera sits inside."""
        from pydrake.geometry import Role

        if self.diagram is not None:
            raise ConfigError("hide() must be called before finalize()")
        sid = self.plant.get_source_id()
        for g in geometry_ids:
            self.scene_graph.RemoveRole(sid, g, Role.kPerception)

    def _check(self) -> None:
        if self.diagram is None:
            raise ConfigError("call VtkReferenceCamera.finalize() before rendering")

    def set_pose(self, X_WC) -> None:
        """Moves the camera (a parameter of the sensor: invalidates the cached image)."""
        from pydrake.math import RigidTransform

        self._check()
        X = X_WC if isinstance(X_WC, RigidTransform) else RigidTransform(np.asarray(X_WC, float))
        self.sensor.SetX_PB(self.sensor_context, X)

    def eval_color(self):
        """Evaluates (renders, unless cached) the colour image; a Drake ImageRgba8U."""
        self._check()
        return self.sensor.color_image_output_port().Eval(self.sensor_context)

    def render(self, X_WC) -> np.ndarray:
        """``(height, width, 4)`` uint8 RGBA colour image at camera pose ``X_WC``."""
        self.set_pose(X_WC)
        return np.array(self.eval_color().data, copy=True)
