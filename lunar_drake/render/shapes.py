"""Triangle meshes of SceneGraph shapes (for ray casting the rover's own geometry)."""

from __future__ import annotations

import numpy as np


def box_mesh(lx: float, ly: float, lz: float):
    """(V, 3), (F, 3) of an axis-aligned box centred at the origin (m)."""
    h = 0.5 * np.array([lx, ly, lz])
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    v = s * h
    f = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ]
    )
    return v, f


def cylinder_mesh(radius: float, length: float, *, n: int = 24):
    """Cylinder about +z centred at the origin (m), closed with caps."""
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ring = np.c_[radius * np.cos(a), radius * np.sin(a)]
    bot = np.c_[ring, np.full(n, -0.5 * length)]
    top = np.c_[ring, np.full(n, 0.5 * length)]
    v = np.vstack([bot, top, [[0, 0, -0.5 * length], [0, 0, 0.5 * length]]])
    f = []
    for k in range(n):
        j = (k + 1) % n
        f += [[k, j, n + j], [k, n + j, n + k], [2 * n, j, k], [2 * n + 1, n + k, n + j]]
    return v, np.array(f)


def sphere_mesh(radius: float, *, n: int = 12):
    """UV sphere centred at the origin (m)."""
    th = np.linspace(0.0, np.pi, n + 1)
    ph = np.linspace(0.0, 2.0 * np.pi, 2 * n, endpoint=False)
    v = [[0, 0, radius]]
    for t in th[1:-1]:
        for p in ph:
            v.append(
                [radius * np.sin(t) * np.cos(p), radius * np.sin(t) * np.sin(p), radius * np.cos(t)]
            )
    v.append([0, 0, -radius])
    m = 2 * n
    f = [[0, 1 + k, 1 + (k + 1) % m] for k in range(m)]
    for r in range(n - 2):
        b = 1 + r * m
        for k in range(m):
            j = (k + 1) % m
            f += [[b + k, b + m + k, b + m + j], [b + k, b + m + j, b + j]]
    last = len(v) - 1
    b = 1 + (n - 2) * m
    f += [[last, b + (k + 1) % m, b + k] for k in range(m)]
    return np.array(v, float), np.array(f)


def shape_mesh(shape):
    """Vertices and faces (in the geometry frame) of a pydrake Shape, or None when the
    shape type is not supported (it is then left out of the ray-cast scene)."""
    from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere

    if isinstance(shape, Box):
        return box_mesh(shape.width(), shape.depth(), shape.height())
    if isinstance(shape, Cylinder):
        return cylinder_mesh(shape.radius(), shape.length())
    if isinstance(shape, Sphere):
        return sphere_mesh(shape.radius())
    if isinstance(shape, Ellipsoid):
        v, f = sphere_mesh(1.0)
        return v * np.array([shape.a(), shape.b(), shape.c()]), f
    if isinstance(shape, Capsule):
        return cylinder_mesh(shape.radius(), shape.length() + 2 * shape.radius())
    return None
