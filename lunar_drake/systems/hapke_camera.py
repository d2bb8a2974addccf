"""HapkeCamera: a stereo (or single) camera rendering the Hapke-lit terrain and the rover."""

from __future__ import annotations

import dataclasses as dc
import functools
from concurrent.futures import Future, ThreadPoolExecutor

import numba
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject, Role
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector
from pydrake.systems.sensors import ImageDepth32F, ImageGrey8U, ImageLabel16I

from lunar_drake import rng
from lunar_drake.errors import LunarDrakeError, OutOfRangeError, SimulationError
from lunar_drake.render import sensor as sensor_mod
from lunar_drake.render.camera import AU_KM, TerrainCameraRenderer
from lunar_drake.render.raycast import DynamicMesh
from lunar_drake.render.row_queue import workers
from lunar_drake.render.shapes import shape_mesh
from lunar_drake.sensors.sampling import delivered_index, samples_in_flight
from lunar_drake.systems.leaf import Leaf


@dc.dataclass(frozen=True)
class CameraMount:
    """A camera rigidly attached to a plant body: name, BodyIndex and X_BC (Drake camera
    convention: +z optical axis, +x right, +y down)."""

    name: str
    body_index: object
    X_BC: RigidTransform


@dc.dataclass(frozen=True, eq=False)
class Frame:
    """One camera's frame: raw uint16 (12-bit codes), depth (m), label (0 sky, 1 terrain,
    2 rover), I/F radiance, capture time and index, and the 8-bit ``preview`` of the raw
    codes through ``sensor`` (computed on first use: a mission that never shows or writes
    its frames never pays for it; blank without a sensor). Immutable (kept in abstract
    state without copies)."""

    raw: np.ndarray
    depth: np.ndarray
    label: np.ndarray
    radiance: np.ndarray
    time_s: float
    index: int
    sensor: object = None

    @functools.cached_property
    def preview(self) -> np.ndarray:
        if self.sensor is None:
            return np.zeros(self.raw.shape, np.uint8)
        return sensor_mod.to_preview_8bit(
            self.raw, params=self.sensor, auto=False,
            full_scale=float(2**self.sensor.adc_bits - 1),
        )  # fmt: skip

    def __deepcopy__(self, memo):
        return self


class PendingFrames:
    """The frames of one capture (camera name -> :class:`Frame`), rendered on the
    camera's worker thread: ``index`` and ``time_s`` at once, the frames on first use
    (:meth:`frames` waits for them; an error in the render is raised there). Kept in
    abstract state without copies."""

    __slots__ = ("_future", "index", "time_s")

    def __init__(self, *, index: int, time_s: float, future: Future):
        self.index = int(index)
        self.time_s = float(time_s)
        self._future = future

    def frames(self) -> dict:
        return self._future.result()

    def __deepcopy__(self, memo):
        return self


def _entry_index(entry) -> int:
    """The frame index of a ring entry (a dict of Frames or PendingFrames)."""
    if isinstance(entry, PendingFrames):
        return entry.index
    return next(iter(entry.values())).index


@functools.cache
def concurrent_kernels_safe() -> bool:
    """Whether numba's threading layer lets two Python threads launch parallel kernels
    at once (OpenMP and TBB do; the ``workqueue`` fallback aborts the process)."""
    _probe(np.zeros(4), workers())  # a parallel kernel selects the layer
    return numba.threading_layer() != "workqueue"


@numba.njit(parallel=True, cache=True)
def _probe(a, nwork):  # pragma: no cover - compiled
    for i in numba.prange(nwork):
        a[i % a.size] = i


def rover_meshes(plant, scene_graph, model_instance, *, albedo: float = 0.5, exclude_bodies=()):
    """Illustration geometry of a model instance as (GeometryId, DynamicMesh) pairs,
    leaving out ``exclude_bodies`` (e.g. the camera head the cameras sit inside)."""
    inspector = scene_graph.model_inspector()
    skip = {int(b) for b in exclude_bodies}
    out = []
    for b in plant.GetBodyIndices(model_instance):
        if int(b) in skip:
            continue
        fid = plant.GetBodyFrameIdIfExists(b)
        if fid is None:
            continue
        for gid in inspector.GetGeometries(fid, Role.kIllustration):
            mesh = shape_mesh(inspector.GetShape(gid))
            if mesh is None:
                continue
            out.append((gid, DynamicMesh(vertices=mesh[0], faces=mesh[1], albedo=albedo)))
    return out


class HapkeCamera(Leaf):
    """Renders every mounted camera at ``rate_hz`` (periodic unrestricted update from
    t = 0) and holds the frames in its state, so outputs are cheap and deterministic.
    Frame k (taken at t_k = k / rate_hz) is delivered at t_k + ``delay_s``: the outputs
    show the latest delivered frame (blank, index -1, before the first), as every
    sensor does (:class:`~lunar_drake.systems.sampled_sensor.SampledSensor`).

    With ``delay_s > 0`` a frame is rendered on the camera's own worker thread while the
    simulation goes on (its inputs -- poses, lights, the lightmap, a copy of the tracks
    near the camera -- are taken at the capture instant, so the result is the same
    bytes as a render in place), and the outputs wait for it only if it is not done by
    its delivery; the worker runs numba's kernels on every core, which the operating
    system shares with the simulation. With ``delay_s = 0`` (or where numba's threading
    layer cannot run kernels from two threads) it renders in the update itself.

    .. pydrake_system::

        name: HapkeCamera
        input_ports:
        - body_poses
        - geometry_query
        - sun_direction_W
        - sun_distance_km
        - earth_direction_W
        - earth_distance_km
        - earth_phase
        - exposure (optional)
        - lightmap (optional)
        - track_depth (optional)
        output_ports:
        - <name>.raw
        - <name>.preview
        - <name>.depth
        - <name>.label

    ``exposure`` is (exposure_s, gain); unconnected, the CameraConfig defaults are used.
    Exposure <= 0 or gain <= 0 raises OutOfRangeError. ``lightmap`` / ``track_depth``
    are abstract callables ``(x, y) -> value`` in site coordinates (lit fraction, groove
    depth in m). Sensor noise is keyed by (seed, system name, camera, frame index).
    ``<name>.raw`` is an abstract uint16 numpy array (12-bit codes); preview, depth and
    label are Drake images. Vectors are in the world (site) frame.

    Args:
        renderer: a TerrainCameraRenderer (shared by the mounts).
        mounts: CameraMount list (e.g. left and right of a stereo pair).
        rover_geometry: (GeometryId, DynamicMesh) pairs drawn and shadowed from
            SceneGraph poses. rate_hz: frame rate. seed, name: noise stream.
        lights: up to 4 (BodyIndex, p_BL, d_BL, SpotLight template) lamps carried by plant
            bodies; the template's position/direction are replaced each frame.
    """

    def __init__(
        self,
        *,
        renderer: TerrainCameraRenderer,
        mounts,
        rover_geometry=(),
        rate_hz: float = 1.0,
        delay_s: float = 0.0,
        seed: int = 0,
        name: str = "camera",
        lights=(),
    ):
        super().__init__()
        if not 0 < rate_hz <= 100:
            raise OutOfRangeError(f"rate_hz = {rate_hz!r}; allowed (0, 100] Hz")
        if not 0 <= delay_s <= 3600:
            raise OutOfRangeError(f"delay_s = {delay_s!r}; allowed [0, 3600] s")
        self._delay = float(delay_s)
        self._depth = samples_in_flight(rate_hz=rate_hz, delay_s=delay_s)
        self._r = renderer
        self._pool = None  # the worker thread, started by the first deferred render
        self._mounts = list(mounts)
        self._gids = [g for g, _ in rover_geometry]
        self._lights = list(lights)
        self._rate = float(rate_hz)
        self._keys = {m.name: rng.stream_key(seed, f"{name}/{m.name}") for m in self._mounts}
        m = renderer.model
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.geometry_query_input = self.DeclareAbstractInputPort(
            "geometry_query", AbstractValue.Make(QueryObject())
        )
        self.sun_direction_input = self.DeclareVectorInputPort("sun_direction_W", 3)
        self.sun_distance_input = self.DeclareVectorInputPort("sun_distance_km", 1)
        self.earth_direction_input = self.DeclareVectorInputPort("earth_direction_W", 3)
        self.earth_distance_input = self.DeclareVectorInputPort("earth_distance_km", 1)
        self.earth_phase_input = self.DeclareVectorInputPort("earth_phase", 1)
        self.exposure_input = self.DeclareVectorInputPort("exposure", 2)
        self.lightmap_input = self.DeclareAbstractInputPort(
            "lightmap", AbstractValue.Make(object())
        )
        self.track_depth_input = self.DeclareAbstractInputPort(
            "track_depth", AbstractValue.Make(object())
        )
        blank = {mt.name: _blank(m.width, m.height) for mt in self._mounts}
        # State: the frames in flight, newest first (one set per sample).
        self._state = self.DeclareAbstractState(AbstractValue.Make((blank,) * self._depth))
        self._blank = blank
        prereq = {self.all_state_ticket()}
        if self._depth > 1:
            prereq.add(self.time_ticket())
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / self._rate, 0.0, self._update)
        self.ports = {}
        for mt in self._mounts:
            n = mt.name
            self.ports[f"{n}.raw"] = self.DeclareAbstractOutputPort(
                f"{n}.raw",
                lambda: AbstractValue.Make(np.zeros((1, 1), np.uint16)),
                lambda c, o, n=n: o.set_value(self._frames(c)[n].raw),
                prerequisites_of_calc=prereq,
            )
            self.ports[f"{n}.preview"] = self.DeclareAbstractOutputPort(
                f"{n}.preview",
                lambda: AbstractValue.Make(ImageGrey8U(m.width, m.height)),
                lambda c, o, n=n: self._to_image(o, ImageGrey8U, self._frames(c)[n].preview),
                prerequisites_of_calc=prereq,
            )
            self.ports[f"{n}.depth"] = self.DeclareAbstractOutputPort(
                f"{n}.depth",
                lambda: AbstractValue.Make(ImageDepth32F(m.width, m.height)),
                lambda c, o, n=n: self._to_image(o, ImageDepth32F, self._frames(c)[n].depth),
                prerequisites_of_calc=prereq,
            )
            self.ports[f"{n}.label"] = self.DeclareAbstractOutputPort(
                f"{n}.label",
                lambda: AbstractValue.Make(ImageLabel16I(m.width, m.height)),
                lambda c, o, n=n: self._to_image(o, ImageLabel16I, self._frames(c)[n].label),
                prerequisites_of_calc=prereq,
            )
        self.frame_index_output = self.DeclareVectorOutputPort(
            "frame_index",
            BasicVector(1),
            lambda c, o: o.SetFromVector([_entry_index(self._delivered(c))]),
            prerequisites_of_calc=prereq,
        )

    def _delivered(self, context):
        """The ring entry delivered by the context's time (a dict camera name -> Frame,
        or PendingFrames)."""
        ring = context.get_abstract_state(self._state).get_value()
        if self._depth == 1:
            return ring[0]
        k = delivered_index(context.get_time(), rate_hz=self._rate, delay_s=self._delay)
        if k < 0:
            return self._blank
        newest = _entry_index(ring[0])
        return ring[min(max(newest - k, 0), self._depth - 1)]

    def _frames(self, context) -> dict:
        """The frames delivered by the context's time (camera name -> Frame)."""
        entry = self._delivered(context)
        return entry.frames() if isinstance(entry, PendingFrames) else entry

    @staticmethod
    def _to_image(output, cls, array):
        img = output.get_mutable_value()
        if img.width() != array.shape[1] or img.height() != array.shape[0]:
            img.resize(array.shape[1], array.shape[0])
        img.mutable_data[:, :, 0] = array

    def frame(self, context, name: str) -> Frame:
        """The latest Frame of camera ``name`` in this system's context."""
        return self._frames(context)[name]

    def _optional(self, port, context):
        return port.Eval(context) if port.HasValue(context) else None

    def _update(self, context, state):
        t = context.get_time()
        index = round(t * self._rate)
        poses = self.body_poses_input.Eval(context)
        query = self.geometry_query_input.Eval(context)
        sun = self.sun_direction_input.Eval(context)
        sun_d = float(self.sun_distance_input.Eval(context)[0]) or AU_KM
        earth = self.earth_direction_input.Eval(context)
        earth_d = float(self.earth_distance_input.Eval(context)[0]) or 384_400.0
        phase = float(self.earth_phase_input.Eval(context)[0])
        expo = self._optional(self.exposure_input, context)
        model = self._r.model
        exposure_s, gain = (
            (model.exposure_s, model.gain) if expo is None else (float(expo[0]), float(expo[1]))
        )
        if not exposure_s > 0:
            raise OutOfRangeError(f"camera exposure = {exposure_s!r} s; must be > 0")
        if not gain > 0:
            raise OutOfRangeError(f"camera gain = {gain!r}; must be > 0")
        lightmap = self._optional(self.lightmap_input, context)
        tracks_in = self._optional(self.track_depth_input, context)
        spots = []
        for b, p_BL, d_BL, tmpl in self._lights:
            X_WB = poses[int(b)]
            spots.append(
                dc.replace(
                    tmpl,
                    position_W=tuple(X_WB.multiply(p_BL)),
                    direction_W=tuple(X_WB.rotation().multiply(d_BL)),
                )
            )
        illum, sun_up = self._r.illumination(
            sun_dir_W=sun,
            sun_distance_km=sun_d,
            earth_dir_W=earth if np.any(earth) else None,
            earth_distance_km=earth_d,
            earth_phase=phase,
            spotlights=spots,
        )
        dyn = [query.GetPoseInWorld(g).GetAsMatrix4() for g in self._gids]
        X_WCs = [poses[int(mt.body_index)].multiply(mt.X_BC) for mt in self._mounts]
        # one track window for the rig (its cameras are centimetres apart), 1 m wider
        centre = np.mean([X.translation() for X in X_WCs], axis=0)
        spread = max(float(np.linalg.norm(X.translation() - centre)) for X in X_WCs)
        tracks = self._track_sampler(tracks_in, centre, half_m=25.0 + spread + 1.0)
        for mt, X_WC in zip(self._mounts, X_WCs, strict=True):
            self._check_above_terrain(mt.name, X_WC.translation(), t)
        render = functools.partial(
            self._render,
            X_WCs=X_WCs,
            illum=illum,
            sun_up=sun_up,
            dyn=dyn,
            lightmap=lightmap,
            tracks=tracks,
            exposure_s=exposure_s,
            gain=gain,
            index=index,
            t=t,
        )
        if self._delay > 0.0 and concurrent_kernels_safe():
            if self._pool is None:
                # numba's kernels run on every core from the worker too: while the
                # simulation waits for a frame, both render; while it runs, the OS shares
                # them (all but one core left frames late: measured in docs/design.md)
                self._pool = ThreadPoolExecutor(1, thread_name_prefix="lunar_drake.camera")
            entry = PendingFrames(index=index, time_s=t, future=self._pool.submit(render))
        else:
            entry = render()
        ring = context.get_abstract_state(self._state).get_value()
        state.get_mutable_abstract_state(self._state).set_value((entry, *ring[:-1]))

    def _render(self, *, X_WCs, illum, sun_up, dyn, lightmap, tracks, exposure_s, gain, index, t):
        """The frames of one capture (camera name -> Frame) from inputs taken at its
        instant; touches no Context (it may run on the worker thread)."""
        frames = {}
        for mt, X_WC in zip(self._mounts, X_WCs, strict=True):
            shaded = self._r.shade(
                X_WC=X_WC,
                illumination=illum,
                dynamic_poses=dyn,
                lightmap=lightmap if sun_up else None,
                track_depth=tracks,
            )
            raw = self._r.expose(
                shaded,
                exposure_s=exposure_s,
                gain=gain,
                key=self._keys[mt.name],
                frame_index=index,
            )
            depth = np.where(np.isfinite(shaded.depth), shaded.depth, np.inf).astype(np.float32)
            frames[mt.name] = Frame(
                raw=raw,
                depth=depth,
                label=shaded.label.astype(np.int16),
                radiance=shaded.radiance,
                time_s=t,
                index=index,
                sensor=self._r.sensor,
            )
        return frames

    @staticmethod
    def _track_sampler(tracks, p, half_m: float = 25.0):
        """A RasterSampler of the wheel-track raster near the camera (grooves farther than
        ``half_m`` are sub-pixel), or the callable itself if it is not a TrackRaster."""
        if tracks is None or not hasattr(tracks, "window"):
            return tracks
        if tracks.tile_count == 0:
            return None
        from lunar_drake.render.shading import RasterSampler

        # only the tiles with tracks (and a margin of zeros): the same values and
        # gradients as the whole window, a fraction of its cells
        window = tracks.tracked_window(
            left=p[0] - half_m, bottom=p[1] - half_m, right=p[0] + half_m, top=p[1] + half_m
        )
        if window is None:
            return None
        return RasterSampler(window[0], bounds=window[1], outside=0.0)

    def _check_above_terrain(self, name: str, p, t: float) -> None:
        hf = self._r.heightfield
        b = hf.bounds
        if b.left <= p[0] <= b.right and b.bottom <= p[1] <= b.top:
            try:
                z = float(hf.height(np.array([p[0]]), np.array([p[1]]))[0])
            except LunarDrakeError:
                return
            if p[2] <= z:
                raise SimulationError(
                    f"camera {name!r} at ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) m is inside the "
                    f"terrain (ground at {z:.2f} m) at t = {t:.2f} s"
                )


def _blank(w: int, h: int) -> Frame:
    return Frame(
        raw=np.zeros((h, w), np.uint16),
        depth=np.full((h, w), np.inf, np.float32),
        label=np.zeros((h, w), np.int16),
        radiance=np.zeros((h, w), np.float32),
        time_s=-1.0,
        index=-1,
    )
