"""The fast Hapke camera engine: DEM ray marching plus one compiled shading pass.

Same scene, lights, terms and output units as the reference engine
(:mod:`lunar_drake.render.shading`, Open3D/Embree over LOD triangle tiles with numpy
shading), built for frame rate on a few CPU cores:

* **terrain visibility** straight on the DEM's mip pyramid
  (:mod:`lunar_drake.render.heightfield_trace`), no triangle mesh or BVH;
* **rover visibility**: Embree rays only for the pixels that the rover's triangles
  cover when projected into the image (near-plane clipped, one pixel of margin);
* **terrain shading** in one numba kernel per frame: normal map (+ wheel-track bump),
  albedo map, baked lightmap, Sun, indirect fill and Earthshine through a tabulated
  Hapke/Lunar-Lambert reflectance (:class:`~lunar_drake.render.hapke_lut.ReflectanceLUT`,
  trilinear; accuracy in docs/lighting.md), with the sub-cell regolith texture
  (:mod:`~lunar_drake.render.regolith`) and the B-spline lightmap
  (:mod:`~lunar_drake.render.soft_shadow`) when the config asks for them;
* the **soft rover shadow** (:func:`~lunar_drake.render.shading.rover_shadow_factor`,
  Embree) on the pixels the kernel's bounding-sphere cull keeps, rover pixels shaded by
  the reference :func:`~lunar_drake.render.shading.shade` (few pixels), spotlights by
  the reference spotlight code over the terrain hits (numpy; night scenes are slower).

Differences from the reference engine, all sub-pixel or within the LUT error: the
surface is the DEM's bilinear surface (mip levels with distance) instead of LOD
triangles; silhouettes are resolved per azimuth bin; the BRDF is tabulated.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numba
import numpy as np

from lunar_drake.errors import ConfigError
from lunar_drake.render.hapke_lut import (
    ReflectanceLUT,
    lut_axis_f32,
    lut_corner_f32,
    trilerp,
)
from lunar_drake.render.heightfield_trace import DemPyramid, direction_f32, trace_heightfield
from lunar_drake.render.raycast import (
    INVALID_ID,
    PinholeCamera,
    RayHits,
    TerrainRaycaster,
    camera_ray_directions,
)
from lunar_drake.render.regolith import (
    P_ALB,
    P_COS,
    P_CS,
    P_LAMBDA,
    P_OU,
    P_OV,
    P_SIN,
    P_SLOPE,
    P_SS,
    apply_texture,
    build_texture,
    inverse_footprint,
    load_i32,
    load_pair_f32,
    octave_blend,
    octave_cell,
    octave_weight,
    wrap_coordinates,
)
from lunar_drake.render.row_queue import fetch_add, workers
from lunar_drake.render.shading import (
    GBuffer,
    Illumination,
    RasterSampler,
    ShadedImage,
    ShadingConfig,
    add_spotlight,
    fill_direction,
    rover_shadow_factor,
    shade,
)

__all__ = ["FastTerrainEngine", "rover_pixel_mask"]

_NO_TEX = np.zeros((2, 2), np.float32)
_ROWS = 8  # rows a worker takes from the queue at a time (neighbours share DEM cells)
_NO_PARAM = np.zeros(6, np.float64)


def _tex_args(sampler: RasterSampler | None):
    """``(values, params)`` for :func:`_tex`: params = (1/cell_x, 1/cell_y, left, top,
    use_outside, outside)."""
    if sampler is None:
        return _NO_TEX, _NO_PARAM
    left, _, _, top = sampler.bounds
    out = sampler.outside
    p = np.array(
        [sampler._sx, sampler._sy, left, top, 0.0 if out is None else 1.0, out or 0.0],
        np.float64,
    )
    return np.ascontiguousarray(sampler.values, np.float32), p


@numba.njit(cache=True, inline="always", error_model="numpy")
def _tex(a, p, x, y):
    """Bilinear sample at site (x, y), the RasterSampler convention (edge clamped; beyond
    the half-pixel band ``p[5]`` when ``p[4]``)."""
    h = a.shape[0]
    w = a.shape[1]
    col = (x - p[2]) * p[0] - 0.5
    row = (p[3] - y) * p[1] - 0.5
    if p[4] != 0.0 and (row < -0.5 or row > h - 0.5 or col < -0.5 or col > w - 0.5):
        return p[5]
    if col < 0.0:
        col = 0.0
    elif col > w - 1.0:
        col = w - 1.0
    if row < 0.0:
        row = 0.0
    elif row > h - 1.0:
        row = h - 1.0
    c0 = min(int(col), max(w - 2, 0))
    r0 = min(int(row), max(h - 2, 0))
    c1 = min(c0 + 1, w - 1)
    r1 = min(r0 + 1, h - 1)
    fc = col - c0
    fr = row - r0
    t = a[r0, c0] + fc * (a[r0, c1] - a[r0, c0])
    b = a[r1, c0] + fc * (a[r1, c1] - a[r1, c0])
    return t + fr * (b - t)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _surface_cell(h, w, p, x, y):
    """The bilinear cell of the (h, w, 3) surface texture at site (x, y), edge clamped
    (the RasterSampler convention): ``(k, dc, dr, fc, fr)``, the flat int32 index of
    channel 0 at its (r0, c0) corner, the index steps to the next column and row (0 at
    a clamped edge) and the float32 fractions (cell position in float64)."""
    col = (x - p[2]) * p[0] - 0.5
    row = (p[3] - y) * p[1] - 0.5
    col = min(max(col, 0.0), w - 1.0)
    row = min(max(row, 0.0), h - 1.0)
    # col, row >= 0: int32 truncation is int() (and vectorizes)
    c0 = min(np.int32(col), np.int32(max(w - 2, 0)))
    r0 = min(np.int32(row), np.int32(max(h - 2, 0)))
    c1 = min(c0 + np.int32(1), np.int32(w - 1))
    r1 = min(r0 + np.int32(1), np.int32(h - 1))
    fc = np.float32(col - c0)
    fr = np.float32(row - r0)
    w32 = np.int32(w)
    three = np.int32(3)
    return (r0 * w32 + c0) * three, (c1 - c0) * three, (r1 - r0) * w32 * three, fc, fr


@numba.njit(cache=True, inline="always", error_model="numpy")
def _lut_cell_gie(tab, x, y, cg):
    """:func:`~lunar_drake.render.hapke_lut.lut_cell_f32` for the table stored phase
    first, ``tab[g, i, e]`` (:func:`lut_phase_major`): the same fractions, the flat
    int32 index of the (i0, j0, k0) corner in that layout."""
    ni = tab.shape[1] - 1
    ne = tab.shape[2] - 1
    i0, j0, k0, fx, fy, fz = lut_corner_f32(x, y, cg, ni, ne, tab.shape[0] - 1)
    k = (k0 * np.int32(ni + 1) + i0) * np.int32(ne + 1) + j0
    return k, fx, fy, fz


def lut_phase_major(table: np.ndarray) -> np.ndarray:
    """The reflectance table ``table[i, e, g]`` stored as ``[g, i, e]`` (C order) for
    the shading kernel: the same values, read with the same trilinear blend.

    A frame's pixels read a light's table at nearly the same phase angle (it varies
    smoothly over the image) but at scattered incidence and emission (bumped normals):
    with the emission axis contiguous the cells a row reads share cache lines, where the
    phase-contiguous layout spent a line on every (i, e) pair."""
    return np.ascontiguousarray(np.transpose(table, (2, 0, 1)))


@numba.njit(cache=True, inline="always", error_model="numpy")
def _light_term(lut, n, NX, NY, NZ, D0, D1, D2, YE, lx, ly, lz, irradiance, out, KI, F3, T8):
    """``out[j] = irradiance * r`` of the distant light toward (lx, ly, lz) for the
    row's pixels j < n, all float32, in three loops: table cells (vector code), the
    eight corner reads (a loop of loads only), the trilinear blend (vector code). The
    light is passed as scalars, not an array whose loads the stores could alias.
    ``lut`` is the phase-major table (:func:`lut_phase_major`).

    Loads through computed indices keep a loop scalar where the compiler does not emit
    gathers (AMD Zen: no ``fast-gather``), so they get a loop of their own."""
    m = np.float32(lut.shape[1] - 1)
    for j in range(n):
        ci = NX[j] * lx + NY[j] * ly + NZ[j] * lz
        cg = -(D0[j] * lx + D1[j] * ly + D2[j] * lz)
        # ci <= 0 reads the table's last i row, which is 0: no light, no branch
        k, fx, fy, fz = _lut_cell_gie(lut, lut_axis_f32(ci, m), YE[j], cg)
        KI[j] = k
        F3[0, j] = fx
        F3[1, j] = fy
        F3[2, j] = fz
    si = np.int32(lut.shape[2])
    sg = np.int32(lut.shape[1]) * si
    for j in range(n):  # corners t[di][dj][dk] (i, e, g) at k + di si + dj + dk sg
        k = KI[j]
        # e neighbours are adjacent (dj = 0, 1): one 64-bit load per pair
        T8[0, j], T8[2, j] = load_pair_f32(lut, k)
        T8[1, j], T8[3, j] = load_pair_f32(lut, k + sg)
        T8[4, j], T8[6, j] = load_pair_f32(lut, k + si)
        T8[5, j], T8[7, j] = load_pair_f32(lut, k + si + sg)
    for j in range(n):
        r = trilerp(
            T8[0, j], T8[1, j], T8[2, j], T8[3, j], T8[4, j], T8[5, j], T8[6, j], T8[7, j],
            F3[0, j], F3[1, j], F3[2, j],
        )  # fmt: skip
        out[j] = irradiance * r


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def _row_max(a, n):
    """``max(a[:n])`` (a called function: fastmath lets the reduction vectorize; NaN-free
    input)."""
    m = a[0]
    for j in range(n):
        m = max(m, a[j])
    return m


@numba.njit(cache=True, inline="always")
def _sky_pixel(i, rad_out, cand_out, label_out, depth_out):
    """The outputs of a pixel the terrain kernel does not shade (sky, or the rover's)."""
    rad_out[i] = 0.0
    cand_out[i] = 0
    label_out[i] = 0
    depth_out[i] = np.inf


@numba.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def _shade_terrain(
    t, R, fx, fy, cx, cy, skip, width, height, cam,
    surf, spar, afac_scale,
    lma, lpar, use_lm, gxa, gya, gpar, use_bump,
    ttop, tbot, tpar, tperiod, tfade, use_tex, pix_ang, soft_lm,
    lut, ldirs, lirr, sun_light, sphere, sun_out, other_out, cand_out,
    rad_out, depth_out, label_out, nwork,
):  # fmt: skip
    """Per pixel: the radiance (the sum of the lights), rover-shadow cull, camera-z depth
    and label (1 terrain, 0 sky or ``skip``); at the cull's candidates only (``cand_out``
    1; elsewhere they are left as they were), the sun term (before the rover shadow) and
    the other lights' term, which the caller recombines with the rover shadow.

    Row by row in short passes over the row's terrain pixels (directions and positions,
    surface texture, normals, one pass per light, lightmap, cull): each pass is a
    simple loop the compiler schedules well, where one long per-pixel body stalled.
    Every table read (surface texture, regolith octaves, BRDF table, lightmap) is split
    into an index pass (vector code), a loop of loads only and a blend pass (vector
    code): without gathers a loop that loads through computed indices stays scalar."""
    nl = ldirs.shape[0]
    m_e = lut.shape[2] - 1  # the phase-major table: [g, i, e]
    n_oct = tpar.shape[0]
    tsize = np.float32(math.sqrt(ttop.size))
    tinv = np.float32(1.0) / tsize
    sh = surf.shape[0]
    sw = surf.shape[1]
    R32 = R.astype(np.float32)
    ifx = np.float32(1.0 / fx)
    cx32 = np.float32(cx)
    counter = np.zeros(1, np.int64)  # the next row to render (row_queue)
    for _w in numba.prange(nwork):
        col_of = np.empty(width, np.int64)
        D0 = np.empty(width, np.float32)
        D1 = np.empty(width, np.float32)
        D2 = np.empty(width, np.float32)
        X = np.empty(width)
        Y = np.empty(width)
        Z = np.empty(width)
        GX = np.empty(width)
        GY = np.empty(width)
        NX = np.empty(width, np.float32)
        NY = np.empty(width, np.float32)
        NZ = np.empty(width, np.float32)
        AF = np.empty(width, np.float32)
        YE = np.empty(width, np.float32)
        ZC = np.empty(width, np.float32)
        SUN = np.zeros(width, np.float32)
        OTH = np.zeros(width, np.float32)
        TMP = np.empty(width, np.float32)
        FT = np.empty(width, np.float32)
        TT = np.empty(width, np.float32)
        XW = np.empty(width, np.float32)
        YW = np.empty(width, np.float32)
        TA = np.empty(width, np.float32)
        TX = np.empty(width, np.float32)
        TY = np.empty(width, np.float32)
        KI = np.empty(width, np.int32)
        K2 = np.empty((2, width), np.int32)
        F3 = np.empty((3, width), np.float32)
        T8 = np.empty((12, width), np.float32)
        P2 = np.empty((2, width), np.int32)
        LO = np.empty(width, np.uint8)
        CU = np.zeros(width, np.uint8)
        row = -1
        end = 0
        while True:
            row += 1
            if row >= end:  # the next _ROWS rows from the queue
                row = fetch_add(counter, _ROWS)
                end = min(row + _ROWS, height)
            if row >= height:
                break
            base = row * width
            # the row's terrain pixels: their count (vector code), then, when they form
            # one run of columns (the usual case), the run without branches and the sky
            # values on the other columns only; else the general compaction
            n = 0
            for col in range(width):
                n += (t[base + col] < np.inf) & (skip[base + col] == 0)
            first = 0
            last = -1
            if n > 0:
                while not (t[base + first] < np.inf and skip[base + first] == 0):
                    first += 1
                last = width - 1
                while not (t[base + last] < np.inf and skip[base + last] == 0):
                    last -= 1
            if n > 0 and last - first + 1 == n:
                for col in range(first):
                    _sky_pixel(base + col, rad_out, cand_out, label_out, depth_out)
                for col in range(last + 1, width):
                    _sky_pixel(base + col, rad_out, cand_out, label_out, depth_out)
                for j in range(n):
                    col_of[j] = first + j
                    TT[j] = t[base + first + j]
            else:
                n = 0
                for col in range(width):
                    i = base + col
                    _sky_pixel(i, rad_out, cand_out, label_out, depth_out)
                    if t[i] < np.inf and skip[i] == 0:
                        col_of[n] = col
                        TT[n] = t[i]
                        n += 1
            for j in range(n):  # the worker's buffers hold the last row's values
                SUN[j] = 0.0
                OTH[j] = 0.0
                CU[j] = 0
            yc32 = np.float32((row - cy) / fy)
            for j in range(n):  # directions (float32, as they are stored) and hit points
                d0, d1, d2, zc = direction_f32(R32, ifx, cx32, yc32, col_of[j])
                ZC[j] = zc
                ti = TT[j]
                D0[j] = d0
                D1[j] = d1
                D2[j] = d2
                X[j] = cam[0] + ti * d0
                Y[j] = cam[1] + ti * d1
                Z[j] = cam[2] + ti * d2
            # normal map and albedo: cells, the twelve reads, the bilinear blend
            for j in range(n):
                k, dc, dr, fc, fr = _surface_cell(sh, sw, spar, X[j], Y[j])
                KI[j] = k
                K2[0, j] = dc
                K2[1, j] = dr
                F3[0, j] = fc
                F3[1, j] = fr
            for j in range(n):
                k = KI[j]
                dc = K2[0, j]
                dr = K2[1, j]
                # a corner's (nx, ny) pair in one 64-bit load, its albedo in another
                T8[0, j], T8[1, j] = load_pair_f32(surf, k)
                T8[2, j] = load_i32(surf, k + 2)
                T8[3, j], T8[4, j] = load_pair_f32(surf, k + dc)
                T8[5, j] = load_i32(surf, k + dc + 2)
                T8[6, j], T8[7, j] = load_pair_f32(surf, k + dr)
                T8[8, j] = load_i32(surf, k + dr + 2)
                T8[9, j], T8[10, j] = load_pair_f32(surf, k + dr + dc)
                T8[11, j] = load_i32(surf, k + dr + dc + 2)
            one = np.float32(1.0)
            for j in range(n):
                fc = F3[0, j]
                fr = F3[1, j]
                w00 = (one - fr) * (one - fc)
                w01 = (one - fr) * fc
                w10 = fr * (one - fc)
                w11 = fr * fc
                NX[j] = w00 * T8[0, j] + w01 * T8[3, j] + w10 * T8[6, j] + w11 * T8[9, j]
                NY[j] = w00 * T8[1, j] + w01 * T8[4, j] + w10 * T8[7, j] + w11 * T8[10, j]
                alb = w00 * T8[2, j] + w01 * T8[5, j] + w10 * T8[8, j] + w11 * T8[11, j]
                AF[j] = alb * np.float32(afac_scale)
            if use_bump:
                # the track gradients: read only where the raster reaches (elsewhere they
                # are its outside value, 0), then the bump on every pixel
                gh = gxa.shape[0]
                gw = gxa.shape[1]
                nin = 0
                for j in range(n):
                    GX[j] = gpar[5]
                    GY[j] = gpar[5]
                    col = (X[j] - gpar[2]) * gpar[0] - 0.5
                    row_ = (gpar[3] - Y[j]) * gpar[1] - 0.5
                    if gpar[4] == 0.0 or not (
                        row_ < -0.5 or row_ > gh - 0.5 or col < -0.5 or col > gw - 0.5
                    ):
                        KI[nin] = j
                        nin += 1
                for m in range(nin):
                    j = KI[m]
                    GX[j] = _tex(gxa, gpar, X[j], Y[j])
                    GY[j] = _tex(gya, gpar, X[j], Y[j])
                for j in range(n):
                    nx = NX[j]
                    ny = NY[j]
                    nz = math.sqrt(min(max(1.0 - nx * nx - ny * ny, 1e-6), 1.0))
                    if nz > 1e-3:
                        bx = nx / nz + GX[j]
                        by = ny / nz + GY[j]
                        inv = 1.0 / math.sqrt(bx * bx + by * by + 1.0)
                        NX[j] = bx * inv
                        NY[j] = by * inv
            if use_tex and n > 0:  # sub-cell regolith texture (render/regolith.py)
                for j in range(n):  # 1 / footprint = sqrt(cos_e) / (distance x pixel angle)
                    nx = NX[j]
                    ny = NY[j]
                    nz2 = min(max(one - nx * nx - ny * ny, np.float32(1e-6)), one)
                    nz = np.float32(math.sqrt(nz2))
                    ce = max(-(nx * D0[j] + ny * D1[j] + nz * D2[j]), np.float32(0.05))
                    FT[j] = np.float32(math.sqrt(ce)) / (TT[j] * np.float32(pix_ang))
                    NZ[j] = nz
                    TA[j] = 0.0
                    TX[j] = 0.0
                    TY[j] = 0.0
                for j in range(n):  # site coordinates wrapped to the texture's period
                    XW[j] = wrap_coordinates(X[j], tperiod)
                    YW[j] = wrap_coordinates(Y[j], tperiod)
                imax = _row_max(FT, n)
                for k in range(n_oct):
                    lamf = np.float32(tpar[k, P_LAMBDA] / tfade)
                    if lamf * imax <= one:  # this octave is off in the whole row
                        continue
                    cs = np.float32(tpar[k, P_CS])
                    ss = np.float32(tpar[k, P_SS])
                    ou = np.float32(tpar[k, P_OU])
                    ov = np.float32(tpar[k, P_OV])
                    c = np.float32(tpar[k, P_COS])
                    sn = np.float32(tpar[k, P_SIN])
                    wa = np.float32(tpar[k, P_ALB])
                    ws = np.float32(tpar[k, P_SLOPE])
                    for j in range(n):
                        kk, du, dv = octave_cell(tsize, tinv, cs, ss, ou, ov, XW[j], YW[j])
                        KI[j] = kk
                        F3[0, j] = du
                        F3[1, j] = dv
                    for j in range(n):
                        kk = KI[j]
                        P2[0, j] = load_i32(ttop, kk)
                        P2[1, j] = load_i32(tbot, kk)
                    for j in range(n):
                        w = octave_weight(lamf, FT[j])
                        a, gu, gv = octave_blend(P2[0, j], P2[1, j], F3[0, j], F3[1, j])
                        wsj = w * ws
                        TA[j] += (w * wa) * a
                        TX[j] += wsj * (c * gu + sn * gv)
                        TY[j] += wsj * (c * gv - sn * gu)
                for j in range(n):  # bump the normal, scale the albedo
                    rz = one / max(NZ[j], np.float32(1e-3))
                    bx = NX[j] * rz - TX[j]
                    by = NY[j] * rz - TY[j]
                    inv = one / np.float32(math.sqrt(bx * bx + by * by + one))
                    NX[j] = bx * inv
                    NY[j] = by * inv
                    AF[j] *= max(one + TA[j], np.float32(0.05))
            for j in range(n):  # nz and the emission axis of the table
                nx = NX[j]
                ny = NY[j]
                nz = np.float32(math.sqrt(min(max(one - nx * nx - ny * ny, np.float32(1e-6)), one)))
                NZ[j] = nz
                YE[j] = lut_axis_f32(-(nx * D0[j] + ny * D1[j] + nz * D2[j]), np.float32(m_e))
            for k in range(nl):
                lx = np.float32(ldirs[k, 0])
                ly = np.float32(ldirs[k, 1])
                lz = np.float32(ldirs[k, 2])
                e = np.float32(lirr[k])
                # one call site for all lights: LLVM vectorized only one of two inlined
                # copies, and the other ran scalar (3.5x slower per light, measured)
                _light_term(lut, n, NX, NY, NZ, D0, D1, D2, YE, lx, ly, lz, e, TMP, KI, F3, T8)
                if k == sun_light:
                    for j in range(n):
                        SUN[j] = TMP[j]
                else:
                    for j in range(n):
                        OTH[j] += TMP[j]
            if sun_light >= 0 and use_lm and soft_lm:
                # quadratic B-spline of the lightmap (render/soft_shadow.py): cells and
                # weights, the nine reads, the taps
                lh = lma.shape[0]
                lw = lma.shape[1]
                half = np.float32(0.5)
                for j in range(n):
                    col = (X[j] - lpar[2]) * lpar[0] - 0.5
                    row_ = (lpar[3] - Y[j]) * lpar[1] - 0.5
                    out_ = (lpar[4] != 0.0) & (
                        (row_ < -0.5) | (row_ > lh - 0.5) | (col < -0.5) | (col > lw - 0.5)
                    )
                    LO[j] = np.uint8(out_)
                    col = min(max(col, -0.5), lw - 0.5)
                    row_ = min(max(row_, -0.5), lh - 0.5)
                    fc = np.floor(col + 0.5)
                    fr = np.floor(row_ + 0.5)
                    tc = np.float32(col - fc)
                    tr = np.float32(row_ - fr)
                    # fc, fr >= 0 (col, row >= -0.5): int32 truncation is int()
                    ic = min(np.int32(fc), np.int32(lw - 1))
                    ir = min(np.int32(fr), np.int32(lh - 1))
                    lw32 = np.int32(lw)
                    k = ir * lw32 + ic
                    KI[j] = k
                    K2[0, j] = ic - max(ic - np.int32(1), np.int32(0))  # to the left column
                    K2[1, j] = min(ic + np.int32(1), np.int32(lw - 1)) - ic  # to the right
                    P2[0, j] = (ir - max(ir - np.int32(1), np.int32(0))) * lw32  # up a row
                    P2[1, j] = (min(ir + np.int32(1), np.int32(lh - 1)) - ir) * lw32  # down
                    TA[j] = half * (half - tc) * (half - tc)
                    TX[j] = np.float32(0.75) - tc * tc
                    TY[j] = half * (half + tc) * (half + tc)
                    FT[j] = half * (half - tr) * (half - tr)
                    XW[j] = np.float32(0.75) - tr * tr
                    YW[j] = half * (half + tr) * (half + tr)
                for j in range(n):
                    k = KI[j]
                    cl = K2[0, j]
                    cr = K2[1, j]
                    r0 = k - P2[0, j]
                    r2 = k + P2[1, j]
                    T8[0, j] = load_i32(lma, r0 - cl)
                    T8[1, j] = load_i32(lma, r0)
                    T8[2, j] = load_i32(lma, r0 + cr)
                    T8[3, j] = load_i32(lma, k - cl)
                    T8[4, j] = load_i32(lma, k)
                    T8[5, j] = load_i32(lma, k + cr)
                    T8[6, j] = load_i32(lma, r2 - cl)
                    T8[7, j] = load_i32(lma, r2)
                    T8[8, j] = load_i32(lma, r2 + cr)
                lout = np.float32(lpar[5])
                for j in range(n):
                    f = (
                        FT[j] * (TA[j] * T8[0, j] + TX[j] * T8[1, j] + TY[j] * T8[2, j])
                        + XW[j] * (TA[j] * T8[3, j] + TX[j] * T8[4, j] + TY[j] * T8[5, j])
                        + YW[j] * (TA[j] * T8[6, j] + TX[j] * T8[7, j] + TY[j] * T8[8, j])
                    )
                    f = min(max(f, np.float32(0.0)), np.float32(1.0))
                    SUN[j] *= f + np.float32(LO[j]) * (lout - f)
            elif sun_light >= 0 and use_lm:
                for j in range(n):
                    SUN[j] *= np.float32(min(max(_tex(lma, lpar, X[j], Y[j]), 0.0), 1.0))
            if sun_light >= 0 and sphere[4] > 0.0:
                # rover-shadow candidates: the Sun ray from p (offset along the geometric
                # normal) passes the rover's sphere within the disk
                lx = ldirs[sun_light, 0]
                ly = ldirs[sun_light, 1]
                lz = ldirs[sun_light, 2]
                rad = sphere[3]
                for j in range(n):
                    qx = X[j] - sphere[0]
                    qy = Y[j] - sphere[1]
                    qz = Z[j] - sphere[2]
                    tp = -(qx * lx + qy * ly + qz * lz)
                    qq = qx * qx + qy * qy + qz * qz
                    reach = (max(tp, 0.0) + rad) * sphere[5] + rad + sphere[6]
                    CU[j] = np.uint8(
                        (SUN[j] > 0.0)
                        & (tp > -rad - sphere[6])
                        & (qq - tp * tp <= reach * reach + 1e-5 * qq + 1e-6)
                    )
            for j in range(n):  # outputs (vector code), then stored at their columns
                sun_i = np.float32(SUN[j] * AF[j] * math.pi)
                other_i = np.float32(OTH[j] * AF[j] * math.pi)
                SUN[j] = sun_i
                OTH[j] = other_i
                TT[j] = TT[j] * ZC[j]  # camera-z depth
            if n > 0 and col_of[n - 1] - col_of[0] == n - 1:  # one run of columns: vector stores
                b0 = base + col_of[0]
                for j in range(n):
                    rad_out[b0 + j] = SUN[j] + OTH[j]
                    label_out[b0 + j] = 1
                    depth_out[b0 + j] = TT[j]
                    cand_out[b0 + j] = CU[j]
            else:
                for j in range(n):
                    i = base + col_of[j]
                    rad_out[i] = SUN[j] + OTH[j]
                    label_out[i] = 1
                    depth_out[i] = TT[j]
                    cand_out[i] = CU[j]
            if sphere[4] > 0.0:  # the caller reads sun and other at candidates only
                for j in range(n):
                    if CU[j]:
                        i = base + col_of[j]
                        sun_out[i] = SUN[j]
                        other_out[i] = OTH[j]


def _in_frustum(tri, camera: PinholeCamera, near_m: float, margin_px: float = 2.0):
    """(F,) bool: triangles (F, 3, 3) in C not wholly outside one face of the view
    frustum (the image grown by ``margin_px``, and the near plane): a half-space through
    the camera centre per image side, so the test holds for any depth sign."""
    x, y, z = tri[..., 0], tri[..., 1], tri[..., 2]
    w, h = camera.width - 1.0, camera.height - 1.0
    m = margin_px
    out = (z < near_m).all(axis=1)
    out |= (camera.fx * x + (camera.cx + m) * z < 0.0).all(axis=1)  # u < -m
    out |= (camera.fx * x - (w + m - camera.cx) * z > 0.0).all(axis=1)  # u > w + m
    out |= (camera.fy * y + (camera.cy + m) * z < 0.0).all(axis=1)
    out |= (camera.fy * y - (h + m - camera.cy) * z > 0.0).all(axis=1)
    return ~out


_STACK: tuple = ((), None)  # (the meshes, their stacked arrays): the last set seen


def _stacked(meshes):
    """All meshes' vertices (V, 3), each vertex's mesh (V,) and the faces (F, 3) indexing
    the stacked vertices; remembered for the last list of meshes (by identity)."""
    global _STACK
    seen, arrays = _STACK
    if len(seen) == len(meshes) and all(a is b for a, b in zip(seen, meshes, strict=True)):
        return arrays
    offs = np.cumsum([0] + [m.vertices.shape[0] for m in meshes])
    arrays = (
        np.concatenate([m.vertices for m in meshes]),
        np.repeat(np.arange(len(meshes)), np.diff(offs)),
        np.concatenate([m.faces.astype(np.int64) + o for m, o in zip(meshes, offs, strict=False)]),
    )
    _STACK = (tuple(meshes), arrays)
    return arrays


def rover_pixel_mask(meshes, poses, camera: PinholeCamera, X_WC, *, near_m: float = 1e-3):
    """``(height, width)`` bool: pixels whose ray may hit one of the posed meshes.

    Every triangle is clipped to the camera's near plane ``z_C >= near_m``, projected and
    filled (OpenCV), then the mask is grown by one pixel: conservative for pixel-centre
    rays, so casting only these rays finds every rover hit.
    """
    import cv2

    X = np.asarray(X_WC, np.float64)
    R_CW = X[:3, :3].T
    p_WC = X[:3, 3]
    mask = np.zeros((camera.height, camera.width), np.uint8)
    K = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy]])
    shift = 4  # fixed-point bits for fillPoly
    polys = []
    if len(poses) != len(meshes):
        raise ConfigError(f"{len(poses)} poses for {len(meshes)} meshes; one pose per mesh")
    if meshes:
        # every mesh's vertices into C in one product (the meshes stacked once, cached)
        V, of_mesh, F = _stacked(meshes)
        Xg = np.asarray([np.asarray(X, np.float64) for X in poses]).reshape(-1, 4, 4)
        R_CG = np.einsum("ij,mjk->mik", R_CW, Xg[:, :3, :3])
        p_C = (Xg[:, :3, 3] - p_WC) @ R_CW.T
        v_C = np.einsum("vij,vj->vi", R_CG[of_mesh], V) + p_C[of_mesh]
        tri = v_C[F]  # (F, 3, 3)
        tri = tri[_in_frustum(tri, camera, near_m)]
        front = tri[:, :, 2] >= near_m
        nfront = front.sum(axis=1)
        full = tri[nfront == 3]
        if full.shape[0]:
            uv = np.einsum("ij,fkj->fki", K[:, :2], full[:, :, :2] / full[:, :, 2:3])
            uv += K[:, 2]
            polys.extend(list(uv))
        cut = (nfront > 0) & (nfront < 3)
        for tr, fr in zip(tri[cut], front[cut], strict=True):
            pts = []
            for a in range(3):  # Sutherland-Hodgman against z = near_m
                b = (a + 1) % 3
                pa, pb = tr[a], tr[b]
                if fr[a]:
                    pts.append(pa)
                if fr[a] != fr[b]:
                    s = (near_m - pa[2]) / (pb[2] - pa[2])
                    pts.append(pa + s * (pb - pa))
            P = np.array(pts)
            polys.append((K[:, :2] @ (P[:, :2] / P[:, 2:3]).T).T + K[:, 2])
    if polys:
        # polygons reaching far outside the image are cut to a box around it first
        # (convex-convex intersection), so fixed-point coordinates cannot overflow
        w, h = camera.width, camera.height
        box = np.array([[-w, -h], [2 * w, -h], [2 * w, 2 * h], [-w, 2 * h]], np.float32)
        fixed = []
        for uv in polys:
            if (
                (uv[:, 0] < -w).any()
                or (uv[:, 0] > 2 * w).any()
                or (uv[:, 1] < -h).any()
                or (uv[:, 1] > 2 * h).any()
            ):
                _, cut = cv2.intersectConvexConvex(
                    np.ascontiguousarray(uv, np.float32), box, handleNested=True
                )
                if cut is None or len(cut) < 3:
                    continue
                uv = cut.reshape(-1, 2).astype(np.float64)
            fixed.append(np.round(uv * (1 << shift)).astype(np.int32))
        for poly in fixed:  # one by one: fillPoly's even-odd rule would cut overlaps out
            cv2.fillConvexPoly(mask, poly, 1, lineType=cv2.LINE_8, shift=shift)
        mask = cv2.dilate(mask, np.ones((3, 3), np.uint8))
    return mask.astype(bool)


def _compact_gbuffer(camera, idx, pos, nrm, view, hits, *, dynamic: bool) -> GBuffer:
    """A G-buffer of the pixels ``idx`` only (hits aligned with them), all rover
    (``dynamic``) or all terrain, for the reference shading code."""
    m = idx.size
    return GBuffer(
        width=camera.width,
        height=camera.height,
        index=idx,
        position=pos,
        normal=nrm,
        view=view,
        dynamic=np.full(m, dynamic),
        terrain=np.full(m, not dynamic),
        hits=hits,
        label=np.zeros((1, 1), np.int16),
        depth=np.zeros((1, 1), np.float32),
        pixel_angle_rad=1.0 / max(camera.fx, camera.fy),
        hits_compact=True,
    )


@dataclass(frozen=True)
class FastTerrainEngine:
    """Per-site state of the fast engine (pyramid, samplers, LUT); frames via
    :meth:`render`.

    Attributes:
        pyramid: the DEM mip pyramid. lut: the tabulated terrain reflectance.
        normals: (nx, ny) samplers of the smooth DEM normals. albedo: sampler or None.
        config: the shading config (shadow samples, albedo reference, ...).
        bin_factor, step_fraction, lod_factor: see :func:`trace_heightfield`.
    """

    pyramid: DemPyramid
    lut: ReflectanceLUT
    normals: tuple[RasterSampler, RasterSampler]
    albedo: RasterSampler | None
    config: ShadingConfig
    surface: np.ndarray
    surface_params: np.ndarray
    bin_factor: float = 1.0
    step_fraction: float = 1.0
    lod_factor: float = 1.0

    def render(
        self,
        *,
        camera: PinholeCamera,
        X_WC,
        illumination: Illumination,
        raycaster: TerrainRaycaster,
        brdf,
        lightmap: RasterSampler | None = None,
        track_depth: RasterSampler | None = None,
    ) -> ShadedImage:
        """One frame (same units and outputs as :func:`~lunar_drake.render.shading.shade`).

        Args:
            raycaster: holds the posed dynamic (rover) meshes; its static scene is unused.
            brdf: the exact terrain BRDF, used for the few rover pixels' shading call.
        """
        X = np.asarray(X_WC, np.float64)
        W, H = camera.width, camera.height
        tr = trace_heightfield(
            self.pyramid,
            width=W,
            height=H,
            fx=camera.fx,
            fy=camera.fy,
            cx=camera.cx,
            cy=camera.cy,
            X_WC=X,
            bin_factor=self.bin_factor,
            step_fraction=self.step_fraction,
            lod_factor=self.lod_factor,
        )
        t = tr.t
        R = tr.R_WC
        n = W * H
        cam = X[:3, 3].astype(np.float64)

        # rover pixels: Embree only where the rover's triangles project
        rover_idx = np.zeros(0, np.int64)
        rover_hits = None
        meshes = raycaster.dynamic_meshes
        if meshes:
            mask = rover_pixel_mask(meshes, raycaster._dyn_poses, camera, X)
            cand = np.flatnonzero(mask.reshape(-1))
            if cand.size:
                rays = np.empty((cand.size, 6), np.float32)
                rays[:, :3] = cam.astype(np.float32)
                rays[:, 3:] = tr.directions(cand).T
                hits = raycaster.cast_rays(rays, common_origin=True)
                closer = (hits.geometry_id != INVALID_ID) & (hits.t_hit < t[cand])
                k = np.flatnonzero(closer)
                rover_idx = cand[k]
                rover_hits = RayHits(
                    t_hit=hits.t_hit[k],
                    geometry_id=hits.geometry_id[k],
                    primitive_id=hits.primitive_id[k],
                    primitive_uvs=hits.primitive_uvs[k],
                    normals=hits.normals[k],
                )
        skip = np.zeros(n, np.uint8)
        skip[rover_idx] = 1

        # terrain shading kernel
        il = illumination
        ldirs, lirr, sun_light = [], [], -1
        if il.sun_irradiance > 0.0:
            sun_light = 0
            ldirs.append(il.sun_direction_W)
            lirr.append(il.sun_irradiance)
            if il.fill_fraction > 0.0:
                ldirs.append(tuple(fill_direction(il.sun_direction_W, il.fill_elevation_rad)))
                lirr.append(il.fill_fraction * il.sun_irradiance)
        if il.earth_direction_W is not None and il.earth_irradiance > 0.0:
            ldirs.append(il.earth_direction_W)
            lirr.append(il.earth_irradiance)
        ldirs_a = np.array(ldirs, np.float64).reshape(-1, 3)
        lirr_a = np.array(lirr, np.float64)
        sphere = np.zeros(7, np.float64)
        sph = raycaster.dynamic_bounding_sphere() if meshes else None
        if sph is not None and sun_light == 0:
            c, r = sph
            tan_a = math.tan(il.sun_angular_radius_rad)
            sphere[:] = [c[0], c[1], c[2], r, 1.0, 1.01 * tan_a, 2.0 * self.config.shadow_bias_m]
        lma, lpar = _tex_args(lightmap)
        gxa = gya = _NO_TEX
        gpar = _NO_PARAM
        if track_depth is not None:
            track_depth.gradient(np.zeros(1), np.zeros(1))  # builds the gradient rasters
            gxa, gya = track_depth._grad  # type: ignore[misc]
            _, gpar = _tex_args(track_depth)
            gpar = gpar.copy()
            gpar[5] = 0.0  # zero gradient outside (as RasterSampler.gradient)
        sun_t = np.empty(n, np.float32)
        other_t = np.empty(n, np.float32)
        cand = np.empty(n, np.uint8)
        rad = np.empty(n, np.float32)
        depth = np.empty(n, np.float32)
        label = np.empty(n, np.int16)
        tex = build_texture(self.config.texture)
        pix_ang = 1.0 / max(camera.fx, camera.fy)
        _shade_terrain(
            t, R, camera.fx, camera.fy, camera.cx, camera.cy, skip, W, H, cam,
            self.surface, self.surface_params, 1.0 / self.config.albedo_reference,
            lma, lpar, lightmap is not None, gxa, gya, gpar, track_depth is not None,
            tex.top, tex.bottom, tex.params, tex.period, tex.fade, tex.enabled, pix_ang,
            self.config.soft_shadows,
            self._lut_gie, ldirs_a, lirr_a, sun_light, sphere, sun_t, other_t, cand,
            rad, depth, label, workers(),
        )  # fmt: skip

        # soft rover shadow on the candidate terrain pixels
        ci = np.flatnonzero(cand)
        if ci.size:
            tc = t[ci]
            p = cam.astype(np.float32)[:, None] + tc[None, :] * tr.directions(ci)
            nx = self.normals[0](p[0], p[1])
            ny = self.normals[1](p[0], p[1])
            nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 1e-6, 1.0))
            f = rover_shadow_factor(
                raycaster,
                p,
                np.stack([nx, ny, nz]),
                il.sun_direction_W,
                angular_radius_rad=il.sun_angular_radius_rad,
                samples=self.config.shadow_samples,
                bias_m=self.config.shadow_bias_m,
                image_shape=(H, W),
                pixel_index=ci,
                pixel_footprint_m=tc * np.float32(1.0 / max(camera.fx, camera.fy)),
                max_penumbra_px=int(self.config.max_penumbra_px),
            )
            rad[ci] = sun_t[ci] * f + other_t[ci]

        if il.spotlights:
            self._spotlights(rad, label == 1, t, tr, cam, camera, il, raycaster, track_depth)
        if rover_idx.size:
            lab, _, _ = raycaster.classify(rover_hits.geometry_id, rover_hits.primitive_id)
            label[rover_idx] = lab
            d_C = camera_ray_directions(W, H, camera.fx, camera.fy, camera.cx, camera.cy)
            depth[rover_idx] = rover_hits.t_hit * d_C[2, rover_idx]
            rad[rover_idx] = self._shade_rover(
                rover_idx, rover_hits, tr, cam, camera, il, raycaster, brdf, lightmap
            )
        return ShadedImage(rad.reshape(H, W), depth.reshape(H, W), label.reshape(H, W))

    # ------------------------------------------------------------------------------------
    def _shade_rover(self, idx, hits, tr, cam, camera, il, raycaster, brdf, lightmap):
        d = tr.directions(idx)
        pos = cam.astype(np.float32)[:, None] + hits.t_hit[None, :] * d
        nrm = np.ascontiguousarray(hits.normals.T)
        flip = (nrm * d).sum(axis=0) > 0
        nrm[:, flip] *= np.float32(-1.0)
        gb = _compact_gbuffer(camera, idx, pos, nrm, -d, hits, dynamic=True)
        out = shade(
            gb, raycaster, il, brdf=brdf, albedo=None, lightmap=lightmap, config=self.config
        )
        return out.radiance.reshape(-1)[idx]

    def _spotlights(self, rad, terrain, t, tr, cam, camera, il, raycaster, track_depth):
        """Adds the spotlights on terrain pixels (the reference engine's numpy code)."""
        idx = np.flatnonzero(terrain)
        if idx.size == 0:
            return
        d = tr.directions(idx)
        pos = cam.astype(np.float32)[:, None] + t[idx][None, :] * d
        nx = self.normals[0](pos[0], pos[1])
        ny = self.normals[1](pos[0], pos[1])
        nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 1e-6, 1.0))
        nrm = np.stack([nx, ny, nz]).astype(np.float32)
        m = idx.size
        hits = RayHits(
            t_hit=t[idx],
            geometry_id=np.zeros(m, np.uint32),
            primitive_id=np.zeros(m, np.uint32),
            primitive_uvs=np.zeros((m, 2), np.float32),
            normals=nrm.T,
        )
        gb = _compact_gbuffer(camera, idx, pos, nrm, -d, hits, dynamic=False)
        n_b = nrm
        if track_depth is not None:
            from lunar_drake.render.shading import bumped_normals

            n_b = bumped_normals(gb, track_depth, self.config.bump_step_m)
        v = gb.view
        cos_e = np.maximum((n_b * v).sum(axis=0), 0.0).astype(np.float32)
        afac = (
            None
            if self.albedo is None
            else self.albedo(pos[0], pos[1]) * np.float32(1.0 / self.config.albedo_reference)
        )
        tex = build_texture(self.config.texture)
        if tex.enabled:  # as the kernel and the reference engine
            ifoot = inverse_footprint(t[idx], gb.pixel_angle_rad, cos_e)
            n_b, afac = apply_texture(tex, pos[0], pos[1], ifoot, n_b, afac)
            cos_e = np.maximum((n_b * v).sum(axis=0), 0.0).astype(np.float32)

        def radiance_term(cos_i, cos_g, sel=None, fn=None):
            ce = cos_e if sel is None else cos_e[sel]
            np.clip(cos_g, -1.0, 1.0, out=cos_g)
            f = self.lut(cos_i, ce, np.arccos(cos_g))
            if afac is not None:
                f = f * (afac if sel is None else afac[sel])
            return f.astype(np.float32)

        total = np.zeros(m, np.float32)
        for spot in il.spotlights:
            add_spotlight(total, gb, n_b, v, spot, radiance_term, raycaster, self.config)
        rad[idx] += total * np.float32(math.pi)

    @classmethod
    def build(
        cls,
        *,
        heightfield,
        reflectance,
        normals: tuple[RasterSampler, RasterSampler],
        albedo: RasterSampler | None,
        config: ShadingConfig,
        max_px: int = 8192,
        lut_size: int = 129,
    ) -> FastTerrainEngine:
        """Pyramid of the site DEM, the reflectance table and the surface texture
        (normal x, normal y and albedo interleaved on the normal map's grid; the albedo
        is resampled bilinearly when its grid differs) -- once per site/params."""
        nxs, nys = normals
        h, w = nxs.values.shape
        surf = np.zeros((h, w, 3), np.float32)
        surf[..., 0] = nxs.values
        surf[..., 1] = nys.values
        if albedo is None:
            surf[..., 2] = config.albedo_reference
        elif albedo.values.shape == (h, w) and tuple(albedo.bounds) == tuple(nxs.bounds):
            surf[..., 2] = albedo.values
        else:
            left, bottom, right, top = nxs.bounds
            xs = left + (np.arange(w) + 0.5) * (right - left) / w
            ys = top - (np.arange(h) + 0.5) * (top - bottom) / h
            X, Y = np.meshgrid(xs, ys)
            surf[..., 2] = albedo(X.ravel(), Y.ravel()).reshape(h, w)
        _, spar = _tex_args(nxs)
        return cls(
            pyramid=DemPyramid.from_heightfield(heightfield, max_px=max_px),
            lut=ReflectanceLUT.build(reflectance, n_i=lut_size, n_e=lut_size, n_g=lut_size),
            normals=normals,
            albedo=albedo,
            config=config,
            surface=surf,
            surface_params=spar,
        )

    @functools.cached_property
    def _lut_gie(self) -> np.ndarray:
        """The shading kernel's copy of the reflectance table (:func:`lut_phase_major`)."""
        return lut_phase_major(self.lut.table)

    def with_options(self, **kw) -> FastTerrainEngine:
        return replace(self, **kw)
