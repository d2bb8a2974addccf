"""TerrainVisualizer: draws the site terrain in Meshcat as a decimated, albedo-coloured mesh."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus

from lunar_drake.systems.leaf import Leaf
from lunar_drake.terrain.heightfield import Heightfield


def terrain_lod_mesh(
    heightfield: Heightfield, *, max_px: int, albedo: np.ndarray | None = None, albedo_gain=4.0
):
    """Vertices (3, N) in the site frame (m), faces (3, M) int32 and colours (3, N) in [0, 1]
    of a regular-grid mesh of the terrain decimated to at most ``max_px`` a side.

    ``albedo`` (optional) is a full- or reduced-resolution albedo grid; it is resampled
    to the mesh grid by block averaging / nearest index. NaN cells are dropped.
    """
    z, _res = heightfield.decimated(max_size=max_px)
    z = np.asarray(z, dtype=np.float64)
    nr, nc = z.shape
    b = heightfield.bounds
    x0, x1, y0, y1 = b.left, b.right, b.bottom, b.top
    xs = x0 + (np.arange(nc) + 0.5) * (x1 - x0) / nc
    ys = y1 - (np.arange(nr) + 0.5) * (y1 - y0) / nr
    X, Y = np.meshgrid(xs, ys)
    verts = np.stack([X.ravel(), Y.ravel(), z.ravel()])
    if albedo is None:
        a = np.full(z.shape, 0.12)
    else:
        ri = (np.arange(nr) * albedo.shape[0]) // nr
        ci = (np.arange(nc) * albedo.shape[1]) // nc
        a = np.asarray(albedo, dtype=np.float64)[np.ix_(ri, ci)]
    colors = np.repeat(np.clip(a * albedo_gain, 0.0, 1.0).ravel()[None, :], 3, axis=0)
    idx = np.arange(nr * nc).reshape(nr, nc)
    v00, v01 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    v10, v11 = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    # Counter-clockwise seen from above (+z): rows run south, columns east.
    faces = np.concatenate([np.stack([v00, v10, v11]), np.stack([v00, v11, v01])], axis=1)
    valid = np.isfinite(verts[2])
    keep = valid[faces].all(axis=0)
    faces = faces[:, keep]
    verts[2, ~valid] = 0.0
    return verts, faces.astype(np.int32), colors


class TerrainVisualizer(Leaf):
    """Sends the terrain to Meshcat once, at initialization.

    .. pydrake_system::

        name: TerrainVisualizer
        input_ports:
        - heightfield

    Args:
        meshcat: the pydrake Meshcat instance.
        max_mesh_px: mesh grid side after decimation (vertices).
        albedo: optional albedo grid (any resolution) for vertex colours.
        albedo_gain: display gain on albedo.
        path: Meshcat scene path.
        frame_view: also set a black sky, hide the grid and point the camera at the site.
    """

    def __init__(
        self,
        *,
        meshcat,
        max_mesh_px: int = 384,
        albedo=None,
        albedo_gain: float = 4.0,
        path: str = "/terrain",
        frame_view: bool = True,
    ):
        super().__init__()
        self._meshcat = meshcat
        self._max_px = int(max_mesh_px)
        self._albedo = albedo
        self._gain = float(albedo_gain)
        self._path = path
        self._frame_view = bool(frame_view)
        self.heightfield_input = self.DeclareAbstractInputPort(
            "heightfield",
            AbstractValue.Make(Heightfield.from_array(np.zeros((2, 2)), resolution_m=1.0)),
        )
        self.DeclareInitializationPublishEvent(self._draw)

    def _draw(self, context):
        hf = self.heightfield_input.Eval(context)
        verts, faces, colors = terrain_lod_mesh(
            hf, max_px=self._max_px, albedo=self._albedo, albedo_gain=self._gain
        )
        self._meshcat.SetTriangleColorMesh(self._path, verts, faces, colors)
        if self._frame_view:
            self._set_view(hf)
        return EventStatus.Succeeded()

    def _set_view(self, hf: Heightfield) -> None:
        """Black sky, no grid, a low ambient light, and a camera over the site's SW corner."""
        m = self._meshcat
        m.SetProperty("/Grid", "visible", False)
        m.SetProperty("/Axes", "visible", False)
        m.SetProperty("/Background", "top_color", [0.0, 0.0, 0.0])
        m.SetProperty("/Background", "bottom_color", [0.02, 0.02, 0.03])
        m.SetProperty("/Lights/AmbientLight/<object>", "intensity", 0.25)
        # Meshcat's camera-side point lights would add a bright spot; the Sun (MeshcatSun)
        # and the ambient term light the scene instead.
        for light in ("PointLightNegativeX", "PointLightPositiveX"):
            m.SetProperty(f"/Lights/{light}/<object>", "intensity", 0.0)
        b = hf.bounds
        half = 0.5 * max(b.right - b.left, b.top - b.bottom)
        z0 = float(np.nanmean(hf.decimated(max_size=16)[0]))
        m.SetCameraPose(
            camera_in_world=np.array([-0.55 * half, -0.55 * half, z0 + 0.3 * half]),
            target_in_world=np.array([0.0, 0.0, z0]),
        )
