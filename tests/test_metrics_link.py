"""``summary.json``'s ``link`` section: counts per direction and the delivery latency
labelled ``min``, ``median``, ``max`` (s)."""

import math
from types import SimpleNamespace

from lunar_drake.comms.link import LinkRecord
from lunar_drake.metrics import link_stats


def _rec(direction, seq, t_sent, t_received, *, dropped=False, reason="", size=100):
    return LinkRecord(direction=direction, channel="main", topic="telemetry", seq=seq,
                      bytes=size, t_sent=t_sent, t_received=t_received, dropped=dropped,
                      reason=reason)  # fmt: skip


def test_latency_is_labelled_min_median_max_of_the_delivered():
    nan = math.nan
    logs = SimpleNamespace(link=[
        _rec("downlink", 0, 0.0, 1.30),  # 1.30 s
        _rec("downlink", 1, 1.0, 2.25),  # 1.25 s
        _rec("downlink", 2, 2.0, 3.40),  # 1.40 s
        _rec("downlink", 3, 3.0, 4.90),  # 1.90 s
        _rec("downlink", 4, 4.0, nan, dropped=True, reason="loss"),
        _rec("downlink", 5, 5.0, nan),  # in flight at the end
        _rec("uplink", 0, 0.5, nan, dropped=True, reason="loss"),
    ])  # fmt: skip
    out = link_stats(logs)
    down = out["downlink"]
    # Median of an even count: the mean of the middle two (1.30, 1.40).
    assert down["latency_s"] == {"min": 1.25, "median": 1.35, "max": 1.9}
    assert list(down["latency_s"]) == ["min", "median", "max"]
    assert (down["messages"], down["delivered"], down["dropped"]) == (6, 4, 1)
    assert down["in_flight_at_end"] == 1 and down["bytes"] == 600
    assert out["uplink"]["latency_s"] is None  # nothing delivered
    assert out["uplink"]["dropped_by_reason"] == {"loss": 1}
