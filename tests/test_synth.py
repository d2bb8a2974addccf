"""The tiled synthesis pipeline end to end: outputs, determinism, tile invariance, errors."""

import hashlib
import json

import numpy as np
import pytest
import rasterio

from lunar_drake.errors import ConfigError, LunarDrakeError, NoDataError, RasterError
from lunar_drake.terrain.synth import OUTPUT_FILES, SynthConfig, synthesize_site


def _digests(d):
    return {f: hashlib.sha256((d / f).read_bytes()).hexdigest() for f in OUTPUT_FILES}


def _config(**kw):
    base = dict(
        size_px=512,
        resolution_m=0.05,
        factor=16,
        seed=11,
        min_crater_m=0.3,
        min_rock_m=0.08,
        rock_abundance=0.02,
        tile_px=512,
        workers=1,
    )
    base.update(kw)
    return SynthConfig(**base)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    products = synthesize_site(config=_config(), out_dir=out, progress=False)
    return out, products


def test_outputs_exist_and_are_georeferenced(site):
    out, products = site
    for f in OUTPUT_FILES:
        assert (out / f).stat().st_size > 0, f
    with rasterio.open(out / "dem.tif") as ds:
        assert ds.crs is not None and ds.crs.is_projected
        assert ds.res == (0.05, 0.05)
        assert ds.shape == (512, 512)
        z = ds.read(1)
    assert np.isfinite(z).all()
    assert z.std() > 0.01  # relief exists
    with rasterio.open(out / "normals.tif") as ds:
        n = ds.read().astype(np.float64) / 32767.0
    assert n.shape == (3, 512, 512)
    assert np.allclose(np.linalg.norm(n, axis=0), 1.0, atol=1e-3)
    assert (n[2] > 0).all()
    with rasterio.open(out / "rock_mask.tif") as ds:
        mask = ds.read(1)
    assert set(np.unique(mask)) <= {0, 1}
    assert mask.sum() > 0
    with rasterio.open(out / "albedo.tif") as ds:
        a = ds.read(1)
    assert 0.0 <= a.min() and a.max() <= 1.0
    header = (out / "craters.csv").read_text().splitlines()[0]
    assert header == "x_m,y_m,diameter_m,depth_m,age_yr,freshness"
    header = (out / "rocks.csv").read_text().splitlines()[0]
    assert header == "x_m,y_m,diameter_m,height_m,population"
    info = json.loads((out / "site.json").read_text())
    assert info["stats"]["craters"] == len(products.craters) > 10
    assert info["stats"]["rocks"] == len(products.rocks) > 10
    # no temporary files left behind
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_rocks_raise_the_dem_where_the_mask_says(site):
    out, products = site
    with rasterio.open(out / "rock_mask.tif") as ds:
        mask = ds.read(1).astype(bool)
    big = products.rocks.diameter_m > 0.3
    assert big.any()
    r, c = products.grid.to_pixel(products.rocks.x_m[big], products.rocks.y_m[big])
    r = np.rint(r).astype(int)
    c = np.rint(c).astype(int)
    inside = (r >= 0) & (r < 512) & (c >= 0) & (c < 512)
    assert mask[r[inside], c[inside]].mean() > 0.9


def test_same_seed_same_bytes_across_tiles_and_workers(tmp_path):
    """The issue's check: tiles of 256 and 1024 px, 1 and 2 workers, one odd tiling."""
    cfg = dict(size_px=1024, resolution_m=0.04, factor=32, min_crater_m=0.5, min_rock_m=0.1)
    ref = None
    for tile, workers in ((1024, 1), (256, 2), (256, 1), (384, 2)):
        d = tmp_path / f"t{tile}w{workers}"
        synthesize_site(
            config=_config(tile_px=tile, workers=workers, **cfg), out_dir=d, progress=False
        )
        got = _digests(d)
        if ref is None:
            ref = got
        assert got == ref, (tile, workers)


def test_same_seed_same_bytes_twice(site, tmp_path):
    out, _ = site
    synthesize_site(config=_config(), out_dir=tmp_path, progress=False)
    assert _digests(tmp_path) == _digests(out)


def test_different_seed_differs(site, tmp_path):
    out, _ = site
    synthesize_site(config=_config(seed=12), out_dir=tmp_path, progress=False, overview=False)
    a = rasterio.open(out / "dem.tif").read(1)
    b = rasterio.open(tmp_path / "dem.tif").read(1)
    assert not np.array_equal(a, b)


def _write_dem(
    path,
    z,
    *,
    crs="+proj=stere +lat_0=-90 +lat_ts=-90 +lon_0=0 +R=1737400 +units=m",
    res=1.0,
    transform=True,
):
    from rasterio.transform import Affine

    kw = dict(driver="GTiff", height=z.shape[0], width=z.shape[1], count=1, dtype="float32")
    if transform:
        kw["transform"] = Affine(res, 0, 1000.0, 0, -res, 2000.0)
        kw["crs"] = crs
    with rasterio.open(path, "w", **kw) as ds:
        ds.write(z.astype(np.float32), 1)


def test_upscale_real_dem_keeps_its_samples(tmp_path):
    yy, xx = np.mgrid[0:32, 0:32]
    coarse = 3.0 * np.sin(xx / 5.0) + 0.1 * yy
    src = tmp_path / "coarse.tif"
    _write_dem(src, coarse, res=2.0)
    cfg = SynthConfig(
        from_dem=str(src),
        factor=8,
        seed=3,
        min_crater_m=4.0,
        rock_abundance=0.0,
        ejecta_rock_abundance=0.0,
        tile_px=128,
    )
    products = synthesize_site(config=cfg, out_dir=tmp_path / "up", progress=False)
    assert products.stats["rocks"] == 0
    with rasterio.open(tmp_path / "up" / "dem.tif") as ds:
        assert ds.shape == (256, 256)
        assert ds.res == (0.25, 0.25)
        # fine pixel (0, 0) is centred on coarse pixel (0, 0) at (1001, 1999)
        assert ds.xy(0, 0) == pytest.approx((1001.0, 1999.0))
        fine = ds.read(1)
    # Coarse samples are kept exactly wherever no crater was stamped.
    from lunar_drake.terrain.craters import crater_extent_m

    g = products.grid
    x, y = g.pixel_centers(0, 0, 256, 256)
    X, Y = np.meshgrid(x[::8], y[::8])
    cr = products.craters
    reach = crater_extent_m(cr.diameter_m, params=cfg.crater_shape)
    touched = np.zeros(X.shape, bool)
    for cx, cy, rr in zip(cr.x_m, cr.y_m, reach, strict=True):
        touched |= (X - cx) ** 2 + (Y - cy) ** 2 <= (rr + 0.25) ** 2
    assert (~touched).mean() > 0.2
    np.testing.assert_allclose(fine[::8, ::8][~touched], coarse[~touched], atol=1e-4)


def test_bad_inputs(tmp_path):
    z = np.ones((16, 16))
    z[3, 4] = np.nan
    holes = tmp_path / "holes.tif"
    _write_dem(holes, z)
    with pytest.raises(NoDataError, match="nodata"):
        synthesize_site(config=SynthConfig(from_dem=str(holes), factor=4), out_dir=tmp_path / "o")
    plain = tmp_path / "plain.tif"
    _write_dem(plain, np.ones((16, 16)), transform=False)
    with pytest.raises(RasterError):
        synthesize_site(config=SynthConfig(from_dem=str(plain), factor=4), out_dir=tmp_path / "o")
    with pytest.raises(LunarDrakeError):
        synthesize_site(
            config=SynthConfig(from_dem=str(tmp_path / "nope.tif"), factor=4),
            out_dir=tmp_path / "o",
        )
    with pytest.raises(ConfigError, match="factor = 3"):
        SynthConfig(factor=3)
    with pytest.raises(ConfigError, match="size_px = 100"):
        SynthConfig(size_px=100, factor=32)
    with pytest.raises(ConfigError, match=r"rock_abundance = 1\.2"):
        SynthConfig(rock_abundance=1.2)


def test_site_is_georeferenced_at_its_latitude_longitude(tmp_path):
    from lunar_drake.terrain.crs import xy_to_lonlat

    cfg = _config(size_px=64, factor=8, center_lat_deg=-85.4, center_lon_deg=31.6, tile_px=64)
    synthesize_site(config=cfg, out_dir=tmp_path, progress=False, overview=False)
    with rasterio.open(tmp_path / "dem.tif") as ds:
        cx = ds.bounds.left + 0.5 * (ds.bounds.right - ds.bounds.left)
        cy = ds.bounds.bottom + 0.5 * (ds.bounds.top - ds.bounds.bottom)
        lon, lat = xy_to_lonlat(cx, cy, crs=ds.crs)
    assert float(lat) == pytest.approx(-85.4, abs=1e-9)
    assert float(lon) == pytest.approx(31.6, abs=1e-9)
    with pytest.raises(ConfigError, match=r"center_lat_deg = 0\.0"):
        _config(center_lat_deg=0.0)
