"""The library face of rgtbus: what ``import rgtbus`` offers (docs/api.md).

* ``load_scenario(path_or_text_or_name)`` -> ``Scenario``;
* ``run(scenario, *, seed, bus, engine, log)`` -> ``RunResult`` (``.summary`` is what
  ``rgtbus run --json`` prints);
* ``launch(scenario, *, procs, seed, log_dir, zenoh, key_file, realtime, timeout, tls)`` ->
  ``RunResult``: the units as OS processes over zenoh (``rgtbus.units.launch``), the same
  summary but for wall time and paths;
* ``open_log(path)`` -> ``Log`` (``.summary()``, ``.metadata``, DataFrames);
* ``sweep(scenario, *, grid, seeds, ...)`` -> a DataFrame of the rows ``rgtbus sweep`` writes;
* ``study(file_or_name_or_mapping, *, out, failures, budget, ...)`` -> ``StudyResult``
  (``.points``, ``.runs``: what ``rgtbus study`` writes; docs/studies.md): ``rgtbus.study`` is
  ``rgtbus.units.study.study`` itself.

Every command is a thin wrapper over these: the same errors (``RgtbusError``, one line with
file:line: key), the same results.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import rgtbus.checks as checks
from rgtbus.errors import BadInput
from rgtbus.units.result import RunResult, result_of

if TYPE_CHECKING:
    from collections.abc import Callable

    from rgtbus.engine.steering import Requests
    from rgtbus.scenario import Scenario
    from rgtbus.telemetry.frames import Log
    from rgtbus.telemetry.live import LiveView


def load_scenario(source: str | os.PathLike[str] | Scenario) -> Scenario:
    """A scenario from a file path, TOML text, or the name of a shipped scenario (``"gate"``;
    ``rgtbus scenarios`` lists them). Bad input: ``RgtbusError`` naming file:line: key."""
    from rgtbus.scenario import Scenario
    from rgtbus.scenario import load_scenario as load

    if isinstance(source, Scenario):
        return source
    return load(source)


def run(
    scenario: str | os.PathLike[str] | Scenario,
    *,
    seed: int | None = None,
    bus: str = "memory",
    engine: str = "event",
    log: str | os.PathLike[str] | None = None,
    traces: bool = False,
    key: bytes | None = None,
    realtime: float | None = None,
    progress: Callable[[float, int], None] | None = None,
    live: LiveView | None = None,
    control: Requests | None = None,
) -> RunResult:
    """Run every unit of ``scenario`` in this process and return its summary.

    ``seed`` overrides the scenario's; ``bus``: ``"memory"`` (in-process) or ``"zenoh"``;
    ``engine``: ``"event"`` or ``"dense"`` (identical results); ``log``: a path to write the
    MCAP log to (``None``: no log); ``traces``: resonator states in the log; ``key``: the
    run's shared secret (frames signed and checked); ``realtime``: pace the run at that many
    simulated seconds per wall second; ``progress(sim_seconds, step)``: called as the run
    goes; ``live``: a Foxglove live view offered every message (needs ``log``); ``control``:
    where a steered run's requests come from (``live.control``, a ``Controller``, for a
    Foxglove client's; anything with ``take``, ``wait`` and ``clock``: docs/foxglove.md),
    each applied at a window boundary and logged on /control/*. A run that
    fails returns its summary with ``error`` set (and its log closed and readable); bad
    arguments raise ``RgtbusError``."""
    from rgtbus.bus.registry import bus_kinds
    from rgtbus.telemetry.recorder import NullRecorder
    from rgtbus.units.group import run_group

    sc = load_scenario(scenario)
    if seed is not None:
        sc = sc.with_seed(seed)
    checks.choice(bus, bus_kinds(), "bus")
    checks.choice(engine, checks.ENGINES, "engine")
    if realtime is not None:
        checks.realtime(realtime)
    options: dict[str, Any] = {
        "traces": traces, "engine": engine, "key": key, "realtime": realtime,
        "progress": progress, "control": control,
    }  # fmt: skip
    if log is None:
        if live is not None:
            live.close()
            raise BadInput("a live view needs a log (log=PATH): it serves what is logged")
        out = run_group(sc, bus, NullRecorder(), **options)
        return result_of(sc, out.summary, None, out.misreads)
    from rgtbus.telemetry.logfile import close_log
    from rgtbus.telemetry.logfile import open_log as open_file

    path = Path(log)
    try:
        stream, recorder = open_file(path, live)
    except BaseException:
        if live is not None:
            live.close()
        raise
    interrupted = False
    try:
        if live is not None:
            live.begin()
        out = run_group(sc, bus, recorder, **options)
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM where the caller maps it (rgtbus run)
        interrupted = True
        if not recorder.failed:
            recorder.log("fatal", "run interrupted: its log is cut here", 0)
        raise
    except BaseException as exc:
        if not recorder.failed:  # a log that cannot be written cannot take the line either
            recorder.log("fatal", f"run failed: {exc}", 0)
        raise
    finally:
        try:
            # an interrupted run's log ends as a cut one: replay --verify checks it that far
            close_log(stream, recorder, finished=not interrupted)
        finally:
            if live is not None:
                live.close()
    out.summary["log"] = str(path)
    return result_of(sc, out.summary, path, out.misreads)


def open_log(source: str | os.PathLike[str] | IO[bytes]) -> Log:
    """A run's MCAP log, read (CRC-checked) and organised: ``.summary()`` (the summary of
    ``rgtbus run --json``, from the log alone), ``.metadata``, and DataFrames ``.decisions()``,
    ``.decodes()``, ``.spikes()``, ``.transmissions()``, ``.medium()``, ``.messages(topic)``.
    From a path, each topic is read from the file when first asked for (keep the file); from
    a binary stream, the log is read whole at once."""
    from rgtbus.telemetry.frames import open_log as open_frames

    return open_frames(source)


def sweep(
    scenario: str | os.PathLike[str] | Scenario,
    *,
    grid: dict[str, Any],
    seeds: int | list[int] | range,
    workers: int | None = None,
    out: str | os.PathLike[str] | None = None,
    scheduler: str | None = None,
    **options: Any,
) -> Any:
    """Run ``scenario`` over ``seeds`` and the ``grid`` of keys (``n``, ``engine``, any dotted
    scenario key) on a process pool (or the Dask cluster at ``scheduler``) and return the
    rows ``rgtbus sweep`` writes, as a pandas DataFrame. Works from a script or notebook cell
    without a main guard. ``out``: a directory to keep the tables in (``results.parquet``,
    ``decisions.parquet``)."""
    from rgtbus.units.sweep import sweep as run_sweep

    return run_sweep(
        scenario, grid=grid, seeds=seeds, workers=workers, out=out, scheduler=scheduler, **options
    )

