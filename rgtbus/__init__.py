"""rgtbus: socialised autonomous units by Reflexive Game Theory over a shared resonator medium."""

from rgtbus.errors import RgtbusError

__version__ = "0.1.0"
__all__ = ["RgtbusError", "__version__"]
