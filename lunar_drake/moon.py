"""Physical constants of the Moon used across lunar_drake (defined once, here)."""

from __future__ import annotations

import math

GRAVITY_MPS2 = 1.62
"""Mean lunar surface gravity (m/s^2); NASA GSFC Moon Fact Sheet."""

GRAVITY_W = (0.0, 0.0, -GRAVITY_MPS2)
"""Gravity in a site frame W with z up (m/s^2)."""

ROTATION_RATE_RAD_S = 2.0 * math.pi / (27.321661 * 86400.0)
"""Sidereal rotation rate of the Moon (rad/s): 2 pi / 27.321661 d (Moon Fact Sheet)."""
