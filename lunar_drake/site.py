"""From a scenario to a site on disk: synthesize (cached by content hash) or use a DEM."""

from __future__ import annotations

import dataclasses as dc
import os
import shutil
from pathlib import Path

from lunar_drake.errors import RasterNotFoundError
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
        seed=scenario.random_seed,
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
    tmp = entry.parent / f".{entry.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        synthesize_site(config=config, out_dir=tmp, progress=progress)
        # A stale, incomplete entry (an older crash) is moved aside, never a complete one.
        if entry.exists() and not all((entry / f).exists() for f in OUTPUT_FILES):
            stale = entry.parent / f".{entry.name}.stale-{os.getpid()}"
            os.rename(entry, stale)
            shutil.rmtree(stale, ignore_errors=True)
        try:
            os.rename(tmp, entry)
        except OSError:
            # Another process finished the same site first: use theirs (same bytes).
            if not all((entry / f).exists() for f in OUTPUT_FILES):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return Site(
        dem=entry / "dem.tif",
        albedo=entry / "albedo.tif",
        directory=entry,
        synthesized=True,
        cached=False,
    )
