"""Sample timing shared by all sensors: sample indices and delivery with a delay."""

from __future__ import annotations

import math

from lunar_drake.errors import OutOfRangeError, check_range

#: Time tolerance (s) when a sample time is compared with the simulation clock.
TIME_EPS_S = 1.0e-9


def sample_index(time_s: float, rate_hz: float) -> int:
    """Index k of the periodic sample at ``time_s`` (samples at t = k / rate_hz).

    Must lie in [0, 2**31): 248 days at 100 Hz.
    """
    k = round(time_s * rate_hz)
    if not 0 <= k < 2**31:
        raise OutOfRangeError(f"sample index {k} at t = {time_s:.6g} s; must be in [0, 2**31)")
    return int(k)


def delivered_index(time_s: float, *, rate_hz: float, delay_s: float) -> int:
    """Index of the latest sample delivered by ``time_s``: the largest k with
    ``k / rate_hz + delay_s <= time_s`` (-1 before the first delivery)."""
    return math.floor((time_s - delay_s) * rate_hz + TIME_EPS_S * rate_hz)


def samples_in_flight(*, rate_hz: float, delay_s: float) -> int:
    """How many samples a sensor must hold so the one due for delivery is still there:
    1 without delay, else floor(delay * rate) + 2."""
    if delay_s <= 0.0:
        return 1
    return math.floor(delay_s * rate_hz + TIME_EPS_S) + 2


def check_sampling(rate_hz: float, delay_s: float, *, max_rate_hz: float = 1.0e4) -> None:
    """Validates a sensor's ``rate_hz`` and ``delay_s`` (errors name the field)."""
    check_range("rate_hz", rate_hz, 0.0, max_rate_hz, lo_open=True, unit=" Hz")
    check_range("delay_s", delay_s, 0.0, 3600.0, unit=" s")
