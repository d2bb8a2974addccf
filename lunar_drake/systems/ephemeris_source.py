"""EphemerisSource: the Sun and Earth in the site's sky, from SPICE, as Drake outputs."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus

from lunar_drake.ephemeris.kernels import ensure_kernels
from lunar_drake.ephemeris.sun_earth import (
    ABCORRS,
    SiteLocation,
    site_frame_rotation,
    sun_earth_enu,
    utc_to_tdb_s,
)
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.systems.leaf import Leaf

# Discrete state layout.
_SUN_DIR = slice(0, 3)
_EARTH_DIR = slice(3, 6)
_SUN_DIST, _EARTH_DIST, _PHASE, _SUN_EL, _SUN_AZ, _EARTH_EL, _EARTH_AZ = range(6, 13)
_STATE_SIZE = 13
# Numeric parameter layout.
_P_LAT, _P_LON, _P_HEIGHT, _P_EPOCH = range(4)

WORLD_FRAMES = ("enu", "polar_grid")


class EphemerisSource(Leaf):
    """Sun and Earth directions, distances and Earth's phase at the site (paper section 5).

    .. pydrake_system::

        name: EphemerisSource
        output_ports:
        - sun_direction_W
        - sun_distance_km
        - earth_direction_W
        - earth_distance_km
        - earth_phase
        - sun_elevation_deg
        - sun_azimuth_deg
        - earth_elevation_deg
        - earth_azimuth_deg

    Simulation time 0 is ``epoch_utc``; simulation time ``t`` (s) is the epoch plus ``t``
    TDB seconds. A periodic discrete update every ``update_period_s`` (and one at
    initialization) evaluates SPICE (``sun_earth_enu``, apparent directions with
    ``abcorr``) at the event time and holds the result in discrete state, so outputs
    are a zero-order hold: cheap to evaluate and deterministic. The Sun moves about
    0.5 deg per hour in the lunar sky, i.e. 1.4e-4 deg per second, so 1 s is far finer
    than any consumer needs; lightmap-style consumers may use 60 s or more. The default
    context already holds the values at the epoch.

    Outputs (all BasicVector):

    * ``sun_direction_W`` (3): unit vector from the site towards the Sun's centre, in W.
    * ``sun_distance_km`` (1): site-Sun distance (km).
    * ``earth_direction_W`` (3), ``earth_distance_km`` (1): the same for Earth.
    * ``earth_phase`` (1): illuminated fraction of Earth's disk seen from the site.
    * ``sun_elevation_deg``, ``sun_azimuth_deg``, ``earth_elevation_deg``,
      ``earth_azimuth_deg`` (1 each): true horizon coordinates (deg), azimuth clockwise
      from true north, elevation above the site's horizontal plane (no terrain).

    W is the site's East-North-Up frame (``world_frame="enu"``) or, with
    ``world_frame="polar_grid"``, the polar-stereographic grid frame of lunar_drake's
    terrain rasters (x grid east, y grid north, z up) via ``site_frame_rotation``; the two
    coincide at longitude 0 and differ by the meridian convergence elsewhere.

    The site (latitude, longitude, height) and the epoch (TDB s past J2000) are numeric
    parameters, so a Context may move them without rebuilding the diagram (the next
    initialization or periodic event picks them up).

    Args:
        site: where the rover is (the site centre).
        epoch_utc: UTC of simulation time 0, ISO 8601 (e.g. "2027-11-20T12:00:00").
        extra_kernels: extra SPICE kernels furnished after the project's own.
        update_period_s: period of the discrete update (s), > 0.
        abcorr: SPICE aberration correction ("LT+S": apparent, as seen from the site).
        world_frame: "enu" or "polar_grid" (see above).
    """

    def __init__(
        self,
        *,
        site: SiteLocation,
        epoch_utc: str,
        extra_kernels: Sequence[str] = (),
        update_period_s: float = 1.0,
        abcorr: str = "LT+S",
        world_frame: str = "enu",
    ):
        super().__init__()
        if not isinstance(site, SiteLocation):
            raise ConfigError(f"site must be a SiteLocation, got {type(site).__name__}")
        period = float(update_period_s)
        if not (np.isfinite(period) and period > 0.0):
            raise OutOfRangeError(
                f"update_period_s = {update_period_s!r}; allowed a finite value > 0 s"
            )
        if str(abcorr).upper() not in ABCORRS:
            raise ConfigError(f"abcorr = {abcorr!r}; allowed {', '.join(ABCORRS)}")
        if world_frame not in WORLD_FRAMES:
            raise ConfigError(f"world_frame = {world_frame!r}; allowed {', '.join(WORLD_FRAMES)}")
        self._extra_kernels = tuple(str(k) for k in extra_kernels)
        ensure_kernels(self._extra_kernels)
        self._abcorr = str(abcorr).upper()
        self._world_frame = world_frame
        self._update_period_s = period
        epoch = utc_to_tdb_s(epoch_utc)

        params = np.array([site.latitude_deg, site.longitude_deg, site.height_m, epoch])
        self._param_index = self.DeclareNumericParameter(BasicVector(params))
        initial = self._evaluate(params, 0.0)
        self._state_index = self.DeclareDiscreteState(initial)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

        xd = {self.xd_ticket()}

        def port(name, sl, size):
            def calc(context, output):
                x = context.get_discrete_state(self._state_index).value()
                output.SetFromVector(np.atleast_1d(x[sl]))

            return self.DeclareVectorOutputPort(name, size, calc, prerequisites_of_calc=xd)

        self.sun_direction_output = port("sun_direction_W", _SUN_DIR, 3)
        self.sun_distance_output = port("sun_distance_km", slice(_SUN_DIST, _SUN_DIST + 1), 1)
        self.earth_direction_output = port("earth_direction_W", _EARTH_DIR, 3)
        self.earth_distance_output = port(
            "earth_distance_km", slice(_EARTH_DIST, _EARTH_DIST + 1), 1
        )
        self.earth_phase_output = port("earth_phase", slice(_PHASE, _PHASE + 1), 1)
        self.sun_elevation_output = port("sun_elevation_deg", slice(_SUN_EL, _SUN_EL + 1), 1)
        self.sun_azimuth_output = port("sun_azimuth_deg", slice(_SUN_AZ, _SUN_AZ + 1), 1)
        self.earth_elevation_output = port(
            "earth_elevation_deg", slice(_EARTH_EL, _EARTH_EL + 1), 1
        )
        self.earth_azimuth_output = port("earth_azimuth_deg", slice(_EARTH_AZ, _EARTH_AZ + 1), 1)

    @property
    def update_period_s(self) -> float:
        """Period of the discrete update (s)."""
        return self._update_period_s

    def _evaluate(self, params: np.ndarray, t: float) -> np.ndarray:
        site = SiteLocation(float(params[_P_LAT]), float(params[_P_LON]), float(params[_P_HEIGHT]))
        se = sun_earth_enu(
            epoch_tdb_s=float(params[_P_EPOCH]) + t,
            site=site,
            abcorr=self._abcorr,
            extra_kernels=self._extra_kernels,
        )
        sun, earth = se.sun_dir_enu, se.earth_dir_enu
        if self._world_frame == "polar_grid":
            R_EW = site_frame_rotation(site)
            sun, earth = R_EW.T @ sun, R_EW.T @ earth
        x = np.empty(_STATE_SIZE)
        x[_SUN_DIR], x[_EARTH_DIR] = sun, earth
        x[_SUN_DIST], x[_EARTH_DIST] = se.sun_distance_km, se.earth_distance_km
        x[_PHASE] = se.earth_phase
        x[_SUN_EL], x[_SUN_AZ] = se.sun_elevation_deg, se.sun_azimuth_deg
        x[_EARTH_EL], x[_EARTH_AZ] = se.earth_elevation_deg, se.earth_azimuth_deg
        return x

    def _update(self, context, discrete_state):
        params = context.get_numeric_parameter(self._param_index).value()
        discrete_state.set_value(self._state_index, self._evaluate(params, context.get_time()))
        return EventStatus.Succeeded()

    def epoch_tdb_s(self, context) -> float:
        """Simulation time 0 in ``context`` (TDB s past J2000)."""
        return float(context.get_numeric_parameter(self._param_index).GetAtIndex(_P_EPOCH))

    def set_epoch_utc(self, context, epoch_utc: str) -> None:
        """Moves simulation time 0 in ``context`` (takes effect at the next event)."""
        context.get_mutable_numeric_parameter(self._param_index).SetAtIndex(
            _P_EPOCH, utc_to_tdb_s(epoch_utc)
        )

    def site(self, context) -> SiteLocation:
        """The site in ``context``."""
        p = context.get_numeric_parameter(self._param_index).value()
        return SiteLocation(float(p[_P_LAT]), float(p[_P_LON]), float(p[_P_HEIGHT]))

    def set_site(self, context, site: SiteLocation) -> None:
        """Moves the site in ``context`` (takes effect at the next event)."""
        if not isinstance(site, SiteLocation):
            raise ConfigError(f"site must be a SiteLocation, got {type(site).__name__}")
        param = context.get_mutable_numeric_parameter(self._param_index)
        param.SetAtIndex(_P_LAT, site.latitude_deg)
        param.SetAtIndex(_P_LON, site.longitude_deg)
        param.SetAtIndex(_P_HEIGHT, site.height_m)
