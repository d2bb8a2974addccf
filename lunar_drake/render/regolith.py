"""Sub-cell regolith texture: seeded, band-limited albedo and bump detail (issue 14).

The DEM (0.1 m cells on the default site) and its albedo map carry nothing below a cell,
so the foreground looked smooth and clay-like and a stereo matcher had nothing to lock
on. This module adds millimetre-to-decimetre detail as a pure function of the site
coordinates ``(x, y)`` and a seed -- the same for both cameras of a stereo pair and for
every frame, moving with the terrain:

* an **albedo modulation** ``albedo *= max(1 + a(x, y), 0.05)`` (relative, zero mean);
* a **bump** ``h(x, y)`` whose gradient tilts the shading normal,
  ``n' ~ (n_x / n_z - h_x, n_y / n_z - h_y, 1)`` (the hit point does not move; cast
  shadows and the lightmap ignore it).

Both are sums of octaves ``k = 0 .. K-1`` of wavelength ``lambda_k =
longest_wavelength_m / 2**k`` down to ``shortest_wavelength_m`` (defaults 8 cm .. 5 mm,
five octaves; the DEM's bilinear surface carries the scales of two 0.1 m cells and up)
with a fractal spectrum: an octave's height amplitude goes as
``lambda**hurst`` (its slope as ``lambda**(hurst - 1)``), its albedo amplitude as
``lambda**albedo_exponent``; the totals are ``rms_slope_deg`` and ``albedo_contrast``.

Tables. One periodic table of ``table_size``^2 texels holds band-limited noise: white
noise from ``np.random.default_rng(seed)`` filtered in Fourier space by a log-Gaussian
band one octave wide around 8 texels per wavelength (so it tiles exactly), the gradient
of a height noise (exact, from the spectrum) and an independent albedo noise, each
normalized to unit rms. Every octave reads it bilinearly, scaled, rotated and offset
differently (so neither the tiling nor the table's axes show). Each texel stores the
four corners of its bilinear cell (two int32 words, one gather each: 6-bit gradient
components over +-4 rms, 4-bit albedo over +-3 rms), so a sample is two loads; the
quantization adds noise of about 3 % (gradient) and 12 % (albedo) of an octave's rms.
The octave rotations are Pythagorean (``(a, b) / 65``), so the whole texture is periodic
with ``P = 65 * table_size * longest_wavelength_m / 8`` (83 m by default): site
coordinates are wrapped to ``[0, P)`` in float64 and the rest runs in float32, eight
pixels per vector instruction, with the same precision anywhere on a large site.

Band limit: an octave is off where its wavelength is below ``fade_footprints`` (2) pixel
footprints and fully on above twice that, linear in between,
``w = clip(lambda / (fade * footprint) - 1, 0, 1)``, so far terrain neither aliases nor
shimmers. The footprint is ``distance * pixel_angle / sqrt(max(cos_e, 0.05))``: the
distance over the focal length in pixels, stretched by the geometric mean of the
foreshortening (a footprint on grazing ground is ``1 / cos_e`` longer along the view).

:func:`sample_octave` (numba, ``inline="always"``) is the one-octave sampler; the fast
engine's shading kernel runs its halves, :func:`octave_cell` and :func:`octave_blend`, in
loops of their own with the two table reads in between (vector code on CPUs without
fast gathers); :func:`sample_texture_nb` sums the octaves per point
(numba) and :func:`sample_texture` is the numpy version of the reference engine (the
same float32 operations in the same order).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from lunar_drake.errors import OutOfRangeError

__all__ = [
    "RegolithTexture",
    "RegolithTextureConfig",
    "apply_texture",
    "build_texture",
    "inverse_footprint",
    "octave_blend",
    "octave_cell",
    "octave_weight",
    "sample_octave",
    "sample_texture",
    "sample_texture_nb",
    "wrap_coordinates",
]

TEXELS_PER_WAVELENGTH = 8
"""Centre wavelength of the table's noise band, in texels."""

PYTHAGOREAN_HYPOTENUSE = 65
_PAIRS = ((16, 63), (25, 60), (33, 56), (39, 52), (52, 39), (56, 33), (60, 25), (63, 16))

_BAND_SIGMA_OCTAVES = 0.35  # log2 width (sigma) of the band filter
_MIN_COS_E = 0.05  # foreshortening floor of the footprint
_MIN_ALBEDO_FACTOR = 0.05  # the albedo factor 1 + a is clamped here
GRAD_QUANT = 31.0 / 4.0  # 6-bit signed gradient: +-31 over +-4 rms
ALB_QUANT = 7.0 / 3.0  # 4-bit signed albedo: +-7 over +-3 rms

# columns of RegolithTexture.params (one row per octave)
P_CS, P_SS, P_OU, P_OV, P_COS, P_SIN, P_ALB, P_SLOPE, P_LAMBDA = range(9)


@dataclass(frozen=True)
class RegolithTextureConfig:
    """Sub-cell regolith texture (see the module docstring).

    Attributes:
        enabled: False = no texture (the DEM's albedo and normals only).
        seed: seeds the noise table and the octaves' rotations and offsets; fixed by
            default, so a site looks the same in every run, camera and frame.
        albedo_contrast: rms of the relative albedo modulation, all octaves on, [0, 0.5].
        rms_slope_deg: rms slope of the bump (of the gradient's magnitude), all octaves
            on, deg, [0, 30].
        longest_wavelength_m: wavelength of the coarsest octave (m), (0, 10].
        shortest_wavelength_m: the finest octave is the last halving of the wavelength
            at or above this (m), (0, longest_wavelength_m]; at most 12 octaves.
        hurst: height amplitude per octave ~ ``lambda**hurst`` (slope ~
            ``lambda**(hurst - 1)``: below 1 the fine scales are steeper), [0, 2].
        albedo_exponent: albedo amplitude per octave ~ ``lambda**albedo_exponent``, [-1, 2].
        fade_footprints: an octave fades out between ``2 x`` and ``1 x`` this many pixel
            footprints of wavelength, [1, 8].
        table_size: side of the periodic noise table (texels), a power of two in
            [32, 512].
    """

    enabled: bool = True
    seed: int = 14
    albedo_contrast: float = 0.08
    rms_slope_deg: float = 5.0
    longest_wavelength_m: float = 0.08
    shortest_wavelength_m: float = 0.005
    hurst: float = 0.8
    albedo_exponent: float = 0.3
    fade_footprints: float = 2.0
    table_size: int = 128

    def __post_init__(self) -> None:
        def check(name: str, lo: float, hi: float, *, open_lo: bool = False) -> None:
            v = getattr(self, name)
            ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            ok = ok and (v > lo if open_lo else v >= lo) and v <= hi
            if not ok:
                bound = f"({lo:g}, {hi:g}]" if open_lo else f"[{lo:g}, {hi:g}]"
                raise OutOfRangeError(f"texture {name} = {v!r} is invalid; allowed {bound}")

        if not isinstance(self.enabled, bool):
            raise OutOfRangeError(f"texture enabled = {self.enabled!r} is invalid; a bool")
        if not (
            isinstance(self.seed, int | np.integer)
            and not isinstance(self.seed, bool)
            and 0 <= self.seed < 2**63
        ):
            raise OutOfRangeError(f"texture seed = {self.seed!r} is invalid; an integer >= 0")
        check("albedo_contrast", 0.0, 0.5)
        check("rms_slope_deg", 0.0, 30.0)
        check("longest_wavelength_m", 0.0, 10.0, open_lo=True)
        check("shortest_wavelength_m", 0.0, self.longest_wavelength_m, open_lo=True)
        check("hurst", 0.0, 2.0)
        check("albedo_exponent", -1.0, 2.0)
        check("fade_footprints", 1.0, 8.0)
        n = self.table_size
        if not (
            isinstance(n, int | np.integer)
            and not isinstance(n, bool)
            and 32 <= n <= 512
            and n & (n - 1) == 0
        ):
            raise OutOfRangeError(
                f"texture table_size = {n!r} is invalid; a power of two in [32, 512]"
            )
        if self.octaves > 12:
            raise OutOfRangeError(
                f"texture shortest_wavelength_m = {self.shortest_wavelength_m!r} gives "
                f"{self.octaves} octaves; at most 12 (longest / shortest < 2**12)"
            )

    @property
    def octaves(self) -> int:
        """Number of octaves: wavelengths ``longest / 2**k >= shortest``."""
        r = self.longest_wavelength_m / self.shortest_wavelength_m
        return math.floor(math.log2(r) + 1e-9) + 1

    @property
    def wavelengths_m(self) -> np.ndarray:
        return self.longest_wavelength_m / 2.0 ** np.arange(self.octaves)

    @property
    def period_m(self) -> float:
        """The texture's period in x and y (m)."""
        return (
            PYTHAGOREAN_HYPOTENUSE
            * self.table_size
            * self.longest_wavelength_m
            / TEXELS_PER_WAVELENGTH
        )


@dataclass(frozen=True, eq=False)
class RegolithTexture:
    """The built table of one :class:`RegolithTextureConfig`.

    Attributes:
        top, bottom: ``(S * S,)`` int32: per texel ``(j, i)`` the corners ``(j, i)``,
            ``(j, i + 1)`` (``top``, low and high 16 bits) and ``(j + 1, i)``,
            ``(j + 1, i + 1)`` (``bottom``), each gradient u (bits 0-5), gradient v
            (6-11), albedo (12-15), signed, in units of ``1 / GRAD_QUANT`` and
            ``1 / ALB_QUANT`` of the unit-rms fields.
        params: ``(K, 9)`` float64 per octave: the rotation times texels per metre
            (``cs``, ``ss``), offsets u and v (texels), the unit rotation (cos, sin),
            albedo weight, slope weight (per axis), wavelength (m).
        size: S. period: the texture's period (m). fade: ``fade_footprints``.
        enabled: the config's flag (and a non-zero amplitude).
    """

    config: RegolithTextureConfig
    top: np.ndarray
    bottom: np.ndarray
    params: np.ndarray
    size: int
    period: float
    fade: float
    enabled: bool


def _band(size: int) -> np.ndarray:
    k = np.fft.fftfreq(size, 1.0 / size)
    kr = np.hypot(k[None, :], k[:, None])
    k0 = size / TEXELS_PER_WAVELENGTH
    lg = np.log2(np.where(kr > 0, kr, 1.0) / k0)
    f = np.exp(-0.5 * (lg / _BAND_SIGMA_OCTAVES) ** 2)
    f[0, 0] = 0.0
    return f


def _quantize(v: np.ndarray, scale: float, lim: int) -> np.ndarray:
    return np.clip(np.rint(v * scale), -lim, lim).astype(np.int64)


def pack_corners(gu: np.ndarray, gv: np.ndarray, a: np.ndarray):
    """``(top, bottom)`` int32 words of unit-rms fields on an (S, S) periodic grid."""
    q = (
        (_quantize(gu, GRAD_QUANT, 31) & 0x3F)
        | ((_quantize(gv, GRAD_QUANT, 31) & 0x3F) << 6)
        | ((_quantize(a, ALB_QUANT, 7) & 0xF) << 12)
    )
    right = np.roll(q, -1, axis=1)  # (j, i + 1)
    top = q | (right << 16)
    bottom = np.roll(top, -1, axis=0)  # (j + 1, i), (j + 1, i + 1)
    return (
        top.astype(np.uint32).view(np.int32).reshape(-1),
        bottom.astype(np.uint32).view(np.int32).reshape(-1),
    )


@functools.lru_cache(maxsize=8)
def build_texture(config: RegolithTextureConfig) -> RegolithTexture:
    """The noise table and per-octave parameters (numpy, deterministic; cached)."""
    s = int(config.table_size)
    rng = np.random.default_rng([int(config.seed), 0x5E60_1174])
    band = _band(s)
    k = np.fft.fftfreq(s, 1.0 / s)
    fa = np.fft.fft2(rng.standard_normal((s, s))) * band
    fh = np.fft.fft2(rng.standard_normal((s, s))) * band
    a = np.fft.ifft2(fa).real
    gu = np.fft.ifft2(fh * (2j * math.pi / s) * k[None, :]).real  # d/d column
    gv = np.fft.ifft2(fh * (2j * math.pi / s) * k[:, None]).real  # d/d row
    g = math.sqrt(0.5 * (np.mean(gu * gu) + np.mean(gv * gv)))
    top, bottom = pack_corners(gu / g, gv / g, a / a.std())

    lam = config.wavelengths_m
    K = lam.size
    aw = lam**config.albedo_exponent
    aw *= config.albedo_contrast / math.sqrt(float(np.sum(aw * aw)))
    sw = lam ** (config.hurst - 1.0)
    # rms of the gradient magnitude = tan(rms slope); per axis 1 / sqrt(2) of it
    sw *= math.tan(math.radians(config.rms_slope_deg)) / math.sqrt(2.0 * float(np.sum(sw * sw)))
    dirs = np.array(
        [(a_ / 65.0, b_ / 65.0) for a_, b_ in _PAIRS]
        + [(-b_ / 65.0, a_ / 65.0) for a_, b_ in _PAIRS]
        + [(-a_ / 65.0, -b_ / 65.0) for a_, b_ in _PAIRS]
        + [(b_ / 65.0, -a_ / 65.0) for a_, b_ in _PAIRS]
    )
    pick = rng.permutation(dirs.shape[0])[:K] if K <= dirs.shape[0] else rng.integers(0, 32, K)
    cs = dirs[pick]
    off = rng.integers(0, s, (K, 2)) + rng.uniform(0.0, 1.0, (K, 2))
    params = np.zeros((K, 9), np.float64)
    scale = TEXELS_PER_WAVELENGTH / lam
    params[:, P_CS] = cs[:, 0] * scale
    params[:, P_SS] = cs[:, 1] * scale
    params[:, P_OU] = off[:, 0]
    params[:, P_OV] = off[:, 1]
    params[:, P_COS] = cs[:, 0]
    params[:, P_SIN] = cs[:, 1]
    params[:, P_ALB] = aw / ALB_QUANT
    params[:, P_SLOPE] = sw / GRAD_QUANT
    params[:, P_LAMBDA] = lam
    for arr in (top, bottom, params):
        arr.setflags(write=False)
    return RegolithTexture(
        config=config,
        top=top,
        bottom=bottom,
        params=params,
        size=s,
        period=config.period_m,
        fade=float(config.fade_footprints),
        enabled=bool(config.enabled) and (config.albedo_contrast > 0 or config.rms_slope_deg > 0),
    )


# ----------------------------------------------------------------------------------------
# numba samplers
# ----------------------------------------------------------------------------------------
def _field(lo: int, bits: int):
    """An intrinsic: the signed ``bits``-bit field at bit ``lo`` of a 32-bit word as
    float32 (32-bit shifts: numba would widen them to 64 bits, halving the vectors)."""

    @intrinsic
    def field_f32(typingctx, w):
        def codegen(context, builder, signature, args):
            (v,) = args
            i32 = ir.IntType(32)
            if v.type.width > 32:
                v = builder.trunc(v, i32)
            x = builder.shl(v, ir.Constant(i32, 32 - lo - bits))
            x = builder.ashr(x, ir.Constant(i32, 32 - bits))
            return builder.sitofp(x, ir.FloatType())

        return types.float32(w), codegen

    return field_f32


@intrinsic
def load_i32(typingctx, arr, k):
    """``arr[k]`` of a contiguous 1-D array with a 32-bit index and no negative-index
    wraparound (the caller guarantees ``0 <= k < arr.size``): the vectorizer then
    emits 32-bit-index gathers, about a quarter faster than numba's indexing."""

    def codegen(context, builder, signature, args):
        a, kk = args
        ary = context.make_array(signature.args[0])(context, builder, value=a)
        i32 = ir.IntType(32)
        if kk.type.width > 32:
            kk = builder.trunc(kk, i32)
        ptr = builder.gep(ary.data, [builder.sext(kk, ir.IntType(64))], inbounds=True)
        return builder.load(ptr)

    return arr.dtype(arr, k), codegen


@intrinsic
def load_pair_f32(typingctx, arr, k):
    """``(arr[k], arr[k + 1])`` of a contiguous float32 array (flat index, 32 bits, no
    wraparound; the caller guarantees ``0 <= k`` and ``k + 1 < arr.size``) as one 64-bit
    load: a loop of table reads issues half the loads."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.float32):
        return None

    def codegen(context, builder, signature, args):
        a, kk = args
        ary = context.make_array(signature.args[0])(context, builder, value=a)
        i32 = ir.IntType(32)
        if kk.type.width > 32:
            kk = builder.trunc(kk, i32)
        ptr = builder.gep(ary.data, [builder.sext(kk, ir.IntType(64))], inbounds=True)
        vty = ir.VectorType(ir.FloatType(), 2)
        v = builder.load(builder.bitcast(ptr, vty.as_pointer()), align=4)
        lo = builder.extract_element(v, ir.Constant(i32, 0))
        hi = builder.extract_element(v, ir.Constant(i32, 1))
        return context.make_tuple(builder, signature.return_type, (lo, hi))

    return types.UniTuple(types.float32, 2)(arr, k), codegen


_gu_lo, _gv_lo, _a_lo = _field(0, 6), _field(6, 6), _field(12, 4)
_gu_hi, _gv_hi, _a_hi = _field(16, 6), _field(22, 6), _field(28, 4)


@numba.njit(cache=True, inline="always", error_model="numpy")
def octave_weight(lam_over_fade, inv_foot):
    """Band-limit weight of an octave: ``clip(lambda / (fade * foot) - 1, 0, 1)``
    (float32; ``lam_over_fade = lambda / fade``, ``inv_foot = 1 / footprint``)."""
    w = np.float32(lam_over_fade) * inv_foot - np.float32(1.0)
    return min(max(w, np.float32(0.0)), np.float32(1.0))


@numba.njit(cache=True, inline="always", error_model="numpy")
def wrap_coordinates(x, period):
    """Site coordinate wrapped to ``[0, period)`` (float64 in, float32 out)."""
    return np.float32(x - period * np.floor(x * (1.0 / period)))


@numba.njit(cache=True, inline="always", error_model="numpy")
def octave_cell(size, inv_size, cs, ss, ou, ov, x, y):
    """The table cell of one octave at wrapped site coordinates (x, y): ``(k, du, dv)``,
    the flat int32 texel index and the float32 fractions inside it (no table reads: the
    fast engine runs this as vector code, then the two loads in a loop of their own)."""
    u = cs * x - ss * y + ou
    v = ss * x + cs * y + ov
    u = u - size * np.floor(u * inv_size)
    v = v - size * np.floor(v * inv_size)
    fu = np.floor(u)
    fv = np.floor(v)
    return np.int32(fv * size + fu), u - fu, v - fv


@numba.njit(cache=True, inline="always", error_model="numpy")
def octave_blend(p, q, du, dv):
    """``(albedo noise, dN/du, dN/dv)`` from a cell's two words ``p = top[k]``, ``q =
    bottom[k]`` and the fractions of :func:`octave_cell` (float32, no table reads)."""
    one = np.float32(1.0)
    w00 = (one - dv) * (one - du)
    w01 = (one - dv) * du
    w10 = dv * (one - du)
    w11 = dv * du
    a = w00 * _a_lo(p) + w01 * _a_hi(p) + w10 * _a_lo(q) + w11 * _a_hi(q)
    gu = w00 * _gu_lo(p) + w01 * _gu_hi(p) + w10 * _gu_lo(q) + w11 * _gu_hi(q)
    gv = w00 * _gv_lo(p) + w01 * _gv_hi(p) + w10 * _gv_lo(q) + w11 * _gv_hi(q)
    return a, gu, gv


@numba.njit(cache=True, inline="always", error_model="numpy")
def sample_octave(top, bottom, size, inv_size, cs, ss, ou, ov, x, y):
    """One octave at wrapped site coordinates (x, y) (float32, from
    :func:`wrap_coordinates`): ``(albedo noise, dN/du, dN/dv)`` in table units (the
    caller rotates the gradient with the octave's (cos, sin) and applies the weights).

    ``size``, ``inv_size``: S and 1 / S (float32); ``cs, ss``: the rotation times texels
    per metre; ``(ou, ov)`` the offset (texels). All float32, two loads:
    :func:`octave_cell` then :func:`octave_blend`."""
    k, du, dv = octave_cell(size, inv_size, cs, ss, ou, ov, x, y)
    return octave_blend(load_i32(top, k), load_i32(bottom, k), du, dv)


@numba.njit(cache=True, error_model="numpy")
def sample_texture_nb(top, bottom, params, period, fade, x, y, inv_foot, out_a, out_gx, out_gy):
    """Per point (numba): ``out_a`` the relative albedo modulation, ``out_gx, out_gy``
    the bump gradient (site axes, m/m), octaves weighted by :func:`octave_weight` of the
    inverse footprint ``inv_foot`` (1/m, :func:`inverse_footprint`)."""
    size = np.float32(np.sqrt(top.size))
    inv = np.float32(1.0) / size
    for p in range(x.size):
        fp = np.float32(inv_foot[p])
        xw = wrap_coordinates(x[p], period)
        yw = wrap_coordinates(y[p], period)
        sa = np.float32(0.0)
        sx = np.float32(0.0)
        sy = np.float32(0.0)
        for k in range(params.shape[0]):
            w = octave_weight(params[k, P_LAMBDA] / fade, fp)
            a, gu, gv = sample_octave(
                top, bottom, size, inv,
                np.float32(params[k, P_CS]), np.float32(params[k, P_SS]),
                np.float32(params[k, P_OU]), np.float32(params[k, P_OV]), xw, yw,
            )  # fmt: skip
            c = np.float32(params[k, P_COS])
            s = np.float32(params[k, P_SIN])
            wa = w * np.float32(params[k, P_ALB])
            ws = w * np.float32(params[k, P_SLOPE])
            sa += wa * a
            sx += ws * (c * gu + s * gv)
            sy += ws * (c * gv - s * gu)
        out_a[p] = sa
        out_gx[p] = sx
        out_gy[p] = sy


# ----------------------------------------------------------------------------------------
# numpy sampler (reference engine)
# ----------------------------------------------------------------------------------------
def _fields_np(w: np.ndarray, lo: int, bits: int) -> np.ndarray:
    return ((w << np.int32(32 - lo - bits)) >> np.int32(32 - bits)).astype(np.float32)


def sample_texture(
    tex: RegolithTexture, x, y, inv_foot
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """numpy version of :func:`sample_texture_nb`: ``(a, gx, gy)`` float32 at site points
    ``(x, y)`` (m) with inverse pixel footprints ``inv_foot`` (1/m)."""
    x = np.asarray(x, np.float64).reshape(-1)
    y = np.asarray(y, np.float64).reshape(-1)
    fp = np.asarray(inv_foot, np.float32).reshape(-1)
    m = x.size
    sa = np.zeros(m, np.float32)
    sx = np.zeros(m, np.float32)
    sy = np.zeros(m, np.float32)
    P = tex.period
    xw = (x - P * np.floor(x * (1.0 / P))).astype(np.float32)
    yw = (y - P * np.floor(y * (1.0 / P))).astype(np.float32)
    size = np.float32(tex.size)
    inv = np.float32(1.0) / size
    one = np.float32(1.0)
    for k in range(tex.params.shape[0]):
        cs, ss, ou, ov, c, s, alb, slope, lam = tex.params[k]
        w = np.float32(lam / tex.fade) * fp - one
        np.clip(w, 0.0, 1.0, out=w)
        sel = np.flatnonzero(w > 0)
        if sel.size == 0:
            continue
        xs, ys, ws = xw[sel], yw[sel], w[sel]
        cs32, ss32 = np.float32(cs), np.float32(ss)
        u = cs32 * xs - ss32 * ys + np.float32(ou)
        v = ss32 * xs + cs32 * ys + np.float32(ov)
        u = u - size * np.floor(u * inv)
        v = v - size * np.floor(v * inv)
        fu = np.floor(u)
        fv = np.floor(v)
        kk = (fv * size + fu).astype(np.int32)
        du = u - fu
        dv = v - fv
        w00 = (one - dv) * (one - du)
        w01 = (one - dv) * du
        w10 = dv * (one - du)
        w11 = dv * du
        p = tex.top[kk]
        q = tex.bottom[kk]

        def bil(lo, bits, p=p, q=q, w00=w00, w01=w01, w10=w10, w11=w11):
            return (
                w00 * _fields_np(p, lo, bits)
                + w01 * _fields_np(p, lo + 16, bits)
                + w10 * _fields_np(q, lo, bits)
                + w11 * _fields_np(q, lo + 16, bits)
            )

        a, gu, gv = bil(12, 4), bil(0, 6), bil(6, 6)
        c32, s32 = np.float32(c), np.float32(s)
        wa = ws * np.float32(alb)
        wsl = ws * np.float32(slope)
        sa[sel] += wa * a
        sx[sel] += wsl * (c32 * gu + s32 * gv)
        sy[sel] += wsl * (c32 * gv - s32 * gu)
    return sa, sx, sy


def inverse_footprint(distance, pixel_angle_rad: float, cos_e) -> np.ndarray:
    """1 / texture footprint (1/m, float32): ``sqrt(max(cos_e, 0.05)) / (distance *
    pixel_angle)`` (the fast engine computes the same in float32)."""
    ce = np.maximum(np.asarray(cos_e, np.float32), np.float32(_MIN_COS_E))
    d = np.asarray(distance, np.float32) * np.float32(pixel_angle_rad)
    return (np.sqrt(ce) / d).astype(np.float32)


def apply_texture(tex: RegolithTexture, x, y, inv_foot, normal, afac):
    """Textured ``(normal, afac)`` at terrain points: ``normal`` (3, M) unit normals,
    ``afac`` (M,) albedo factors or None (= 1). Returns new float32 arrays."""
    a, gx, gy = sample_texture(tex, x, y, inv_foot)
    n = np.asarray(normal, np.float32)
    rz = np.float32(1.0) / np.maximum(n[2], np.float32(1e-3))
    bx = n[0] * rz - gx
    by = n[1] * rz - gy
    inv = np.float32(1.0) / np.sqrt(bx * bx + by * by + np.float32(1.0))
    out_n = np.stack([bx * inv, by * inv, inv]).astype(np.float32)
    fac = np.maximum(np.float32(1.0) + a, np.float32(_MIN_ALBEDO_FACTOR))
    out_a = fac if afac is None else np.asarray(afac, np.float32) * fac
    return out_n, out_a
