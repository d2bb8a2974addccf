"""TelemetryStore: every datum mission control has, for history queries and realtime
subscribers, plus the latest map products (goals, plan, costmap, camera frame)."""

from __future__ import annotations

import bisect
import dataclasses as dc
import math
from collections.abc import Callable, Iterable

from lunar_drake.errors import ConfigError
from lunar_drake.mission_control.dictionary import BY_KEY


class UnknownPointError(ConfigError):
    """A telemetry key that is not in the dictionary."""


def check_key(key: str) -> str:
    """``key`` if the dictionary has it, else :class:`UnknownPointError` listing a few."""
    if key not in BY_KEY:
        some = ", ".join(sorted(BY_KEY)[:6])
        raise UnknownPointError(f"unknown telemetry key {key!r}; the dictionary has "
                                f"{len(BY_KEY)} keys ({some}, ...; GET /api/dictionary)")
    return key


@dc.dataclass
class Series:
    """One point's samples in time order: ``times`` (s) and ``values``."""

    times: list = dc.field(default_factory=list)
    values: list = dc.field(default_factory=list)

    def add(self, t: float, value) -> None:
        if not self.times or t >= self.times[-1]:
            self.times.append(t)
            self.values.append(value)
            return
        k = bisect.bisect_right(self.times, t)
        self.times.insert(k, t)
        self.values.insert(k, value)


@dc.dataclass
class MapState:
    """What the site map shows: ``goals`` ((x, y, status), ...), the planned ``path``
    ((x, y), ...) of the goto ``plan_seq``, and the science samples placed by the ground
    (``science``: heat layer -> [(x, y, value), ...]; layers of
    :data:`~lunar_drake.mission_control.dictionary.HEAT_LAYERS`) and, with the
    instructor overlay only, the rover's ``truth`` track ((t_s, x, y, yaw), ...)."""

    goals: list = dc.field(default_factory=list)
    path: list = dc.field(default_factory=list)
    plan_seq: int = -1
    science: dict = dc.field(default_factory=dict)
    truth: list = dc.field(default_factory=list)


class TelemetryStore:
    """Datums by key and realtime subscribers.

    ``add(datums)`` appends ``(key, t_s, value)`` triples and calls every listener with
    the new ones; ``history(key, start, end)`` returns one point's samples between two
    times (s, inclusive). ``now_s`` is the newest simulation time seen.
    """

    def __init__(self):
        self.series: dict[str, Series] = {}
        self.map = MapState()
        self.now_s = 0.0
        self.listeners: list[Callable[[list], None]] = []

    def add(self, datums: Iterable) -> list:
        new = []
        for key, t, value in datums:
            if key not in BY_KEY:
                continue
            if isinstance(value, float) and not math.isfinite(value):
                continue
            self.series.setdefault(key, Series()).add(float(t), value)
            new.append((key, float(t), value))
            self.now_s = max(self.now_s, float(t))
        for listen in list(self.listeners):
            listen(new)
        return new

    def history(self, key: str, *, start_s: float = -math.inf, end_s: float = math.inf) -> list:
        """``[(t_s, value), ...]`` of ``key`` with start_s <= t <= end_s."""
        check_key(key)
        s = self.series.get(key)
        if s is None:
            return []
        i = bisect.bisect_left(s.times, start_s)
        j = bisect.bisect_right(s.times, end_s)
        return list(zip(s.times[i:j], s.values[i:j], strict=True))

    def latest(self, key: str):
        """The newest ``(t_s, value)`` of ``key``, or None."""
        check_key(key)
        s = self.series.get(key)
        return (s.times[-1], s.values[-1]) if s and s.times else None
