"""The drill: regolith brought up from depth at a stop and read by NIRVSS (numpy; no
Drake).

A drill command (``depth_m``, ``step_m``) is refused beyond ``max_depth_m`` (1 m, the
reference mission's drill) or with a step that does not divide it into at most 100
samples. At a stop the drill brings up one sample every ``seconds_per_step`` from
``step_m``, ``2 step_m``, ... down to ``depth_m``; each sample holds the world model's
ice at that depth under the hole (``ice_wt_pct`` below the dry layer, none above it)
and NIRVSS reads its ice band under its own lamp (``ice_per_wt_pct`` x wt% plus
``sigma_lamp`` noise, clipped to [0, 1]). The ground turns the band depth back into wt%.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import OutOfRangeError, check_range

#: The deepest sample any drill command may ask for (m): the reference mission's 1 m.
MAX_DEPTH_M = 1.0


@dc.dataclass
class DrillConfig:
    """The drill (see the module docstring).

    Attributes:
        enabled: carried by the rover (off by default; its samples are read by NIRVSS,
            so ``sensors.nirvss`` must be on too).
        x_m: the hole ahead of the chassis centre (m).
        seconds_per_step: time to bring up one sample (s), (0, 3600].
        max_depth_m: deepest sample (m), (0, 1].
    """

    enabled: bool = False
    x_m: float = 0.6
    seconds_per_step: float = 30.0
    max_depth_m: float = MAX_DEPTH_M

    def validate(self) -> None:
        check_range("x_m", self.x_m, -5.0, 5.0, unit=" m")
        check_range("seconds_per_step", self.seconds_per_step, 0.0, 3600.0, lo_open=True,
                    unit=" s")  # fmt: skip
        check_range("max_depth_m", self.max_depth_m, 0.0, MAX_DEPTH_M, lo_open=True, unit=" m")


def check_drill_request(depth_m: float, step_m: float, *, max_depth_m: float = MAX_DEPTH_M,
                        what: str = "drill") -> int:  # fmt: skip
    """Number of samples of a drill to ``depth_m`` in steps of ``step_m``; raises a
    one-line OutOfRangeError naming the value and what is allowed."""
    sep = "" if what.endswith(".") else " "
    check_range(f"{what}{sep}depth_m", depth_m, 0.0, max_depth_m, lo_open=True,
                unit=f" m (the drill reaches {max_depth_m:g} m)")  # fmt: skip
    check_range(f"{what}{sep}step_m", step_m, 0.0, depth_m, lo_open=True,
                unit=" m (at most the depth)")  # fmt: skip
    n = math.floor(depth_m / step_m + 1e-9)
    if n > 100:
        raise OutOfRangeError(
            f"{what}{sep}step_m = {step_m:g} m makes {n} samples down to {depth_m:g} m; at most 100"
        )
    return n


def ice_at_depth(dry_layer_m: float, ice_wt_pct: float, depth_m: float) -> float:
    """Ice (wt%) in a sample from ``depth_m``: none above the dry layer."""
    return float(ice_wt_pct) if depth_m >= dry_layer_m else 0.0


def read_sample(ice_wt_pct: float, generator: np.random.Generator, *, ice_per_wt_pct: float,
                sigma: float) -> float:  # fmt: skip
    """NIRVSS's ice band depth of a sample (one normal draw)."""
    return float(np.clip(ice_per_wt_pct * ice_wt_pct + sigma * generator.standard_normal(),
                         0.0, 1.0))  # fmt: skip


__all__ = ["MAX_DEPTH_M", "DrillConfig", "check_drill_request", "ice_at_depth", "read_sample"]
