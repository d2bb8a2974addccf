"""The Hapke camera: closed-form shading of a flat plane, determinism, the stereo pair in
the mission diagram, Sun below the horizon, bad exposure and a camera inside the ground."""

import math

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix

from lunar_drake.errors import OutOfRangeError
from lunar_drake.render.camera import CameraConfig, TerrainCameraRenderer
from lunar_drake.render.hapke import HIGHLANDS_643NM, hapke_reflectance
from lunar_drake.terrain.heightfield import Heightfield


def _flat(n=128, res=0.25):
    return Heightfield.from_array(np.zeros((n, n), np.float32), resolution_m=res)


def _down_camera(height=3.0):
    # Camera +z (optical axis) = world -z, +x = world +x, +y = world -y.
    R = RotationMatrix(np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]))
    return RigidTransform(R, [0.0, 0.0, height])


@pytest.mark.parametrize("engine,rtol", [("raycast", 1e-4), ("heightfield", 2e-3)])
def test_flat_plane_matches_closed_form_hapke(engine, rtol):
    # the heightfield engine reads a tabulated BRDF (see hapke_lut), hence its tolerance
    r = TerrainCameraRenderer(
        heightfield=_flat(), model=CameraConfig(width=65, height=49, engine=engine)
    )
    el = math.radians(30.0)
    illum, up = r.illumination(sun_dir_W=(math.cos(el), 0.0, math.sin(el)))
    assert up
    img = r.shade(X_WC=_down_camera(), illumination=illum)
    centre = float(img.radiance[24, 32])
    # Sun and the 3 % fill (opposite azimuth, same elevation) both see cos_i = sin(30),
    # cos_e = 1 and phase 60 deg at the nadir pixel: I/F = pi * 1.03 * r.
    refl = float(
        hapke_reflectance(0.5, 1.0, math.radians(60.0), params=HIGHLANDS_643NM, dtype=np.float64)
    )
    assert centre == pytest.approx(math.pi * 1.03 * refl, rel=rtol)
    assert img.label[24, 32] == 1
    assert float(img.depth[24, 32]) == pytest.approx(3.0, rel=1e-5)


def test_sensor_frames_are_bit_identical_and_exposure_checked():
    r = TerrainCameraRenderer(heightfield=_flat(), model=CameraConfig(width=64, height=48))
    illum, _ = r.illumination(sun_dir_W=(0.9, 0.0, 0.43))
    img = r.shade(X_WC=_down_camera(), illumination=illum)
    a = r.expose(img, exposure_s=0.002, gain=1.0, key=7, frame_index=3)
    b = r.expose(img, exposure_s=0.002, gain=1.0, key=7, frame_index=3)
    c = r.expose(img, exposure_s=0.002, gain=1.0, key=7, frame_index=4)
    assert a.dtype == np.uint16 and a.max() <= 4095
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert r.expose(img, exposure_s=0.004, gain=1.0, key=7, frame_index=3).mean() > a.mean()
    with pytest.raises(OutOfRangeError, match="exposure"):
        r.expose(img, exposure_s=0.0, gain=1.0, key=7, frame_index=3)
    with pytest.raises(OutOfRangeError, match="exposure_s"):
        CameraConfig(exposure_s=-1.0)


def test_sun_below_horizon_is_dark_but_not_black():
    r = TerrainCameraRenderer(heightfield=_flat(), model=CameraConfig(width=64, height=48))
    day, _ = r.illumination(sun_dir_W=(0.9, 0.0, 0.2))
    night, up = r.illumination(
        sun_dir_W=(0.99, 0.0, -0.05),
        earth_dir_W=(0.0, 0.9, 0.4),
        earth_distance_km=384_400.0,
        earth_phase=0.8,
    )
    assert not up
    lit = r.shade(X_WC=_down_camera(), illumination=day).radiance
    dark = r.shade(X_WC=_down_camera(), illumination=night).radiance
    assert 0 < dark.mean() < 0.05 * lit.mean()
    # Earthshine alone is tiny but present.
    only_earth, _ = r.illumination(
        sun_dir_W=(0.99, 0.0, -0.05),
        earth_dir_W=(0.0, 0.9, 0.4),
        earth_distance_km=384_400.0,
        earth_phase=0.8,
    )
    assert only_earth.earth_irradiance > 0


def _camera_after(scenario, site, t):
    """(mission diagram, simulator, camera system, its context) after ``t`` seconds."""
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.scenario_files import apply_overrides

    scenario = apply_overrides(scenario, f"{{simulation_duration: {t + 1.0}}}")
    d = MakeMissionDiagram(scenario=scenario, site=site)
    sim = Simulator(d)
    sim.AdvanceTo(t)
    cam = d.GetSubsystemByName("plant").GetSubsystemByName("camera")
    return d, sim, cam, cam.GetMyContextFromRoot(sim.get_context())


def test_mission_stereo_pair_renders_terrain_and_is_deterministic(small_site):
    from lunar_drake.scenario_files import apply_overrides

    scenario, site = small_site
    s = apply_overrides(scenario, "{sensors: {camera: {width: 96, height: 72, rate_hz: 1.0}}}")
    frames = []
    for _ in range(2):
        d, sim, cam, ctx = _camera_after(s, site, 1.5)
        frames.append({n: cam.frame(ctx, n) for n in ("left", "right")})
    left, right = frames[0]["left"], frames[0]["right"]
    assert left.index == 1 and left.raw.shape == (72, 96)
    assert (left.label == 1).mean() > 0.2  # terrain in view
    assert left.raw.max() > 100  # lit terrain registers
    assert not np.array_equal(left.raw, right.raw)  # a stereo baseline apart
    for n in ("left", "right"):
        assert np.array_equal(frames[0][n].raw, frames[1][n].raw)
    out = d.GetOutputPort("camera.left.preview").Eval(d.GetMyContextFromRoot(sim.get_context()))
    assert out.width() == 96 and out.height() == 72


def test_camera_frames_arrive_delay_after_they_are_taken(small_site):
    from lunar_drake.scenario_files import apply_overrides

    scenario, site = small_site
    s = apply_overrides(
        scenario, "{sensors: {camera: {width: 48, height: 36, rate_hz: 2.0, delay_s: 0.7}}}"
    )
    _, _, cam, ctx = _camera_after(s, site, 0.69)
    assert cam.frame(ctx, "left").index == -1  # frame 0 (t = 0) not delivered yet
    _, _, cam, ctx = _camera_after(s, site, 1.75)
    f = cam.frame(ctx, "left")  # frames 0..2 are due by 1.7 s; frame 3 (1.5 s) at 2.2 s
    assert f.index == 2 and f.time_s == 1.0


@pytest.mark.parametrize("engine", ["raycast", "heightfield"])
def test_camera_inside_the_terrain_is_an_error(engine):
    from lunar_drake.errors import SimulationError
    from lunar_drake.systems.hapke_camera import CameraMount, HapkeCamera

    r = TerrainCameraRenderer(
        heightfield=_flat(), model=CameraConfig(width=32, height=24, engine=engine)
    )
    cam = HapkeCamera(renderer=r, mounts=[CameraMount("left", 0, RigidTransform())])
    ctx = cam.CreateDefaultContext()
    cam.body_poses_input.FixValue(ctx, [RigidTransform([0.0, 0.0, -0.5])])
    from pydrake.geometry import QueryObject

    cam.geometry_query_input.FixValue(ctx, QueryObject())
    cam.sun_direction_input.FixValue(ctx, [0.9, 0.0, 0.4])
    cam.sun_distance_input.FixValue(ctx, [1.496e8])
    cam.earth_direction_input.FixValue(ctx, [0.0, 0.0, 0.0])
    cam.earth_distance_input.FixValue(ctx, [3.84e5])
    cam.earth_phase_input.FixValue(ctx, [0.0])
    with pytest.raises(SimulationError, match="inside the terrain"):
        cam._update(ctx, ctx.get_mutable_state())


def test_rover_spotlights_from_the_scenario():
    from lunar_drake.errors import ConfigError
    from lunar_drake.scenario_files import load_scenario

    s = load_scenario(scenario_name="night")
    assert len(s.rover.lights) == 2 and s.rover.lights[0].body == "chassis"
    five = "[" + ", ".join(["{body: chassis}"] * 5) + "]"
    with pytest.raises(OutOfRangeError, match="at most 4"):
        load_scenario(scenario_name="small", scenario_text=f"{{rover: {{lights: {five}}}}}")
    with pytest.raises(ConfigError, match="inner_half_angle_deg"):
        load_scenario(
            scenario_name="small",
            scenario_text=(
                "{rover: {lights: [{outer_half_angle_deg: 20, inner_half_angle_deg: 30}]}}"
            ),
        )
    # A lamp in the dark: its cone lights the ground below it, nothing outside.
    from lunar_drake.render.shading import SpotLight

    r = TerrainCameraRenderer(heightfield=_flat(), model=CameraConfig(width=64, height=48))
    lamp = SpotLight(
        position_W=(0.0, 0.0, 2.0),
        direction_W=(0.0, 0.0, -1.0),
        up_W=(1, 0, 0),
        intensity=0.05,
        outer_half_angle_rad=math.radians(10),
        inner_half_angle_rad=math.radians(5),
    )
    illum, up = r.illumination(sun_dir_W=(1.0, 0.0, -0.2), spotlights=[lamp])
    img = r.shade(X_WC=_down_camera(height=3.0), illumination=illum).radiance
    assert not up
    assert img[24, 32] > 20 * img[2, 2]


def test_mission_lamps_light_the_night_and_gimbal_looks_down(small_site):
    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.errors import ConfigError
    from lunar_drake.scenario_files import apply_overrides

    scenario, site = small_site
    base = (
        "{site: {epoch_utc: '2027-11-25T00:00:00'}, sensors: {camera: {width: 64, height: 48,"
        " rate_hz: 1.0, exposure_s: 0.05, gain: 4.0}}"
    )
    means = []
    for lamps in ("", ", rover: {lights: [{body: chassis, intensity_W_per_sr: 200.0}]}"):
        s = apply_overrides(scenario, base + lamps + "}")
        _, _, cam, ctx = _camera_after(s, site, 1.5)
        f = cam.frame(ctx, "left")
        means.append(float(f.raw.mean()))
        # The gimbal points the pair at the ground ahead: mostly terrain in view.
        assert (f.label == 1).mean() > 0.5
    assert means[1] > 2.0 * means[0] + 1.0
    bad = apply_overrides(scenario, "{rover: {lights: [{body: bumper}]}}")
    with pytest.raises(ConfigError, match=r"rover\.lights\[0\]\.body = 'bumper'"):
        MakeMissionDiagram(scenario=bad, site=site)


def test_render_command_at_any_time(cache, tmp_path):
    from lunar_drake.cli.render import render_stereo
    from lunar_drake.scenario_files import load_scenario

    s = load_scenario(
        scenario_name="small",
        scenario_text="{sensors: {camera: {width: 48, height: 32, rate_hz: 0.2}}}",
    )
    paths = render_stereo(scenario=s, time_s=3.0, out_dir=tmp_path / "r", progress=False)
    names = {p.name for p in paths}
    assert {"left.png", "right.png", "left_preview.png", "render.json"} <= names
    import json

    assert json.loads((tmp_path / "r" / "render.json").read_text())["time_s"] == 5.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]  # no temporary leftovers


def test_lightmap_source_interpolates_baked_maps_lazily():
    from lunar_drake.ephemeris.sun_earth import SiteLocation
    from lunar_drake.errors import OutOfRangeError as OOR
    from lunar_drake.render.lightmap import lightmap
    from lunar_drake.systems.lightmap_source import LightmapSource

    yy, xx = np.mgrid[0:64, 0:64]
    z = (0.3 * np.sin(xx / 5.0) * np.cos(yy / 7.0)).astype(np.float32)
    hf = Heightfield.from_array(z, resolution_m=0.1)
    src = LightmapSource(
        heightfield=hf,
        site=SiteLocation(-85.4, 31.6),
        epoch_utc="2027-11-15T00:00:00",
        duration_s=7200.0,
    )
    assert src.times_s == (0.0, 3600.0, 7200.0)
    a, e = src.sun_az_el_deg[1]
    direct = lightmap(z, sun_azimuth_deg=a, sun_elevation_deg=e, resolution_m=0.1)
    np.testing.assert_array_equal(src.lightmap_at(3600.0), direct)
    mid = src.lightmap_at(1800.0)
    np.testing.assert_allclose(mid, 0.5 * (src.lightmap_at(0.0) + direct), atol=1e-6)
    with pytest.raises(OOR, match="outside"):
        src.lightmap_at(9000.0)


def test_delayed_frames_render_on_the_worker_thread_with_the_same_bytes(small_site, monkeypatch):
    """With a delivery delay the camera renders on its worker thread while the simulation
    goes on; the delivered frames are the bytes of a render in the update itself."""
    import threading

    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.systems import hapke_camera

    scenario, site = small_site
    s = apply_overrides(
        scenario, "{sensors: {camera: {width: 64, height: 48, rate_hz: 2.0, delay_s: 0.7}}}"
    )
    threads = set()
    shade = TerrainCameraRenderer.shade

    def recording_shade(self, **kw):
        threads.add(threading.current_thread().name)
        return shade(self, **kw)

    monkeypatch.setattr(TerrainCameraRenderer, "shade", recording_shade)
    out = {}
    for mode in ("worker", "in place"):
        if mode == "in place":
            monkeypatch.setattr(hapke_camera, "concurrent_kernels_safe", lambda: False)
        threads.clear()
        _, _, cam, ctx = _camera_after(s, site, 1.75)
        ring = ctx.get_abstract_state(0).get_value()
        pending = [isinstance(e, hapke_camera.PendingFrames) for e in ring]
        out[mode] = {n: cam.frame(ctx, n) for n in ("left", "right")}
        if mode == "worker":
            assert (
                all(pending)
                and threads
                and all(t.startswith("lunar_drake.camera") for t in threads)
            ), (pending, threads)
        else:
            assert not any(pending) and threads == {threading.current_thread().name}
    for n in ("left", "right"):
        a, b = out["worker"][n], out["in place"][n]
        assert a.index == b.index == 2
        for field in ("raw", "depth", "label", "radiance"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), (n, field)


def test_an_error_in_a_deferred_render_reaches_the_reader(small_site, monkeypatch):
    from lunar_drake.errors import SimulationError
    from lunar_drake.scenario_files import apply_overrides

    scenario, site = small_site
    s = apply_overrides(
        scenario, "{sensors: {camera: {width: 32, height: 24, rate_hz: 2.0, delay_s: 0.3}}}"
    )

    def failing_shade(self, **kw):
        raise SimulationError("render failed")

    monkeypatch.setattr(TerrainCameraRenderer, "shade", failing_shade)
    with pytest.raises(SimulationError, match="render failed"):
        _, _, cam, ctx = _camera_after(s, site, 0.4)
        cam.frame(ctx, "left")
