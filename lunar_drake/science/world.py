"""The world model of a site: every layer, written as GeoTIFFs and heat maps.

``lunar-drake world build SITE_DIR --out DIR [--utc TIME]`` (:func:`build_world`). Each
layer is computed only from those before it:

==========================  ======  ==================================================
file                        unit    from
==========================  ======  ==================================================
``psr.tif`` (uint8)         1/0     the DEM and the Sun's elevation envelope over a year
                                    (never any of the disk visible: 1)
``lit_fraction.tif``        -       the Sun's disk visible at the epoch (lightmap)
``t_max_K.tif``             K       the highest direct flux over the year, terrain IR
``t_mean_K.tif``            K       the time-mean direct flux, terrain IR
``temperature_K.tif``       K       the Sun at the epoch (lightmap), terrain IR
``frost_area_frac.tif``     -       psr, t_max (patch areas)
``oh_ppm.tif``              ppm     temperature at the epoch
``dry_layer_m.tif``         m       t_max, t_mean
``ice_wt_pct.tif``          wt%     dry layer, crater catalog (rims and ages)
``h_minerals_ppm.tif``      ppm     seeded fractal noise
``minerals.tif``            wt%     seeded fractal noise, one band per mineral (named)
==========================  ======  ==================================================

Plus ``<layer>.png`` heat maps over the hillshade, ``world.png`` (six layers side by
side) and ``world.json`` (the epoch, the
Sun's envelope, per-layer statistics, the configuration), written last: a directory
with ``world.json`` is complete. Every layer is range-checked before it is written
(:func:`check_layer`); each file is written under a temporary name and renamed.

Layers are computed in blocks of ``tile_px`` rows and written window by window
(:func:`stream_world`). Up to ``thermal.whole_max_mpx`` the DEM, the sunlight
accumulators and the temperature extremes are held whole (about 45 bytes per pixel);
larger DEMs, such as the paper's 30720^2, are built out of core (:func:`_stream_strips`,
:mod:`.strips`: the DEM read a strip at a time, a decimated far field, the passes'
arrays on disk). Every value is bit-identical for any ``tile_px``.
"""

from __future__ import annotations

import dataclasses as dc
import json
import math
import time
from pathlib import Path

import numpy as np

from lunar_drake.errors import LunarDrakeError, RasterNotFoundError
from lunar_drake.science import minerals as mineral_layers
from lunar_drake.science import thermal, volatiles
from lunar_drake.science.config import MINERALS, WorldConfig
from lunar_drake.science.sun_envelope import SunEnvelope, sun_envelope


class WorldModelError(LunarDrakeError, ValueError):
    """A site the world model cannot be built from, or a layer outside its range."""


#: Layer name -> (unit, physical range (lo, hi), colour map); ``minerals`` is 4 bands.
LAYERS = {
    "psr": ("1 = permanent shadow", (0, 1), "gray_r"),
    "lit_fraction": ("visible fraction of the Sun at the epoch", (0.0, 1.0), "gray"),
    "t_max_K": ("K", (0.0, 450.0), "inferno"),
    "t_mean_K": ("K", (0.0, 450.0), "inferno"),
    "temperature_K": ("K", (0.0, 450.0), "inferno"),
    "frost_area_frac": ("area fraction", (0.0, 1.0), "Blues"),
    "oh_ppm": ("ppm", (0.0, 1e5), "viridis"),
    "dry_layer_m": ("m", (0.0, 100.0), "copper_r"),
    "ice_wt_pct": ("wt%", (0.0, 100.0), "Blues"),
    "h_minerals_ppm": ("ppm", (0.0, 1e5), "magma"),
    "minerals": ("wt%", (0.0, 100.0), "cividis"),
}


def default_utc() -> str:
    """The default scenario's epoch (``site.epoch_utc``)."""
    from lunar_drake.scenario_files import load_scenario

    return load_scenario(scenario_name="default").site.epoch_utc


def _iso_utc(utc: str) -> str:
    """``utc`` as given when it is ISO 8601, else as SPICE reads it (``JD 2461359.5``,
    ``Nov 15 2027``), in ISO 8601 to the millisecond: ``world.json`` always holds ISO."""
    import datetime

    from lunar_drake.ephemeris.sun_earth import tdb_s_to_utc, utc_to_tdb_s

    try:
        datetime.datetime.fromisoformat(str(utc))
        return str(utc)
    except ValueError:
        return tdb_s_to_utc(utc_to_tdb_s(utc))


def check_layer(name: str, values: np.ndarray) -> tuple[float, float]:
    """``(min, max)`` of ``values``; raises :class:`WorldModelError` naming the layer, its
    range and the allowed one when ``values`` has NaN or leaves the layer's physical
    range."""
    if name not in LAYERS:
        raise WorldModelError(f"layer {name!r} is unknown; layers are {tuple(LAYERS)}")
    unit, (lo, hi), _ = LAYERS[name]
    v = np.asarray(values)
    if v.size == 0:
        raise WorldModelError(f"layer {name!r} is empty")
    vmin, vmax = float(np.min(v)), float(np.max(v))  # NaN propagates to both
    if not (math.isfinite(vmin) and math.isfinite(vmax)) or vmin < lo or vmax > hi:
        raise WorldModelError(
            f"layer {name!r} spans [{vmin:g}, {vmax:g}] {unit}, outside its physical range "
            f"[{lo:g}, {hi:g}]"
        )
    return vmin, vmax


@dc.dataclass(frozen=True)
class Craters:
    """The parts of a site's crater catalog the world model reads (site metres, yr)."""

    x_m: np.ndarray
    y_m: np.ndarray
    diameter_m: np.ndarray
    age_yr: np.ndarray


def read_craters(path) -> Craters:
    """``craters.csv`` of a synthesized site (``x_m,y_m,diameter_m,...,age_yr``)."""
    p = Path(path)
    if not p.is_file():
        raise WorldModelError(
            f"site {str(p.parent)!r} has no crater catalog ({p.name}); the ice layer needs "
            "one: synthesize the site with 'lunar-drake terrain synth'"
        )
    with open(p) as f:
        header = f.readline().strip().split(",")
    need = ("x_m", "y_m", "diameter_m", "age_yr")
    missing = [c for c in need if c not in header]
    if missing:
        raise WorldModelError(f"{str(p)!r} lacks column(s) {missing}; it has {header}")
    try:
        data = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise WorldModelError(f"{str(p)!r} is not a numeric crater table: {exc}") from None
    cols = {c: data[:, header.index(c)] if data.size else np.zeros(0) for c in need}
    bad = ~np.isfinite(np.column_stack(list(cols.values()))).all(axis=1) if data.size else []
    if np.any(bad) or (data.size and ((cols["diameter_m"] <= 0) | (cols["age_yr"] < 0)).any()):
        wrong = (cols["diameter_m"] <= 0) | (cols["age_yr"] < 0) if data.size else bad
        row = int(np.argmax(bad)) if np.any(bad) else int(np.argmax(wrong))
        raise WorldModelError(
            f"{str(p)!r} row {row + 2}: crater values must be finite with diameter_m > 0 "
            "and age_yr >= 0"
        )
    return Craters(**cols)


#: Every file a world directory may hold (a rebuild may replace a directory of only these).
WORLD_FILES = frozenset(
    [*(f"{n}.tif" for n in LAYERS), *(f"{n}.png" for n in LAYERS), "world.png", "world.json"]
)


@dc.dataclass(frozen=True)
class World:
    """Layers of a site (arrays, row 0 north) and where they sit.

    Attributes:
        layers: name -> array (``minerals``: ``(bands, rows, cols)``).
        resolution_m: pixel (m). transform, crs: the DEM's (GeoTIFF georeferencing).
        utc: the epoch of ``temperature_K`` and ``oh_ppm``. envelope: the Sun's.
        sun_azimuth_deg, sun_elevation_deg: the Sun at the epoch (grid frame, deg).
    """

    layers: dict
    resolution_m: float
    transform: object
    crs: object
    utc: str
    envelope: SunEnvelope
    sun_azimuth_deg: float
    sun_elevation_deg: float


#: Version of the layers' computation: part of the cache key (:func:`world_key`), so a
#: cached world built by older code is rebuilt. 2: hull-sweep horizons (:mod:`.sweep`).
#: 3: a cell lit at the epoch is not permanent shadow; ``t_max`` >= the epoch's.
MODEL_VERSION = 3

#: Pixels per block of :func:`stream_world`.
_BLOCK_PX = 1 << 22
#: Rows of the GeoTIFFs' tiles (:class:`~lunar_drake.terrain.geotiff.GeoTiffWriter`).
_TIFF_TILE = 256
#: GDAL's block cache (MB) while a world is built out of core: its default, 5 % of the
#: machine's memory, would hold 1.2 GB of DEM and layer tiles here.
_GDAL_CACHE_MB = 256


class ArraySink:
    """Collects streamed layer blocks into whole arrays (:func:`compute_world`)."""

    def __init__(self, shape) -> None:
        self.shape = tuple(shape)
        self.layers: dict = {}

    def put(self, name: str, row0: int, block: np.ndarray) -> None:
        check_layer(name, block)
        if name not in self.layers:
            lead = block.shape[:-2]
            self.layers[name] = np.empty((*lead, *self.shape), block.dtype)
        self.layers[name][..., row0 : row0 + block.shape[-2], :] = block


class FileSink:
    """Writes streamed layer blocks as GeoTIFFs (windowed, each under a temporary name
    until complete), with per-layer statistics and decimated previews for the heat maps.

    Blocks are range-checked at once, then written by one background thread in the order
    they came (so a file's bytes never depend on it), overlapping the next block's
    computation; a block must not change after :meth:`put`. Use as a context manager: on
    leaving, every write is finished; on an exception every unfinished file is discarded.
    """

    def __init__(self, out_dir, *, shape, transform, crs, max_px: int = 640,
                 compress: str = "none") -> None:  # fmt: skip
        from concurrent.futures import ThreadPoolExecutor

        self.compress = None if compress == "none" else compress
        self.out = Path(out_dir)
        self.shape = tuple(shape)
        self.transform, self.crs = transform, crs
        self.step = max(1, math.ceil(max(self.shape) / max_px))
        self.writers: dict = {}
        self.stats: dict = {}
        self.band_stats: dict = {}
        self.previews: dict = {}
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="world-writer")
        self._pending: list = []

    def __enter__(self) -> FileSink:
        return self

    def put(self, name: str, row0: int, block: np.ndarray) -> None:
        from lunar_drake.terrain.geotiff import GeoTiffWriter

        vmin, vmax = check_layer(name, block)
        if name not in self.writers:
            bands = block.shape[0] if block.ndim == 3 else 1
            w = GeoTiffWriter(self.out / f"{name}.tif", height=self.shape[0], width=self.shape[1],
                              count=bands, dtype=block.dtype, transform=self.transform,
                              crs=self.crs, descriptions=MINERALS if name == "minerals" else None,
                              canonical=False, interleave="pixel",
                              compress=self.compress)  # fmt: skip
            # Rows written in order to a pixel-interleaved file land in canonical block
            # order by themselves: the bytes do not depend on the block size.
            self.writers[name] = w.__enter__()
            self.stats[name] = [math.inf, -math.inf, 0.0, 0]
            self.previews[name] = []
        st = self.stats[name]
        st[0], st[1] = min(st[0], vmin), max(st[1], vmax)
        self._pending.append(self._pool.submit(self._store, name, row0, block))
        while len(self._pending) > 2:  # at most two blocks waiting: bounded memory
            self._pending.pop(0).result()

    def _store(self, name: str, row0: int, block: np.ndarray) -> None:
        """The background part of :meth:`put`: the window, the sums (and each band's
        extremes and sum) and the preview."""
        self.writers[name].write(block, row0=row0, col0=0)
        st = self.stats[name]
        st[2] += float(np.sum(block, dtype=np.float64))
        st[3] += block.size
        if block.ndim == 3:
            bands = self.band_stats.setdefault(name, [[math.inf, -math.inf, 0.0]
                                                      for _ in range(block.shape[0])])  # fmt: skip
            for b, bs in zip(block, bands, strict=True):
                bs[0], bs[1] = min(bs[0], float(b.min())), max(bs[1], float(b.max()))
                bs[2] += float(np.sum(b, dtype=np.float64))
        first = (-row0) % self.step
        self.previews[name].append(np.array(block[..., first :: self.step, :: self.step]))

    def flush(self) -> None:
        """Waits for every block handed over so far (raises the first write error)."""
        pending, self._pending = self._pending, []
        for f in pending:
            f.result()

    def preview(self, name: str) -> np.ndarray:
        """The layer decimated by ``step`` (every band of ``minerals``)."""
        self.flush()
        return np.concatenate(self.previews[name], axis=-2)

    def summary(self) -> dict:
        """Per layer: unit, min, max, mean; a multi-band layer (``minerals``) also each
        band's, by name, under ``bands``."""
        self.flush()
        out = {n: {"unit": LAYERS[n][0], "min": st[0], "max": st[1], "mean": st[2] / st[3]}
               for n, st in self.stats.items()}  # fmt: skip
        for n, bands in self.band_stats.items():
            per_band = self.stats[n][3] / len(bands)
            names = MINERALS if n == "minerals" else [f"band{i + 1}" for i in range(len(bands))]
            out[n]["bands"] = {nm: {"min": b[0], "max": b[1], "mean": b[2] / per_band}
                               for nm, b in zip(names, bands, strict=True)}  # fmt: skip
        return out

    def __exit__(self, exc_type, exc, tb) -> None:
        err = None
        try:
            self.flush()
        except Exception as e:  # a failed write: discard every file
            err = e
        self._pool.shutdown(wait=True)
        if exc_type is None and err is not None:
            exc_type, exc, tb = type(err), err, err.__traceback__
        for w in self.writers.values():
            try:
                w.__exit__(exc_type, exc, tb)
            except Exception as e:  # keep closing the others; report the first
                err = err or e
        if err is not None and (exc is None or exc is err):
            raise err


def stream_world(
    z: np.ndarray,
    *,
    sink,
    resolution_m: float,
    craters: Craters,
    seed: int,
    envelope: SunEnvelope,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    sun_distance_au: float = 1.0,
    config: WorldConfig | None = None,
    horizon_mask=None,
    progress=None,
) -> None:
    """Computes every layer of DEM ``z`` (row 0 north, site origin at its centre) and
    hands it to ``sink.put(name, row0, block)`` in blocks of ``config.tile_px`` rows
    (range-checked by the sink). Whole-grid arrays held at once: the DEM, five sunlight
    accumulators (float32), then the two temperature extremes and the shadow labels;
    every other layer is computed and handed on block by block.

    ``progress(stage, fraction)`` is called as stages complete.
    """
    cfg = config or WorldConfig()
    cfg.validate()
    z = np.asarray(z)
    if z.ndim != 2 or z.size == 0:
        raise WorldModelError(f"the DEM has shape {z.shape}; a non-empty 2-D grid is needed")
    if not np.isfinite(z).all():
        raise WorldModelError("the DEM has nodata cells; the world model needs a complete DEM")
    rows, cols = z.shape
    t = cfg.thermal
    blocks = _row_blocks(rows, cols, cfg.tile_px)

    def report(stage, frac):
        if progress is not None:
            progress(stage, frac)

    if t.out_of_core(z.shape):
        _stream_strips(lambda r0, r1: z[r0:r1], z.shape, sink=sink, resolution_m=resolution_m,
                       craters=craters, seed=seed, envelope=envelope,
                       sun_azimuth_deg=sun_azimuth_deg, sun_elevation_deg=sun_elevation_deg,
                       sun_distance_au=sun_distance_au, config=cfg, horizon_mask=horizon_mask,
                       report=report)  # fmt: skip
        return

    illum = thermal.illumination(
        z,
        resolution_m=resolution_m,
        envelope=envelope,
        sun_azimuth_deg=sun_azimuth_deg,
        sun_elevation_deg=sun_elevation_deg,
        sun_distance_au=sun_distance_au,
        config=t,
        horizon_mask=horizon_mask,
        chunk=min(int(cfg.tile_px), 64),
        workers=cfg.workers,
        progress=lambda i, n: report("sun over a year", 0.7 * i / n),
    )
    k = thermal.coarse_factor(resolution_m, t)
    sin2_h = thermal.sky_horizons(z, resolution_m=resolution_m, config=t, workers=cfg.workers)
    sources = np.stack([
        thermal.terrain_source(q, resolution_m=resolution_m, config=t)
        for q in (illum.q_max_w_m2, illum.q_mean_w_m2, illum.q_now_w_m2)
    ])  # fmt: skip
    report("view factors", 0.75)
    t_max = np.empty((rows, cols), np.float32)
    t_mean = np.empty((rows, cols), np.float32)
    for b in blocks:
        sl = slice(b.start, b.stop)
        sink.put("psr", b.start, (illum.ever_lit[sl] == 0).astype(np.uint8))
        sink.put("lit_fraction", b.start, illum.lit_now[sl])
        q = np.stack([illum.q_max_w_m2[sl], illum.q_mean_w_m2[sl], illum.q_now_w_m2[sl]])
        temps = thermal.temperature_rows(z, q, sources, sin2_h, resolution_m=resolution_m,
                                         rows=b, config=t)  # fmt: skip
        t_now = temps[2]
        # The epoch is a moment of the year (its Sun at its own azimuth, not a sector's).
        t_max[sl] = np.maximum(temps[0], t_now)
        t_mean[sl] = np.minimum(temps[1], t_max[sl])
        sink.put("temperature_K", b.start, t_now)
        sink.put("oh_ppm", b.start, volatiles.oh_ppm(t_now, config=cfg.oh))
    cold = (illum.ever_lit == 0) & (t_max < cfg.ice.stable_K)
    del illum, sources
    report("temperatures", 0.85)
    labels, areas = volatiles.label_patches(cold)
    del cold
    per_patch = volatiles.frost_of_areas(areas, resolution_m=resolution_m, config=cfg.frost)
    rim = _rim((rows, cols), k=k, resolution_m=resolution_m, craters=craters, config=cfg)
    report("shadow patches and gardening", 0.87)
    for b in blocks:
        sl = slice(b.start, b.stop)
        sink.put("t_max_K", b.start, t_max[sl])
        sink.put("t_mean_K", b.start, t_mean[sl])
        sink.put("frost_area_frac", b.start, per_patch[labels[sl]].astype(np.float32))
        dry = volatiles.dry_layer_m(t_max[sl], t_mean[sl], config=cfg.ice)
        sink.put("dry_layer_m", b.start, dry)
        ice = volatiles.ice_wt_pct(dry, thermal.upsample(rim, k, b, cols), config=cfg.ice)
        sink.put("ice_wt_pct", b.start, ice.astype(np.float32))
        report("volatiles", 0.87 + 0.06 * b.stop / rows)
    del labels, t_max, t_mean
    _stream_minerals(sink, seed=seed, blocks=blocks, cols=cols, resolution_m=resolution_m,
                     config=cfg, report=report)  # fmt: skip
    report("done", 1.0)


def _row_blocks(rows: int, cols: int, tile_px: int, *, align: int = 1) -> list[range]:
    """Blocks of whole rows, at most ``tile_px`` of them and about 4 Mpx (their
    temporaries are float64 and several layers deep). ``align``: blocks of at least
    that many rows, when ``tile_px`` allows, rounded down to a multiple of it (so that
    each block completes a row of GeoTIFF tiles)."""
    step = max(1, min(int(tile_px), max(_BLOCK_PX // max(cols, 1), align)))
    if step >= align:
        step -= step % align
    return [range(r0, min(rows, r0 + step)) for r0 in range(0, rows, step)]


class _Scratch:
    """Whole-grid float arrays kept on disk, read and written by rows (plain file reads
    and writes, not a memory map: they never count as the process's memory)."""

    def __init__(self, directory, cols: int) -> None:
        self.dir = Path(directory)
        self.cols = int(cols)
        self.dtypes: dict = {}

    def write(self, name: str, row0: int, block: np.ndarray) -> None:
        block = np.ascontiguousarray(block)
        self.dtypes.setdefault(name, block.dtype)
        path = self.dir / f"{name}.raw"
        with open(path, "r+b" if path.exists() else "w+b") as f:
            f.seek(row0 * self.cols * block.dtype.itemsize)
            f.write(block.tobytes())

    def remove(self, name: str) -> None:
        (self.dir / f"{name}.raw").unlink(missing_ok=True)

    def read(self, name: str, r0: int, r1: int) -> np.ndarray:
        dt = np.dtype(self.dtypes[name])
        with open(self.dir / f"{name}.raw", "rb") as f:
            f.seek(r0 * self.cols * dt.itemsize)
            a = np.fromfile(f, dtype=dt, count=(r1 - r0) * self.cols)
        return a.reshape(r1 - r0, self.cols)


def _stream_strips(read_rows, shape, *, sink, resolution_m, craters, seed, envelope,
                   sun_azimuth_deg, sun_elevation_deg, sun_distance_au, config, horizon_mask,
                   report, scratch_dir=None) -> None:  # fmt: skip
    """:func:`stream_world` with the DEM read by ``read_rows(r0, r1)`` and nothing of the
    grid's size held whole (``config.thermal.out_of_core``): the illumination strip by
    strip (:mod:`.strips`), the fluxes, temperature extremes and shadow labels kept on
    disk in ``scratch_dir`` (default the system's temporary directory) between passes,
    the view factors and terrain sources on coarse cells, patches joined across blocks
    (:class:`~.volatiles.StripLabels`)."""
    import tempfile

    from lunar_drake.science import strips

    cfg = config
    t = cfg.thermal
    rows, cols = (int(v) for v in shape)
    # Whole rows of 256-px GeoTIFF tiles at a time: GDAL then never holds a part-written
    # tile in its cache nor writes one twice (compressed).
    blocks = _row_blocks(rows, cols, cfg.tile_px, align=_TIFF_TILE)
    k = thermal.coarse_factor(resolution_m, t)

    def read(r0, r1):
        zz = np.asarray(read_rows(r0, r1))
        if not np.isfinite(zz).all():
            raise WorldModelError(
                "the DEM has nodata cells; the world model needs a complete DEM"
            )
        return zz

    jobs = thermal.sweep_jobs(envelope, sun_azimuth_deg=sun_azimuth_deg,
                              sun_elevation_deg=sun_elevation_deg,
                              sun_distance_au=sun_distance_au, config=t,
                              horizon_mask=horizon_mask)  # fmt: skip
    q_names = ("q_max", "q_mean", "q_now")
    with tempfile.TemporaryDirectory(prefix=".world-scratch-", dir=scratch_dir) as tmp:
        scratch = _Scratch(tmp, cols)
        for r0, il in strips.illumination_strips(
            read, shape, resolution_m=resolution_m, jobs=jobs, config=t,
            horizon_mask=horizon_mask, chunk=min(int(cfg.tile_px), 64), workers=cfg.workers,
            progress=lambda i, n: report("sun over a year", 0.7 * i / n),
        ):  # fmt: skip
            n = il.ever_lit.shape[0]
            for b in _row_blocks(n, cols, cfg.tile_px, align=_TIFF_TILE):
                sl = slice(b.start, b.stop)
                sink.put("psr", r0 + b.start, (il.ever_lit[sl] == 0).astype(np.uint8))
                # A copy: a view waiting to be written would keep the window alive.
                sink.put("lit_fraction", r0 + b.start, il.lit_now[sl].copy())
            scratch.write("ever_lit", r0, il.ever_lit)
            q = (il.q_max_w_m2, il.q_mean_w_m2, il.q_now_w_m2)
            for name, a in zip(q_names, q, strict=True):
                scratch.write(name, r0, a)
            del il
        sin2_h = thermal.sky_horizons_coarse(
            strips.coarse_dem(read, shape, k), resolution_m=resolution_m * k, config=t,
            workers=cfg.workers)  # fmt: skip
        sources = np.stack([
            thermal.source_of_means(
                strips.coarse_dem(lambda a, b, n=name: scratch.read(n, a, b), shape, k),
                resolution_m=resolution_m, config=t)
            for name in q_names
        ])  # fmt: skip
        report("view factors", 0.75)
        patches = volatiles.StripLabels()
        for b in blocks:
            w0, w1 = max(0, b.start - 1), min(rows, b.stop + 1)
            q = np.stack([scratch.read(name, b.start, b.stop) for name in q_names])
            temps = thermal.temperature_rows(read(w0, w1), q, sources, sin2_h,
                                             resolution_m=resolution_m, rows=b, z_row0=w0,
                                             grid_rows=rows, config=t)  # fmt: skip
            t_now = temps[2]
            t_max = np.maximum(temps[0], t_now)  # the epoch is a moment of the year
            t_mean = np.minimum(temps[1], t_max)
            sink.put("temperature_K", b.start, t_now)
            sink.put("oh_ppm", b.start, volatiles.oh_ppm(t_now, config=cfg.oh))
            scratch.write("t_max", b.start, t_max)
            scratch.write("t_mean", b.start, t_mean)
            cold = (scratch.read("ever_lit", b.start, b.stop) == 0) & (t_max < cfg.ice.stable_K)
            scratch.write("labels", b.start, patches.add(cold).astype(np.int32))
        for name in (*q_names, "ever_lit"):  # done with: the disk space back at once
            scratch.remove(name)
        report("temperatures", 0.85)
        per_label = volatiles.frost_of_areas(patches.areas(), resolution_m=resolution_m,
                                             config=cfg.frost)  # fmt: skip
        rim = _rim((rows, cols), k=k, resolution_m=resolution_m, craters=craters, config=cfg)
        report("shadow patches and gardening", 0.87)
        for b in blocks:
            t_max = scratch.read("t_max", b.start, b.stop)
            t_mean = scratch.read("t_mean", b.start, b.stop)
            sink.put("t_max_K", b.start, t_max)
            sink.put("t_mean_K", b.start, t_mean)
            labels = scratch.read("labels", b.start, b.stop)
            sink.put("frost_area_frac", b.start, per_label[labels].astype(np.float32))
            dry = volatiles.dry_layer_m(t_max, t_mean, config=cfg.ice)
            sink.put("dry_layer_m", b.start, dry)
            ice = volatiles.ice_wt_pct(dry, thermal.upsample(rim, k, b, cols), config=cfg.ice)
            sink.put("ice_wt_pct", b.start, ice.astype(np.float32))
            report("volatiles", 0.87 + 0.06 * b.stop / rows)
    _stream_minerals(sink, seed=seed, blocks=blocks, cols=cols, resolution_m=resolution_m,
                     config=cfg, report=report)  # fmt: skip
    report("done", 1.0)


def _stream_minerals(sink, *, seed, blocks, cols, resolution_m, config, report) -> None:
    rows = blocks[-1].stop
    for b in blocks:
        h, minerals = mineral_layers.mineral_fields(
            seed, window=(b.start, 0, len(b), cols), resolution_m=resolution_m,
            config=config.minerals)  # fmt: skip
        sink.put("h_minerals_ppm", b.start, h)
        sink.put("minerals", b.start, minerals)
        report("minerals", 0.93 + 0.07 * b.stop / rows)


def _rim(shape, *, k: int, resolution_m: float, craters, config) -> np.ndarray:
    """The ice's rim factor on the coarse cells of ``k x k`` pixels of a grid of
    ``shape`` (site origin at its centre)."""
    rows, cols = shape
    return volatiles.rim_factor(
        (-(-rows // k), -(-cols // k)),
        resolution_m=resolution_m * k,
        x0_m=-0.5 * cols * resolution_m,
        y1_m=0.5 * rows * resolution_m,
        craters=craters,
        config=config.ice,
    )


def compute_world(z: np.ndarray, **kwargs) -> dict:
    """Every layer of DEM ``z`` as whole arrays, in :data:`LAYERS` order (the keyword
    arguments of :func:`stream_world`, without ``sink``)."""
    sink = ArraySink(np.shape(z))
    stream_world(z, sink=sink, **kwargs)
    return {n: sink.layers[n] for n in LAYERS}


def _site_seed(site_dir: Path) -> int:
    """The seed of the site's ``site.json`` (``config.seed``); 0 for a site without one
    (an imported DEM). A ``site.json`` that cannot be read as such is an error."""
    path = site_dir / "site.json"
    if not path.exists():
        return 0
    try:
        seed = json.loads(path.read_text()).get("config", {}).get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"config.seed = {seed!r} is not a non-negative integer")
    except (OSError, ValueError, AttributeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise WorldModelError(f"{str(path)!r} is not a site's site.json: {msg}") from None
    return seed


def build_world(
    *,
    site_dir,
    out_dir,
    utc: str | None = None,
    config: WorldConfig | None = None,
    seed: int | None = None,
    png: bool = True,
    progress: bool = True,
) -> dict:
    """Builds the world model of ``site_dir`` (a synthesized site: ``dem.tif`` and
    ``craters.csv``) into ``out_dir``; returns the ``world.json`` summary.

    Raises:
        WorldModelError: no crater catalog, or a layer out of its physical range.
        RasterNotFoundError / RasterError / CRSError: a missing or bad DEM.
    """
    from lunar_drake.ephemeris.sun_earth import SiteLocation, enu_basis, sun_earth_enu
    from lunar_drake.render.lightmap import site_and_grid_north
    from lunar_drake.science.sun_envelope import AU_KM
    from lunar_drake.terrain.heightfield import Heightfield

    cfg = config or WorldConfig()
    cfg.validate()
    site_dir = Path(site_dir)
    dem = site_dir / "dem.tif"
    if not site_dir.is_dir():
        what = "is a file, not a site directory" if site_dir.exists() else "does not exist"
        raise RasterNotFoundError(
            f"site {str(site_dir)!r} {what} (a site directory from 'lunar-drake "
            "terrain synth' is needed)"
        )
    if not dem.is_file():
        raise RasterNotFoundError(
            f"site {str(site_dir)!r} has no dem.tif; a site directory from 'lunar-drake "
            "terrain synth' is needed"
        )
    craters = read_craters(site_dir / "craters.csv")
    utc = _iso_utc(utc or default_utc())
    seed = _site_seed(site_dir) if seed is None else int(seed)
    t0 = time.perf_counter()
    from rasterio.env import get_gdal_config, set_gdal_config

    hf = Heightfield.open(dem)
    cache = get_gdal_config("GDAL_CACHEMAX")  # an integer: bytes above 100000, else MB
    strips = False
    try:
        shape = tuple(int(v) for v in hf.shape)
        strips = cfg.thermal.out_of_core(shape)
        if strips:
            set_gdal_config("GDAL_CACHEMAX", _GDAL_CACHE_MB)
        z = None
        if not strips:
            z = np.asarray(hf.read_window(0, 0, *shape), np.float32)
            holes = int(np.count_nonzero(~np.isfinite(z)))
            if holes:
                raise WorldModelError(
                    f"{str(dem)!r} has {holes} nodata cells; the world model needs a complete DEM"
                )
        env = sun_envelope(hf, utc=utc, config=cfg.sun)
        site, beta = site_and_grid_north(hf, enu_basis=enu_basis, SiteLocation=SiteLocation)
        se = sun_earth_enu(utc=utc, site=site)
        az = (float(se.sun_azimuth_deg) + beta) % 360.0
        el = float(se.sun_elevation_deg)
        transform, crs, res = hf.transform, hf.crs, hf.resolution_m
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        clock = _StageClock(t0, _progress_bar(progress))
        clock("read the DEM and the Sun's envelope", 0.0)
        sun = dict(envelope=env, sun_azimuth_deg=az, sun_elevation_deg=el,
                   sun_distance_au=float(se.sun_distance_km) / AU_KM)  # fmt: skip
        try:
            with FileSink(out, shape=shape, transform=transform, crs=crs,
                          compress=cfg.compress) as sink:  # fmt: skip
                if strips:
                    def read_rows(r0, r1):
                        return hf.read_window(r0, 0, r1 - r0, shape[1])

                    _stream_strips(read_rows, shape, sink=sink, resolution_m=res,
                                   craters=craters, seed=seed, config=cfg, horizon_mask=None,
                                   report=clock, scratch_dir=out, **sun)  # fmt: skip
                    z = _decimated(read_rows, shape, sink.step)
                else:
                    stream_world(z, sink=sink, resolution_m=res, craters=craters, seed=seed,
                                 config=cfg, progress=clock, **sun)  # fmt: skip
        finally:
            clock(None, None)  # closes the bar; the clock goes on
    finally:
        hf.close()
        if strips and isinstance(cache, int):
            set_gdal_config("GDAL_CACHEMAX", cache)
    return _finish_world(
        out,
        sink,
        z=z,
        z_step=sink.step if strips else 1,
        resolution_m=res,
        utc=utc,
        envelope=env,
        sun_azimuth_deg=az,
        sun_elevation_deg=el,
        config=cfg,
        png=png,
        extra={"site_dir": str(site_dir.resolve()), "seed": seed},
        clock=clock,
    )


def _decimated(read_rows, shape, step: int) -> np.ndarray:
    """Every ``step``-th row and column of the DEM read by ``read_rows(r0, r1)``."""
    rows, cols = shape
    block = step * max(1, _BLOCK_PX // max(cols * step, 1))
    return np.concatenate([
        np.asarray(read_rows(r0, min(rows, r0 + block)))[::step, ::step].copy()  # not a view
        for r0 in range(0, rows, block)  # that would keep the whole block alive
    ])  # fmt: skip


def write_world(
    world: World,
    *,
    out_dir,
    z=None,
    config: WorldConfig | None = None,
    png: bool = True,
    extra: dict | None = None,
) -> dict:
    """Writes every layer's GeoTIFF (and heat map) of an in-memory world, then
    ``world.json``; returns it."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    shape = np.shape(world.layers["psr"])
    with FileSink(out, shape=shape, transform=world.transform, crs=world.crs) as sink:
        for name, arr in world.layers.items():
            sink.put(name, 0, np.asarray(arr))
    return _finish_world(out, sink, z=z, resolution_m=world.resolution_m, utc=world.utc,
                         envelope=world.envelope, sun_azimuth_deg=world.sun_azimuth_deg,
                         sun_elevation_deg=world.sun_elevation_deg, config=config, png=png,
                         extra=extra)  # fmt: skip


def _finish_world(out: Path, sink: FileSink, *, z, resolution_m, utc, envelope,
                  sun_azimuth_deg, sun_elevation_deg, config, png, extra,
                  clock=None, z_step: int = 1) -> dict:  # fmt: skip
    """Heat maps from the sink's previews, then ``world.json`` (last; with the build's
    ``seconds`` and ``stage_seconds`` when a :class:`_StageClock` is given). ``z``: the
    DEM, or every ``z_step``-th row and column of it."""
    from lunar_drake.files import atomic_write_text

    step = sink.step
    zp = None if z is None else np.asarray(z)[:: step // z_step, :: step // z_step]
    if png:
        previews = {n: sink.preview(n) for n in sink.writers}
        # The overview (the longest) first, so that it does not finish last alone.
        figures = [(overview, (out / "world.png", previews),
                    {"resolution_m": resolution_m * step, "z": zp,
                     "title": f"World model at {utc}"})]  # fmt: skip
        figures += [
            (heat_map, (out / f"{name}.png", arr),
             {"name": name, "resolution_m": resolution_m * step, "z": zp})
            for name, arr in previews.items()
        ]  # fmt: skip
        _draw(figures, workers=(config or WorldConfig()).workers)
    stats = sink.summary()
    summary = {
        "utc": utc,
        "resolution_m": resolution_m,
        "shape": list(sink.shape),
        "sun_at_epoch": {"azimuth_deg": sun_azimuth_deg, "elevation_deg": sun_elevation_deg},
        "sun_envelope": {
            "samples": envelope.samples,
            "azimuth_bins": int(envelope.azimuth_deg.size),
            "max_elevation_deg": envelope.max_elevation_deg,
            "azimuth_deg": [round(float(v), 4) for v in envelope.azimuth_deg],  # centres
            "el_max_deg": [round(float(v), 4) for v in envelope.el_max_deg],
        },
        "psr_fraction": stats["psr"]["mean"],
        "layers": stats,
        "minerals": list(MINERALS),
        "config": dc.asdict(config or WorldConfig()),
        **(extra or {}),
    }
    if clock is not None:
        clock("heat maps", 1.0)
        summary["seconds"] = round(clock.total_s, 2)
        summary["stage_seconds"] = {k: round(v, 2) for k, v in clock.stages.items()}
    atomic_write_text(out / "world.json", json.dumps(summary, indent=2) + "\n")
    return summary


_FIGURES: list = []


def _drawing_child() -> None:
    """A drawing worker's signals: SIGTERM kills it at once (the pool's terminate() must
    not wait on Python code in a child blocked on a queue lock) and Ctrl-C is left to the
    parent, which terminates the pool."""
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _draw_one(i: int) -> None:
    fn, args, kwargs = _FIGURES[i]
    fn(*args, **kwargs)


def _draw(figures: list, *, workers: int) -> None:
    """Calls each ``(fn, args, kwargs)`` of ``figures``: in ``workers`` forked processes
    where the platform forks and this process runs no other Python thread but tqdm's
    monitor (a fork copies no lock another thread holds; each figure is drawn whole by
    one process, the same bytes as here), else here, one after the other."""
    import multiprocessing as mp
    import threading

    others = [t for t in threading.enumerate()
              if t is not threading.current_thread() and t.name != "tqdm_monitor"]  # fmt: skip
    if (workers <= 1 or len(figures) < 2 or others
            or "fork" not in mp.get_all_start_methods()):  # fmt: skip
        for fn, args, kwargs in figures:
            fn(*args, **kwargs)
        return
    import matplotlib.figure  # noqa: F401  (imported once, before the fork)

    _FIGURES[:] = figures  # the children inherit it; nothing is pickled but indices
    try:
        pool = mp.get_context("fork").Pool(min(workers, len(figures)),
                                           initializer=_drawing_child)  # fmt: skip
        try:
            pool.map(_draw_one, range(len(figures)), chunksize=1)
            pool.close()  # the workers leave by themselves once the queue is done
        except BaseException:
            pool.terminate()
            raise
        finally:
            pool.join()
    finally:
        _FIGURES.clear()


class _StageClock:
    """A ``progress(stage, fraction)`` callback that times the stages (a report closes
    the work since the previous one, which is charged to the report's stage) and
    forwards to ``bar``; ``stage = None`` closes the bar."""

    def __init__(self, t0: float, bar=None) -> None:
        self.t0, self.last, self.bar = t0, t0, bar
        self.stages: dict = {}

    def __call__(self, stage, fraction) -> None:
        now = time.perf_counter()
        if stage is not None:
            self.stages[stage] = self.stages.get(stage, 0.0) + now - self.last
            self.last = now
        if self.bar is not None:
            self.bar(stage, fraction)
            if stage is None:
                self.bar = None

    @property
    def total_s(self) -> float:
        return time.perf_counter() - self.t0


def write_named_bands(path, arr, *, names, transform, crs, nodata=None) -> None:
    """A GeoTIFF (atomic, :func:`~lunar_drake.terrain.geotiff.write_geotiff`) whose bands
    carry ``names`` as their descriptions."""
    import rasterio

    from lunar_drake.files import atomic_path
    from lunar_drake.terrain.geotiff import write_geotiff

    with atomic_path(path, what="raster") as tmp:
        write_geotiff(tmp, arr, transform=transform, crs=crs, nodata=nodata)
        with rasterio.open(tmp, "r+") as ds:
            for k, n in enumerate(names, start=1):
                ds.set_band_description(k, n)


def world_key(site_dir, *, utc: str, config: WorldConfig) -> str:
    """Cache key of a site's world model: its ``site.json`` (what determines the site's
    bytes), the epoch, the configuration (tile size and workers excluded: they never
    change a byte) and :data:`MODEL_VERSION`."""
    import hashlib

    site_dir = Path(site_dir)
    try:
        site_text = (site_dir / "site.json").read_text()
    except OSError:
        raise WorldModelError(
            f"site {str(site_dir)!r} has no site.json; the world model needs a site from "
            "'lunar-drake terrain synth'"
        ) from None
    cfg = dc.asdict(config)
    cfg.pop("tile_px"), cfg.pop("workers")
    cfg["sun"].pop("horizon_resolution_deg")  # read by nothing (kept for older files)
    text = json.dumps(
        {"site": site_text, "utc": utc, "config": cfg, "layers": list(LAYERS),
         "model": MODEL_VERSION},
        sort_keys=True,
    )  # fmt: skip
    return hashlib.blake2b(text.encode(), digest_size=8).hexdigest()


def cached_world_dir(site_dir, *, utc: str, config: WorldConfig | None = None,
                     progress: bool = False) -> tuple[Path, bool]:  # fmt: skip
    """``(directory, was_cached)``: a site's world model at ``utc``, built on first use
    into ``<cache>/worlds/<key>`` (see :func:`world_key`; ``cache`` as for sites,
    $LUNAR_DRAKE_CACHE)."""
    from lunar_drake.files import staged_directory
    from lunar_drake.site import cache_root

    cfg = config or WorldConfig()
    d = cache_root() / "worlds" / world_key(site_dir, utc=utc, config=cfg)
    if (d / "world.json").is_file():
        return d, True
    d.parent.mkdir(parents=True, exist_ok=True)
    with staged_directory(d) as tmp:
        build_world(
            site_dir=site_dir, out_dir=tmp, utc=utc, config=cfg, png=False, progress=progress
        )
    return d, False


def cached_world(
    site_dir, *, utc: str, config: WorldConfig | None = None, names=None, progress: bool = False
) -> dict:
    """The layers ``names`` (default all) of a site's world model at ``utc``
    (:func:`cached_world_dir`: built on first use, read from the cache afterwards;
    range-checked)."""
    d, _ = cached_world_dir(site_dir, utc=utc, config=config, progress=progress)
    return {n: read_world_layer(d, n) for n in (names or LAYERS)}


#: The sensors (``scenario.sensors.<name>``) that read the site's world model.
WORLD_SENSORS = ("nss", "nirvss", "drill")


def _world_sensors(scenario) -> list[str]:
    return [n for n in WORLD_SENSORS if getattr(scenario.sensors, n).enabled]


def needs_world(scenario) -> bool:
    """Whether a run of ``scenario`` reads the site's world model (a science sensor)."""
    return bool(_world_sensors(scenario))


def _world_site_dir(site, who: str) -> Path:
    directory = site.site.directory
    if directory is None or not (Path(directory) / "craters.csv").is_file():
        raise WorldModelError(
            f"{who} needs a synthesized site with a crater catalog; the site "
            f"{str(site.site.dem)!r} has none (set terrain to synthesize one)"
        )
    return Path(directory)


def run_world(*, scenario, site, progress: bool = False) -> tuple[Path, bool]:
    """``(directory, was_cached)`` of a run's world model (:func:`cached_world_dir`),
    built now if a science sensor will read it: before the diagram, so a progress bar
    can show it."""
    who = _world_sensors(scenario)[0]
    return cached_world_dir(_world_site_dir(site, f"sensors.{who}"),
                            utc=scenario.site.epoch_utc, config=scenario.science,
                            progress=progress)  # fmt: skip


def site_layers(*, scenario, site, names, who: str, progress: bool = False) -> dict:
    """Layers ``names`` of a run's site at its epoch (the world model, built on first
    use and cached: :func:`cached_world`); ``who`` names the instrument in the error a
    site without a crater catalog raises."""
    return cached_world(_world_site_dir(site, who), utc=scenario.site.epoch_utc,
                        config=scenario.science, names=names, progress=progress)  # fmt: skip


def hydrogen_map(*, scenario, site, progress: bool = False):
    """The :class:`~lunar_drake.science.nss.HydrogenMap` of a run's site at its epoch."""
    from lunar_drake.science.nss import HydrogenMap

    layers = site_layers(scenario=scenario, site=site, who="sensors.nss", progress=progress,
                         names=("dry_layer_m", "ice_wt_pct", "h_minerals_ppm"))  # fmt: skip
    return HydrogenMap.centred(**layers, resolution_m=site.heightfield.resolution_m)


def surface_map(*, scenario, site, progress: bool = False):
    """The :class:`~lunar_drake.science.nirvss.SurfaceMap` of a run's site at its epoch."""
    from lunar_drake.science.nirvss import LAYERS as NIRVSS_LAYERS
    from lunar_drake.science.nirvss import SurfaceMap

    layers = site_layers(scenario=scenario, site=site, who="sensors.nirvss",
                         names=NIRVSS_LAYERS, progress=progress)  # fmt: skip
    return SurfaceMap.centred(layers, resolution_m=site.heightfield.resolution_m)


def read_world_layer(out_dir, name: str) -> np.ndarray:
    """One layer of a built world (checked against its physical range)."""
    from lunar_drake.terrain.geotiff import open_raster

    path = Path(out_dir) / f"{name}.tif"
    if name not in LAYERS:
        raise WorldModelError(f"layer {name!r} is unknown; layers are {tuple(LAYERS)}")
    if not path.is_file():
        raise RasterNotFoundError(f"world layer {str(path)!r} does not exist")
    with open_raster(path) as ds:
        a = ds.read()
    a = a[0] if a.shape[0] == 1 else a
    check_layer(name, a)
    return a


def heat_map(path, arr, *, name: str, resolution_m: float, z=None, max_px: int = 1024) -> None:
    """A PNG of a layer (first band of ``minerals``) over the hillshade, with a colour bar
    and site-metre axes; written atomically."""
    from matplotlib.figure import Figure

    from lunar_drake.files import atomic_path

    a = np.asarray(arr, np.float64)
    title = name
    if a.ndim == 3:
        a, title = a[0], f"{name}: {MINERALS[0]}"
    step = max(1, math.ceil(max(a.shape) / max_px))
    a = a[::step, ::step]
    rows, cols = a.shape
    ext = [
        -0.5 * cols * step * resolution_m,
        0.5 * cols * step * resolution_m,
        -0.5 * rows * step * resolution_m,
        0.5 * rows * step * resolution_m,
    ]
    unit, _, cmap = LAYERS[name]
    fig = Figure(figsize=(7.5, 6.2), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    rgb, mappable = _blend(a, None if z is None else np.asarray(z)[::step, ::step],
                           resolution_m * step, cmap)  # fmt: skip
    ax.imshow(rgb, extent=ext, interpolation="nearest")
    fig.colorbar(mappable, ax=ax, label=unit, shrink=0.85)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(title)
    with atomic_path(path, what="figure") as tmp:
        fig.savefig(tmp, format="png", pil_kwargs={"compress_level": 3})


def _blend(a: np.ndarray, z, res: float, cmap: str):
    """``(rgb, mappable)``: layer ``a`` coloured by ``cmap``, laid at 75 % over the
    hillshade of ``z`` (pixel ``res`` m) when given; one image, drawn once."""
    import matplotlib as mpl

    norm = mpl.colors.Normalize(float(np.nanmin(a)), float(np.nanmax(a)))
    mappable = mpl.cm.ScalarMappable(norm=norm, cmap=cmap)
    rgb = mappable.to_rgba(a)[..., :3]
    if z is not None:
        shade = hillshade(np.asarray(z, np.float64), res)[..., None]
        rgb = 0.75 * rgb + 0.25 * shade
    return np.clip(rgb, 0.0, 1.0), mappable


#: The panels of ``world.png``.
OVERVIEW_LAYERS = ("psr", "temperature_K", "dry_layer_m", "frost_area_frac", "ice_wt_pct", "oh_ppm")


def overview(
    path, layers: dict, *, resolution_m: float, z=None, title: str = "", max_px: int = 512
) -> None:
    """``world.png``: the six main layers side by side over the hillshade."""
    from matplotlib.figure import Figure

    from lunar_drake.files import atomic_path

    fig = Figure(figsize=(15, 9.6), dpi=90)
    for k, name in enumerate(OVERVIEW_LAYERS):
        a = np.asarray(layers[name], np.float64)
        step = max(1, math.ceil(max(a.shape) / max_px))
        a = a[::step, ::step]
        rows, cols = a.shape
        half_x, half_y = 0.5 * cols * step * resolution_m, 0.5 * rows * step * resolution_m
        ext = [-half_x, half_x, -half_y, half_y]
        ax = fig.add_subplot(2, 3, k + 1)
        unit, _, cmap = LAYERS[name]
        zz = None if z is None else np.asarray(z)[::step, ::step]
        rgb, im = _blend(a, zz, resolution_m * step, cmap)
        ax.imshow(rgb, extent=ext, interpolation="nearest")
        fig.colorbar(im, ax=ax, label=unit, shrink=0.8)
        ax.set_title(name)
        ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path, what="figure") as tmp:
        fig.savefig(tmp, format="png", pil_kwargs={"compress_level": 3})


def hillshade(z: np.ndarray, res: float, az_deg: float = 315.0, el_deg: float = 35.0):
    """Shaded relief in [0, 1] of DEM ``z`` (pixel ``res`` m) lit from ``az_deg``, ``el_deg``."""
    n = thermal.surface_normals(z, res)
    return np.clip(np.tensordot(thermal.sun_vector(az_deg, el_deg), n, axes=1), 0.0, 1.0)


def _progress_bar(enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    bar = tqdm(total=100, desc="world model", unit="%", leave=False)
    state = {"n": 0}

    def update(stage, frac):
        if stage is None:
            bar.close()
            return
        n = round(100 * frac)
        bar.set_postfix_str(stage)
        bar.update(max(0, n - state["n"]))
        state["n"] = max(state["n"], n)

    return update


__all__ = [
    "LAYERS",
    "MODEL_VERSION",
    "WORLD_FILES",
    "WORLD_SENSORS",
    "ArraySink",
    "Craters",
    "FileSink",
    "World",
    "WorldModelError",
    "build_world",
    "cached_world",
    "cached_world_dir",
    "check_layer",
    "compute_world",
    "default_utc",
    "heat_map",
    "hillshade",
    "hydrogen_map",
    "needs_world",
    "overview",
    "read_craters",
    "read_world_layer",
    "run_world",
    "stream_world",
    "surface_map",
    "world_key",
    "write_named_bands",
    "write_world",
]
