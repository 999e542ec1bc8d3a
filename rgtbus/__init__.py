"""rgtbus: socialised autonomous units by Reflexive Game Theory over a shared resonator medium.

The library (docs/api.md)::

    import rgtbus
    result = rgtbus.run("gate", seed=1, log="logs/gate.mcap")
    log = rgtbus.open_log(result.log)
    log.decisions()          # a pandas DataFrame, one row per unit and round

Names are imported on first use, so ``import rgtbus`` stays fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from rgtbus._version import __version__
from rgtbus.errors import BadInput, BadLog, IOFailure, PeerSilent, RgtbusError

if TYPE_CHECKING:
    from rgtbus.api import load_scenario, open_log, run, sweep
    from rgtbus.scenario import Scenario
    from rgtbus.telemetry.frames import Log
    from rgtbus.units.launch import launch
    from rgtbus.units.result import RunResult
    from rgtbus.units.study import study

_LAZY = {
    "load_scenario": "rgtbus.api",
    "run": "rgtbus.api",
    "launch": "rgtbus.units.launch",
    "open_log": "rgtbus.api",
    "sweep": "rgtbus.api",
    "study": "rgtbus.units.study",
    "RunResult": "rgtbus.units.result",
    "Log": "rgtbus.telemetry.frames",
    "Scenario": "rgtbus.scenario",
}

__all__ = [
    "BadInput",
    "BadLog",
    "IOFailure",
    "Log",
    "PeerSilent",
    "RgtbusError",
    "RunResult",
    "Scenario",
    "__version__",
    "launch",
    "load_scenario",
    "open_log",
    "run",
    "study",
    "sweep",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'rgtbus' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
