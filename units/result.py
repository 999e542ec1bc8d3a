"""What a run gives back, whichever way it ran: ``RunResult`` (``rgtbus.run``,
``rgtbus.launch``; docs/api.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rgtbus.errors import BadInput

if TYPE_CHECKING:
    import pandas as pd

    from rgtbus.misreads import DecodeErrors
    from rgtbus.scenario import Scenario
    from rgtbus.telemetry.frames import Log


@dataclass
class RunResult:
    """What ``rgtbus.run`` and ``rgtbus.launch`` return. ``summary``: the dict ``rgtbus run
    --json`` prints (its keys are ``rgtbus.summary.SUMMARY_JSON_KEYS``); ``log``: the log
    written (``None`` without one; a launch's merged ``run.mcap``); ``scenario``: the scenario
    as run (its seed set); ``failures``: every failure the run names, root causes first (a
    launch may name several: a unit that died, then those that waited for it), the first of
    them the summary's ``error``; ``interrupted``: a launch stopped by SIGINT or SIGTERM (its
    units stopped, its log merged all the same)."""

    summary: dict[str, Any]
    scenario: Scenario
    log: Path | None = None
    # the whole summary (``rgtbus.summary.summarise``): also steps, bus statistics, each
    # unit's own relationship table
    details: dict[str, Any] = field(default_factory=dict, repr=False)
    failures: list[str] = field(default_factory=list)
    interrupted: bool = False
    # every misread decode, as the summary counts them (``decode_errors()``)
    misreads: DecodeErrors | None = field(default=None, repr=False, compare=False)

    @property
    def ok(self) -> bool:
        """The run finished without an error."""
        return self.summary.get("error") is None

    def open_log(self) -> Log:
        """The run's log, read back (``RgtbusError`` if the run wrote none)."""
        if self.log is None:
            raise BadInput("this run wrote no log: run it with log=PATH")
        from rgtbus.telemetry.frames import open_log

        return open_log(self.log)

    def decode_errors(self) -> pd.DataFrame:
        """Every misread decode of the run, one row each (``Log.decode_errors()``'s columns:
        ``unit, turn, kind, decoded, sent, left_wrong``); the summary's ``decode_errors``
        counts them. From the run itself, else (a result rebuilt without its details) from its
        log."""
        if self.misreads is None:
            return self.open_log().decode_errors()
        return self.misreads.frame()

    def decisions(self) -> pd.DataFrame:
        """The summary's decisions as a DataFrame (one row per unit and round), as
        ``Log.decisions()`` gives them."""
        from rgtbus.telemetry.frames import decisions_frame

        return decisions_frame(self.summary)


def result_of(
    sc: Scenario, summary: dict[str, Any], log: Path | None, misreads: DecodeErrors | None = None
) -> RunResult:
    """The ``RunResult`` of a run in one process from its whole summary (its error, if any,
    the one failure it names) and its misreads."""
    from rgtbus.summary import summary_json

    error = summary.get("error")
    return RunResult(
        summary_json(summary), sc, log, summary, [error] if error else [], misreads=misreads
    )
