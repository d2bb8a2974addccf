"""Science records as downlink payloads (no Drake)."""

from __future__ import annotations

import dataclasses as dc

#: Downlink topic of science records.
TOPIC = "science"
#: Bytes of one record as flown: instrument id (1), index (4), time (8), two 32-bit
#: values, the on-board pose estimate as six 32-bit floats, padding.
RECORD_BYTES = 48


@dc.dataclass(frozen=True)
class ScienceRecord:
    """One instrument sample, as the rover sends it down.

    Attributes:
        instrument: ``"nss"``. index: the instrument's sample index.
        t_sample_s: when the sample was taken (s, simulation time; for counts, the end
            of the ``integration_s`` they cover, drawn for the footprint at that instant).
        values: the instrument's values (NSS: epithermal and thermal counts).
        integration_s: the integration time (s).
        pose_estimate: the on-board estimate (x, y, z, roll, pitch, yaw; m, rad) at the
            sample time, for the ground to place it.
    """

    instrument: str
    index: int
    t_sample_s: float
    values: tuple
    integration_s: float
    pose_estimate: tuple

    def size_bytes(self) -> int:
        return RECORD_BYTES


__all__ = ["RECORD_BYTES", "TOPIC", "ScienceRecord"]
