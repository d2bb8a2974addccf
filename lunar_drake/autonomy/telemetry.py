"""The rover's housekeeping telemetry: one float64 vector per packet."""

from __future__ import annotations

import numpy as np

#: Fields of a telemetry packet, in order (units in the names; mode is an index into
#: :data:`~lunar_drake.autonomy.commands.MODES`; command_seq is the newest command
#: handled, -1 for none).
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
)


def pack_telemetry(*, pose_estimate, twist_command, brake, mode, command_seq) -> np.ndarray:
    """A telemetry packet (see :data:`TELEMETRY_FIELDS`)."""
    return np.concatenate(
        [
            np.asarray(pose_estimate, np.float64)[:6],
            np.asarray(twist_command, np.float64)[:3],
            [float(brake), float(mode), float(command_seq)],
        ]
    )
