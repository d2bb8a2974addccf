"""Wheel tracks: the TrackRaster core and the WheelTracks LeafSystem (paper section 5)."""

from __future__ import annotations

import copy
import itertools
import math

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from scipy.interpolate import RegularGridInterpolator

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render import shading as sh
from lunar_drake.render.tracks import TrackProfile, TrackRaster
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS
from lunar_drake.systems.wheel_tracks import LAST_CONTACT_FIELDS, WheelTracks

C = 0.02  # cell (m)


def _cells(r: TrackRaster, left, bottom, right, top):
    """Cell values (north-up) and their centre coordinates (site m)."""
    v, (l, _, _, t) = r.window(left=left, bottom=bottom, right=right, top=top)
    xc = l + (np.arange(v.shape[1]) + 0.5) * r.cell_m
    yc = t - (np.arange(v.shape[0]) + 0.5) * r.cell_m
    X, Y = np.meshgrid(xc, yc)
    return v, X, Y


def _seg_dist(X, Y, p0, p1):
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    L2 = float(d @ d)
    t = (
        np.zeros_like(X)
        if L2 == 0
        else np.clip(((X - p0[0]) * d[0] + (Y - p0[1]) * d[1]) / L2, 0, 1)
    )
    return np.hypot(X - p0[0] - t * d[0], Y - p0[1] - t * d[1]), t


def _profile(dist, half, edge):
    """Independent statement of the documented cross profile."""
    inner = half - edge
    out = np.where(dist <= inner, 1.0, 0.5 * (1 + np.cos(np.pi * (dist - inner) / edge)))
    return np.where(dist >= half, 0.0, out)


# ----------------------------------------------------------------------------------------
# Core
# ----------------------------------------------------------------------------------------
def test_straight_segment_groove_with_rounded_edges_and_caps():
    r = TrackRaster(cell_m=C)
    p0, p1, w, d = (1.003, 1.011), (2.004, 1.011), 0.2, 0.03
    r.stamp_segment(p0, p1, width_m=w, depth_m=d)
    v, X, Y = _cells(r, 0.7, 0.7, 2.3, 1.3)
    dist, _ = _seg_dist(X, Y, p0, p1)
    half, edge = 0.1, max(0.15 * 0.1, C)  # the roll-off is never narrower than a cell
    assert (v[dist <= half - edge] == np.float32(d)).all()
    assert (v[dist >= half] == 0).all()
    band = (dist > half - edge) & (dist < half)
    assert band.sum() > 50  # the rounded edge is resolved by real cells
    assert ((v[band] > 0) & (v[band] < d)).all()
    np.testing.assert_allclose(v, d * _profile(dist, half, edge), atol=1e-8)
    # lookups: centre line at full depth, 0 beside the tread and beyond the round ends
    xs = np.linspace(1.05, 1.95, 50)
    np.testing.assert_array_equal(r.depth_at(xs, np.full(50, 1.011)), np.float32(d))
    assert (r.depth_at(xs, np.full(50, 1.011 + 0.13)) == 0).all()
    assert (r.depth_at(xs, np.full(50, 1.011 - 0.13)) == 0).all()
    assert r.depth_at(2.004 + 0.04, 1.011) > 0  # inside the cap
    assert r.depth_at(2.004 + 0.13, 1.011) == 0
    # a lateral cross-section falls monotonically from the axis to the rim
    prof = r.depth_at(np.full(40, 1.5), 1.011 + np.linspace(0.0, 0.12, 40))
    assert (np.diff(prof) <= 0).all() and prof[0] == np.float32(d) and prof[-1] == 0


def test_depth_interpolates_and_max_combines():
    r = TrackRaster(cell_m=C)
    r.stamp_segment((0.01, 0.51), (1.01, 0.51), width_m=0.1, depth_m=0.01, depth_end_m=0.03)
    np.testing.assert_allclose(r.depth_at([0.01, 0.51, 1.01], 0.51), [0.01, 0.02, 0.03], rtol=1e-6)
    r.stamp_segment((0.01, 0.51), (1.01, 0.51), width_m=0.1, depth_m=0.02)  # shallower part
    np.testing.assert_allclose(r.depth_at([0.01, 0.51, 1.01], 0.51), [0.02, 0.02, 0.03], rtol=1e-6)
    before = r.window(left=0, bottom=0, right=1.2, top=1)[0]
    r.stamp_segment((0.2, 0.51), (0.8, 0.51), width_m=0.1, depth_m=0.0)  # no-op
    np.testing.assert_array_equal(r.window(left=0, bottom=0, right=1.2, top=1)[0], before)


def test_curved_path_is_continuous_union_of_capsules():
    """Chords (0.26 m) longer than the tread (0.114 m): swept rectangles would leave wedge
    gaps at the outer side of every joint; the stamped union must equal the profile of
    the distance to the whole polyline."""
    r = TrackRaster(cell_m=C)
    R, w, d = 1.5, 0.114, 0.012
    ang = np.radians(np.arange(0, 121, 10))
    pts = np.stack([0.3 + R * np.cos(ang), -0.2 + R * np.sin(ang)], axis=1)
    for a, b in itertools.pairwise(pts):
        r.stamp_segment(a, b, width_m=w, depth_m=d)
    v, X, Y = _cells(r, -1.5, -0.5, 2.0, 1.5)
    dist = np.min([_seg_dist(X, Y, a, b)[0] for a, b in itertools.pairwise(pts)], 0)
    half = w / 2
    edge = max(0.15 * half, C)
    np.testing.assert_allclose(v, d * _profile(dist, half, edge), atol=1e-8)
    # along the true arc (within the chord sagitta, 5.7 mm, of the polyline) the groove
    # bottom is full depth everywhere: no gaps at the joints
    th = np.radians(np.linspace(0.5, 119.5, 3000))
    got = r.depth_at(0.3 + R * np.cos(th), -0.2 + R * np.sin(th))
    np.testing.assert_array_equal(got, np.float32(d))
    # outside joints: points on the outer side within the flat bottom are full depth
    outer = (R + 0.005) * np.stack([np.cos(ang[1:-1]), np.sin(ang[1:-1])], 1) + [0.3, -0.2]
    np.testing.assert_allclose(r.depth_at(outer[:, 0], outer[:, 1]), d, rtol=1e-6)


def test_memory_grows_only_along_path():
    r = TrackRaster(cell_m=C)  # 256-cell tiles: 5.12 m
    assert r.tile_count == 0 and r.nbytes == 0 and r.bounds() is None
    for i in range(199):  # 19.9 m east along y = 1 m
        r.stamp_segment((0.1 * i + 0.1, 1.0), (0.1 * i + 0.2, 1.0), width_m=0.114, depth_m=0.01)
    assert r.tile_keys() == [(0, 0), (0, 1), (0, 2), (0, 3)]
    assert r.nbytes == 4 * 256 * 256 * 4
    # a 141 m diagonal across a 200 m site: only tiles the tread crosses
    r2 = TrackRaster(cell_m=C)
    r2.stamp_segment((-50.0, -49.7), (50.0, 50.3), width_m=0.114, depth_m=0.01)
    s = 256 * C
    keys = np.array(r2.tile_keys())
    assert 20 <= len(keys) <= 2 * math.ceil(100 / s) + 2  # vs. 1600 for the whole site
    centres = (keys[:, ::-1] + 0.5) * s  # (x, y) of tile centres
    off_line = np.abs(centres[:, 1] - centres[:, 0] - 0.3) / math.sqrt(2)
    assert (off_line < s / math.sqrt(2) + 0.06).all()
    # zero-depth stamps allocate nothing
    r3 = TrackRaster(cell_m=C)
    r3.stamp_segment((0, 0), (3, 3), width_m=0.2, depth_m=0.0)
    assert r3.tile_count == 0


def test_depth_at_vectorized_bilinear_and_zero_off_tile():
    r = TrackRaster(cell_m=C, tile_cells=8)  # 0.16 m tiles: many tile seams
    rng = np.random.default_rng(3)
    for _ in range(40):
        a = rng.uniform(-0.6, 0.6, 2)
        r.stamp_segment(
            a, a + rng.uniform(-0.2, 0.2, 2), width_m=0.08, depth_m=rng.uniform(0, 0.03)
        )
    v, (left, bottom, right, top) = r.window(left=-1, bottom=-1, right=1, top=1)
    ny, nx = v.shape
    yc = top - (np.arange(ny) + 0.5) * C
    xc = left + (np.arange(nx) + 0.5) * C
    ref = RegularGridInterpolator((yc[::-1], xc), v[::-1].astype(np.float64))
    q = rng.uniform(-0.95, 0.95, (2, 300, 7))
    got = r.depth_at(q[0], q[1])
    assert got.shape == (300, 7) and got.dtype == np.float32
    np.testing.assert_allclose(got, ref(np.stack([q[1], q[0]], -1)), atol=1e-7)
    assert (got > 0).mean() > 0.05
    # broadcasting and scalars
    assert r.depth_at(np.zeros((4, 1)), np.zeros((1, 5))).shape == (4, 5)
    assert r.depth_at(0.0, 0.0).shape == ()
    # far away, NaN and no tiles at all: 0
    np.testing.assert_array_equal(r.depth_at([50.0, np.nan, 0.0], [50.0, 0.0, np.inf]), 0)
    assert (TrackRaster().depth_at(q[0], q[1]) == 0).all()
    # the callable form used by shade(track_depth=...)
    np.testing.assert_array_equal(r(q[0], q[1]), got)
    # a RasterSampler over a window gives the same values inside it
    s = sh.RasterSampler(v, bounds=(left, bottom, right, top), outside=0.0)
    np.testing.assert_allclose(s(q[0], q[1]).reshape(got.shape), got, atol=1e-6)  # f32 coords


def test_grouser_pattern_period_along_track():
    r = TrackRaster(cell_m=C)
    prof = TrackProfile(grouser_pitch_m=0.08, grouser_fraction=0.5)
    # cell centres at x = 0.01 + 0.02 k, i.e. s = 0.02 k along the track
    r.stamp_segment((0.01, 0.01), (1.01, 0.01), width_m=0.2, depth_m=0.02, profile=prof)
    s = np.arange(0, 1.0, 0.02)
    got = r.depth_at(0.01 + s, 0.01)
    expect = 0.02 * (1 - 0.5 * 0.5 * (1 - np.cos(2 * np.pi * s / 0.08)))
    np.testing.assert_allclose(got, expect, rtol=1e-5)
    assert got[8] == np.float32(0.02) and abs(got[10] - 0.01) < 1e-7  # s = 0.16, 0.20
    # the phase continues across segments through s0_m
    r2 = TrackRaster(cell_m=C)
    r2.stamp_segment((0.01, 0.01), (0.51, 0.01), width_m=0.2, depth_m=0.02, profile=prof)
    r2.stamp_segment((0.51, 0.01), (1.01, 0.01), width_m=0.2, depth_m=0.02, s0_m=0.5, profile=prof)
    np.testing.assert_allclose(r2.depth_at(0.01 + s, 0.01), got, atol=1e-9)


def test_copy_on_write_snapshots():
    r = TrackRaster(cell_m=C)
    r.stamp_segment((0.5, 0.5), (1.5, 0.5), width_m=0.1, depth_m=0.01)
    r.stamp_segment((8.0, 0.5), (9.0, 0.5), width_m=0.1, depth_m=0.01)  # another tile
    snap = r.copy()
    keys = [(0, 0), (0, 1)]
    assert all(np.shares_memory(snap.tile(k), r.tile(k)) for k in keys)  # no data copied
    before = snap.window(left=0, bottom=0, right=10, top=1)[0]
    r.stamp_segment((0.5, 0.5), (1.5, 0.5), width_m=0.1, depth_m=0.05)  # deeper, tile (0, 0)
    r.stamp_segment((12.0, 12.0), (13.0, 12.0), width_m=0.1, depth_m=0.05)  # new tile
    np.testing.assert_array_equal(snap.window(left=0, bottom=0, right=10, top=1)[0], before)
    assert snap.tile_count == 2 and r.tile_count == 3
    assert r.depth_at(1.0, 0.5) == np.float32(0.05) and snap.depth_at(1.0, 0.5) == np.float32(0.01)
    assert np.shares_memory(snap.tile((0, 1)), r.tile((0, 1)))  # untouched tile still shared
    assert not np.shares_memory(snap.tile((0, 0)), r.tile((0, 0)))  # touched one copied
    # stamping the snapshot leaves the original alone; deepcopy (Drake's clone) is a copy
    deep = copy.deepcopy(snap)
    snap.stamp_segment((8.0, 0.5), (9.0, 0.5), width_m=0.1, depth_m=0.09)
    assert r.depth_at(8.5, 0.5) == np.float32(0.01) and deep.depth_at(8.5, 0.5) == np.float32(0.01)
    assert snap.depth_at(8.5, 0.5) == np.float32(0.09)
    with pytest.raises(ValueError):
        snap.tile((0, 0))[0, 0] = 1.0  # views are read-only


def test_stamping_is_deterministic():
    def build():
        r = TrackRaster(cell_m=C)
        rng = np.random.default_rng(11)
        p = np.zeros(2)
        for _ in range(300):
            q = p + rng.normal(0, 0.05, 2)
            r.stamp_segment(p, q, width_m=0.114, depth_m=rng.uniform(0.001, 0.02))
            p = q
        return r

    a, b = build(), build()
    assert a.tile_keys() == b.tile_keys()
    for k in a.tile_keys():
        assert a.tile(k).tobytes() == b.tile(k).tobytes()


def test_validation():
    with pytest.raises(OutOfRangeError, match="cell_m"):
        TrackRaster(cell_m=0.0)
    with pytest.raises(OutOfRangeError, match="tile_cells"):
        TrackRaster(tile_cells=3)
    r = TrackRaster()
    with pytest.raises(OutOfRangeError, match="width_m"):
        r.stamp_segment((0, 0), (1, 0), width_m=0.0, depth_m=0.01)
    with pytest.raises(OutOfRangeError, match=r"depth_m = -0\.01"):
        r.stamp_segment((0, 0), (1, 0), width_m=0.1, depth_m=-0.01)
    with pytest.raises(ConfigError, match="p1_xy"):
        r.stamp_segment((0, 0), (np.nan, 0), width_m=0.1, depth_m=0.01)
    with pytest.raises(OutOfRangeError, match="edge_fraction"):
        TrackProfile(edge_fraction=1.5)
    with pytest.raises(OutOfRangeError, match="grouser_fraction"):
        TrackProfile(grouser_fraction=-0.1)
    with pytest.raises(OutOfRangeError, match="wheel_width_m"):
        WheelTracks(wheel_bodies=[1], wheel_width_m=-1.0)
    with pytest.raises(ConfigError, match="wheel_bodies"):
        WheelTracks(wheel_bodies=[], wheel_width_m=0.1)


def test_bump_mapped_groove_in_render():
    """shade(track_depth=TrackRaster): only the groove walls change the image; the wall
    facing the Sun brightens, the one facing away darkens."""
    from lunar_drake.render.raycast import PinholeCamera, TerrainRaycaster
    from lunar_drake.render.terrain_lod import TerrainLOD, TileCache
    from lunar_drake.terrain.heightfield import Heightfield

    hf = Heightfield.from_array(np.zeros((64, 64), np.float32), resolution_m=0.1)
    rc = TerrainRaycaster()
    rc.set_terrain(TerrainLOD.build(hf, cache=TileCache(), tile_px=32))
    cam = PinholeCamera.from_fov(width=96, height=96, fov_y_rad=0.6)
    X = np.eye(4)
    X[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]  # looking down, image up = north
    X[:3, 3] = (0.0, 0.0, 2.0)
    g = sh.trace(rc, cam, X)
    el = math.radians(25.0)
    il = sh.Illumination(sun_direction_W=(0.0, math.cos(el), math.sin(el)), fill_fraction=0.0)
    tracks = TrackRaster(cell_m=C)
    tracks.stamp_segment(
        (-0.6, 0.0), (0.6, 0.0), width_m=0.3, depth_m=0.03, profile=TrackProfile(edge_fraction=0.5)
    )
    flat = sh.shade(g, rc, il).radiance.ravel()[g.index]
    bump = sh.shade(g, rc, il, track_depth=tracks).radiance.ravel()[g.index]
    x, y = g.position[0], g.position[1]
    inside = np.abs(x) < 0.5
    far = (np.abs(y) > 0.2) | (np.abs(x) > 0.7)
    bottom = inside & (np.abs(y) < 0.03)
    north_wall = inside & (y > 0.09) & (y < 0.13)  # rises northward: faces away from Sun
    south_wall = inside & (y < -0.09) & (y > -0.13)
    assert far.sum() > 1000 and bottom.sum() > 50 and north_wall.sum() > 50
    # zero depth gradient: the same normal up to its renormalization (float32 ulps)
    np.testing.assert_allclose(bump[far], flat[far], rtol=1e-6)
    np.testing.assert_allclose(bump[bottom], flat[bottom], rtol=1e-6)
    assert (bump[north_wall] < flat[north_wall]).all()
    assert (bump[south_wall] > flat[south_wall]).all()


# ----------------------------------------------------------------------------------------
# LeafSystem
# ----------------------------------------------------------------------------------------
NF = len(WHEEL_STATE_FIELDS)


def _wheel_state(sinkages, off=()):
    ws = np.zeros((len(sinkages), NF))
    ws[:, WHEEL_STATE_FIELDS.index("sinkage_m")] = sinkages
    for k in off:
        ws[k, WHEEL_STATE_FIELDS.index("off_terrain")] = 1.0
    return ws.ravel()


def _poses(p1, p3):
    return [RigidTransform(), RigidTransform(p1), RigidTransform([9, 9, 9]), RigidTransform(p3)]


def _sim(**kw):
    sys = WheelTracks(wheel_bodies=[1, 3], wheel_width_m=0.114, **kw)
    sim = Simulator(sys)
    return sys, sim, sim.get_mutable_context()


def _drive(sys, sim, ctx, steps):
    """steps: list of (p1, p3, sinkages, off); one update each at t = 0, 0.1, ..."""
    snaps = []
    for k, (p1, p3, sink, off) in enumerate(steps):
        sys.body_poses_input.FixValue(ctx, _poses(p1, p3))
        sys.wheel_state_input.FixValue(ctx, _wheel_state(sink, off))
        sim.AdvanceTo(0.1 * k + 0.05)  # runs exactly the update at t = 0.1 k
        snaps.append(sys.track_depth_output.Eval(ctx))
    return snaps


def test_system_stamps_segments_between_updates():
    sys, sim, ctx = _sim()
    steps = [
        ((1.0, 1.0, 0.17), (1.0, 2.0, 0.17), (0.010, 0.0005), ()),  # wheel 3 too shallow
        ((1.5, 1.0, 0.17), (1.5, 2.0, 0.17), (0.020, 0.020), ()),  # wheel 3 first contact
        ((1.5, 1.4, 0.17), (2.5, 2.0, 0.17), (0.020, 0.020), (1,)),  # wheel 3 off terrain
    ]
    snaps = _drive(sys, sim, ctx, steps)
    expect = TrackRaster(cell_m=C)
    expect.stamp_segment((1.0, 1.0), (1.0, 1.0), width_m=0.114, depth_m=0.010)
    expect.stamp_segment((1.0, 1.0), (1.5, 1.0), width_m=0.114, depth_m=0.01, depth_end_m=0.02)
    expect.stamp_segment((1.5, 2.0), (1.5, 2.0), width_m=0.114, depth_m=0.020)
    expect.stamp_segment((1.5, 1.0), (1.5, 1.4), width_m=0.114, depth_m=0.02)
    got = sys.tracks(ctx)
    assert isinstance(got, TrackRaster) and isinstance(snaps[-1], TrackRaster)
    win = dict(left=0, bottom=0, right=3, top=3)
    np.testing.assert_array_equal(got.window(**win)[0], expect.window(**win)[0])
    np.testing.assert_array_equal(snaps[-1].window(**win)[0], expect.window(**win)[0])
    np.testing.assert_allclose(got.depth_at([1.25, 1.25, 2.0], [1.0, 2.0, 2.0]), [0.015, 0, 0])
    last = ctx.get_discrete_state(0).value().reshape(2, len(LAST_CONTACT_FIELDS))
    np.testing.assert_allclose(last[0], [1.5, 1.4, 0.02, 0.9, 1.0])
    assert last[1, LAST_CONTACT_FIELDS.index("in_contact")] == 0.0


def test_system_breaks_groove_on_jump_and_after_lift_off():
    sys, sim, ctx = _sim(max_jump_m=0.5)
    steps = [
        ((1.0, 1.0, 0.2), (1.0, 2.0, 0.2), (0.01, 0.01), ()),
        ((2.0, 1.0, 0.2), (1.2, 2.0, 0.2), (0.01, 0.0), ()),  # wheel 1 jumps 1 m; 3 lifts
        ((2.0, 1.0, 0.2), (1.4, 2.0, 0.2), (0.01, 0.01), ()),  # 3 lands again at 1.4
    ]
    _drive(sys, sim, ctx, steps)
    r = sys.tracks(ctx)
    assert r.depth_at(1.0, 1.0) > 0 and r.depth_at(2.0, 1.0) > 0
    assert r.depth_at(1.5, 1.0) == 0  # no groove across the jump
    assert r.depth_at(1.0, 2.0) > 0 and r.depth_at(1.4, 2.0) > 0
    assert r.depth_at(1.2, 2.0) == 0  # nothing while airborne


def test_output_snapshots_survive_later_updates():
    sys, sim, ctx = _sim()
    snaps = _drive(
        sys,
        sim,
        ctx,
        [
            ((1.0, 1.0, 0.2), (1.0, 2.0, 0.2), (0.01, 0.01), ()),
            ((1.2, 1.0, 0.2), (1.2, 2.0, 0.2), (0.01, 0.01), ()),
        ],
    )
    s1 = snaps[1]
    win = dict(left=0, bottom=0, right=3, top=3)
    v1 = s1.window(**win)[0].copy()
    _drive_more = [
        ((1.2, 1.0, 0.2), (1.2, 2.0, 0.2), (0.05, 0.05), ()),  # re-stamp deeper, same tile
        ((1.4, 1.0, 0.2), (1.4, 2.0, 0.2), (0.05, 0.05), ()),
    ]
    for k, (p1, p3, sink, off) in enumerate(_drive_more, start=2):
        sys.body_poses_input.FixValue(ctx, _poses(p1, p3))
        sys.wheel_state_input.FixValue(ctx, _wheel_state(sink, off))
        sim.AdvanceTo(0.1 * k + 0.05)
    now = sys.track_depth_output.Eval(ctx)
    np.testing.assert_array_equal(s1.window(**win)[0], v1)
    assert now.depth_at(1.2, 1.0) == np.float32(0.05) and s1.depth_at(1.2, 1.0) == np.float32(0.01)
    assert now.depth_at(1.4, 2.0) > 0 and s1.depth_at(1.4, 2.0) == 0


def test_system_is_deterministic():
    steps = [
        ((0.1 * k, 0.02 * k * k, 0.2), (0.1 * k, 1 + 0.1 * k, 0.2), (0.01 + 0.001 * k, 0.02), ())
        for k in range(6)
    ]
    outs = []
    for _ in range(2):
        sys, sim, ctx = _sim()
        _drive(sys, sim, ctx, steps)
        r = sys.tracks(ctx)
        outs.append([r.tile(k).tobytes() for k in r.tile_keys()])
    assert outs[0] == outs[1] and len(outs[0]) > 0


def test_output_connects_to_a_camera_style_input():
    """HapkeCamera declares ``track_depth`` as an abstract input of AbstractValue.Make(
    object()); the WheelTracks output must connect to such a port and evaluate to a
    callable."""

    class Consumer(LeafSystem):
        def __init__(self):
            super().__init__()
            self.track_depth_input = self.DeclareAbstractInputPort(
                "track_depth", AbstractValue.Make(object())
            )

    b = DiagramBuilder()
    tracks = b.AddSystem(WheelTracks(wheel_bodies=[1, 3], wheel_width_m=0.114))
    cons = b.AddSystem(Consumer())
    b.Connect(tracks.track_depth_output, cons.track_depth_input)
    b.ExportInput(tracks.body_poses_input, "body_poses")
    b.ExportInput(tracks.wheel_state_input, "wheel_state")
    d = b.Build()
    sim = Simulator(d)
    ctx = sim.get_mutable_context()
    d.get_input_port(0).FixValue(ctx, _poses((1.0, 1.0, 0.2), (1.0, 2.0, 0.2)))
    d.get_input_port(1).FixValue(ctx, _wheel_state((0.01, 0.01)))
    sim.AdvanceTo(0.05)
    f = cons.track_depth_input.Eval(cons.GetMyContextFromRoot(ctx))
    np.testing.assert_allclose(
        f(np.array([1.0, 1.0, 5.0]), np.array([1.0, 2.0, 5.0])), [0.01, 0.01, 0]
    )


def test_tracked_window_samples_as_the_whole_window():
    """The camera's cut-down window (tiles with tracks + 2 cells of zeros) has the whole
    window's values and gradients everywhere in the rectangle, edges and off-tile
    ground included, and far fewer cells."""
    r = TrackRaster(cell_m=C, tile_cells=16)  # 0.32 m tiles
    rng = np.random.default_rng(8)
    for _ in range(12):
        a = rng.uniform(0.3, 1.1, 2)
        r.stamp_segment(a, a + rng.uniform(-0.3, 0.3, 2), width_m=0.1, depth_m=0.02)
    r.stamp_segment((2.9, -0.5), (3.4, -0.4), width_m=0.1, depth_m=0.02)  # half outside
    r.stamp_segment((0.05, 1.57), (0.25, 1.57), width_m=0.03, depth_m=0.02)  # a tile's top row
    win = dict(left=-1.0, bottom=-1.0, right=3.0, top=3.0)
    full = sh.RasterSampler(*r.window(**win)[:1], bounds=r.window(**win)[1], outside=0.0)
    cut_values, cut_bounds = r.tracked_window(**win)
    cut = sh.RasterSampler(cut_values, bounds=cut_bounds, outside=0.0)
    assert cut_values.size < full.values.size / 2
    assert cut_bounds[2] == pytest.approx(3.0) and cut_bounds[1] > -0.99  # clipped; cut
    q = rng.uniform(-1.2, 3.2, (2, 20000))
    edge = np.linspace(-1.2, 3.2, 2000)  # along the cut's edges and the stamped area's
    q = np.concatenate([q, [edge, np.full_like(edge, cut_bounds[3])],
                        [np.full_like(edge, cut_bounds[0]), edge]], axis=1)  # fmt: skip
    np.testing.assert_allclose(cut(q[0], q[1]), full(q[0], q[1]), atol=1e-6)
    for g_cut, g_full in zip(cut.gradient(q[0], q[1]), full.gradient(q[0], q[1]), strict=True):
        np.testing.assert_allclose(g_cut, g_full, atol=2e-4)  # m/m; slopes reach ~1
        assert np.abs(g_full).max() > 0.1
    assert r.tracked_window(left=10, bottom=10, right=11, top=11) is None
    with pytest.raises(OutOfRangeError, match="window"):
        r.tracked_window(left=1, bottom=0, right=0, top=1)
    with pytest.raises(OutOfRangeError, match="window"):
        r.tracked_window(left=float("nan"), bottom=0, right=1, top=1)
    with pytest.raises(OutOfRangeError, match="margin_cells = -1"):
        r.tracked_window(**win, margin_cells=-1)
