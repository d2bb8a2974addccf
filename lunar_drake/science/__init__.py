"""Science: the world model of lunar volatiles (pure numpy/scipy, no Drake).

The paper's section 8: a stack of rasters, each computed only from those before it --
DEM, Sun over a year and at the epoch, permanent shadow, surface temperature, surface
frost, OH, the dry layer, ice below it, hydrogen-bearing minerals and minerals.

* :mod:`.config` -- :class:`~.config.WorldConfig` (one typed section per layer);
* :mod:`.sun_envelope` -- the Sun's elevation envelope over a year, by azimuth;
* :mod:`.thermal` -- illumination (permanent shadow, direct flux) and temperatures;
* :mod:`.volatiles` -- frost, OH, dry layer and ice relations;
* :mod:`.minerals` -- seeded, tile-invariant fractal noise layers;
* :mod:`.world` -- the whole stack for a site, written as GeoTIFFs and heat maps.
"""
