"""The rover's housekeeping telemetry: one float64 vector per packet."""

from __future__ import annotations

import math

import numpy as np

#: Fields of a telemetry packet, in order (units in the names; mode is an index into
#: :data:`~lunar_drake.autonomy.commands.MODES`; command_seq is the newest command
#: handled, -1 for none; safe_reason an index into
#: :data:`~lunar_drake.autonomy.commands.SAFE_REASONS`; mode_changes counts every mode
#: transition on board since the start, so the ground sees one it missed between packets;
#: motion_seq is the seq of the newest drive or goto command accepted, -1 for none;
#: soc and array_W from the power sensor, NaN without one).
TELEMETRY_FIELDS = (
    "x_m",
    "y_m",
    "z_rel_m",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "vx_cmd_mps",
    "vy_cmd_mps",
    "wz_cmd_radps",
    "brake",
    "mode",
    "command_seq",
    "safe_reason",
    "mode_changes",
    "motion_seq",
    "soc",
    "array_W",
)


def pack_telemetry(*, pose_estimate, twist_command, brake, status, power=None) -> np.ndarray:
    """A telemetry packet (see :data:`TELEMETRY_FIELDS`); ``status`` is the executor's
    (mode, command_seq, safe_reason, mode_changes, motion_seq); ``power`` the power
    sensor's (soc, array W, load W) or None."""
    p = (math.nan, math.nan) if power is None else (float(power[0]), float(power[1]))
    return np.concatenate(
        [
            np.asarray(pose_estimate, np.float64)[:6],
            np.asarray(twist_command, np.float64)[:3],
            [float(brake)],
            np.asarray(status, np.float64)[:5],
            p,
        ]
    )


def field(packet, name: str) -> float:
    """One field of a telemetry packet."""
    return float(packet[TELEMETRY_FIELDS.index(name)])
