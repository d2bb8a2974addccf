"""Benchmark: a full-shading Hapke camera frame against Drake's RenderEngineVtk.

    .venv/bin/python benchmarks/render.py --out bench_render.json
    .venv/bin/python benchmarks/render.py --frames 5 --no-size-check --images /tmp/frames

Scene (the ``default`` scenario): the synthesized 2048^2 site at 0.1 m, the rover at
its spawn pose, a camera at the rover's left mast camera position (about 1.5 m above
the terrain) looking east (grid +x), tilted ``--tilt`` (14) deg down -- the mission
gimbal's aim at the ground 6 m ahead -- with 1280 x 960 px and a 45 deg vertical field
of view; the Sun and Earth from the ephemeris at the scenario epoch (sim time 0).
Frame ``i`` moves the camera ``i * --step`` (0.1 m) east, following the ground, so no
image is cached between frames; the LOD centre stays put (< lod_recenter_m of motion).
The rover stands still, so its Embree BVH is built once (it is rebuilt when a pose
changes), as VTK keeps its meshes.

Hapke (:class:`lunar_drake.render.camera.TerrainCameraRenderer`, full shading, engine
``--engine``, default ``heightfield``): one ray per pixel (the heightfield engine marches
the DEM's mip pyramid and casts Embree rays only where the rover projects; the raycast
engine casts every ray into the LOD triangles and the rover meshes), Hapke blended BRDF x
albedo map x baked lightmap (baked once beforehand, not timed; its bake time is
reported) x soft rover shadow, indirect fill, Earthshine; then the sensor (``expose``:
exposure, noise, 12-bit codes). ``hapke_fps = 1 / median(shade + expose)`` over
``--frames`` frames after one start-up frame (which builds the LOD and BVH, or the DEM
pyramid and the reflectance table) and ``--warmup`` (5) untimed frames right before
the timed ones; VTK gets the same. A second pass renders the same frames with the
engine's visibility and shading calls wrapped in timers (the rest is "other"); its
images are checked bit-identical to the first pass. With ``--reference-frames N`` (3) the
raycast reference engine renders the first N frames too (``reference_engine`` in the
JSON: its frame rate and its agreement with the timed engine on frame 1).

VTK (:class:`benchmarks.vtk_reference.VtkReferenceCamera`): the same LOD mesh
(``TerrainLOD.merged()``, skirts included -- the very triangles the ray caster sees)
written to an OBJ with the albedo draped as a texture, welded to the world of a
MultibodyPlant/SceneGraph that also holds the rover (its SDF visuals; the camera head
hidden, as in the Hapke renderer), one directional Sun light, RgbdSensor with the same
intrinsics and pose. Each frame sets the sensor pose (a Context parameter, which
invalidates the cached image) and evaluates the colour image port.
``vtk_fps = 1 / median``.

By default all timed Hapke frames run first, then all VTK frames, each renderer in its
steady state; ``ratio = hapke_fps / vtk_fps``. ``--block N`` interleaves blocks of N
Hapke and N VTK frames instead, so that slow drifts of the load from other tenants of a
shared machine fall on both alike; measured here, a Hapke frame that follows VTK
frames runs slower (its data has left the caches), so interleaving lowers the ratio.

With the size check (default) a 640 x 480 VTK camera is timed too, so the full-size time
is seen to scale with the pixel count (it really renders), and an Eval without a pose
change shows the cache hit.

Both renderers' frames are also timed in process CPU seconds (``time.process_time``:
every thread of this process, numba's and llvmpipe's workers included), so that on a
machine shared with other jobs, where the wall clock of a frame depends on how much of
the cores the scheduler gives it, the work per frame can be compared as well:
``cpu_ratio = vtk_cpu_s / hapke_cpu_s`` (medians). The machine's ``speed_index_s``
(``benchmarks/speed_index.py``: ``../shared/bench/speed_index.py`` in a child process)
is measured first and recorded, with the load average before and after.

Prints a table; writes JSON with --out. Goals: hapke_fps >= 10, ratio >= 2.5.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import hashlib
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
import traceback

import numpy as np

from lunar_drake.files import atomic_write_text, check_output_file

GOALS = {"hapke_fps": 10.0, "ratio": 2.5}


def _vtk():
    """The VTK reference camera module (beside this script)."""
    try:
        from benchmarks import vtk_reference
    except ImportError:  # run as a script: benchmarks/ itself is on sys.path
        import vtk_reference
    return vtk_reference


def _speed_index():
    """``(measure_speed_index, speed_index_line)`` of the speed-index helper beside this
    script."""
    try:
        from benchmarks import speed_index
    except ImportError:  # run as a script: benchmarks/ itself is on sys.path
        import speed_index
    return speed_index.measure_speed_index, speed_index.speed_index_line


def _loadavg():
    """The 1-minute load average (None where the OS has none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def _median(xs):
    return float(statistics.median(xs)) if xs else None


def camera_pose(p_WC, tilt_deg: float) -> np.ndarray:
    """4x4 X_WC of a Drake camera (+z forward, +x right, +y down) looking grid east,
    pitched ``tilt_deg`` down."""
    t = math.radians(tilt_deg)
    z = np.array([math.cos(t), 0.0, -math.sin(t)])
    x = np.array([0.0, -1.0, 0.0])
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, y, z])
    X[:3, 3] = p_WC
    return X


def _rover_plant(scenario, hf):
    """A finalized plant with the scenario's rover at its spawn pose: (plant,
    scene_graph, rover, diagram, diagram context)."""
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    b = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(b, 0.0)
    rover = add_spawned_rover(plant, scenario, hf)
    plant.Finalize()
    diagram = b.Build()
    ctx = diagram.CreateDefaultContext()
    return plant, sg, rover, diagram, ctx


def add_spawned_rover(plant, scenario, hf):
    """Adds the scenario's rover to an unfinalized plant and sets its default pose to the
    spawn pose (floating base)."""
    from lunar_drake.models.rover_sdf import add_rover
    from lunar_drake.models.spawn import spawn_pose

    rc = scenario.rover
    rover = add_rover(plant, description=rc.description)
    X = spawn_pose(
        heightfield=hf,
        rover=rover,
        x_m=rc.spawn_x_m,
        y_m=rc.spawn_y_m,
        yaw_rad=math.radians(rc.spawn_yaw_deg),
        soil=scenario.soil,
    )
    plant.SetDefaultFloatingBaseBodyPose(rover.chassis, X)
    return rover


def _gl_libraries() -> list[str]:
    """Names of the GL/EGL/Mesa shared libraries loaded in this process (Linux), to tell
    a software rasterizer (Mesa swrast/llvmpipe) from a GPU driver."""
    keys = ("EGL", "libGL", "swrast", "llvmpipe", "gallium", "nvidia", "OSMesa")
    try:
        with open("/proc/self/maps") as f:
            return sorted(
                {os.path.basename(ln.split()[-1]) for ln in f if any(k in ln for k in keys)}
            )
    except OSError:
        return []


def split_frames(renderer, poses, illum, dyn, lmap, frames, engine="raycast") -> dict:
    """Renders frames 1..frames again with the engine's visibility and shading calls
    wrapped in timers (raycast: ``lunar_drake.render.camera``'s ``trace`` and ``shade``;
    heightfield: ``lunar_drake.render.fast_engine``'s ``trace_heightfield`` and
    ``_shade_terrain``); per-frame seconds of each and of the rest of
    ``TerrainCameraRenderer.shade``, and radiance hashes. Empty if the module does not
    use those names."""
    if engine == "raycast":
        import lunar_drake.render.camera as camera_mod

        names = ("trace", "shade")
    else:
        import lunar_drake.render.fast_engine as camera_mod

        names = ("trace_heightfield", "_shade_terrain")

    out = {"trace": [], "shade": [], "other": [], "hashes": []}
    orig_trace = getattr(camera_mod, names[0], None)
    orig_shade = getattr(camera_mod, names[1], None)
    if orig_trace is None or orig_shade is None:
        return out
    acc = {}

    def timed(name, fn):
        def wrapper(*a, **kw):
            t0 = time.perf_counter()
            r = fn(*a, **kw)
            acc[name] = acc.get(name, 0.0) + time.perf_counter() - t0
            return r

        return wrapper

    setattr(camera_mod, names[0], timed("trace", orig_trace))
    setattr(camera_mod, names[1], timed("shade", orig_shade))
    try:
        for i in range(1, frames + 1):
            acc.clear()
            t0 = time.perf_counter()
            sh = renderer.shade(X_WC=poses[i], illumination=illum, dynamic_poses=dyn, lightmap=lmap)
            total = time.perf_counter() - t0
            tr, sd = acc.get("trace", 0.0), acc.get("shade", 0.0)
            out["trace"].append(tr)
            out["shade"].append(sd)
            out["other"].append(total - tr - sd)
            out["hashes"].append(_hash(sh.radiance))
    finally:
        setattr(camera_mod, names[0], orig_trace)
        setattr(camera_mod, names[1], orig_shade)
    if not out["trace"] or min(out["trace"]) == 0.0:  # trace not called through the module
        return {"trace": [], "shade": [], "other": [], "hashes": []}
    return out


def _hash(a) -> str:
    return hashlib.blake2b(np.ascontiguousarray(a).tobytes(), digest_size=8).hexdigest()


class VtkBench:
    """RenderEngineVtk timing: :meth:`frame` per pose, :meth:`finish` for the rest."""

    def __init__(self, args, *, obj, sun_W, poses, scenario, hf, rover_bodies_hidden):
        VtkReferenceCamera = _vtk().VtkReferenceCamera

        self.args, self.obj, self.sun_W, self.poses = args, obj, sun_W, poses
        self.out = {}
        t0 = time.perf_counter()
        cam = VtkReferenceCamera(
            obj_path=obj,
            width=args.width,
            height=args.height,
            fov_y_deg=args.fov,
            sun_dir_W=sun_W,
            cast_shadows=args.vtk_shadows,
        )
        if not args.no_rover:
            rover = add_spawned_rover(cam.plant, scenario, hf)
            cam.plant.Finalize()
            insp = cam.scene_graph.model_inspector()
            from pydrake.geometry import Role

            hide = []
            for name in rover_bodies_hidden:
                body = cam.plant.GetBodyByName(name, rover.model_instance)
                fid = cam.plant.GetBodyFrameIdOrThrow(body.index())
                hide += list(insp.GetGeometries(fid, Role.kPerception))
            cam.hide(hide)
        cam.finalize()
        self.cam = cam
        self.out["setup_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        cam.render(poses[0])
        self.out["first_frame_s"] = time.perf_counter() - t0
        self.times, self.cpu, self.hashes, self.last = [], [], [], None

    def frame(self, i: int, *, record: bool = True) -> float:
        """Sets pose i and evaluates the colour image; returns the Eval time (s)."""
        self.cam.set_pose(self.poses[i])
        c0 = time.process_time()
        t0 = time.perf_counter()
        img = self.cam.eval_color()
        dt = time.perf_counter() - t0
        dc = time.process_time() - c0
        if not record:
            return dt
        self.times.append(dt)
        self.cpu.append(dc)
        self.last = np.array(img.data, copy=True)
        self.hashes.append(_hash(self.last))
        if self.args.images and i == 1:
            import cv2

            cv2.imwrite(os.path.join(self.args.images, "vtk.png"), self.last[..., 2::-1])
        return dt

    def finish(self) -> dict:
        """The cache-hit Eval, the half-size check; returns the results dict."""
        args, out, last = self.args, self.out, self.last
        t0 = time.perf_counter()
        self.cam.eval_color()  # no pose change: a cache hit
        out["cached_eval_s"] = time.perf_counter() - t0
        out["color_s"] = self.times
        out["color_cpu_s"] = self.cpu
        out["distinct_images"] = len(set(self.hashes))
        out["mean_rgb"] = float(last[..., :3].mean()) if last is not None else None
        out["gl_libraries"] = _gl_libraries()
        if not args.no_size_check:
            VtkReferenceCamera = _vtk().VtkReferenceCamera

            w, h = args.width // 2, args.height // 2
            small = VtkReferenceCamera(
                obj_path=self.obj,
                width=w,
                height=h,
                fov_y_deg=args.fov,
                sun_dir_W=self.sun_W,
                cast_shadows=args.vtk_shadows,
            )
            small.finalize()
            small.render(self.poses[0])
            ts = []
            for X in self.poses[1:4]:
                small.set_pose(X)
                t0 = time.perf_counter()
                small.eval_color()
                ts.append(time.perf_counter() - t0)
            out["size_check"] = {"width": w, "height": h, "color_s_median": _median(ts)}
        return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="default", help="scenario name (default: default)")
    p.add_argument("--frames", type=int, default=10, help="timed frames (after 1 warm-up)")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=960)
    p.add_argument("--fov", type=float, default=45.0, help="vertical field of view (deg)")
    p.add_argument("--tilt", type=float, default=14.0, help="camera pitch down (deg)")
    p.add_argument("--step", type=float, default=0.1, help="camera motion per frame (m)")
    p.add_argument("--no-rover", action="store_true", help="terrain only (no rover meshes)")
    p.add_argument(
        "--engine",
        default="heightfield",
        choices=["heightfield", "raycast"],
        help="Hapke camera engine timed for hapke_fps (default: heightfield)",
    )
    p.add_argument(
        "--reference-frames",
        type=int,
        default=3,
        help="also time this many frames of the raycast reference engine (0: skip)",
    )
    p.add_argument("--no-vtk", action="store_true", help="skip the RenderEngineVtk reference")
    p.add_argument(
        "--warmup",
        type=int,
        default=5,
        help="untimed frames per renderer right before its timed ones (default 5)",
    )
    p.add_argument(
        "--block",
        type=int,
        default=0,
        help="timed frames run in blocks of this many Hapke then VTK frames (default 0: "
        "all Hapke frames, then all VTK frames; 1 alternates frame by frame)",
    )
    p.add_argument("--vtk-shadows", action="store_true", help="VTK shadow mapping on")
    p.add_argument("--no-size-check", action="store_true", help="skip the half-size VTK timing")
    p.add_argument(
        "--tune-malloc",
        action="store_true",
        help="call raycast.tune_malloc_for_large_arrays() first (process-wide glibc tuning)",
    )
    p.add_argument("--images", default=None, help="write hapke.png / vtk.png previews here")
    p.add_argument("--seed", type=int, default=0, help="sensor noise seed")
    p.add_argument("--out", default=None, help="write results JSON here")
    args = p.parse_args(argv)
    if args.out:
        check_output_file(args.out, what="results JSON")
    if args.frames < 5:
        p.error(f"--frames = {args.frames}; at least 5")
    if args.warmup < 0 or args.block < 0:
        p.error(f"--warmup = {args.warmup}, --block = {args.block}; both must be >= 0")
    if args.images:
        os.makedirs(args.images, exist_ok=True)
    t_start = time.perf_counter()
    load_before = _loadavg()
    measure_speed_index, speed_index_line = _speed_index()
    speed = measure_speed_index()
    malloc_tuned = False
    if args.tune_malloc:
        from lunar_drake.render.raycast import tune_malloc_for_large_arrays

        malloc_tuned = tune_malloc_for_large_arrays()

    from lunar_drake import rng
    from lunar_drake.ephemeris.sun_earth import SiteLocation
    from lunar_drake.render import shading
    from lunar_drake.render.camera import CameraConfig, TerrainCameraRenderer
    from lunar_drake.render.lightmap import lightmap
    from lunar_drake.render.terrain_lod import TerrainLOD
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site
    from lunar_drake.systems.ephemeris_source import EphemerisSource
    from lunar_drake.systems.hapke_camera import rover_meshes
    from lunar_drake.systems.lightmap_source import sun_grid_az_el

    # --- scene ------------------------------------------------------------------------
    t0 = time.perf_counter()
    write_terrain_obj = _vtk().write_terrain_obj
    s = load_scenario(scenario_name=args.scenario)
    site_data = load_site(s, progress=False)
    hf, albedo = site_data.heightfield, site_data.albedo
    site_s = time.perf_counter() - t0
    site = SiteLocation(s.site.latitude_deg, s.site.longitude_deg)
    az, el = (
        float(v[0]) for v in sun_grid_az_el(site=site, epoch_utc=s.site.epoch_utc, times_s=[0.0])
    )
    eph = EphemerisSource(site=site, epoch_utc=s.site.epoch_utc, world_frame="polar_grid")
    ec = eph.CreateDefaultContext()
    sun_W = np.asarray(eph.sun_direction_output.Eval(ec), float)
    sun_km = float(eph.sun_distance_output.Eval(ec)[0])
    earth_W = np.asarray(eph.earth_direction_output.Eval(ec), float)
    earth_km = float(eph.earth_distance_output.Eval(ec)[0])
    earth_phase = float(eph.earth_phase_output.Eval(ec)[0])

    model = CameraConfig(
        width=args.width,
        height=args.height,
        fov_y_deg=args.fov,
        shadow_samples=s.sensors.camera.shadow_samples,
        engine=args.engine,
    )
    plant, sg, rover, _diagram, dctx = _rover_plant(s, hf)  # keep the diagram alive
    head = rover.left_camera.body()
    pctx = plant.GetMyContextFromRoot(dctx)
    p0 = rover.left_camera.CalcPoseInWorld(pctx).translation()
    ground0 = float(hf.height(np.array([p0[0]]), np.array([p0[1]]))[0])
    above = float(p0[2]) - ground0
    poses = []
    for i in range(args.frames + 1):
        x = float(p0[0]) + i * args.step
        g = float(hf.height(np.array([x]), np.array([p0[1]]))[0])
        poses.append(camera_pose([x, float(p0[1]), g + above], args.tilt))

    geometry = []
    if not args.no_rover:
        geometry = rover_meshes(
            plant,
            sg,
            rover.model_instance,
            exclude_bodies=[rover.left_camera.body().index(), rover.right_camera.body().index()],
        )
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(dctx))
    dyn = [query.GetPoseInWorld(gid).GetAsMatrix4() for gid, _ in geometry]

    # --- lightmap (baked once, not timed per frame) -----------------------------------
    t0 = time.perf_counter()
    z, res = hf.decimated(max_size=s.lighting.lightmap_max_px)
    lm = lightmap(
        np.asarray(z, np.float32), sun_azimuth_deg=az, sun_elevation_deg=el, resolution_m=res
    )
    lm_sampler = shading.RasterSampler.on_heightfield(lm, hf, outside=1.0)
    bake_s = time.perf_counter() - t0

    # --- LOD mesh (shared by both renderers) ------------------------------------------
    t0 = time.perf_counter()
    lod = TerrainLOD.build(
        hf,
        center_xy=(float(p0[0]), float(p0[1])),
        tile_px=model.tile_px,
        near_radius_m=model.near_radius_m,
    )
    lod_s = time.perf_counter() - t0

    # --- Hapke ------------------------------------------------------------------------
    renderer = TerrainCameraRenderer(
        heightfield=hf, albedo=albedo, model=model, dynamic_meshes=[m for _, m in geometry]
    )
    illum, sun_up = renderer.illumination(
        sun_dir_W=sun_W,
        sun_distance_km=sun_km,
        earth_dir_W=earth_W,
        earth_distance_km=earth_km,
        earth_phase=earth_phase,
    )
    lmap = lm_sampler if sun_up else None
    key = rng.stream_key(args.seed, "bench/render/camera")
    cpu_s = []  # process CPU seconds of every Hapke frame (the timed ones picked below)

    def hapke_frame(i):
        c0 = time.process_time()
        t0 = time.perf_counter()
        sh = renderer.shade(X_WC=poses[i], illumination=illum, dynamic_poses=dyn, lightmap=lmap)
        t1 = time.perf_counter()
        raw = renderer.expose(
            sh,
            exposure_s=model.exposure_s,
            gain=model.gain,
            key=key,
            frame_index=i,
        )
        t2 = time.perf_counter()
        cpu_s.append(time.process_time() - c0)
        return sh, raw, t1 - t0, t2 - t1

    t0 = time.perf_counter()
    hapke_frame(0)
    hapke_first_s = time.perf_counter() - t0

    # --- VTK set-up (its first frame is its warm-up) ------------------------------------
    vtk_bench, vtk, vtk_error, obj_s = None, None, None, None
    tmpdir = tempfile.TemporaryDirectory(prefix="lunar_bench_vtk_")
    if not args.no_vtk:
        try:
            t0 = time.perf_counter()
            V, F = lod.merged()
            surface = np.concatenate(
                [np.arange(t.faces.shape[0]) < t.n_surface_faces for t in lod.tiles]
            )
            obj = write_terrain_obj(
                os.path.join(tmpdir.name, "terrain.obj"),
                V,
                F,
                albedo=albedo,
                bounds=tuple(hf.bounds),
                normal_faces=surface,
            )
            obj_s = time.perf_counter() - t0
            vtk_bench = VtkBench(
                args,
                obj=obj,
                sun_W=sun_W,
                poses=poses,
                scenario=s,
                hf=hf,
                rover_bodies_hidden=[head.name()],
            )
        except Exception as exc:  # VTK may lack an offscreen GL context
            vtk_error = f"{type(exc).__name__}: {exc}"
            traceback.print_exc()

    # --- timed frames: blocks of --block Hapke frames and --block VTK frames in turn, so
    # both see the same machine load (the first frame of a block finds caches cold)
    shade_s, expose_s, total_s, radiance_hashes, hapke_cpu_s = [], [], [], [], []
    sh = raw = None
    block = args.frames if args.block <= 0 else min(args.block, args.frames)
    # each renderer's first block follows --warmup untimed frames of its own (poses 1,
    # 2, ...): the first frames after start-up, or after the other renderer's frames,
    # run slower (caches, heap growth)
    warm = range(1, min(args.warmup, args.frames) + 1)
    for start in range(1, args.frames + 1, block):
        frames = range(start, min(start + block, args.frames + 1))
        for i in warm if start == 1 else ():
            hapke_frame(i)
        for i in frames:
            sh, raw, a, b = hapke_frame(i)
            hapke_cpu_s.append(cpu_s[-1])
            shade_s.append(a)
            expose_s.append(b)
            total_s.append(a + b)
            radiance_hashes.append(_hash(sh.radiance))
        if vtk_bench is not None:
            for i in warm if start == 1 else ():
                vtk_bench.frame(i, record=False)
            for i in frames:
                vtk_bench.frame(i)
    if vtk_bench is not None:
        try:
            vtk = vtk_bench.finish()
        except Exception as exc:
            vtk_error = f"{type(exc).__name__}: {exc}"
            traceback.print_exc()
    vtk_bench = None
    tmpdir.cleanup()
    label = sh.label
    hapke_stats = {
        "sky_fraction": float(np.mean(label == 0)),
        "rover_fraction": float(np.mean(label == 2)),
        "mean_i_over_f": float(sh.radiance[label > 0].mean()) if (label > 0).any() else 0.0,
        "mean_raw_code": float(raw.mean()),
        "distinct_images": len(set(radiance_hashes)),
    }
    if args.images:
        import cv2

        from lunar_drake.render import sensor as sensor_mod

        prev = sensor_mod.to_preview_8bit(raw, params=renderer.sensor)
        cv2.imwrite(os.path.join(args.images, "hapke.png"), prev)

    # Second pass: the same frames with the camera module's trace() and shade() wrapped
    # in timers (whatever else TerrainCameraRenderer.shade does is "other").
    for i in warm:  # after the VTK frames: warm up again
        hapke_frame(i)
    split = split_frames(renderer, poses, illum, dyn, lmap, args.frames, args.engine)
    trace_s, split_shade_s, other_s = split["trace"], split["shade"], split["other"]
    split_same = split["hashes"] == radiance_hashes if split["hashes"] else None

    hapke_fps = 1.0 / _median(total_s)

    # --- the raycast reference engine on the same frames --------------------------------
    reference = None
    if args.engine != "raycast" and args.reference_frames > 0:
        ref = TerrainCameraRenderer(
            heightfield=hf,
            albedo=albedo,
            model=dc.replace(model, engine="raycast"),
            dynamic_meshes=[m for _, m in geometry],
        )
        ref.shade(X_WC=poses[0], illumination=illum, dynamic_poses=dyn, lightmap=lmap)
        ref_s, agree = [], None
        for i in range(1, min(args.reference_frames, args.frames) + 1):
            t0 = time.perf_counter()
            rs = ref.shade(X_WC=poses[i], illumination=illum, dynamic_poses=dyn, lightmap=lmap)
            ref.expose(rs, exposure_s=model.exposure_s, gain=model.gain, key=key, frame_index=i)
            ref_s.append(time.perf_counter() - t0)
            if i == 1:
                fs = renderer.shade(
                    X_WC=poses[i], illumination=illum, dynamic_poses=dyn, lightmap=lmap
                )
                both = (fs.label == rs.label) & (rs.label > 0)
                rel = np.abs(fs.radiance[both] - rs.radiance[both]) / np.maximum(
                    rs.radiance[both], 1e-4
                )
                agree = {
                    "label_agreement": float((fs.label == rs.label).mean()),
                    "radiance_rel_diff_median": float(np.median(rel)),
                    "radiance_rel_diff_p90": float(np.quantile(rel, 0.9)),
                    "mean_i_over_f": [
                        float(fs.radiance[both].mean()),
                        float(rs.radiance[both].mean()),
                    ],
                }
        reference = {
            "engine": "raycast",
            "total_s_median": _median(ref_s),
            "fps": 1.0 / _median(ref_s),
            "frames": len(ref_s),
            "agreement_frame_1": agree,
        }

    vtk_fps = 1.0 / _median(vtk["color_s"]) if vtk else None
    ratio = hapke_fps / vtk_fps if vtk_fps else None
    vtk_cpu = _median(vtk["color_cpu_s"]) if vtk else None
    hapke_cpu = _median(hapke_cpu_s)
    cpu_ratio = vtk_cpu / hapke_cpu if vtk_cpu and hapke_cpu else None
    load_after = _loadavg()

    timings = {
        "hapke_shade_s": _median(shade_s),
        "hapke_expose_s": _median(expose_s),
        "hapke_total_s": _median(total_s),
        "hapke_cpu_s": hapke_cpu,
        "vtk_cpu_s": vtk_cpu,
        "hapke_trace_s": _median(trace_s),
        "hapke_shade_only_s": _median(split_shade_s),
        "hapke_shade_other_s": _median(other_s),
        "hapke_first_frame_s": hapke_first_s,
        "vtk_color_s": _median(vtk["color_s"]) if vtk else None,
        "vtk_first_frame_s": vtk["first_frame_s"] if vtk else None,
        "vtk_cached_eval_s": vtk["cached_eval_s"] if vtk else None,
        "vtk_half_size_color_s": (vtk.get("size_check") or {}).get("color_s_median")
        if vtk
        else None,
        "vtk_setup_s": vtk["setup_s"] if vtk else None,
        "obj_write_s": obj_s,
        "site_load_s": site_s,
        "lod_build_s": lod_s,
    }
    result = {
        "hapke_fps": hapke_fps,
        "vtk_fps": vtk_fps,
        "ratio": ratio,
        "cpu_ratio": cpu_ratio,
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
        "load_average": {"before": load_before, "after": load_after},
        "block": block,
        "warmup": args.warmup,
        "goals": GOALS,
        "goals_met": {
            "hapke_fps": hapke_fps >= GOALS["hapke_fps"],
            "ratio": None if ratio is None else ratio >= GOALS["ratio"],
        },
        "frames": args.frames,
        "width": args.width,
        "height": args.height,
        "fov_y_deg": args.fov,
        "triangles": int(lod.triangle_count),
        "skirt_triangles": int(lod.stats.skirt_triangles),
        "rover_triangles": int(sum(m.faces.shape[0] for _, m in geometry)),
        "timings": timings,
        "per_frame_s": {
            "hapke_shade": shade_s,
            "hapke_expose": expose_s,
            "hapke_trace": trace_s,
            "hapke_shade_only": split_shade_s,
            "hapke_shade_other": other_s,
            "vtk_color": vtk["color_s"] if vtk else [],
            "hapke_cpu": hapke_cpu_s,
            "vtk_cpu": vtk["color_cpu_s"] if vtk else [],
        },
        "split_pass_identical": split_same,
        "engine": args.engine,
        "reference_engine": reference,
        "lightmap_bake_s": bake_s,
        "lightmap_px": list(np.asarray(z).shape),
        "scene": {
            "scenario": args.scenario,
            "camera_start_W": [float(v) for v in poses[0][:3, 3]],
            "camera_above_ground_m": above,
            "tilt_deg": args.tilt,
            "step_m": args.step,
            "sun_azimuth_deg": az,
            "sun_elevation_deg": el,
            "earth_direction_W": earth_W.tolist(),
            "earth_phase": earth_phase,
            "rover": not args.no_rover,
            "hapke": hapke_stats,
        },
        "vtk": {
            "mesh": "TerrainLOD.merged() (same triangles as the Hapke ray caster, skirts "
            "included), albedo texture, vertex normals from surface faces",
            "light": "one directional Sun light" + (" with shadow map" if args.vtk_shadows else ""),
            "cast_shadows": bool(args.vtk_shadows),
            "distinct_images": vtk["distinct_images"] if vtk else None,
            "mean_rgb": vtk["mean_rgb"] if vtk else None,
            "size_check": vtk.get("size_check") if vtk else None,
            "gl_libraries": vtk["gl_libraries"] if vtk else None,
            "error": vtk_error,
        },
        "malloc_tuned": malloc_tuned,
        "machine": os.cpu_count(),
        "platform": {"python": sys.version.split()[0], "platform": platform.platform()},
        "wall_s": time.perf_counter() - t_start,
    }

    def ms(v):
        return "-" if v is None else f"{1e3 * v:8.1f}"

    print(
        f"{args.scenario}: {args.width}x{args.height}, fov {args.fov} deg, "
        f"{lod.triangle_count} LOD triangles (+{result['rover_triangles']} rover), "
        f"Sun az {az:.1f} el {el:.2f} deg, {args.frames} frames, {os.cpu_count()} CPUs"
    )
    print(f"{'stage (median), engine ' + args.engine:<34s} {'ms':>8s}")
    rows = [
        ("hapke shade (visibility + shading)", timings["hapke_shade_s"]),
        ("  visibility (ray cast / DEM march)", timings["hapke_trace_s"]),
        ("  shading kernel / numpy shade", timings["hapke_shade_only_s"]),
        ("  other (rover, shadow rays, ...)", timings["hapke_shade_other_s"]),
        ("hapke expose (sensor)", timings["hapke_expose_s"]),
        ("hapke total", timings["hapke_total_s"]),
        ("hapke first frame (LOD + BVH)", timings["hapke_first_frame_s"]),
        ("vtk colour image", timings["vtk_color_s"]),
        (
            f"vtk colour image {args.width // 2}x{args.height // 2}",
            timings["vtk_half_size_color_s"],
        ),
        ("vtk Eval without pose change", timings["vtk_cached_eval_s"]),
        ("vtk first frame", timings["vtk_first_frame_s"]),
    ]
    for name, v in rows:
        print(f"{name:<34s} {ms(v):>8s}")
    print(
        f"lightmap bake {bake_s:.2f} s ({z.shape[0]}x{z.shape[1]} px); OBJ write "
        + ("-" if obj_s is None else f"{obj_s:.2f} s")
    )
    goal = f"(goal >= {GOALS['hapke_fps']:g})"
    print(
        f"hapke_fps {hapke_fps:.2f} {goal}; vtk_fps "
        + ("null" if vtk_fps is None else f"{vtk_fps:.2f}")
        + "; ratio "
        + ("null" if ratio is None else f"{ratio:.2f}")
        + f" (goal >= {GOALS['ratio']:g}); blocks of {block} frames"
    )
    print(
        "CPU s per frame (all threads): hapke "
        + ("-" if hapke_cpu is None else f"{hapke_cpu:.3f}")
        + ", vtk "
        + ("-" if vtk_cpu is None else f"{vtk_cpu:.3f}")
        + "; cpu_ratio "
        + ("null" if cpu_ratio is None else f"{cpu_ratio:.2f}")
        + f"; load average {load_before} -> {load_after}"
    )
    print(speed_index_line(speed))
    if reference:
        ag = reference["agreement_frame_1"] or {}
        print(
            f"raycast reference engine: {1e3 * reference['total_s_median']:.1f} ms/frame "
            f"({reference['fps']:.2f} fps, {reference['frames']} frames); labels agree "
            f"{100 * ag.get('label_agreement', float('nan')):.2f}%, radiance rel. diff "
            f"median {100 * ag.get('radiance_rel_diff_median', float('nan')):.2f}% "
            f"p90 {100 * ag.get('radiance_rel_diff_p90', float('nan')):.2f}%"
        )
    if vtk_error:
        print(f"VTK failed: {vtk_error}")
    if args.out:
        atomic_write_text(args.out, json.dumps(result, indent=2), what="results JSON")
    return 0


if __name__ == "__main__":
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("render.py")  # as the lunar-drake program runs (lunar_drake/allocator.py)
    sys.exit(main())
