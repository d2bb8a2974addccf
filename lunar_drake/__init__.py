"""lunar_drake: a Lunar rover mission simulator built on Drake.

See README.md for the two commands that set up and run everything, and
``../shared/DESIGN.md`` for the architecture.
"""

from lunar_drake.errors import LunarDrakeError

__all__ = ["LunarDrakeError", "__version__"]
__version__ = "0.1.0"
