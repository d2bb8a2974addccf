"""Terrain: georeferenced rasters and the synthetic-site pipeline (numpy only, no Drake).

Conventions shared by every module here
---------------------------------------
* A grid is a 2-D array ``z[row, col]``; row 0 is the northern edge, col 0 the western.
  GeoTIFFs are pixel-is-area with ``Affine(res, 0, x_min, 0, -res, y_max)``.
* Site coordinates ``(x, y)`` are metres, x east (grid east), y north (grid north),
  z up, with the origin at the centre of the site raster. Pixel ``(r, c)`` of an
  ``nrows x ncols`` grid at resolution ``res`` has its centre at
  ``x = (c + 0.5 - ncols / 2) * res``, ``y = (nrows / 2 - r - 0.5) * res``
  (see :mod:`lunar_drake.terrain.grid`).
* Tiled work names a window by ``(row0, col0, nrows, ncols)`` in global pixel indices.
  Per-pixel randomness comes from :func:`lunar_drake.rng.hash_normal` keyed by global
  pixel indices, so a tile's bytes never depend on the tiling.
"""
