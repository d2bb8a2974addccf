"""Tests for lunar_drake.terrain.{crs, geotiff, heightfield}."""

from __future__ import annotations

import math
import os
import pickle
import warnings

import dask.array as da
import numpy as np
import pytest
import rasterio
import rasterio.io
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from lunar_drake.errors import (
    CRSError,
    NoDataError,
    OutOfBoundsError,
    OutOfRangeError,
    RasterError,
    RasterNotFoundError,
)
from lunar_drake.terrain import heightfield as hf_mod
from lunar_drake.terrain.crs import (
    MOON_RADIUS_M,
    lonlat_to_xy,
    moon_north_polar_stereographic,
    moon_south_polar_stereographic,
    require_projected_metres,
    xy_to_lonlat,
)
from lunar_drake.terrain.geotiff import (
    GeoTiffWriter,
    raster_info,
    read_window,
    write_geotiff,
)
from lunar_drake.terrain.heightfield import Heightfield, MinMaxPyramid

SPS = moon_south_polar_stereographic()
T = Affine(0.5, 0.0, 1000.0, 0.0, -0.5, -2000.0)


def _files(d) -> list[str]:
    return sorted(os.listdir(d))


def _random_with_nans(shape, seed=0, frac=0.3):
    rng = np.random.default_rng(seed)
    z = rng.normal(size=shape).astype(np.float32)
    z[rng.random(shape) < frac] = np.nan
    z[4:9, 4:9] = np.nan  # an all-NaN region spanning several pyramid cells
    return z


# ---------------------------------------------------------------------------------- crs
def test_polar_crs_definition_and_lonlat_round_trip():
    for crs, lat0 in ((SPS, -90), (moon_north_polar_stereographic(), 90)):
        p = crs.to_dict()
        assert p["proj"] == "stere" and p["lat_0"] == lat0 and p["R"] == MOON_RADIUS_M
        assert crs.is_projected and crs.linear_units_factor[1] == 1.0
    # stereographic (variant A, k=1): rho = 2 R tan(pi/4 - |lat|/2); south: y = rho cos(lon)
    x, y = lonlat_to_xy([0.0, 90.0], [-89.0, -88.0], crs=SPS)
    rho1 = 2 * MOON_RADIUS_M * math.tan(math.radians(0.5))
    rho2 = 2 * MOON_RADIUS_M * math.tan(math.radians(1.0))
    np.testing.assert_allclose(x, [0.0, rho2], atol=1e-6)
    np.testing.assert_allclose(y, [rho1, 0.0], atol=1e-6)
    xn, yn = lonlat_to_xy(0.0, 89.0, crs=moon_north_polar_stereographic())
    assert abs(float(xn)) < 1e-6 and float(yn) == pytest.approx(-rho1, rel=1e-12)
    lon, lat = xy_to_lonlat([1234.5, -50000.0], [-777.0, 20000.0], crs=SPS)
    xb, yb = lonlat_to_xy(lon, lat, crs=SPS)
    np.testing.assert_allclose([xb, yb], [[1234.5, -50000.0], [-777.0, 20000.0]], atol=1e-6)


def test_require_projected_metres_rejects_bad_crs():
    assert require_projected_metres(SPS, source="x").is_projected
    with pytest.raises(CRSError, match=r"/data/a\.tif.*no coordinate reference system"):
        require_projected_metres(None, source="/data/a.tif")
    with pytest.raises(CRSError, match=r"/data/b\.tif.*geographic.*EPSG:4326"):
        require_projected_metres("EPSG:4326", source="/data/b.tif")
    km = "+proj=stere +lat_0=-90 +lat_ts=-90 +lon_0=0 +R=1737400 +units=km"
    with pytest.raises(CRSError, match=r"/data/c\.tif.*kilometre"):
        require_projected_metres(km, source="/data/c.tif")


# ------------------------------------------------------------------------------ geotiff
def test_write_geotiff_round_trip_2d_and_3d(tmp_path):
    rng = np.random.default_rng(1)
    z = rng.normal(size=(300, 270)).astype(np.float32)
    z[3, 5] = np.nan
    p = tmp_path / "z.tif"
    write_geotiff(p, z, transform=T, crs=SPS, nodata=float("nan"), compress="deflate")
    info = raster_info(p)
    assert (info.height, info.width, info.count, info.dtype) == (300, 270, 1, "float32")
    assert info.transform == T and math.isnan(info.nodata)
    assert info.crs.to_dict()["lat_0"] == -90 and info.block_shape == (256, 256)
    w = read_window(p, row0=0, col0=2, nrows=10, ncols=20)
    np.testing.assert_array_equal(w, z[0:10, 2:22])  # NaN-equal
    cube = rng.integers(0, 1000, size=(3, 40, 50)).astype(np.int16)
    write_geotiff(tmp_path / "c.tif", cube, transform=T, crs=SPS)
    for b in (1, 2, 3):
        got = read_window(tmp_path / "c.tif", row0=5, col0=7, nrows=30, ncols=40, band=b)
        assert got.dtype == np.int16
        np.testing.assert_array_equal(got, cube[b - 1, 5:35, 7:47])
    assert _files(tmp_path) == ["c.tif", "z.tif"]  # no temp files left behind


def test_geotiff_writer_windows_and_dask_store(tmp_path):
    rng = np.random.default_rng(2)
    z = rng.normal(size=(3, 200, 130)).astype(np.float32)
    p = tmp_path / "w.tif"
    with GeoTiffWriter(
        p, height=200, width=130, count=3, dtype="float32", transform=T, crs=SPS, blocksize=64
    ) as w:
        for r0 in range(0, 200, 64):
            for c0 in range(0, 130, 48):
                w.write(z[:, r0 : r0 + 64, c0 : c0 + 48], row0=r0, col0=c0)
        assert not p.exists()  # renamed only on a clean exit
    with rasterio.open(p) as ds:
        np.testing.assert_array_equal(ds.read(), z)
        assert ds.block_shapes[0] == (64, 64)
    p2 = tmp_path / "d.tif"
    with GeoTiffWriter(p2, height=200, width=130, count=3, transform=T, crs=SPS) as w:
        da.store(da.from_array(z, chunks=(1, 37, 41)), w, lock=False, scheduler="threads")
    with rasterio.open(p2) as ds:
        np.testing.assert_array_equal(ds.read(), z)
    p3 = tmp_path / "e.tif"
    with GeoTiffWriter(p3, height=200, width=130, transform=T, crs=SPS) as w:
        da.store(da.from_array(z[1], chunks=(50, 33)), w, lock=False, scheduler="threads")
    np.testing.assert_array_equal(read_window(p3, row0=0, col0=0, nrows=200, ncols=130), z[1])
    with pytest.raises(OutOfBoundsError, match="row0=190"):
        with GeoTiffWriter(tmp_path / "f.tif", height=200, width=130, transform=T, crs=SPS) as w:
            w.write(np.zeros((20, 20), np.float32), row0=190, col0=0)
    assert _files(tmp_path) == ["d.tif", "e.tif", "w.tif"]


def test_atomic_writes_leave_nothing_on_failure(tmp_path, monkeypatch):
    z = np.ones((100, 100), np.float32)
    p = tmp_path / "a.tif"
    # GeoTiffWriter: an exception after some windows were written
    with pytest.raises(RuntimeError, match="boom"):
        with GeoTiffWriter(p, height=100, width=100, transform=T, crs=SPS) as w:
            w.write(z[:50], row0=0, col0=0)
            assert len(_files(tmp_path)) == 1  # the temporary file exists meanwhile
            raise RuntimeError("boom")
    assert _files(tmp_path) == []
    # write_geotiff: the GDAL write itself fails; an existing file stays intact
    write_geotiff(p, z, transform=T, crs=SPS)
    before = p.read_bytes()

    def failing_write(self, *args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(rasterio.io.DatasetWriter, "write", failing_write)
    with pytest.raises(OSError, match="simulated"):
        write_geotiff(p, 2 * z, transform=T, crs=SPS)
    assert _files(tmp_path) == ["a.tif"] and p.read_bytes() == before
    with pytest.raises(OSError, match="simulated"):
        write_geotiff(tmp_path / "new.tif", z, transform=T, crs=SPS)
    assert _files(tmp_path) == ["a.tif"]


# ------------------------------------------------------------------------- bad inputs
def test_bad_files_raise_specific_errors(tmp_path):
    missing = tmp_path / "nope.tif"
    with pytest.raises(RasterNotFoundError, match=r"nope\.tif"):
        Heightfield.open(missing)
    with pytest.raises(RasterNotFoundError, match=r"nope\.tif"):
        read_window(missing, row0=0, col0=0, nrows=1, ncols=1)

    text = tmp_path / "text.tif"
    text.write_text("this is not a raster\n")
    with pytest.raises(RasterError, match=r"text\.tif") as ei:
        Heightfield.open(text)
    assert not isinstance(ei.value, (RasterNotFoundError, CRSError))
    assert "not recognized" in str(ei.value) or "not a" in str(ei.value).lower()

    bare = tmp_path / "bare.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(
            bare, "w", driver="GTiff", height=8, width=8, count=1, dtype="float32"
        ) as ds:
            ds.write(np.ones((1, 8, 8), np.float32))
    with pytest.raises(RasterError, match=r"bare\.tif.*no geotransform") as ei:
        Heightfield.open(bare)
    assert not isinstance(ei.value, CRSError)

    geo = tmp_path / "geo.tif"
    with rasterio.open(
        geo,
        "w",
        driver="GTiff",
        height=8,
        width=8,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=Affine(0.01, 0.0, 10.0, 0.0, -0.01, 20.0),
    ) as ds:
        ds.write(np.ones((1, 8, 8), np.float32))
    with pytest.raises(CRSError, match=r"geo\.tif.*EPSG:4326"):
        Heightfield.open(geo)
    with pytest.raises(CRSError, match=r"geo\.tif"):
        read_window(geo, row0=0, col0=0, nrows=1, ncols=1)

    nan = tmp_path / "allnan.tif"
    write_geotiff(nan, np.full((40, 30), np.nan, np.float32), transform=T, crs=SPS)
    with pytest.raises(NoDataError, match=r"allnan\.tif"):
        Heightfield.open(nan, block_size=8)
    sentinel = tmp_path / "sentinel.tif"  # all nodata through a nodata value, not NaN
    write_geotiff(sentinel, np.full((20, 20), -9999, np.int16), transform=T, crs=SPS, nodata=-9999)
    with pytest.raises(NoDataError, match=r"sentinel\.tif"):
        Heightfield.open(sentinel)
    one = np.full((20, 20), -9999, np.int16)
    one[19, 0] = 7  # a single valid pixel far from the centre block is found by the scan
    write_geotiff(tmp_path / "one.tif", one, transform=T, crs=SPS, nodata=-9999)
    with Heightfield.open(tmp_path / "one.tif", block_size=8) as hf:
        w = hf.read_window(0, 0, 20, 20)
        assert w.dtype == np.float32 and w[19, 0] == 7.0 and np.isnan(w).sum() == 399
    with pytest.raises(NoDataError, match="all NaN"):
        Heightfield.from_array(np.full((5, 5), np.nan), resolution_m=1.0)
    with pytest.raises(CRSError, match="geographic"):
        Heightfield.from_array(np.zeros((5, 5)), resolution_m=1.0, crs="EPSG:4326")


def test_bad_queries_name_the_point(tmp_path):
    z = np.arange(20 * 30, dtype=np.float64).reshape(20, 30)
    z[10:12, 14:16] = np.nan
    hf = Heightfield.from_array(z, resolution_m=0.5)  # x in [-7.5, 7.5], y in [-5, 5]
    with pytest.raises(OutOfBoundsError, match=r"x=7\.625.*x in \[-7\.5, 7\.5\].*y in \[-5, 5\]"):
        hf.height(np.array([0.0, 7.625]), np.array([0.0, 1.0]))
    with pytest.raises(OutOfBoundsError, match=r"y=-5\.25"):
        hf.slope(0.0, -5.25)
    with pytest.raises(OutOfBoundsError, match="nan"):
        hf.height(np.nan, 0.0)
    with pytest.raises(OutOfBoundsError, match="row0=15"):
        hf.read_window(15, 0, 10, 5)
    # the NaN hole covers pixel centres x in [-0.25, 0.25], y in [-0.75, -0.25]
    with pytest.raises(NoDataError, match=r"x=0\.1.*y=-0\.5"):
        hf.height([3.0, 0.1], [3.0, -0.5])
    with pytest.raises(NoDataError, match=r"x=-1,"):
        hf.normal(-1.0, -0.5)  # 2x2 pixels are valid, but a neighbour used by the gradient is not
    assert np.isfinite(hf.height(-1.0, -0.5))
    # the same from a file: the message names the path
    p = tmp_path / "holes.tif"
    hf.to_geotiff(p)
    with Heightfield.open(p, block_size=8) as hff:
        with pytest.raises(NoDataError, match=r"holes\.tif"):
            hff.height(0.1, -0.5)
        with pytest.raises(OutOfBoundsError, match=r"x=100"):
            hff.height(100.0, 0.0)


# ----------------------------------------------------------------------------- queries
def _plane(shape, res, a=3.25, b=0.31, c=-0.173):
    nrows, ncols = shape
    x = (np.arange(ncols) + 0.5 - ncols / 2) * res
    y = (nrows / 2 - np.arange(nrows) - 0.5) * res
    return a + b * x[None, :] + c * y[:, None], (a, b, c)


def test_plane_is_exact_in_memory_and_from_file(tmp_path):
    shape, res = (37, 52), 0.2
    z, (a, b, c) = _plane(shape, res)
    mem = Heightfield.from_array(z, resolution_m=res, origin_xy=(5000.0, -12000.0))
    mem.to_geotiff(tmp_path / "plane.tif")
    rng = np.random.default_rng(3)
    # inside the hull of pixel centres (the outer half-pixel band is clamped by design)
    hx, hy = 0.5 * res * (shape[1] - 1), 0.5 * res * (shape[0] - 1)
    px = rng.uniform(-hx, hx, size=(6, 7))
    py = rng.uniform(-hy, hy, size=(6, 7))
    with Heightfield.open(tmp_path / "plane.tif", block_size=16) as fil:
        assert fil.dtype == np.float64 and fil.origin_xy == (5000.0, -12000.0)
        for hf in (mem, fil):
            zq = hf.height(px, py)
            assert zq.shape == (6, 7)
            np.testing.assert_allclose(zq, a + b * px + c * py, rtol=1e-9, atol=1e-12)
            gx, gy = hf.gradient(px, py)
            np.testing.assert_allclose(gx, b, rtol=1e-9)
            np.testing.assert_allclose(gy, c, rtol=1e-9)
            n = hf.normal(px, py)
            assert n.shape == (6, 7, 3)
            expect = np.array([-b, -c, 1.0]) / math.sqrt(1 + b * b + c * c)
            np.testing.assert_allclose(n, np.broadcast_to(expect, n.shape), rtol=1e-9)
            np.testing.assert_allclose(hf.slope(px, py), math.atan(math.hypot(b, c)), rtol=1e-9)
            assert isinstance(hf.height(0.1, 0.2), float | np.floating)


def test_heights_within_matches_height_and_flags_edges_and_nodata(tmp_path):
    """The contact's compiled query gives height()'s exact bits inside, and -inf with ok
    False off the raster (less a margin), on non-finite points and next to nodata; the
    file-backed path agrees with the in-memory one."""
    rng = np.random.default_rng(11)
    z = rng.normal(size=(40, 50)).astype(np.float32)
    z[20, 30] = np.nan
    mem = Heightfield.from_array(z, resolution_m=0.1)
    mem.to_geotiff(tmp_path / "z.tif")
    x = rng.uniform(-2.6, 2.6, size=(9, 40))
    y = rng.uniform(-2.1, 2.1, size=(9, 40))
    x[0, :3] = [np.nan, np.inf, 0.0]
    y[0, :3] = [0.0, 0.0, -np.inf]
    x[1, 0], y[1, 0] = (30 + 0.5 - 25) * 0.1 - 0.05, (20 - 20 + 0.5) * 0.1 - 0.05
    margin = 0.1
    with Heightfield.open(tmp_path / "z.tif", block_size=16) as fil:
        for hf in (mem, fil):
            got, ok = hf.heights_within(x, y, margin_m=margin)
            b = mem.bounds
            inside = (
                (x >= b.left + margin)
                & (x <= b.right - margin)
                & (y >= b.bottom + margin)
                & (y <= b.top - margin)
            )
            assert not ok[0, :3].any() and not ok[1, 0] and inside[1, 0]
            for i, j in zip(*np.nonzero(inside), strict=True):
                try:
                    want = mem.height(x[i, j], y[i, j])
                except NoDataError:
                    assert not ok[i, j] and got[i, j] == -np.inf
                    continue
                assert ok[i, j] and got[i, j] == want  # the same bits
            assert not ok[~inside].any() and np.all(got[~inside] == -np.inf)
            assert ok.sum() > 0.5 * ok.size
        # a margin must be a finite distance >= 0, in memory and from a file alike
        for hf in (mem, fil):
            for bad in (np.nan, np.inf, -0.1):
                with pytest.raises(OutOfRangeError, match="margin_m"):
                    hf.heights_within(x, y, margin_m=bad)
    # the kernel's arguments are remembered per margin (the contact asks every step)
    assert mem.within_kernel_args(margin_m=0.1) is mem.within_kernel_args(margin_m=0.1)
    assert mem.within_kernel_args(margin_m=0.1)[2] == mem.bounds.left + 0.1


def test_bilinear_central_differences_and_edge_clamp():
    rng = np.random.default_rng(4)
    z = rng.normal(size=(9, 12))
    res = 0.5
    hf = Heightfield.from_array(z, resolution_m=res)
    xc, yc = hf.grid.pixel_centers(0, 0, 9, 12)
    X, Y = np.meshgrid(xc, yc)
    np.testing.assert_allclose(hf.height(X, Y), z, rtol=0, atol=1e-12)
    # at pixel centres the gradient is numpy's central (one-sided at edges) difference
    dz_drow, dz_dcol = np.gradient(z, res)
    gx, gy = hf.gradient(X, Y)
    np.testing.assert_allclose(gx, dz_dcol, atol=1e-12)
    np.testing.assert_allclose(gy, -dz_drow, atol=1e-12)  # rows grow southwards
    # midway between two centres: the mean of the pair
    assert hf.height(0.5 * (xc[3] + xc[4]), yc[2]) == pytest.approx(0.5 * (z[2, 3] + z[2, 4]))
    # outer half-pixel band: clamped edge values
    bd = hf.bounds
    assert (bd.left, bd.bottom, bd.right, bd.top) == (-3.0, -2.25, 3.0, 2.25)
    assert hf.height(bd.left, bd.top) == pytest.approx(z[0, 0])
    assert hf.height(bd.right, yc[5]) == pytest.approx(z[5, -1])
    # geometry: CRS <-> site coordinates
    hf2 = Heightfield.from_array(z, resolution_m=res, origin_xy=(100.0, 200.0))
    assert hf2.transform == Affine(0.5, 0.0, 97.0, 0.0, -0.5, 202.25)
    assert hf2.site_to_crs(1.0, -1.0) == (101.0, 199.0)
    assert hf2.grid.nrows == 9 and hf2.shape == (9, 12)


def test_lazy_open_reads_only_needed_blocks(tmp_path):
    n, b = 4096, 256
    p = tmp_path / "big.tif"

    def field(r0, c0, nr, nc):
        r, c = np.mgrid[r0 : r0 + nr, c0 : c0 + nc]
        return (0.01 * r - 0.002 * c + np.sin(0.01 * c)).astype(np.float32)

    t = Affine(0.5, 0.0, -1024.0, 0.0, -0.5, 1024.0)
    with GeoTiffWriter(
        p, height=n, width=n, transform=t, crs=SPS, blocksize=256, compress="deflate"
    ) as w:
        for r0 in range(0, n, 1024):
            for c0 in range(0, n, 1024):
                w.write(field(r0, c0, 1024, 1024), row0=r0, col0=c0)
    hf = Heightfield.open(p, block_size=b, cache_blocks=6)
    assert hf.shape == (n, n) and hf.origin_xy == (0.0, 0.0)
    opened = hf.cache_info().pixels_read
    assert opened <= b * b  # the nodata check read only the centre block
    rng = np.random.default_rng(5)
    rows = rng.integers(0, n, size=(6, 8))
    cols = rng.integers(0, n, size=(6, 8))
    for i in range(6):  # 6 batches of 8 scattered pixel centres
        x = (cols[i] + 0.5 - n / 2) * 0.5
        y = (n / 2 - rows[i] - 0.5) * 0.5
        expect = np.array([field(r, c, 1, 1)[0, 0] for r, c in zip(rows[i], cols[i], strict=True)])
        np.testing.assert_allclose(hf.height(x, y), expect, rtol=1e-6)
        info = hf.cache_info()
        assert info.blocks <= 6
    assert info.misses > 6  # blocks were evicted and the cache stayed bounded
    assert info.pixels_read == opened + info.misses * b * b  # every read was a whole block
    assert info.pixels_read < n * n / 2
    np.testing.assert_array_equal(hf.read_window(4000, 17, 50, 60), field(4000, 17, 50, 60))
    # a pickled copy (e.g. for a dask worker) reopens the file lazily
    hf2 = pickle.loads(pickle.dumps(hf))
    assert hf2.cache_info().blocks == 0
    assert hf2.height(0.0, 0.0) == hf.height(0.0, 0.0)
    hf.close()


def test_concurrent_queries_on_a_small_cache(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    z = np.random.default_rng(10).normal(size=(96, 80)).astype(np.float32)
    mem = Heightfield.from_array(z, resolution_m=1.0)
    mem.to_geotiff(tmp_path / "c.tif")
    rng = np.random.default_rng(11)
    pts = [(rng.uniform(-39, 39, 50), rng.uniform(-47, 47, 50)) for _ in range(32)]
    with Heightfield.open(tmp_path / "c.tif", block_size=8, cache_blocks=3) as fil:
        with ThreadPoolExecutor(4) as ex:
            got = list(ex.map(lambda p: fil.normal(*p), pts))
        assert fil.cache_info().blocks <= 3
    for p, g in zip(pts, got, strict=True):
        np.testing.assert_array_equal(g, mem.normal(*p))


# ------------------------------------------------------------------- pyramid, decimation
def _brute_pyramid(z):
    levels = []
    k = 0
    while True:
        s = 1 << k
        h, w = -(-z.shape[0] // s), -(-z.shape[1] // s)
        mn = np.full((h, w), np.nan, np.float32)
        mx = np.full((h, w), np.nan, np.float32)
        for i in range(h):
            for j in range(w):
                blk = z[i * s : (i + 1) * s, j * s : (j + 1) * s]
                if not np.isnan(blk).all():
                    mn[i, j], mx[i, j] = np.nanmin(blk), np.nanmax(blk)
        levels.append((mn, mx))
        if h == 1 and w == 1:
            return levels
        k += 1


def test_pyramid_matches_brute_force_in_memory_and_file(tmp_path, monkeypatch):
    z = _random_with_nans((45, 70), seed=6)
    mem = Heightfield.from_array(z, resolution_m=1.0)
    ref = _brute_pyramid(z)
    pyr = mem.pyramid()
    assert isinstance(pyr, MinMaxPyramid) and pyr.num_levels == len(ref) == 8
    for (mn, mx), (rmn, rmx) in zip(pyr.levels, ref, strict=True):
        assert mn.dtype == np.float32
        np.testing.assert_array_equal(mn, rmn)
        np.testing.assert_array_equal(mx, rmx)
    assert np.isnan(pyr.levels[1][0][2:4, 2:4]).all()  # the all-NaN patch stays NaN
    # file-backed, forced to build window by window
    p = tmp_path / "r.tif"
    mem.to_geotiff(p)
    monkeypatch.setattr(hf_mod, "_IO_TILE", 16)
    with Heightfield.open(p, block_size=8) as fil:
        for start in (0, 2):
            fp = fil.pyramid(start_level=start)
            assert all(lv is None for lv in fp.levels[:start])
            for k in range(start, len(ref)):
                np.testing.assert_array_equal(fp.levels[k][0], ref[k][0])
                np.testing.assert_array_equal(fp.levels[k][1], ref[k][1])
    # range_in_window: exact at level 0, conservative at coarser levels
    rng = np.random.default_rng(7)
    for _ in range(40):
        r0, c0 = int(rng.integers(0, 45)), int(rng.integers(0, 70))
        nr, nc = int(rng.integers(1, 46 - r0)), int(rng.integers(1, 71 - c0))
        blk = z[r0 : r0 + nr, c0 : c0 + nc]
        lo, hi = pyr.range_in_window(0, r0, c0, nr, nc)
        if np.isnan(blk).all():
            assert math.isnan(lo) and math.isnan(hi)
            continue
        assert (lo, hi) == (np.nanmin(blk), np.nanmax(blk))
        lo3, hi3 = pyr.range_in_window(3, r0, c0, nr, nc)
        assert lo3 <= lo and hi3 >= hi
    assert pyr.range_in_window(3, 8, 16, 8, 8) == pyr.range_in_window(0, 8, 16, 8, 8)
    with pytest.raises(OutOfBoundsError, match="col0=65"):
        pyr.range_in_window(0, 0, 65, 1, 10)


def test_decimated_is_nan_aware_block_mean(tmp_path, monkeypatch):
    z = _random_with_nans((45, 70), seed=8)
    mem = Heightfield.from_array(z, resolution_m=0.25)
    d, res = mem.decimated(max_size=20)
    assert d.shape == (12, 18) and res == 1.0 and d.dtype == np.float32  # f = 4
    for i in range(12):
        for j in range(18):
            blk = z[4 * i : 4 * i + 4, 4 * j : 4 * j + 4]
            if np.isnan(blk).all():
                assert np.isnan(d[i, j])
            else:
                assert d[i, j] == pytest.approx(np.nanmean(blk.astype(np.float64)), rel=1e-6)
    p = tmp_path / "d.tif"
    mem.to_geotiff(p)
    monkeypatch.setattr(hf_mod, "_IO_TILE", 16)
    with Heightfield.open(p, block_size=8) as fil:
        df, rf = fil.decimated(max_size=20)
        np.testing.assert_array_equal(df, d)
        assert rf == res
        full, r1 = fil.decimated(max_size=70)
        np.testing.assert_array_equal(full, z)
        assert r1 == 0.25


def test_round_trip_through_geotiff(tmp_path):
    z = _random_with_nans((33, 21), seed=9, frac=0.05)
    hf = Heightfield.from_array(z, resolution_m=0.04, origin_xy=(-3000.0, 4000.0))
    p = tmp_path / "site.tif"
    hf.to_geotiff(p)
    assert _files(tmp_path) == ["site.tif"]
    with Heightfield.open(p) as back:
        assert back.shape == hf.shape and back.resolution_m == 0.04
        assert back.transform == hf.transform and back.origin_xy == hf.origin_xy
        assert back.bounds == hf.bounds and back.dtype == np.float32
        assert back.crs.to_dict() == SPS.to_dict()
        np.testing.assert_array_equal(back.read_window(0, 0, 33, 21), z)
        # a file-backed heightfield copies itself out window by window
        back.to_geotiff(tmp_path / "copy.tif")
    with Heightfield.open(tmp_path / "copy.tif") as cp:
        np.testing.assert_array_equal(cp.read_window(0, 0, 33, 21), z)
    assert _files(tmp_path) == ["copy.tif", "site.tif"]
