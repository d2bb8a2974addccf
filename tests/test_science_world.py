"""The science world model: layer relations, tile invariance, bad input, the CLI."""

import json
import math
import os

import numpy as np
import pytest

from lunar_drake.errors import OutOfRangeError
from lunar_drake.science import thermal, volatiles
from lunar_drake.science.config import FrostConfig, IceConfig, OHConfig, ThermalConfig, WorldConfig
from lunar_drake.science.sun_envelope import envelope_from_samples
from lunar_drake.science.world import Craters, WorldModelError, check_layer, compute_world

RES = 0.25
N = 128


def _bowl_site():
    """A 32 m plain (0.25 m px) with a 16 m wide, 1.6 m deep bowl and a Sun circling at
    3 +- 1.5 deg."""
    y, x = (np.mgrid[0:N, 0:N] + 0.5 - N / 2) * RES
    r = np.hypot(x, y)
    z = np.where(r < 8.0, -1.6 * (1 - (r / 8.0) ** 2) ** 2, 0.0)
    k = np.arange(1461)
    env = envelope_from_samples(
        (k * 12 * 360 / 1461) % 360,
        3.0 + 1.5 * np.sin(2 * np.pi * k / 1461),
        np.full(k.size, 1.495978707e8),
        bins=16,
    )
    craters = Craters(
        x_m=np.array([0.0, 10.0]),
        y_m=np.array([0.0, -10.0]),
        diameter_m=np.array([16.0, 6.0]),
        age_yr=np.array([1e8, 1e7]),
    )
    return z, r, env, craters


@pytest.fixture(scope="module")
def bowl_world():
    z, r, env, craters = _bowl_site()
    layers = compute_world(
        z,
        resolution_m=RES,
        craters=craters,
        seed=3,
        envelope=env,
        sun_azimuth_deg=120.0,
        sun_elevation_deg=3.0,
        config=WorldConfig(tile_px=4096),
    )
    return z, r, layers


def test_frost_only_inside_permanent_shadow(bowl_world):
    _z, r, L = bowl_world
    frost, psr = L["frost_area_frac"], L["psr"]
    assert psr[r < 6].mean() > 0.3 and psr[r > 9].max() == 0  # the bowl's floor, not the plain
    assert (frost > 0).any()
    assert np.all(psr[frost > 0] == 1)


def test_a_cell_lit_at_the_epoch_is_never_permanent_shadow():
    """The year's sectors are swept at their centres (11.25 deg here) but the epoch at
    the Sun's own azimuth (0 deg): a pillar's shadow falls on different cells in the
    two. A cell lit at the epoch is lit once in the year, so it is no permanent shadow
    and holds no frost, and its warmest moment is at least as warm as the epoch."""
    z = np.zeros((64, 64))
    z[2:5, 30:33] = 4.0  # a 4 m pillar near the north edge
    k = np.arange(1461)
    env = envelope_from_samples(np.full(k.size, 5.0), 5.0 + 0.2 * np.sin(2 * np.pi * k / 1461),
                                np.full(k.size, 1.495978707e8), bins=16)  # fmt: skip
    L = compute_world(z, resolution_m=RES, craters=Craters(*(np.zeros(0),) * 4), seed=1,
                      envelope=env, sun_azimuth_deg=0.0, sun_elevation_deg=5.0,
                      config=WorldConfig())  # fmt: skip
    sector_shadow = L["psr"][30:60, 20:30] == 1
    lit_now = L["lit_fraction"][30:60, 20:30] > 0.5
    assert lit_now.all()  # west of the epoch's shadow
    assert not sector_shadow.any()
    assert not (L["psr"] == 1)[L["lit_fraction"] > 0].any()
    assert (L["t_max_K"] >= L["temperature_K"]).all()
    assert (L["frost_area_frac"][L["temperature_K"] > 110.0] == 0).all()
    # Where the epoch's shadow lies, the sector's Sun still shines.
    assert (L["psr"][30:60, 30:33] == 0).all()


def test_frost_grows_with_patch_area():
    psr = np.zeros((20, 20), np.uint8)
    psr[1:3, 1:3] = 1  # 4 px = 4 m^2 at 1 m
    psr[10:16, 10:16] = 1  # 36 m^2
    cfg = FrostConfig(max_area_frac=0.2, area_scale_m2=20.0)
    f = volatiles.frost_area_fraction(psr, np.full(psr.shape, 60.0), resolution_m=1.0, config=cfg)
    assert f[1, 1] == pytest.approx(0.2 * (1 - math.exp(-4 / 20)))
    assert f[12, 12] == pytest.approx(0.2 * (1 - math.exp(-36 / 20)))
    assert f[12, 12] > f[1, 1] > 0 and f[5, 5] == 0
    warm = volatiles.frost_area_fraction(
        psr, np.full(psr.shape, 150.0), resolution_m=1.0, config=cfg
    )
    assert not warm.any()  # no frost where even the warmest moment is above 110 K


def test_temperature_is_radiative_equilibrium_facing_the_sun():
    # A plane sloping 30 deg down to the south, the Sun due south at 60 deg: normal
    # incidence, no terrain above the tangent plane, 1 au.
    south = (np.arange(64) + 0.5 - 32) * 0.5  # m south of the centre, by row (row 0 north)
    z = np.repeat((-south * math.tan(math.radians(30)))[:, None], 64, axis=1)
    cfg = ThermalConfig()
    q = thermal.direct_flux_at(
        z, resolution_m=0.5, sun_azimuth_deg=180.0, sun_elevation_deg=60.0, config=cfg
    )
    view = thermal.view_factor(z, resolution_m=0.5, config=cfg)
    t = thermal.temperature(q, z=z, resolution_m=0.5, config=cfg)
    # (1 - 0.12) 1361 W/m^2 + 16 mW/m^2 = 0.95 * 5.670374419e-8 T^4
    expected = ((0.88 * 1361.0 + 0.016) / (0.95 * 5.670374419e-8)) ** 0.25
    assert expected == pytest.approx(386.2, abs=0.1)
    inner = t[8:-8, 8:-8]
    assert np.allclose(inner, expected, atol=0.05)
    assert view[8:-8, 8:-8].max() < 1e-3  # a plane sees no terrain above its horizon


def test_shadow_is_warmed_by_sunlit_terrain(bowl_world):
    z, r, _env, _craters = _bowl_site()
    cfg = ThermalConfig()
    q = np.zeros(z.shape)
    cold = thermal.temperature(q, z=z, resolution_m=RES, config=cfg)
    q_lit = np.where(r > 9, 150.0, 0.0)  # only the plain is lit
    warm = thermal.temperature(q_lit, z=z, resolution_m=RES, config=cfg)
    floor = (0.016 / (0.95 * 5.670374419e-8)) ** 0.25
    assert cold.min() == pytest.approx(floor) and cold.max() < floor + 0.5  # geothermal: ~23 K
    assert warm[N // 2, N // 2 + 20] > floor + 20  # the bowl's wall sees the lit plain


def test_a_pit_floor_gets_its_view_factor_of_the_terrains_light():
    # A conical pit (floor of radius 2 m, rim 10 m away and 4 m up): from the floor's
    # centre the rim is the horizon at every azimuth, h = atan(4 / 10), so the
    # cosine-weighted view factor is sin^2 h = 0.16 / 1.16. Terrain of absorbed flux S
    # around it: eps sigma T^4 = F ((eps + A) S + eps q_geo) + q_geo (docs/science.md).
    res, n = 0.5, 160
    y, x = (np.mgrid[0:n, 0:n] - (n - 1) / 2.0) * res
    r = np.hypot(x, y)
    z = np.clip(0.5 * (r - 2.0), 0.0, 4.0)
    cfg = ThermalConfig()
    sin2_h = thermal.sky_horizons(z, resolution_m=res, config=cfg)
    k = thermal.coarse_factor(res, cfg)
    s0 = 200.0
    src = np.full((1, *sin2_h.shape[1:]), s0)
    t = thermal.temperature_rows(z, np.zeros((1, n, n)), src, sin2_h, resolution_m=res,
                                 rows=range(n), config=cfg)[0]  # fmt: skip
    eps, a, q_geo = cfg.emissivity, cfg.bond_albedo, cfg.geothermal_w_m2
    centre = t[n // 2 - 1 : n // 2 + 1, n // 2 - 1 : n // 2 + 1].mean()
    f = (eps * 5.670374419e-8 * centre**4 - q_geo) / ((eps + a) * s0 + eps * q_geo)
    assert k == 1 and f == pytest.approx(0.16 / 1.16, rel=0.03)


def test_oh_follows_temperature():
    cfg = OHConfig(min_ppm=100.0, max_ppm=700.0, half_K=300.0, width_K=30.0)
    t = np.array([40.0, 150.0, 250.0, 300.0, 350.0, 390.0])
    oh = volatiles.oh_ppm(t, config=cfg)
    assert np.all(np.diff(oh) < 0)
    assert oh[3] == pytest.approx(400.0)
    assert oh[0] == pytest.approx(100.0 + 600.0 / (1 + math.exp(-260.0 / 30.0)))
    assert oh[-1] == pytest.approx(100.0 + 600.0 / (1 + math.exp(3.0)))


def test_dry_layer_from_the_temperature_wave():
    cfg = IceConfig(stable_K=110.0, skin_depth_m=0.05, max_depth_m=1.5)
    t_max = np.array([90.0, 150.0, 250.0, 200.0])
    t_mean = np.array([60.0, 80.0, 100.0, 130.0])
    d = volatiles.dry_layer_m(t_max, t_mean, config=cfg)
    assert d[0] == 0.0  # cold enough at the surface
    assert d[1] == pytest.approx(0.05 * math.log(70.0 / 30.0))  # 80 + 70 e^(-z/0.05) = 110
    assert d[2] == pytest.approx(0.05 * math.log(150.0 / 10.0))
    assert d[3] == 1.5  # the mean is above 110 K: no stable ice within reach


def test_ice_falls_with_distance_to_a_rim():
    cfg = IceConfig(min_crater_m=5.0, falloff_radii=1.0, age_scale_yr=1e9)
    craters = Craters(
        x_m=np.array([0.0]),
        y_m=np.array([0.0]),
        diameter_m=np.array([10.0]),
        age_yr=np.array([0.0]),
    )
    rim = volatiles.rim_factor(
        (200, 200), resolution_m=0.2, x0_m=-20.0, y1_m=20.0, craters=craters, config=cfg
    )
    row = rim[100, 100:]  # eastwards from the centre; the rim at 5 m (column 25)
    x = (np.arange(100) + 0.5) * 0.2
    outside = x > 5.0
    assert np.all(np.diff(row[outside]) < 0)
    k = int(np.argmin(np.abs(x - 10.0)))  # one radius beyond the rim: e^-1
    y = 20.0 - 100.5 * 0.2  # row 100's centre (m north)
    assert row[k] == pytest.approx(math.exp(-(math.hypot(x[k], y) - 5.0) / 5.0), rel=1e-9)
    ice = volatiles.ice_wt_pct(np.zeros_like(rim), rim, config=cfg)
    assert ice[100, 125] > ice[100, 150] > ice[100, 199]
    small = Craters(
        x_m=np.array([0.0]), y_m=np.array([0.0]), diameter_m=np.array([4.0]), age_yr=np.array([0.0])
    )
    assert not volatiles.rim_factor(
        (50, 50), resolution_m=0.2, x0_m=-5, y1_m=5, craters=small, config=cfg
    ).any()
    deep = volatiles.ice_wt_pct(np.full(rim.shape, 1.5), rim, config=cfg)
    assert not deep.any()  # no ice where the dry layer reaches max_depth_m


def test_tile_size_never_changes_a_byte():
    z, _r, env, craters = _bowl_site()
    out = []
    for tile in (64, 4096):
        out.append(
            compute_world(
                z,
                resolution_m=RES,
                craters=craters,
                seed=3,
                envelope=env,
                sun_azimuth_deg=120.0,
                sun_elevation_deg=3.0,
                config=WorldConfig(tile_px=tile, workers=1 if tile == 64 else 2),
            )
        )
    for name in out[0]:
        assert out[0][name].tobytes() == out[1][name].tobytes(), name


def test_written_files_do_not_depend_on_the_block_size(tmp_path):
    from affine import Affine

    from lunar_drake.science.minerals import minerals_wt_pct
    from lunar_drake.science.world import FileSink
    from lunar_drake.terrain.crs import moon_south_polar_stereographic

    rng = np.random.default_rng(2)
    temp = rng.uniform(40.0, 300.0, size=(300, 70)).astype(np.float32)
    minerals = minerals_wt_pct(1, window=(0, 0, 300, 70), resolution_m=0.5)
    crs = moon_south_polar_stereographic()
    transform = Affine(0.5, 0, 73000.0, 0, -0.5, 118000.0)
    digests = []
    for step in (64, 256, 300):
        out = tmp_path / f"b{step}"
        out.mkdir()
        with FileSink(out, shape=temp.shape, transform=transform, crs=crs) as sink:
            for r0 in range(0, 300, step):
                sink.put("temperature_K", r0, temp[r0 : r0 + step])
                sink.put("minerals", r0, minerals[:, r0 : r0 + step])
        digests.append([(out / f).read_bytes() for f in ("temperature_K.tif", "minerals.tif")])
        assert sink.summary()["temperature_K"]["max"] == pytest.approx(float(temp.max()))
        bands = sink.summary()["minerals"]["bands"]
        assert list(bands) == ["plagioclase", "pyroxene", "olivine", "ilmenite"]
        for b, name in enumerate(bands):
            assert bands[name]["max"] == pytest.approx(float(minerals[b].max()))
            assert bands[name]["mean"] == pytest.approx(float(minerals[b].mean(dtype=float)))
    assert digests[0] == digests[1] == digests[2]


def test_a_failed_background_write_discards_every_file(tmp_path, monkeypatch):
    from affine import Affine

    from lunar_drake.science.world import FileSink
    from lunar_drake.terrain import geotiff
    from lunar_drake.terrain.crs import moon_south_polar_stereographic

    temp = np.full((40, 30), 120.0, np.float32)
    calls = {"n": 0}
    real = geotiff.GeoTiffWriter.write

    def flaky(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full")
        return real(self, *a, **k)

    monkeypatch.setattr(geotiff.GeoTiffWriter, "write", flaky)
    transform = Affine(0.5, 0, 73000.0, 0, -0.5, 118000.0)
    with pytest.raises(OSError, match="disk full"):
        with FileSink(tmp_path, shape=temp.shape, transform=transform,
                      crs=moon_south_polar_stereographic()) as sink:  # fmt: skip
            for r0 in range(0, 40, 10):
                sink.put("temperature_K", r0, temp[r0 : r0 + 10])
                sink.put("t_max_K", r0, temp[r0 : r0 + 10])
    assert list(tmp_path.iterdir()) == []


def test_an_empty_or_incomplete_dem_is_refused():
    _z, _r, env, craters = _bowl_site()
    args = dict(resolution_m=RES, craters=craters, seed=3, envelope=env, sun_azimuth_deg=0.0,
                sun_elevation_deg=3.0)  # fmt: skip
    with pytest.raises(WorldModelError, match=r"shape \(0, 5\)"):
        compute_world(np.zeros((0, 5)), **args)
    holey = np.zeros((8, 8))
    holey[3, 4] = np.nan
    with pytest.raises(WorldModelError, match="nodata"):
        compute_world(holey, **args)


def test_minerals_are_tile_invariant_and_sum_to_100():
    from lunar_drake.science.minerals import h_minerals_ppm, minerals_wt_pct

    whole = minerals_wt_pct(5, window=(0, 0, 64, 64), resolution_m=0.5)
    part = minerals_wt_pct(5, window=(16, 32, 20, 24), resolution_m=0.5)
    assert part.tobytes() == whole[:, 16:36, 32:56].tobytes()
    assert np.allclose(whole.sum(axis=0), 100.0)
    h = h_minerals_ppm(5, window=(0, 0, 64, 64), resolution_m=0.5)
    assert h.min() > 0 and h.std() > 0
    assert not np.array_equal(h, h_minerals_ppm(6, window=(0, 0, 64, 64), resolution_m=0.5))


def test_layers_outside_their_physical_range_are_refused():
    with pytest.raises(WorldModelError, match=r"'temperature_K' spans \[-3, 20\] K"):
        check_layer("temperature_K", np.array([-3.0, 20.0]))
    with pytest.raises(WorldModelError, match="frost_area_frac"):
        check_layer("frost_area_frac", np.array([0.2, 1.5]))
    with pytest.raises(WorldModelError, match=r"NaN|nan"):
        check_layer("ice_wt_pct", np.array([np.nan, 1.0]))
    with pytest.raises(OutOfRangeError, match="bond_albedo"):
        WorldConfig(thermal=ThermalConfig(bond_albedo=1.2)).validate()
    with pytest.raises(OutOfRangeError, match="rim_wt_pct"):
        IceConfig(background_wt_pct=60.0, rim_wt_pct=50.0).validate()


def test_world_build_cli(small_site, tmp_path, capsys):
    from lunar_drake.cli import main

    _scenario, site = small_site
    site_dir = site.site.directory
    out = tmp_path / "world"
    assert main(["world", "build", str(site_dir), "--out", str(out), "--no-progress"]) == 0
    doc = json.loads((out / "world.json").read_text())
    for name in (
        "psr",
        "temperature_K",
        "frost_area_frac",
        "oh_ppm",
        "dry_layer_m",
        "ice_wt_pct",
        "h_minerals_ppm",
        "minerals",
    ):
        assert (out / f"{name}.tif").is_file() and (out / f"{name}.png").is_file()
        assert name in doc["layers"]
    import rasterio

    with rasterio.open(out / "minerals.tif") as ds:
        assert ds.descriptions == ("plagioclase", "pyroxene", "olivine", "ilmenite")
        assert ds.crs is not None
    assert "World model of" in capsys.readouterr().out
    # A site without a crater catalog: one line, exit 2.
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "dem.tif").write_bytes((site_dir / "dem.tif").read_bytes())
    assert main(["world", "build", str(bare), "--out", str(tmp_path / "w2"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "no crater catalog" in err and len(err.splitlines()) == 1


def test_world_config_file_and_bad_layers_on_disk(small_site, tmp_path, capsys):
    from lunar_drake.cli import main
    from lunar_drake.science.world import read_world_layer
    from lunar_drake.terrain.geotiff import write_geotiff

    _scenario, site = small_site
    site_dir = str(site.site.directory)
    bad = tmp_path / "bad.yaml"
    bad.write_text("thermal: {bond_albedo: 1.5}\n")
    assert (
        main(
            [
                "world",
                "build",
                site_dir,
                "--out",
                str(tmp_path / "w"),
                "--config",
                str(bad),
                "--no-progress",
            ]
        )
        == 2
    )
    assert "thermal.bond_albedo = 1.5" in capsys.readouterr().err
    # Not YAML, a Python tag, not a mapping, OH limits crossed, a word or a fraction where
    # a number is wanted, a section that is not a mapping, a misspelt key, an empty
    # --utc, no site:
    # one line each, exit 2, naming what is wrong; nothing built.
    refusals = [
        ("oh: [1, 2\n", "is not valid YAML"),
        ("!!python/object/apply:os.system [echo]\n", "is not valid YAML"),
        ("- 1\n- 2\n", "holds a list"),
        ("oh: {min_ppm: 800}\n", "oh.min_ppm = 800.0 is above max_ppm = 750.0"),
        ("thermal: {bond_albedo: high}\n", "line 1: thermal.bond_albedo = 'high' must be a number"),
        ("thermal: 3\n", "thermal must be a mapping of keys"),
        ("thermal: {bond_albdo: 0.1}\n", "unknown key 'thermal.bond_albdo'"),
        ("compress: zstd\nthermal:\n  strip_px: 1.5\n", "line 3: thermal.strip_px = '1.5'"),
    ]
    for i, (text, msg) in enumerate(refusals):
        f = tmp_path / f"refused{i}.yaml"
        f.write_text(text)
        argv = ["world", "build", site_dir, "--out", str(tmp_path / "w"), "--config", str(f)]
        assert main([*argv, "--no-progress"]) == 2, text
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1, err
    argv = ["world", "build", site_dir, "--out", str(tmp_path / "w"), "--no-progress"]
    assert main([*argv, "--utc", " "]) == 2
    assert "--utc '' is empty" in capsys.readouterr().err
    assert main(["world", "build", str(tmp_path / "nowhere"), "--out", str(tmp_path / "w")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
    typo = tmp_path / "typo.yaml"
    typo.write_text("thermal: {albedo: 0.1}\n")
    assert (
        main(
            [
                "world",
                "build",
                site_dir,
                "--out",
                str(tmp_path / "w"),
                "--config",
                str(typo),
                "--no-progress",
            ]
        )
        == 2
    )
    assert "albedo" in capsys.readouterr().err
    empty = tmp_path / "empty.yaml"
    empty.write_text("# all defaults\n")
    assert main(["world", "build", site_dir, "--out", str(tmp_path / "w0"), "--config",
                 str(empty), "--no-progress"]) == 0  # fmt: skip
    good = tmp_path / "good.yaml"
    good.write_text("sun: {azimuth_bins: 8}\nminerals: {scales_m: [20.0, 5.0]}\n")
    out = tmp_path / "w"
    assert (
        main(
            ["world", "build", site_dir, "--out", str(out), "--config", str(good), "--no-progress"]
        )
        == 0
    )
    doc = json.loads((out / "world.json").read_text())
    assert doc["sun_envelope"]["azimuth_bins"] == 8
    assert doc["config"]["minerals"]["scales_m"] == [20.0, 5.0]
    t = read_world_layer(out, "temperature_K")
    assert t.min() > 20.0
    from affine import Affine

    write_geotiff(
        out / "temperature_K.tif",
        np.full((4, 4), -5.0, np.float32),
        transform=Affine(0.1, 0, 0, 0, -0.1, 0),
        crs=site.heightfield.crs,
    )
    with pytest.raises(WorldModelError, match="temperature_K"):
        read_world_layer(out, "temperature_K")


def test_world_build_bad_sites_and_outputs(small_site, tmp_path, capsys):
    import shutil

    import rasterio

    from lunar_drake.cli import main

    _scenario, site = small_site
    src = site.site.directory
    cases = []
    bad_csv = tmp_path / "bad_csv"
    bad_csv.mkdir()
    for name in ("dem.tif", "site.json"):
        shutil.copy(src / name, bad_csv / name)
    (bad_csv / "craters.csv").write_text("x_m,y_m,diameter_m,age_yr\n1,2,abc,4\n")
    cases.append((bad_csv, "not a numeric crater table"))
    holes = tmp_path / "holes"
    shutil.copytree(src, holes)
    with rasterio.open(holes / "dem.tif", "r+") as ds:
        z = ds.read(1)
        z[3, 4] = np.nan
        ds.write(z, 1)
    cases.append((holes, "1 nodata cells"))
    bad_json = tmp_path / "bad_json"
    shutil.copytree(src, bad_json)
    (bad_json / "site.json").write_text('{"config": {"seed": "seven"}}')
    cases.append((bad_json, "is not a site's site.json: config.seed = 'seven'"))
    torn = tmp_path / "torn"
    shutil.copytree(src, torn)
    (torn / "site.json").write_text('{"config": {"se')
    cases.append((torn, "is not a site's site.json: Unterminated string"))
    for site_dir, msg in cases:
        out = tmp_path / f"w_{site_dir.name}"
        assert main(["world", "build", str(site_dir), "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1
        assert not out.exists()  # nothing half-written
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    assert main(["world", "build", str(src), "--out", str(mine), "--no-progress"]) == 2
    assert "notes.txt" in capsys.readouterr().err
    assert (mine / "notes.txt").read_text() == "keep me"


def test_fractal_noise_is_the_blend_of_hashed_lattice_nodes():
    # Recomputed point by point from rng.hash_uniform, independently of the kernel.
    from lunar_drake import rng
    from lunar_drake.science.minerals import fractal_noise

    scales, res = [50.0, 12.0, 3.0], 0.5
    n = fractal_noise(5, "x", row0=10, col0=30, nrows=20, ncols=20, resolution_m=res,
                      scales_m=scales)  # fmt: skip
    weights = [s / scales[0] for s in scales]

    def fade(t):
        return t * t * t * (t * (t * 6 - 15) + 10)

    for r, c in ((10, 30), (17, 41), (29, 49)):
        total = 0.0
        for k, (s, w) in enumerate(zip(scales, weights, strict=True)):
            key = rng.stream_key(5, f"science/x/octave{k}")
            y, x = (r + 0.5) * res / s, (c + 0.5) * res / s
            iy, ix = math.floor(y), math.floor(x)
            fy, fx = fade(y - iy), fade(x - ix)

            def v(i, j, key=key):
                return float(rng.hash_uniform(key, np.array([i]), np.array([j]))[0])

            top = v(iy, ix) * (1 - fx) + v(iy, ix + 1) * fx
            bottom = v(iy + 1, ix) * (1 - fx) + v(iy + 1, ix + 1) * fx
            total += w * (top * (1 - fy) + bottom * fy - 0.5)
        total /= math.sqrt(sum(w * w for w in weights) / 12.0)
        assert n[r - 10, c - 30] == pytest.approx(total, abs=1e-12)


def test_heat_maps_drawn_in_forked_processes_are_the_same_bytes(tmp_path):
    import threading

    from lunar_drake.science import world as w

    a = np.random.default_rng(5).normal(size=(64, 48))

    def figures(tag):
        return [(w.heat_map, (tmp_path / f"{tag}{i}.png", a + i),
                 {"name": "oh_ppm", "resolution_m": 0.5, "z": np.cumsum(a, 0)})
                for i in range(3)]  # fmt: skip

    w._draw(figures("pool"), workers=2)  # forks where no other thread runs
    hold = threading.Event()
    other = threading.Thread(target=hold.wait)
    other.start()  # with another thread alive the figures are drawn here
    try:
        w._draw(figures("here"), workers=2)
    finally:
        hold.set()
        other.join()
    for i in range(3):
        assert (tmp_path / f"pool{i}.png").read_bytes() == (tmp_path / f"here{i}.png").read_bytes()
    # Which process drew: children in the pool (when no other thread runs), this one else.
    alone = not [t for t in threading.enumerate()
                 if t is not threading.current_thread() and t.name != "tqdm_monitor"]  # fmt: skip
    w._draw([(_write_pid, (tmp_path / f"pid{i}",), {}) for i in range(3)], workers=2)
    pids = {int((tmp_path / f"pid{i}").read_text()) for i in range(3)}
    assert (os.getpid() not in pids) == alone
    other = threading.Thread(target=hold.wait)
    hold.clear()
    other.start()
    try:
        w._draw([(_write_pid, (tmp_path / f"pid{i}",), {}) for i in range(3)], workers=2)
    finally:
        hold.set()
        other.join()
    assert {int((tmp_path / f"pid{i}").read_text()) for i in range(3)} == {os.getpid()}


def _write_pid(path) -> None:
    path.write_text(str(os.getpid()))


def test_envelope_bins_samples_in_grid_azimuth():
    # True azimuth A lies at grid azimuth A + grid_north_deg (the grid's north is turned).
    env = envelope_from_samples([10.0, 10.0, 200.0], [1.0, 3.0, 2.0], [1.5e8, 1.5e8, 1.5e8],
                                bins=12, grid_north_deg=30.0)  # fmt: skip
    assert env.el_max_deg[40 // 30] == 3.0  # 10 + 30 = 40 deg: the sector 30-60
    assert env.el_max_deg[230 // 30] == 2.0
    assert env.weight[1] == pytest.approx(2 / 3) and env.weight[7] == pytest.approx(1 / 3)
    assert np.count_nonzero(env.weight) == 2


def test_mean_flux_is_the_average_over_the_suns_samples():
    # A flat plain: every sample's Sun is wholly up, so the year's mean absorbed flux is
    # the plain average over the samples of (1 - A) S / d^2 sin(e), computed here
    # directly from the samples (not from the sectors' quantile levels).
    rng = np.random.default_rng(3)
    n = 4000
    az = rng.uniform(0.0, 360.0, n)
    el = 1.0 + 2.5 * (0.5 + 0.5 * np.sin(np.radians(3.0 * az)))  # 1-3.5 deg
    d_km = 1.496e8 * (1.0 + 0.01 * np.cos(np.radians(az)))
    env = envelope_from_samples(az, el, d_km, bins=24)
    cfg = ThermalConfig()
    z = np.zeros((48, 48))
    il = thermal.illumination(z, resolution_m=1.0, envelope=env, sun_azimuth_deg=0.0,
                              sun_elevation_deg=2.0, config=cfg)  # fmt: skip
    d_au = d_km / 149_597_870.7
    direct = np.mean((1.0 - cfg.bond_albedo) * cfg.solar_constant_w_m2 / d_au**2
                     * np.sin(np.radians(el)))  # fmt: skip
    assert np.allclose(il.q_mean_w_m2, direct, rtol=5e-3)
    peak = (1.0 - cfg.bond_albedo) * cfg.solar_constant_w_m2 * np.sin(np.radians(el.max()))
    assert il.q_max_w_m2.max() == pytest.approx(peak, rel=0.02)


def test_ice_of_several_craters_of_different_ages():
    cfg = IceConfig(min_crater_m=5.0)
    craters = Craters(x_m=np.array([-10.0, 12.0, 0.0]), y_m=np.array([0.0, 4.0, -14.0]),
                      diameter_m=np.array([8.0, 12.0, 3.0]),
                      age_yr=np.array([0.2, 1.5, 0.0]) * cfg.age_scale_yr)  # fmt: skip
    res = 0.5
    f = volatiles.rim_factor((80, 80), resolution_m=res, x0_m=-20.0, y1_m=20.0,
                             craters=craters, config=cfg)  # fmt: skip
    for r, c in [(40, 20), (30, 64), (52, 40), (70, 40), (5, 5), (40, 44)]:
        x, y = -20.0 + (c + 0.5) * res, 20.0 - (r + 0.5) * res
        keep = 1.0
        for cx, cy, dk, age in [(-10.0, 0.0, 8.0, 0.2), (12.0, 4.0, 12.0, 1.5)]:  # not the 3 m
            dist = abs(math.hypot(x - cx, y - cy) - dk / 2)
            keep *= 1.0 - math.exp(-age) * math.exp(-dist / (cfg.falloff_radii * dk / 2))
        assert f[r, c] == pytest.approx(1.0 - keep, rel=1e-9, abs=1e-12)


_HANDLERS_CHILD = """
import signal, sys
from pathlib import Path
from lunar_drake.science import world as w

def write(path):
    Path(path).write_text(f"{signal.getsignal(signal.SIGTERM)!r}|"
                          f"{signal.getsignal(signal.SIGINT)!r}")

signal.signal(signal.SIGTERM, lambda *_: None)  # as the program takes SIGTERM in Python
w._draw([(write, (f"{sys.argv[1]}/h{i}",), {}) for i in range(2)], workers=2)
"""


def test_drawing_workers_die_on_sigterm_and_leave_ctrl_c_to_the_parent(tmp_path):
    # A forked drawing worker must not inherit the program's Python SIGTERM handler (the
    # pool's terminate() would then wait on Python code in a worker blocked on a queue
    # lock: a build that never returned). In a fresh interpreter, where no other thread
    # runs and the figures are drawn by forked workers.
    import signal
    import subprocess
    import sys

    subprocess.run([sys.executable, "-c", _HANDLERS_CHILD, str(tmp_path)], check=True,
                   timeout=120)  # fmt: skip
    for i in range(2):
        term, intr = (tmp_path / f"h{i}").read_text().split("|")
        assert term == repr(signal.SIG_DFL) and intr == repr(signal.SIG_IGN)
