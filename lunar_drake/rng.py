"""Deterministic random streams.

Three kinds, per DESIGN.md decision 6:

* :func:`generator` -- a numpy ``Generator`` seeded from the scenario seed and a
  stream name (stable across Python runs; never Python's salted ``hash``). Use it for
  things sampled once for a whole site (crater and rock catalogs).
* :func:`sample_generator` -- a numpy ``Generator`` for sample ``k`` of a stream
  (Philox keyed by the stream key and ``k``). Sensors draw each sample's noise from it,
  so a measurement depends only on (seed, system name, sample index, truth) and no
  random state lives outside the Context.
* :func:`hash_uniform` / :func:`hash_normal` -- counter-based values keyed by
  (seed, stream, i, j): the value for a grid cell depends only on its global integer
  position, never on the tile or worker that computes it. Use these for any per-pixel
  noise so that tiled synthesis is bit-identical to whole-grid synthesis.

The hash is SplitMix64's finaliser applied to a combination of the keys; its output
passes the usual avalanche tests and is more than good enough for terrain noise.
"""

from __future__ import annotations

import hashlib

import numpy as np

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV_2_53 = 1.0 / float(1 << 53)


def stream_key(seed: int, name: str) -> int:
    """64-bit key for ``(seed, name)``; stable across runs and platforms."""
    digest = hashlib.blake2b(f"{int(seed)}:{name}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little")


def generator(seed: int, name: str) -> np.random.Generator:
    """A numpy Generator for the named stream under ``seed``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([stream_key(seed, name)])))


def sample_generator(key: int, index: int) -> np.random.Generator:
    """A numpy Generator for sample ``index`` (>= 0) of the stream ``key``.

    Philox is a keyed pseudo-random function: the 128-bit key (``key``, ``index``) gives
    an independent stream per sample, so sample k's values never overlap sample k+1's
    however many values each draws.
    """
    # An explicit uint64 array: a Python list with a key >= 2**63 would go through
    # float64 and lose its low bits.
    return np.random.Generator(np.random.Philox(key=np.array([int(key), int(index)], np.uint64)))


class SampleStream:
    """Per-sample generators of one stream ``key``, cheaply: :meth:`at` returns a
    Generator that draws exactly what ``sample_generator(key, index)`` draws.

    One Philox generator is re-keyed at every call (scratch, no state carried between
    calls): about 4x cheaper than building a Generator per sample. Use the returned
    Generator before the next :meth:`at` call on the same stream.
    """

    def __init__(self, key: int) -> None:
        self._bits = np.random.Philox(key=[int(key), 0])
        self._generator = np.random.Generator(self._bits)
        # The state set at every call: only the key's second word (the index) changes;
        # the setter copies the arrays, so they stay as they are here.
        self._index_key = np.array([np.uint64(int(key)), np.uint64(0)], np.uint64)
        self._state = {
            "bit_generator": "Philox",
            "state": {"counter": np.zeros(4, np.uint64), "key": self._index_key},
            "buffer": np.zeros(4, np.uint64),
            "buffer_pos": 4,
            "has_uint32": 0,
            "uinteger": 0,
        }

    def at(self, index: int) -> np.random.Generator:
        """The Generator of sample ``index`` (>= 0)."""
        self._index_key[1] = np.uint64(int(index))
        self._bits.state = self._state
        return self._generator


def _mix(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def hash_bits(key: int, i, j) -> np.ndarray:
    """Uniform uint64 bits for integer positions ``(i, j)`` (broadcast) under ``key``.

    SplitMix64's output for the counter ``i * 2**32 + j`` under seed ``key``; ``i`` and
    ``j`` must lie in [-2**31, 2**31). Only integer adds, shifts and multiplies, so the
    bits never depend on array shape, SIMD path or tile.
    """
    with np.errstate(over="ignore"):
        ii = np.asarray(i, dtype=np.int64).astype(np.uint64)
        jj = np.asarray(j, dtype=np.int64).astype(np.uint64) & np.uint64(0xFFFFFFFF)
        counter = (ii << np.uint64(32)) | jj
        return _mix(np.uint64(key) + (counter + np.uint64(1)) * _GOLDEN)


def hash_uniform(key: int, i, j) -> np.ndarray:
    """Uniform float64 in [0, 1) for integer positions ``(i, j)`` under ``key``."""
    return (hash_bits(key, i, j) >> _S11).astype(np.float64) * _INV_2_53


def hash_normal(key: int, i, j, *, dtype=np.float32) -> np.ndarray:
    """Approximately standard-normal noise for integer positions ``(i, j)`` under ``key``.

    Irwin-Hall sum of four 16-bit uniforms taken from one 64-bit hash, rescaled to unit
    variance (support +-3.46 sigma). Exact integer arithmetic and one float multiply, so
    it is bit-identical whatever the tiling; adequate for terrain noise, not for
    statistics that need Gaussian tails.
    """
    b = hash_bits(key, i, j)
    m = np.uint64(0xFFFF)
    s = (b & m) + ((b >> np.uint64(16)) & m) + ((b >> np.uint64(32)) & m) + (b >> np.uint64(48))
    # sum of 4 U{0..65535}: mean 2*65535, variance 4*(65536**2-1)/12
    scale = 1.0 / np.sqrt(4.0 * (65536.0**2 - 1.0) / 12.0)
    return ((s.astype(np.int64) - 2 * 65535).astype(dtype)) * dtype(scale)
