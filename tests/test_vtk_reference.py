"""Smoke tests of the RenderEngineVtk reference camera and its OBJ writer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.vtk_reference import (
    VtkReferenceCamera,
    albedo_texture,
    vertex_normals,
    write_terrain_obj,
)
from lunar_drake.errors import ConfigError


def _grid(n=9, spacing=0.1, slope=0.0):
    """An n x n vertex grid centred on the origin (x east, y north), z = slope * x,
    counter-clockwise faces seen from above."""
    yy, xx = np.mgrid[0:n, 0:n]
    x = (xx.ravel() - (n - 1) / 2) * spacing
    y = ((n - 1) / 2 - yy.ravel()) * spacing
    v = np.stack([x, y, slope * x], axis=1)
    f = []
    for r in range(n - 1):
        for c in range(n - 1):
            a = r * n + c
            f += [[a, a + n, a + n + 1], [a, a + n + 1, a + 1]]
    return v, np.array(f, dtype=np.int32)


def test_vertex_normals_of_a_tilted_plane_and_the_face_mask():
    v, f = _grid(slope=0.5)
    n = vertex_normals(v, f)
    expected = np.array([-0.5, 0.0, 1.0]) / math.sqrt(1.25)
    np.testing.assert_allclose(n, np.broadcast_to(expected, n.shape), atol=1e-12)
    # a vertical "skirt" face hanging from vertex 0 tilts its normal unless masked out
    v2 = np.vstack([v, v[0] - [0, 0, 1], v[1] - [0, 0, 1]])
    k = v.shape[0]
    f2 = np.vstack([f, [[0, k, k + 1]]])
    tilted = vertex_normals(v2, f2)
    assert abs(tilted[0] @ expected) < 0.999
    mask = np.arange(f2.shape[0]) < f.shape[0]
    masked = vertex_normals(v2, f2, face_mask=mask)
    np.testing.assert_allclose(masked[0], expected, atol=1e-12)
    np.testing.assert_allclose(masked[k], [0, 0, 1])  # no surface face: +z


def test_albedo_texture_scales_and_clips():
    t = albedo_texture(np.array([[0.0, 0.1], [0.5, np.nan]]), gain=3.0)
    assert t.dtype == np.uint8
    assert t.tolist() == [[0, 77], [255, 0]]  # round(0.3 * 255)


def test_write_terrain_obj_counts_and_indices(tmp_path):
    v, f = _grid(n=5)
    path = write_terrain_obj(
        tmp_path / "t.obj", v, f, albedo=np.full((4, 4), 0.2), bounds=(-0.25, -0.25, 0.25, 0.25)
    )
    lines = path.read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == v.shape[0]
    assert sum(ln.startswith("vt ") for ln in lines) == v.shape[0]
    assert sum(ln.startswith("vn ") for ln in lines) == v.shape[0]
    faces = [ln for ln in lines if ln.startswith("f ")]
    assert len(faces) == f.shape[0]
    assert faces[0] == "f {0}/{0}/{0} {1}/{1}/{1} {2}/{2}/{2}".format(*(f[0] + 1))
    vt0 = [float(x) for x in lines[[ln.startswith("vt ") for ln in lines].index(True)].split()[1:]]
    np.testing.assert_allclose(vt0, [0.1, 0.9])  # vertex 0 at (-0.2, 0.2)
    mtl = (tmp_path / "t.mtl").read_text()
    assert "map_Kd t_albedo.png" in mtl
    assert (tmp_path / "t_albedo.png").exists()
    plain = write_terrain_obj(tmp_path / "p.obj", v, f).read_text()
    assert "vt " not in plain and f"f {f[0][0] + 1}//{f[0][0] + 1} " in plain
    with pytest.raises(ConfigError, match="bounds"):
        write_terrain_obj(tmp_path / "x.obj", v, f, albedo=np.ones((2, 2)))
    with pytest.raises(ConfigError, match="face indices"):
        write_terrain_obj(tmp_path / "x.obj", v, f + v.shape[0])


def _looking_down(height_m: float, x_m: float = 0.0) -> np.ndarray:
    """Drake camera over (x, 0) looking straight down, image right = east, down = south."""
    X = np.eye(4)
    X[:3, :3] = np.diag([1.0, -1.0, -1.0])
    X[:3, 3] = [x_m, 0.0, height_m]
    return X


def test_vtk_camera_renders_the_textured_terrain(tmp_path):
    v, f = _grid(n=33, spacing=0.2)  # 6.4 m square
    albedo = np.zeros((32, 32))
    albedo[:, 16:] = 0.3  # east half bright
    obj = write_terrain_obj(tmp_path / "t.obj", v, f, albedo=albedo, bounds=(-3.3, -3.3, 3.3, 3.3))
    cam = VtkReferenceCamera(obj_path=obj, width=64, height=48, sun_dir_W=[0, 0, 1])
    with pytest.raises(ConfigError, match="finalize"):
        cam.render(_looking_down(5.0))
    cam.finalize()
    try:
        img = cam.render(_looking_down(5.0))
    except RuntimeError as exc:  # pragma: no cover - no offscreen GL on this machine
        pytest.skip(f"RenderEngineVtk cannot render here: {exc}")
    assert img.shape == (48, 64, 4)
    grey = img[..., :3].astype(float).mean(axis=2)
    west, east = grey[10:38, 4:28].mean(), grey[10:38, 36:60].mean()
    assert west < 5 and east > 200  # the texture is draped east-up, lit from above
    # moving the camera (a sensor parameter) re-renders: the boundary shifts left
    moved = cam.render(_looking_down(5.0, x_m=1.0))[..., :3].astype(float).mean(axis=2)
    assert moved[24, 24] > 200 and grey[24, 24] < 5
