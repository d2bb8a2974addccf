"""WheelTracks: grooves left by the rover's wheels in the regolith (paper section 5,
"Wheel Tracks"), as a sparse groove-depth raster for the renderer's bump mapping."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render.tracks import TrackProfile, TrackRaster
from lunar_drake.systems.leaf import Leaf
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS

_NF = len(WHEEL_STATE_FIELDS)
_SINK = WHEEL_STATE_FIELDS.index("sinkage_m")
_OFF = WHEEL_STATE_FIELDS.index("off_terrain")
#: Per-wheel columns of the ``last_contact`` discrete state.
LAST_CONTACT_FIELDS = ("x_m", "y_m", "sinkage_m", "arc_length_m", "in_contact")
_NL = len(LAST_CONTACT_FIELDS)


class WheelTracks(Leaf):
    """Stamps each wheel's groove into a :class:`~lunar_drake.render.tracks.TrackRaster`
    at a fixed period.

    .. pydrake_system::

        name: WheelTracks
        input_ports:
        - body_poses
        - wheel_state
        output_ports:
        - track_depth

    Inputs: ``body_poses`` is the plant's ``get_body_poses_output_port()`` (list of X_WB
    indexed by BodyIndex; W = the site frame, wheel centre = body origin);
    ``wheel_state`` is :class:`~lunar_drake.systems.wheel_regolith_contact.
    WheelRegolithContact`'s ``wheel_state`` (``len(WHEEL_STATE_FIELDS)`` values per
    wheel, in ``wheel_bodies`` order).

    Every ``update_period_s`` (from t = 0; periodic unrestricted update) each wheel in
    contact -- ``sinkage_m > min_sinkage_m`` and not ``off_terrain`` -- stamps the
    segment from its previous contact point to the current one, the contact point being
    the wheel centre's (x, y) (the groove is drawn under the centre: on a slope of
    angle a the true contact patch is up to ``r sin a`` further along the slope), with
    depth varying linearly from the previous to the current sinkage (m) and the tread
    width ``wheel_width_m``. A wheel that was not in contact at the previous update
    (or moved more than ``max_jump_m``, e.g. a teleport) starts a new groove with a
    disk at its current point.

    State: abstract ``tracks`` (the TrackRaster; a new raster is stored on each update,
    copy-on-write, never mutated in place) and discrete ``last_contact`` (per wheel
    ``LAST_CONTACT_FIELDS``: last contact x, y (m, site), sinkage (m), arc length of
    its groove (m, grouser phase), in-contact flag 0/1).

    Output ``track_depth`` (abstract, no feedthrough): the state's TrackRaster, a
    callable ``(x, y) -> groove depth (m, positive down)`` in site coordinates,
    vectorized (float32) -- pass it as ``shade(track_depth=...)`` or to
    ``HapkeCamera``'s ``track_depth`` input. The value is a snapshot: later updates
    never change it, so a renderer may keep and call it while the simulation goes on.

    Args:
        wheel_bodies: BodyIndex (or int) of each wheel, in ``wheel_state`` order.
        wheel_width_m: tread width (m). cell_m: raster cell size (m).
        update_period_s: stamping period (s). min_sinkage_m: sinkage (m) above which a
            wheel marks the soil.
        profile: groove cross-section and grouser pattern (:class:`TrackProfile`).
        max_jump_m: contact-point displacement (m) between updates beyond which the
            groove is broken rather than joined.
        tile_cells: raster tile side (cells).
    """

    def __init__(
        self,
        *,
        wheel_bodies,
        wheel_width_m: float,
        cell_m: float = 0.02,
        update_period_s: float = 0.1,
        min_sinkage_m: float = 0.001,
        profile: TrackProfile | None = None,
        max_jump_m: float = 1.0,
        tile_cells: int = 256,
    ):
        super().__init__()
        self._wheels = [int(b) for b in wheel_bodies]
        if not self._wheels:
            raise ConfigError(f"wheel_bodies = {wheel_bodies!r}; a non-empty list is required")
        if not (math.isfinite(wheel_width_m) and wheel_width_m > 0.0):
            raise OutOfRangeError(f"wheel_width_m = {wheel_width_m!r}; must be finite and > 0 m")
        if not (math.isfinite(update_period_s) and update_period_s > 0.0):
            raise OutOfRangeError(f"update_period_s = {update_period_s!r}; must be > 0 s")
        if not (math.isfinite(min_sinkage_m) and min_sinkage_m >= 0.0):
            raise OutOfRangeError(f"min_sinkage_m = {min_sinkage_m!r}; must be >= 0 m")
        if not max_jump_m > 0.0:
            raise OutOfRangeError(f"max_jump_m = {max_jump_m!r}; must be > 0 m")
        self._width = float(wheel_width_m)
        self._min_sink = float(min_sinkage_m)
        self._profile = TrackProfile() if profile is None else profile
        self._max_jump = float(max_jump_m)
        n = len(self._wheels)
        blank = TrackRaster(cell_m=cell_m, tile_cells=tile_cells)
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.wheel_state_input = self.DeclareVectorInputPort("wheel_state", _NF * n)
        self._tracks = self.DeclareAbstractState(AbstractValue.Make(blank))
        self._last = self.DeclareDiscreteState(_NL * n)
        self.DeclarePeriodicUnrestrictedUpdateEvent(float(update_period_s), 0.0, self._update)
        self.track_depth_output = self.DeclareStateOutputPort("track_depth", self._tracks)

    def tracks(self, context) -> TrackRaster:
        """The TrackRaster held in this system's ``context``."""
        return context.get_abstract_state(self._tracks).get_value()

    def _update(self, context, state):
        poses = self.body_poses_input.Eval(context)
        ws = np.asarray(self.wheel_state_input.Eval(context), dtype=np.float64).reshape(-1, _NF)
        last = np.asarray(context.get_discrete_state(self._last).value(), dtype=np.float64)
        last = last.reshape(-1, _NL).copy()
        raster: TrackRaster | None = None
        for k, b in enumerate(self._wheels):
            p = poses[b].translation()
            sink = float(ws[k, _SINK])
            touching = sink > self._min_sink and ws[k, _OFF] < 0.5 and np.isfinite(p[:2]).all()
            if not touching:
                last[k, 4] = 0.0
                continue
            x, y = float(p[0]), float(p[1])
            lx, ly, lsink, s0, was = last[k]
            step = math.hypot(x - lx, y - ly)
            if was < 0.5 or step > self._max_jump:
                lx, ly, lsink, step = x, y, sink, 0.0
            if raster is None:
                raster = self.tracks(context).copy()
            raster.stamp_segment(
                (lx, ly),
                (x, y),
                width_m=self._width,
                depth_m=lsink,
                depth_end_m=sink,
                s0_m=s0,
                profile=self._profile,
            )
            last[k] = (x, y, sink, s0 + step, 1.0)
        state.get_mutable_discrete_state(self._last).SetFromVector(last.reshape(-1))
        if raster is not None:
            state.get_mutable_abstract_state(self._tracks).set_value(raster)
