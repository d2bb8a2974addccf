"""Camera sensor model: radiance -> electrons -> noisy 12-bit raw image.

Paper section 5 ("Camera Exposure and Bit Depth"): the simulator emulated exposure "with
a linear multiplier on the output color" of the shaders, rendered 16-bit integer images
and "downsampled to 12-bit as a post-render step" because "the reference mission cameras
under consideration have a bit depth of 12". Both paths are here:

* :func:`quantize_16bit` + :func:`downsample_bits` -- the paper's path: a linear float
  image times an exposure multiplier, scaled to 0..65535, then shifted to 12 bits.
* :func:`expose` -- a physical sensor: band radiance -> photo-electrons through the
  optics, Poisson shot noise, dark current, full-well clipping, read noise, analog gain and
  ADC quantisation, stored as uint16 (0..4095, or MSB-aligned 0..65520 on request).

Radiometry (on-axis, paraxial camera equation; vignetting/cos^4 fall-off are left to the
renderer)::

    E_focal   = pi L T / (4 N^2)                    W m^-2    (L: band radiance, W m^-2 sr^-1)
    rate_e    = E_focal * A_pix * QE * lambda / (h c)   e- s^-1
    L         = (I/F) * E_sun,band / (pi d_AU^2)           (radiance from a radiance factor)

``lambda`` is the band's effective wavelength (a panchromatic band treated as
monochromatic), ``E_sun,band`` the solar irradiance integrated over the band at 1 AU.

Noise (all of it counter-based: the draw for a pixel depends only on ``(key,
frame_index, row, col, channel)`` through :mod:`lunar_drake.rng`, so a frame is
bit-identical across runs and no RNG state exists outside the caller):

* shot noise: exact Poisson by inverse-CDF search on a hash uniform for means below
  :data:`POISSON_EXACT_BELOW` electrons; above, a Gaussian with the Poisson variance
  (Irwin-Hall hash normal, +-3.46 sigma support) rounded to whole electrons;
* dark current: its electrons join the Poisson mean;
* full well: collected electrons are clipped at ``full_well_e`` before the readout;
* read noise: Gaussian, ``read_noise_e`` rms in electrons;
* ADC: ``DN = round(electrons * gain / e_per_dn) + black_level_dn`` clipped to
  ``[0, 2**adc_bits - 1]``. With ``gain = 1`` the full well maps to the top code when
  ``gain_e_per_dn`` is left to its default.

:func:`expose` runs a numba kernel (image rows in parallel, SIMD within a row: about 3 ms
for a lit 1280 x 960 frame on two cores, up to ~16 ms when every pixel holds 5-20 e-, where
the exact Poisson search dominates) whose output is bit-identical to the numpy reference
``_expose_2d_numpy`` whatever the thread count. Both evaluate ``exp`` with the C
library's ``exp`` (numpy's SIMD ``np.exp`` differs from it by an ulp on a few per cent of
arguments), so a frame is reproducible on one platform; across C libraries a pixel with
a mean below :data:`POISSON_EXACT_BELOW` may in rare cases differ by one electron.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import math
import threading
import warnings
from dataclasses import dataclass

import numba
import numpy as np

from lunar_drake import rng
from lunar_drake.errors import ConfigError, OutOfRangeError, format_value
from lunar_drake.render.row_queue import fetch_add, workers

H_PLANCK = 6.62607015e-34
"""Planck constant (J s, exact SI)."""
C_LIGHT = 299_792_458.0
"""Speed of light (m/s, exact SI)."""

POISSON_EXACT_BELOW = 20.0
"""Mean electron count below which shot noise is drawn from the exact Poisson law."""

_SHOT, _READ = 0, 1


@dataclass
class SensorParams:
    """Camera sensor and optics (a CMV4000-class global-shutter CMOS, values from memory).

    The preset follows the ams/CMOSIS CMV4000 datasheet (2048 x 2048, 5.5 um pixels,
    10/12-bit ADC, full well ~13.5 ke-, read noise ~13 e- rms, dark current ~125 e-/s at
    25 C) -- a sensor class used on space navigation cameras; numbers **from memory**.
    The optics (f/8, transmission 0.85) stand in for a rover navigation camera (depth of
    field from ~1 m to the horizon); the band is a 400-700 nm panchromatic one.

    Attributes:
        full_well_e: full-well capacity (electrons).
        read_noise_e: temporal read noise (electrons rms).
        adc_bits: ADC resolution (bits), 8..16; the paper's reference cameras are 12-bit.
        gain_e_per_dn: conversion at unity analog gain (e-/DN); None derives
            full_well_e / (2**adc_bits - 1) so that the full well fills the ADC.
        quantum_efficiency: band-averaged QE x fill factor, in (0, 1].
        pixel_pitch_um: pixel pitch (um).
        f_number: lens f-number N.
        optics_transmission: lens + window transmission T, in (0, 1].
        wavelength_um: effective wavelength of the band (um), sets the photon energy.
        band_solar_irradiance_W_m2: solar irradiance over the band at 1 AU (W m^-2);
            ~540 W m^-2 for 400-700 nm, about 40 % of the 1361 W m^-2 total solar
            irradiance (Kopp & Lean 2011, GRL 38, L01706; band fraction from the ASTM
            E-490 AM0 spectrum, from memory). Used by :func:`radiance_from_i_over_f`.
        dark_current_e_s: dark current (e- per second).
        black_level_dn: ADC offset (DN) added after the gain.
        min_exposure_s, max_exposure_s: allowed exposure time range (s).
        max_gain: largest analog gain (dimensionless); gains lie in (0, max_gain].
        msb_aligned: store codes left-shifted by 16 - adc_bits (0..65520) instead of
            right-aligned (0..4095 for 12 bits).
    """

    full_well_e: float = 13_500.0
    read_noise_e: float = 13.0
    adc_bits: int = 12
    gain_e_per_dn: float | None = None
    quantum_efficiency: float = 0.5
    pixel_pitch_um: float = 5.5
    f_number: float = 8.0
    optics_transmission: float = 0.85
    wavelength_um: float = 0.55
    band_solar_irradiance_W_m2: float = 540.0
    dark_current_e_s: float = 125.0
    black_level_dn: int = 0
    min_exposure_s: float = 1e-5
    max_exposure_s: float = 10.0
    max_gain: float = 8.0
    msb_aligned: bool = False

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        _positive("full_well_e", self.full_well_e)
        _nonneg("read_noise_e", self.read_noise_e)
        if not isinstance(self.adc_bits, int) or not 8 <= self.adc_bits <= 16:
            raise OutOfRangeError(f"adc_bits = {self.adc_bits!r} must be an integer in [8, 16]")
        if self.gain_e_per_dn is not None:
            _positive("gain_e_per_dn", self.gain_e_per_dn)
        _unit("quantum_efficiency", self.quantum_efficiency)
        _positive("pixel_pitch_um", self.pixel_pitch_um)
        _positive("f_number", self.f_number)
        _unit("optics_transmission", self.optics_transmission)
        _positive("wavelength_um", self.wavelength_um)
        _positive("band_solar_irradiance_W_m2", self.band_solar_irradiance_W_m2)
        _nonneg("dark_current_e_s", self.dark_current_e_s)
        if not isinstance(self.black_level_dn, int) or not (
            0 <= self.black_level_dn < (1 << self.adc_bits)
        ):
            raise OutOfRangeError(
                f"black_level_dn = {self.black_level_dn!r} must be an integer in "
                f"[0, {(1 << self.adc_bits) - 1}]"
            )
        _positive("min_exposure_s", self.min_exposure_s)
        if not self.max_exposure_s >= self.min_exposure_s:
            raise OutOfRangeError(
                f"max_exposure_s = {format_value(self.max_exposure_s)} must be >= "
                f"min_exposure_s = {format_value(self.min_exposure_s)}"
            )
        _positive("max_gain", self.max_gain)

    @property
    def e_per_dn(self) -> float:
        """Conversion at unity analog gain (e-/DN)."""
        if self.gain_e_per_dn is not None:
            return float(self.gain_e_per_dn)
        return self.full_well_e / ((1 << self.adc_bits) - 1)

    @property
    def max_code(self) -> int:
        """Largest ADC code (2**adc_bits - 1)."""
        return (1 << self.adc_bits) - 1

    @property
    def electrons_per_radiance(self) -> float:
        """Photo-electron rate per unit band radiance ((e-/s) / (W m^-2 sr^-1))."""
        a_pix = (self.pixel_pitch_um * 1e-6) ** 2
        photon_j = H_PLANCK * C_LIGHT / (self.wavelength_um * 1e-6)
        etendue = math.pi * self.optics_transmission / (4.0 * self.f_number**2)
        return etendue * a_pix * self.quantum_efficiency / photon_j


def _positive(name: str, v) -> None:
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise OutOfRangeError(f"{name} = {format_value(v)} must be a finite number > 0")


def _nonneg(name: str, v) -> None:
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
        raise OutOfRangeError(f"{name} = {format_value(v)} must be a finite number >= 0")


def _unit(name: str, v) -> None:
    if not (isinstance(v, (int, float)) and 0 < v <= 1):
        raise OutOfRangeError(f"{name} = {format_value(v)} must lie in (0, 1]")


CMV4000_NAVCAM = SensorParams()
"""The default preset (see :class:`SensorParams`)."""


# ----------------------------------------------------------------------------- radiometry


def radiance_from_i_over_f(
    i_over_f, *, params: SensorParams = CMV4000_NAVCAM, sun_distance_au: float = 1.0
) -> np.ndarray:
    """Band radiance L (W m^-2 sr^-1) of a surface with radiance factor I/F under the Sun.

    ``L = (I/F) E_sun,band / (pi d^2)`` with ``d`` the Sun distance (AU). I/F is
    ``pi r`` of :mod:`lunar_drake.render.hapke` times any shadowing the renderer applies.
    """
    _positive("sun_distance_au", sun_distance_au)
    e_band = params.band_solar_irradiance_W_m2 / sun_distance_au**2
    return np.asarray(i_over_f, dtype=np.float64) * (e_band / math.pi)


def electron_rate(radiance, *, params: SensorParams = CMV4000_NAVCAM) -> np.ndarray:
    """Mean photo-electron rate per pixel (e-/s) for band radiance L (W m^-2 sr^-1)."""
    return np.asarray(radiance, dtype=np.float64) * params.electrons_per_radiance


def exposure_for_level(
    radiance,
    *,
    level: float = 0.8,
    gain: float = 1.0,
    params: SensorParams = CMV4000_NAVCAM,
) -> float:
    """Exposure time (s) putting ``radiance`` at ``level`` of the ADC range (mean signal).

    A simple auto-exposure (the paper's "dynamic exposure" commands): pass a reference
    radiance of the scene (e.g. a high percentile). Clipped to the allowed range.
    """
    if not 0 < level <= 1:
        raise OutOfRangeError(f"level={level!r} must lie in (0, 1]")
    _check_gain(gain, params)
    rate = float(np.max(electron_rate(radiance, params=params)))
    target_e = level * (params.max_code - params.black_level_dn) * params.e_per_dn / gain
    target_e = min(target_e, level * params.full_well_e)
    if rate + params.dark_current_e_s <= 0:
        return params.max_exposure_s
    t = target_e / (rate + params.dark_current_e_s)
    return float(min(max(t, params.min_exposure_s), params.max_exposure_s))


# ----------------------------------------------------------------------------- exposure


def _check_exposure(exposure_s, params: SensorParams) -> float:
    t = float(exposure_s)
    if not (math.isfinite(t) and params.min_exposure_s <= t <= params.max_exposure_s):
        raise OutOfRangeError(
            f"exposure_s={exposure_s!r} must lie in [{params.min_exposure_s:g}, "
            f"{params.max_exposure_s:g}] s"
        )
    return t


def _check_gain(gain, params: SensorParams) -> float:
    g = float(gain)
    if not (math.isfinite(g) and 0 < g <= params.max_gain):
        raise OutOfRangeError(f"gain={gain!r} must lie in (0, {params.max_gain:g}]")
    return g


def _subkey(key: int, frame_index: int, index: int) -> int:
    return int(rng.hash_bits(key, frame_index, index))


_BLOCK = 1 << 14


def _poisson_block(lam: np.ndarray, u: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Poisson draws for one block: exact inversion below the threshold, Gaussian above.

    The inversion runs the CDF recursion p_k = p_(k-1) lam / k over the whole block
    (arithmetic only, no data-dependent indexing) until every pixel's uniform lies below
    its CDF; pixels at or above the threshold run it on a clipped mean and take the
    Gaussian draw instead. A pixel's count is min(first k with u < cdf_k, _POISSON_KMAX)
    whatever the block holds; the numba kernel reproduces it bit for bit.
    """
    thr = POISSON_EXACT_BELOW
    k_gauss = np.maximum(np.floor(lam + np.sqrt(lam) * z + 0.5), 0.0)
    if lam.min() >= thr:
        return k_gauss
    lc = np.minimum(lam, thr)
    low = lam < thr
    p = np.full_like(lc, math.exp(-thr))
    p[low] = _exp_libm(-lc[low])
    cdf = p.copy()
    k = np.zeros_like(lc)
    more = u >= cdf
    n = 0
    while n < _POISSON_KMAX and more.any():
        n += 1
        p *= lc * (1.0 / n)
        cdf += p
        k += more
        np.greater_equal(u, cdf, out=more)
    return np.where(low, k, k_gauss)


def _exp_libm(x: np.ndarray) -> np.ndarray:
    """``exp`` element-wise through the C library (``math.exp``), as the numba kernel calls it.

    ``np.exp``'s SIMD loops differ from libm's ``exp`` by an ulp on a few per cent of
    arguments, which would let a Poisson draw differ between the two implementations.
    """
    return np.fromiter(map(math.exp, x.tolist()), dtype=np.float64, count=x.size)


_POISSON_KMAX = 200


def shot_noise_electrons(mean_e, *, key: int, frame_index: int, channel: int = 0) -> np.ndarray:
    """Poisson-distributed electron counts (float64, whole numbers) with mean ``mean_e``.

    ``mean_e`` is 2-D (rows, cols); the draw for pixel (r, c) depends only on
    ``(key, frame_index, channel, r, c)``. Exact Poisson below
    :data:`POISSON_EXACT_BELOW` electrons, rounded Gaussian above.
    """
    lam = np.ascontiguousarray(mean_e, dtype=np.float64)
    rows, cols = _pixel_index(lam.shape)
    if lam.size and not (np.all(np.isfinite(lam)) and lam.min() >= 0.0):
        raise OutOfRangeError(
            f"mean electron counts must be finite and >= 0; got min {np.nanmin(lam):g}"
        )
    kk = _subkey(key, frame_index, 2 * channel + _SHOT)
    u = rng.hash_uniform(kk, rows, cols).reshape(-1)
    # independent bits for the Gaussian branch: same key, channel slot offset
    kz = _subkey(key, frame_index, 2 * channel + _SHOT + _GAUSS_SLOT)
    z = rng.hash_normal(kz, rows, cols, dtype=np.float64).reshape(-1)
    flat = lam.reshape(-1)
    out = np.empty_like(flat)
    with np.errstate(invalid="ignore"):
        for s in range(0, flat.size, _BLOCK):
            sl = slice(s, s + _BLOCK)
            out[sl] = _poisson_block(flat[sl], u[sl], z[sl])
    return out.reshape(lam.shape)


def _pixel_index(shape):
    if len(shape) != 2:
        raise ConfigError(f"expected a 2-D (rows, cols) image, got shape {shape}")
    return np.arange(shape[0])[:, None], np.arange(shape[1])[None, :]


def expose(
    radiance,
    *,
    exposure_s: float,
    gain: float = 1.0,
    params: SensorParams = CMV4000_NAVCAM,
    key: int,
    frame_index: int,
    radiance_scale: float = 1.0,
    clamp_negative: bool = False,
) -> np.ndarray:
    """Simulate one raw frame from band radiance.

    Runs the compiled per-pixel kernel :func:`_expose_kernel` (numba, rows in parallel);
    its output is bit-identical to the numpy reference :func:`_expose_2d_numpy` and does
    not depend on the thread count (every pixel's draws come from its own counters).

    Args:
        radiance: band radiance at each pixel (W m^-2 sr^-1), shape (rows, cols) or
            (rows, cols, channels); finite and >= 0. Convert a rendered I/F with
            :func:`radiance_from_i_over_f`, or pass the I/F image itself with
            ``radiance_scale=E_sun,band / (pi d^2)`` to fuse that product into the kernel.
            float32 input is read as is (no float64 copy).
        exposure_s: integration time (s), within the sensor's range.
        gain: analog gain (dimensionless), in (0, max_gain].
        params: sensor parameters.
        key: 64-bit noise stream key, e.g. ``rng.stream_key(seed, "camera/left")``.
        frame_index: frame counter (e.g. the capture step), in [-2**31, 2**31).
        radiance_scale: factor applied to ``radiance`` first (finite, > 0); the result is
            bit-identical to passing ``float64(radiance) * radiance_scale``.
        clamp_negative: read negative radiance as 0 (a renderer's rounding below zero),
            bit-identical to passing ``np.maximum(radiance, 0)`` without its copy; NaN
            still fails.

    Returns:
        uint16 raw codes in [0, 2**adc_bits - 1] (left-shifted to the top bits when
        ``params.msb_aligned``), same rows/cols (and channels) as ``radiance``.

    Raises:
        OutOfRangeError: exposure or gain out of range, negative/NaN radiance, bad key.
    """
    t = _check_exposure(exposure_s, params)
    g = _check_gain(gain, params)
    key, frame_index = _check_key(key, frame_index)
    _positive("radiance_scale", radiance_scale)
    L = np.asarray(radiance)
    if L.dtype != np.float32:
        L = L.astype(np.float64, copy=False)
    if L.ndim not in (2, 3):
        raise ConfigError(f"radiance must be (rows, cols) or (rows, cols, channels), got {L.shape}")
    nch = L.shape[2] if L.ndim == 3 else 1
    # (channels, rows, cols), C order: a free view for a 2-D image
    Lc = np.ascontiguousarray(np.moveaxis(L.reshape(L.shape[0], L.shape[1], nch), 2, 0))
    keys = np.array(
        [
            [
                _subkey(key, frame_index, 2 * c + _SHOT),
                _subkey(key, frame_index, 2 * c + _SHOT + _GAUSS_SLOT),
                _subkey(key, frame_index, 2 * c + _READ),
            ]
            for c in range(nch)
        ],
        dtype=np.uint64,
    ).reshape(nch, 3)
    out = np.empty(Lc.shape, dtype=np.uint16)
    bad = np.zeros(Lc.shape[1], dtype=np.int64)
    if Lc.size:
        with _KERNEL_LOCK:
            _expose_kernel(
                Lc,
                float(radiance_scale),
                0.0 if clamp_negative else -np.inf,
                keys,
                params.electrons_per_radiance * t,
                params.dark_current_e_s * t,
                float(params.full_well_e),
                float(params.read_noise_e),
                g / params.e_per_dn,
                float(params.black_level_dn),
                float(params.max_code),
                16 - params.adc_bits if params.msb_aligned else 0,
                out,
                bad,
                workers(),
            )
    if bad.any():
        _raise_bad_input(np.maximum(L, 0) if clamp_negative else L, radiance_scale, params, t)
    if L.ndim == 2:
        return out[0]
    return np.ascontiguousarray(np.moveaxis(out, 0, 2))


def _check_key(key, frame_index) -> tuple[int, int]:
    if not (isinstance(key, (int, np.integer)) and 0 <= int(key) < 1 << 64):
        raise OutOfRangeError(f"key={key!r} must be an integer in [0, 2**64)")
    if not (isinstance(frame_index, (int, np.integer)) and -(1 << 31) <= frame_index < 1 << 31):
        raise OutOfRangeError(f"frame_index={frame_index!r} must be an integer in [-2**31, 2**31)")
    return int(key), int(frame_index)


def _raise_bad_input(L: np.ndarray, radiance_scale: float, params: SensorParams, t: float):
    """The errors of the numpy path for an image the kernel flagged."""
    with np.errstate(over="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # nanmin of an all-NaN image
        L = np.asarray(L, dtype=np.float64) * float(radiance_scale)
        if not (np.all(np.isfinite(L)) and L.min() >= 0.0):
            raise OutOfRangeError(
                f"radiance must be finite and >= 0; got min {np.nanmin(L):g}, "
                f"{int(np.count_nonzero(~np.isfinite(L)))} non-finite values"
            )
        mean_e = L * (params.electrons_per_radiance * t) + params.dark_current_e_s * t
    raise OutOfRangeError(
        f"mean electron counts must be finite and >= 0; got min {np.nanmin(mean_e):g}"
    )


_KERNEL_LOCK = threading.Lock()
"""Serialises kernel launches: numba's workqueue threading layer aborts the process when
two Python threads launch parallel kernels at once."""

_GAUSS_SLOT = 1 << 20
"""Offset of the Gaussian-branch shot-noise stream from the channel's Poisson stream."""


# ----------------------------------------------------------------------------- numba kernel
#
# A port of rng.hash_bits / hash_uniform / hash_normal and of _expose_2d_numpy that does the
# same uint64 (wrapping) and float64 operations in the same order for every pixel; no
# fastmath, so no reassociation or FMA contraction. math.exp is the C library's exp in
# both (the numpy reference calls it through _exp_libm, not np.exp, whose SIMD loops
# differ from it by an ulp on a few per cent of arguments); it is called from a loop that
# cannot be vectorised, so no vector math library can replace it.
#
# Each image row (prange) runs these passes per channel, in row buffers:
#   1. _row_gauss: the mean electrons of every pixel and its rounded-Gaussian shot-noise
#      draw (SIMD-vectorised, branch-free);
#   2. the indices of the pixels with a mean below POISSON_EXACT_BELOW (branch-free);
#   3. _row_poisson: their hash uniforms and exp(-lam), then the CDF recursion in
#      lockstep for groups of _GROUP pixels (SIMD); a pixel's count is
#      min(first n with u < cdf_n, _POISSON_KMAX) whatever its group, as in
#      _poisson_block; the counts replace the Gaussian draws;
#   4. _row_adc: full well, read noise, ADC (SIMD).

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_LO16 = np.uint64(0xFFFF)
_NORMAL_SCALE = float(1.0 / np.sqrt(4.0 * (65536.0**2 - 1.0) / 12.0))
_INV_2_53 = 1.0 / float(1 << 53)
_GROUP = 32
_ROWS = 8  # rows a worker takes from the queue at a time


@numba.njit(cache=True, inline="always")
def _nb_hash_bits(key, counter):
    """rng.hash_bits for the counter ``(i << 32) | (j & 0xFFFFFFFF)``."""
    z = key + (counter + np.uint64(1)) * _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def _nb_normal(b):
    """rng.hash_normal (float64) from hash bits."""
    s = (
        (b & _LO16)
        + ((b >> np.uint64(16)) & _LO16)
        + ((b >> np.uint64(32)) & _LO16)
        + (b >> np.uint64(48))
    )
    return np.float64(np.int64(s) - 2 * 65535) * _NORMAL_SCALE


@numba.njit(cache=True)
def _row_gauss(L, scale, lo, hi, kz, rate, dark_e, lam_out, n_out):
    """Pass 1: mean electrons and Gaussian draws; returns the count of invalid pixels
    (radiance negative or not finite, or an electron mean that overflows). Radiance
    below ``lo`` is read as ``lo`` (0 or -inf; NaN passes, as through np.maximum)."""
    nvalid = 0
    for c in range(L.size):
        v = np.float64(L[c])
        x = (lo if v < lo else v) * scale
        lam = x * rate + dark_e
        nvalid += (x >= 0.0) & (x < np.inf) & (lam < np.inf)
        lam_out[c] = lam
        z = _nb_normal(_nb_hash_bits(kz, hi | np.uint64(c)))
        n_e = np.floor(lam + math.sqrt(lam) * z + 0.5)
        if n_e < 0.0:
            n_e = 0.0
        n_out[c] = n_e
    return L.size - nvalid


@numba.njit(cache=True)
def _row_poisson(idx, lam_row, hi, ks, u, lam, p, cdf, k, n_out):
    """Pass 3: exact Poisson counts for the row pixels ``idx`` into ``n_out``."""
    m = idx.size
    for j in range(m):
        c = idx[j]
        lam[j] = lam_row[c]
        u[j] = np.float64(_nb_hash_bits(ks, hi | np.uint64(c)) >> np.uint64(11)) * _INV_2_53
        k[j] = 0
    last_lam = np.nan
    last_p = np.nan
    for j in range(m):  # scalar libm exp; equal means (e.g. dark sky) reuse the last value
        if lam[j] != last_lam:
            last_lam = lam[j]
            last_p = math.exp(-last_lam)
        p[j] = last_p
        cdf[j] = last_p
    # the CDF recursion p_n = p_(n-1) (lam / n) in lockstep over groups of _GROUP pixels
    # until every u < cdf (unsigned indices: no wraparound test, so the loops vectorise)
    for s in range(0, m, _GROUP):
        s0 = np.uint64(s)
        g = min(_GROUP, m - s)
        more = 0
        for jj in range(g):
            j = s0 + np.uint64(jj)
            more += u[j] >= cdf[j]
        n = 0
        while more > 0 and n < _POISSON_KMAX:
            n += 1
            inv_n = 1.0 / n
            more = 0
            for jj in range(g):
                j = s0 + np.uint64(jj)
                k[j] += u[j] >= cdf[j]
                pj = p[j] * (lam[j] * inv_n)
                p[j] = pj
                cj = cdf[j] + pj
                cdf[j] = cj
                more += u[j] >= cj
    for j in range(m):
        n_out[idx[j]] = np.float64(k[j])


@numba.njit(cache=True)
def _row_adc(n_e, hi, kr, full_well, read_noise, conv, black, max_code, shift, out):
    """Pass 4: full well, read noise and ADC."""
    for c in range(n_e.size):
        e = n_e[c]
        if e > full_well:
            e = full_well
        if read_noise > 0.0:
            e = e + read_noise * _nb_normal(_nb_hash_bits(kr, hi | np.uint64(c)))
        dn = np.floor(e * conv + 0.5) + black
        if not dn >= 0.0:
            dn = 0.0
        if dn > max_code:
            dn = max_code
        out[c] = np.uint16(np.int64(dn) << shift)


@numba.njit(parallel=True, cache=True, fastmath=False, nogil=True)
def _expose_kernel(  # pragma: no cover - compiled
    L, scale, lo, keys, rate, dark_e, full_well, read_noise, conv, black, max_code, shift, out,
    bad, nwork,
):  # fmt: skip
    """Raw codes for L (channels, rows, cols) into out (radiance below ``lo`` read as
    ``lo``); bad[r] counts invalid pixels. Rows
    go to ``nwork`` workers through a queue (:mod:`lunar_drake.render.row_queue`); every
    pixel's draws come from its own counters, so the output does not depend on which
    worker takes a row."""
    nch, rows, cols = L.shape
    thr = POISSON_EXACT_BELOW
    counter = np.zeros(1, np.int64)  # the next row (render/row_queue.py)
    for _w in numba.prange(nwork):
        lam_row = np.empty(cols)
        n_row = np.empty(cols)
        idx = np.empty(cols, dtype=np.int64)
        u = np.empty(cols)
        lam = np.empty(cols)
        p = np.empty(cols)
        cdf = np.empty(cols)
        k = np.empty(cols, dtype=np.int64)
        r = -1
        r_end = 0
        while True:
            r += 1
            if r >= r_end:  # the next _ROWS rows from the queue
                r = fetch_add(counter, _ROWS)
                r_end = min(r + _ROWS, rows)
            if r >= rows:
                break
            hi = np.uint64(r) << np.uint64(32)
            nbad = 0
            for ch in range(nch):
                nbad += _row_gauss(
                    L[ch, r], scale, lo, hi, keys[ch, 1], rate, dark_e, lam_row, n_row
                )
                m = 0
                for c in range(cols):  # branch-free compaction
                    idx[m] = c
                    m += lam_row[c] < thr
                if m > 0:
                    _row_poisson(
                        idx[:m], lam_row, hi, keys[ch, 0], u[:m], lam[:m], p[:m], cdf[:m], k[:m],
                        n_row,
                    )  # fmt: skip
                _row_adc(
                    n_row, hi, keys[ch, 2], full_well, read_noise, conv, black, max_code, shift,
                    out[ch, r],
                )  # fmt: skip
            bad[r] = nbad


# ----------------------------------------------------------------------------- numpy reference


def _expose_2d_numpy(L, t, g, params: SensorParams, key, frame_index, channel):
    """Numpy reference of the kernel for one channel (tests; bit-identical output)."""
    mean_e = L * (params.electrons_per_radiance * t) + params.dark_current_e_s * t
    n_e = shot_noise_electrons(mean_e, key=key, frame_index=frame_index, channel=channel)
    n_e = np.minimum(n_e, params.full_well_e)
    if params.read_noise_e > 0:
        rows, cols = _pixel_index(L.shape)
        kr = _subkey(key, frame_index, 2 * channel + _READ)
        n_e = n_e + params.read_noise_e * rng.hash_normal(kr, rows, cols, dtype=np.float64)
    dn = np.floor(n_e * (g / params.e_per_dn) + 0.5) + params.black_level_dn
    raw = np.clip(dn, 0, params.max_code).astype(np.uint16)
    if params.msb_aligned:
        raw <<= np.uint16(16 - params.adc_bits)
    return raw


# ----------------------------------------------------------------------------- paper's path


def quantize_16bit(linear, *, exposure: float = 1.0) -> np.ndarray:
    """The paper's 16-bit render: ``round(clip(exposure * linear, 0, 1) * 65535)``.

    ``linear`` is a linear float image where 1.0 is white (e.g. an I/F image divided by
    a chosen white level); ``exposure`` is the shaders' linear multiplier (> 0).
    """
    if not (math.isfinite(exposure) and exposure > 0):
        raise OutOfRangeError(f"exposure={exposure!r} must be a finite number > 0")
    x = np.asarray(linear, dtype=np.float64)
    if x.size and np.isnan(x).any():
        raise OutOfRangeError(f"linear image holds {int(np.isnan(x).sum())} NaN values")
    return np.floor(np.clip(x * exposure, 0.0, 1.0) * 65535.0 + 0.5).astype(np.uint16)


def downsample_bits(raw16, *, bits: int = 12) -> np.ndarray:
    """Keep the top ``bits`` of 16-bit codes (the paper's post-render 16 -> 12-bit step)."""
    if not 1 <= bits <= 16:
        raise OutOfRangeError(f"bits={bits!r} must lie in [1, 16]")
    a = np.asarray(raw16)
    if a.dtype != np.uint16:
        raise ConfigError(f"expected a uint16 image, got dtype {a.dtype}")
    return a >> np.uint16(16 - bits)


def to_preview_8bit(
    raw,
    *,
    gamma: float = 2.2,
    auto: bool = True,
    full_scale: int | None = None,
    params: SensorParams = CMV4000_NAVCAM,
    percentiles: tuple[float, float] = (0.5, 99.5),
) -> np.ndarray:
    """8-bit display image from raw codes: linear stretch then ``v ** (1 / gamma)``.

    ``auto`` stretches between the given percentiles of ``raw``; otherwise from 0 to
    ``full_scale`` (default: the top code of ``params``, MSB-aligned if configured).
    """
    if not (math.isfinite(gamma) and gamma > 0):
        raise OutOfRangeError(f"gamma={gamma!r} must be a finite number > 0")
    x = np.asarray(raw, dtype=np.float64)
    if auto:
        lo, hi = (float(v) for v in np.percentile(x, percentiles))
    else:
        lo = 0.0
        if full_scale is None:
            hi = float(params.max_code << (16 - params.adc_bits if params.msb_aligned else 0))
        else:
            hi = float(full_scale)
    if hi <= lo:
        hi = lo + 1.0
    v = np.clip((x - lo) / (hi - lo), 0.0, 1.0) ** (1.0 / gamma)
    return np.floor(v * 255.0 + 0.5).astype(np.uint8)
