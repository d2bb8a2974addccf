"""From a scenario to a site: synthesize it (cached by content hash) or use a DEM, and load
the layers a simulation reads (:class:`SiteData`)."""

from __future__ import annotations

import dataclasses as dc
import json
import os
import shutil
from pathlib import Path

import numpy as np

from lunar_drake.errors import RasterNotFoundError
from lunar_drake.files import temp_sibling
from lunar_drake.scenario import Scenario
from lunar_drake.terrain.sfd import CraterSFD
from lunar_drake.terrain.synth import OUTPUT_FILES, SynthConfig, synthesize_site


@dc.dataclass(frozen=True)
class Site:
    """A site on disk. ``albedo`` is None when a plain DEM is used as-is."""

    dem: Path
    albedo: Path | None
    directory: Path | None
    synthesized: bool
    cached: bool


def cache_root() -> Path:
    """Where synthesized sites are cached: $LUNAR_DRAKE_CACHE or the user cache dir."""
    env = os.environ.get("LUNAR_DRAKE_CACHE")
    if env:
        return Path(env)
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("lunar_drake"))


def synth_config_from_scenario(scenario: Scenario) -> SynthConfig:
    """The SynthConfig a scenario's terrain section describes."""
    t = scenario.terrain
    if t.sfd == "powerlaw":
        sfd = CraterSFD(
            law="powerlaw", coefficient=t.powerlaw_coefficient, exponent=t.powerlaw_exponent
        )
    else:
        sfd = CraterSFD(law=t.sfd)
    return SynthConfig(
        size_px=t.size_px,
        resolution_m=t.resolution_m,
        factor=t.factor,
        seed=scenario.site.seed,
        crater_sfd=sfd,
        min_crater_m=t.min_crater_m,
        max_crater_m=t.max_crater_m or None,
        rock_abundance=t.rock_abundance,
        min_rock_m=t.min_rock_m,
        from_dem=t.dem or None,
        center_lat_deg=scenario.site.latitude_deg,
        center_lon_deg=scenario.site.longitude_deg,
        tile_px=t.tile_px,
        workers=t.workers,
    )


def ensure_site(
    scenario: Scenario, *, cache_dir: str | Path | None = None, progress: bool = True
) -> Site:
    """Returns the scenario's site, synthesizing it into the cache on first use.

    A DEM given with ``terrain.factor == 1`` is used as-is; with a larger factor it is
    fractally upscaled like a synthetic site. The cache entry is keyed by a hash of
    everything that determines the bytes, built in a temporary directory and renamed
    into place when complete, so an interrupted build never leaves a partial entry.
    """
    t = scenario.terrain
    if t.dem and not Path(t.dem).exists():
        raise RasterNotFoundError(f"terrain.dem = {t.dem!r} does not exist")
    if t.dem and t.factor == 1:
        return Site(dem=Path(t.dem), albedo=None, directory=None, synthesized=False, cached=False)
    config = synth_config_from_scenario(scenario)
    root = Path(cache_dir) if cache_dir else cache_root()
    entry = root / "sites" / config.content_key()
    if all((entry / f).exists() for f in OUTPUT_FILES):
        return Site(
            dem=entry / "dem.tif",
            albedo=entry / "albedo.tif",
            directory=entry,
            synthesized=True,
            cached=True,
        )
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(entry)  # unique per call; synthesize_site stages it (complete or absent)
    try:
        synthesize_site(config=config, out_dir=tmp, progress=progress)
        # A stale, incomplete entry (an older crash) is moved aside, never a complete one.
        if entry.exists() and not all((entry / f).exists() for f in OUTPUT_FILES):
            stale = temp_sibling(entry, tag="stale")
            os.rename(entry, stale)
            shutil.rmtree(stale, ignore_errors=True)
        try:
            os.rename(tmp, entry)
        except OSError:
            # Another process finished the same site first: use theirs (same bytes).
            if not all((entry / f).exists() for f in OUTPUT_FILES):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # only left when another process won
    return Site(
        dem=entry / "dem.tif",
        albedo=entry / "albedo.tif",
        directory=entry,
        synthesized=True,
        cached=False,
    )


@dc.dataclass(frozen=True, eq=False)
class SiteData:
    """The site as a simulation reads it.

    Attributes:
        heightfield: the terrain (site frame: x east, y north, z up, m).
        albedo: a reduced normal-albedo grid covering the site, or None.
        info: deterministic facts for summaries (DEM name, shape, resolution, bounds,
            crater and rock counts, content key).
        site: where it came from on disk (None for an in-memory site).
    """

    heightfield: object
    albedo: np.ndarray | None
    info: dict
    site: Site | None = None

    @classmethod
    def from_heightfield(cls, heightfield, *, name: str = "in-memory", albedo=None) -> SiteData:
        """An in-memory site (tests, studies on generated terrain)."""
        return cls(heightfield=heightfield, albedo=albedo, info=_info(heightfield, name, None))


def _info(hf, dem_name: str, site: Site | None) -> dict:
    b = hf.bounds
    info = {
        "dem": dem_name,
        "synthesized": bool(site.synthesized) if site else False,
        "shape_px": [int(v) for v in hf.shape],
        "resolution_m": float(hf.resolution_m),
        "bounds_m": [float(b.left), float(b.right), float(b.bottom), float(b.top)],
    }
    if site is not None and site.directory is not None:
        stats = json.loads((site.directory / "site.json").read_text())["stats"]
        info.update(
            craters=stats["craters"], rocks=stats["rocks"], content_key=stats["content_key"]
        )
    return info


def load_site_layers(site: Site, *, max_albedo_px: int = 1024, in_memory_max_px: int = 4096**2):
    """Opens the site's Heightfield and a reduced albedo grid (or None).

    Rasters up to ``in_memory_max_px`` pixels are loaded into memory; larger ones stay
    file-backed (windowed reads through the Heightfield's block cache).
    """
    from lunar_drake.terrain.heightfield import Heightfield

    hf = Heightfield.open(site.dem)
    rows, cols = hf.shape
    if rows * cols <= in_memory_max_px:
        # Small sites are read whole: per-step contact queries then skip the block cache.
        z = hf.read_window(0, 0, rows, cols)
        hf = Heightfield.from_array(
            z, resolution_m=hf.resolution_m, crs=hf.crs, origin_xy=hf.origin_xy
        )
    albedo = None
    if site.albedo is not None:
        albedo = Heightfield.open(site.albedo).decimated(max_size=max_albedo_px)[0]
    return hf, albedo


def load_site(
    scenario: Scenario, *, cache_dir: str | Path | None = None, progress: bool = True
) -> SiteData:
    """The scenario's site, synthesized into the cache on first use, loaded."""
    site = ensure_site(scenario, cache_dir=cache_dir, progress=progress)
    hf, albedo = load_site_layers(site)
    return SiteData(heightfield=hf, albedo=albedo, info=_info(hf, site.dem.name, site), site=site)
