"""Many processes, one run: ``launch`` (``rgtbus.launch``; docs/api.md).

``launch`` forks one OS process per unit (or ``procs`` processes of even groups of units, in
the scenario's order), each running its units over zenoh (``rgtbus.units.process``): on
loopback by default, a full mesh on free ports (each process listens on its own and connects to
those before it), or through a router process (``router=True``), or over the zenoh options
given (the same for every process); with ``tls`` every process proves itself with its own
certificate (rgtbus.bus.certs) on ``tls/`` endpoints. It collects what each process reports,
names the failures (root causes first: a unit that died or crashed, then one that stalled, then
those that failed for want of them) and always ends with a merged ``run.mcap`` whose ``/run``
record names the first failure. Its summary equals the one-process run's (``rgtbus.run``) but
for wall time and paths.

The launcher forks once it has loaded everything (a unit starts in milliseconds); every process
it starts is reaped (asked to stop, then killed); a unit process asks Linux to stop it when the
launcher dies (``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Collection, Mapping, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from rgtbus.units.group import default_run_id
from rgtbus.units.result import RunResult

import rgtbus.checks as checks
from rgtbus.bus.hello import join_seconds
from rgtbus.bus.registry import cross_process_kind
from rgtbus.errors import BadInput, IOFailure, RgtbusError
from rgtbus.interrupts import interrupted_by
from rgtbus.misreads import DecodeErrors, decode_errors_of
from rgtbus.scenario import Scenario, load_scenario
from rgtbus.summary import summarise, summary_json

ZENOH_OPTIONS = ("mode", "connect", "listen", "multicast", "config")
_FEW_SECONDS = 5.0  # for the other units to report once one has said a member went silent
_STOP_SECONDS = 10.0  # what processes asked to stop still say, within this in all
_BEAT = 2.0  # s: how often a unit process tells the launcher how far its world is
ROUTER_ABOVE = 16  # processes: more than this meet through a router by default, not a mesh
# loaded once by the fork server, so that each unit process starts in milliseconds
_PRELOAD = ["numpy.random", "rgtbus.bus.zenoh", "rgtbus.units.process"]


def _may_fork() -> bool:
    """Whether the unit processes may be forks of this one: not once zenoh is loaded here (a
    notebook that ran over zenoh: a fork would copy a zenoh runtime it cannot use) nor while
    another thread runs (a Dask client: a fork would copy its locks held); then a fork server
    starts them."""
    return "zenoh" not in sys.modules and threading.active_count() == 1


def process_groups(units: Sequence[str], procs: int | None) -> dict[str, list[str]]:
    """The units of each process of a launch, by process name: one process per unit (named
    by its unit) by default; with ``procs`` P, P even groups in the scenario's order, named
    ``proc-<i>``."""
    if procs is None:
        return {u: [u] for u in units}
    if isinstance(procs, bool) or not isinstance(procs, int) or not 1 <= procs <= len(units):
        raise BadInput(f"--procs {procs}: must be 1 to {len(units)} (the number of units)")
    size, extra = divmod(len(units), procs)
    out: dict[str, list[str]] = {}
    at = 0
    for i in range(procs):
        n = size + (i < extra)
        out[f"proc-{i}"] = list(units[at : at + n])
        at += n
    return out


def default_timeout(processes: int) -> float:
    """How long the units of a launch wait for news before they give up, by default: 10 s,
    stretched by how far ``processes`` outnumber this machine's cores (a unit process starved
    of CPU, one of a hundred on two cores, can take a minute over a second's work: 10 s x
    processes / cores)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return 10.0 * max(1.0, processes / (cores or 1))


def free_ports(n: int) -> list[int]:
    """n distinct free TCP ports on loopback (held open together, so no two are the same)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _die_with_parent() -> None:
    """In a child: ask Linux for SIGTERM when the launcher dies, so no unit is left behind even
    if the launcher is killed outright (best effort elsewhere)."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _unit_child(
    conn: Connection,
    sc: Scenario,
    names: list[str],
    log: Path,
    net: dict[str, Any],
    after: list[Any],
    listening: Any,
    **opts: Any,
) -> None:
    """The units ``names`` of a launch, in their own forked process: what ``rgtbus unit``
    does, the result (``{"units": {name: output}}``, or ``{"crash": why}``) sent back on
    ``conn``. It opens its session once the peers it connects to listen (``after``), and
    says when it listens itself (``listening``)."""
    from rgtbus.units.process import run_logged_units

    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the launcher's to handle
    sent = False
    beat_at = 0.0

    def beat(_now: float, steps: int) -> None:
        """Tell the launcher how far the world is (at most every ``_BEAT`` s)."""
        nonlocal beat_at
        if time.monotonic() - beat_at >= _BEAT:
            beat_at = time.monotonic()
            conn.send({"beat": steps})

    def report(outs: dict[str, dict[str, Any]]) -> None:
        """The units' parts, told at once: closing the session may then wait for a dead peer."""
        nonlocal sent
        for o in outs.values():
            o["log"] = str(log)
        conn.send({"units": outs})
        sent = True

    out: dict[str, Any] = {}
    with interrupted_by(signal.SIGTERM):  # a launcher stopping its units
        try:
            for ev in after:  # bounded: a peer that never listens is named by the join
                ev.wait(10.0)
            run_logged_units(
                sc, names, log, zenoh_options=net, progress=beat,
                on_open=listening.set, on_result=report, **opts,
            )  # fmt: skip
        except KeyboardInterrupt:
            out = {"crash": "interrupted"}
        except RgtbusError as exc:
            out = {"crash": str(exc)}
        except BaseException as exc:  # a bug: say what, not a traceback on the launcher's terminal
            out = {"crash": f"{type(exc).__name__}: {exc}"}
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # done: being stopped now loses nothing
    if not sent:
        conn.send(out)
    conn.close()


def _router_child(conn: Connection, endpoint: str, patience: float, **tls: Any) -> None:
    """A zenoh router on ``endpoint`` in its own process (waiting ``patience`` s on a client
    that does not read; ``tls``: ``open_router``'s TLS options), until SIGINT or SIGTERM."""
    from rgtbus.units.process import open_router

    _die_with_parent()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        session = open_router([endpoint], multicast=False, **tls)
    except RgtbusError as exc:
        conn.send(str(exc))
        return
    try:
        conn.send(None)  # listening
        while not stop.wait(0.5):
            pass
    finally:
        session.close()


def _is_stopped(pid: int | None) -> bool:
    """Whether process ``pid`` is stopped (SIGSTOP, a debugger: state T or t in
    ``/proc/<pid>/stat``); False where that cannot be read."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (OSError, TypeError):
        return False
    return stat[stat.rfind(")") + 2 : stat.rfind(")") + 3] in ("T", "t")


class LaunchProcesses:
    """The processes of a launch, forked from the launcher (see the module docstring)."""

    def __init__(self, fork: bool) -> None:
        import multiprocessing

        if fork:  # a fork of the launcher, everything loaded once for all
            for module in _PRELOAD:
                importlib.import_module(module)
            self._mp: Any = multiprocessing.get_context("fork")
        else:  # a fork server: a clean process, started with the modules loaded, forks each
            self._mp = multiprocessing.get_context("forkserver")
            self._mp.set_forkserver_preload(_PRELOAD)
        self.procs: dict[str, Any] = {}
        self._results: dict[str, Connection] = {}
        self._listening: dict[str, Any] = {}
        self._logs: dict[str, Path] = {}

    def start_process(
        self,
        name: str,
        units: list[str],
        sc: Scenario,
        log: Path,
        net: dict[str, Any],
        after: list[str],
        **opts: Any,
    ) -> None:
        """Fork process ``name`` running ``units``; it opens its session once the processes
        ``after`` listen."""
        reader, writer = self._mp.Pipe(duplex=False)
        self._listening[name] = self._mp.Event()
        waits = [self._listening[p] for p in after]
        proc = self._mp.Process(
            target=_unit_child,
            args=(writer, sc, units, log, net, waits, self._listening[name]),
            kwargs=opts,
            name=name,
        )
        proc.start()
        writer.close()
        self.procs[name] = proc
        self._results[name] = reader
        self._logs[name] = log

    def start_router(self, endpoint: str, timeout: float, patience: float, **tls: Any) -> None:
        """Fork a zenoh router on ``endpoint`` (waiting ``patience`` s on a client that does
        not read; ``tls``: ``open_router``'s TLS options); wait until it listens."""
        reader, writer = self._mp.Pipe(duplex=False)
        proc = self._mp.Process(
            target=_router_child, args=(writer, endpoint, patience), kwargs=tls, name="router"
        )
        proc.start()
        writer.close()
        self.procs["router"] = proc
        if not reader.poll(timeout):
            raise BadInput(f"router did not start within {timeout:g} s")
        try:
            problem = reader.recv()
        except EOFError:
            problem = f"router process ended ({_signal_name(proc.exitcode)})"
        if problem is not None:
            raise BadInput(problem)

    def collect(
        self, first: float, stall_after: float, timeout: float, paced: bool = False
    ) -> dict[str, dict[str, Any]]:
        """Every process's result as it comes. A process that runs ends by itself: within its own
        ``timeout`` of hearing nothing from the others (a paced one may run on for seconds up to
        where a dead peer had promised), so it is stalled when its world has not moved for
        ``stall_after`` s (its beats: how far its world is), or ``first`` s before its first move
        (the join, the start); a paced run's process (``paced``) may also wait between moves until
        ``first`` s have passed (``first`` then holds the paced length). One that stays stopped
        (SIGSTOP, state T) for ``timeout`` and a few seconds more is stalled at once: the others
        have given up on it. A stalled process is absent from the result (the launcher stops it and
        asks it what it knew). A process that dies without a result gets ``{"died": exit code}``."""
        from multiprocessing.connection import wait

        out: dict[str, dict[str, Any]] = {}
        waiting = dict(self._results)
        start = time.monotonic()
        deadline = {name: start + first for name in waiting}
        steps: dict[str, int] = {}
        stopped_since: dict[str, float] = {}
        while waiting:
            now = time.monotonic()
            for name in list(waiting):
                if not _is_stopped(self.procs[name].pid):
                    stopped_since.pop(name, None)
                    if now > deadline[name]:
                        del waiting[name]  # its world stopped moving: stalled
                elif now - stopped_since.setdefault(name, now) > timeout + _FEW_SECONDS:
                    del waiting[name]  # stalled
            ready = wait(list(waiting.values()), timeout=0.25)
            for name, conn in list(waiting.items()):
                if conn not in ready:
                    continue
                said = self._result_of(name, conn)
                if "beat" in said:  # the world moved on (or not): not a result
                    if said["beat"] != steps.get(name):
                        steps[name] = said["beat"]
                        moved = time.monotonic()
                        deadline[name] = max(moved + stall_after, start + first if paced else 0)
                    continue
                out[name] = said
                del waiting[name]
        return out

    def _result_of(self, name: str, conn: Connection) -> dict[str, Any]:
        """What process ``name`` sent; ``{"died": exit code}`` when it ended without a word."""
        try:
            said: dict[str, Any] = conn.recv()
            return said
        except (EOFError, OSError):
            proc = self.procs[name]
            proc.join(timeout=5.0)
            return {"died": proc.exitcode}

    def late_results(self, names: list[str], timeout: float) -> dict[str, dict[str, Any]]:
        """What processes that were asked to stop still said (within ``timeout`` s in all)."""
        out: dict[str, dict[str, Any]] = {}
        end = time.monotonic() + timeout
        for name in names:
            conn = self._results[name]
            with contextlib.suppress(EOFError, OSError):
                if conn.poll(max(0.0, end - time.monotonic())):
                    out[name] = conn.recv()
        return out

    def stop(self, names: list[str]) -> None:
        """Ask processes to stop: SIGTERM (its units then finish the log and say so), and
        SIGCONT so that a stopped (SIGSTOP) one can."""
        for name in names:
            p = self.procs[name]
            if p.is_alive() and p.pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p.pid, signal.SIGTERM)
                    os.kill(p.pid, signal.SIGCONT)

    def reap(self) -> None:
        """Every process ended: given a moment to leave on its own (a unit that has sent its
        result is closing its session), then asked to stop, then killed."""
        grace = time.monotonic() + 1.0
        for name, p in self.procs.items():
            if name != "router":
                p.join(timeout=max(0.0, grace - time.monotonic()))
        self.stop([n for n in self.procs if n != "router"])
        router = self.procs.get("router")
        if router is not None and router.is_alive():
            router.terminate()
        deadline = time.monotonic() + 5
        for p in self.procs.values():
            p.join(timeout=max(0.1, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join()


def _signal_name(code: int | None) -> str:
    if code is None:
        return "no exit code"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def _where(log: Path, window: float) -> str:
    """Where a unit's log ends: its last message's time and window (logs are flushed as the
    run goes, so this is at most about a second of simulated time before the unit stopped)."""
    from rgtbus.telemetry.scan import scan_log
    from rgtbus.timebase import seconds

    if not log.exists():
        return "before it opened its log"
    try:
        raw = scan_log(log)
    except RgtbusError:
        return "(its log is unreadable)"
    last = max((m[1] for m in raw.messages), default=None)
    if last is None:
        return "before it logged a message"
    t = seconds(last)
    return f"in window {int(t / window)} (its log ends at t = {t:.3f} s)"


def recovered(unit: str, log: Path) -> dict[str, Any] | None:
    """Unit ``unit``'s part of the run summary from its log, when its process could not say
    it (killed after it wrote its report, stopped, cut off from the launcher): its
    ``/unit/report`` and decodes, its error from the report or its ``end.<unit>`` record.
    None when the log holds no report of it."""
    from rgtbus.telemetry import records
    from rgtbus.telemetry.read import load_replay
    from rgtbus.telemetry.topics import UNIT_ENDED_EARLY, unit_end_record

    try:
        replay = load_replay(log)
    except (RgtbusError, OSError):
        return None
    if not any(m.get("unit") == unit for _, m in replay.by_topic[records.UNIT_REPORT]):
        return None  # (a log with no report at all would read as an old log's tables)
    report = next(r for r in replay.unit_reports() if r["unit"] == unit)
    end = replay.metadata.get(unit_end_record(unit), {})
    world = end.get("detail") if end.get("status") == UNIT_ENDED_EARLY else None
    try:
        sim = float(end.get("sim_seconds", replay.sim_seconds))
    except ValueError:
        sim = replay.sim_seconds
    return {
        "unit": unit, "report": report, "sim_seconds": round(sim, 6), "steps": 0,
        "world_failure": world, "error": world or report.get("failure"), "late": None,
        "bus": {}, "log": str(log), "from_log": True,
    }  # fmt: skip


def unit_failures(
    units: list[str],
    results: dict[str, dict[str, Any]],
    logs: Mapping[str, Path],
    window: float,
    stopped: Collection[str] = (),
) -> tuple[list[str], dict[str, dict[str, Any]]]:
    """The failures of a launch, root causes first (a unit that died or crashed; then one that
    stalled, or that says it was the late one; then the units that failed for want of them),
    and the parts of the summary of every unit that reported, those the launcher had to stop
    (``stopped``) included, and of every unit whose log holds its report though its process
    said nothing: a healthy unit keeps what it knew."""
    died: list[str] = []
    stalled: list[str] = []
    knock_on: list[str] = []
    outputs: dict[str, dict[str, Any]] = {}
    for name in units:
        out = results.get(name)
        log = logs[name]
        if out is None or "report" not in out:
            kept = recovered(name, log)
            if kept is not None:
                outputs[name] = kept
        if out is None:
            if name not in outputs:
                stalled.append(f"unit {name} stalled {_where(log, window)}: no result, stopped")
            elif outputs[name]["error"]:
                knock_on.append(f"unit {name}: {outputs[name]['error']} (from its log)")
        elif "died" in out:
            died.append(f"unit {name} died ({_signal_name(out['died'])}) {_where(log, window)}")
        elif "crash" in out:
            died.append(f"unit {name}: {out['crash']}")
        else:
            outputs[name] = out
            if out.get("late"):
                stalled.append(str(out["late"]))  # it names itself
            elif name in stopped:
                stalled.append(f"unit {name} stalled {_where(log, window)}: stopped")
            elif out["error"]:
                knock_on.append(f"unit {name}: {out['error']}")
    if died:  # the units the launcher stopped were waiting for the dead one: not a cause
        knock_on = [
            f"unit {n}: stopped while waiting for the others" for n in units if n in stopped
        ] + knock_on
        stalled = [x for x in stalled if not x.endswith(": stopped")]
    return died + stalled + knock_on, outputs


def zenoh_given(zenoh: Mapping[str, Any] | None) -> dict[str, Any]:
    """The zenoh options given (``mode``, ``connect``, ``listen``, ``multicast``, ``config``),
    those set to None left out; an unknown one is refused."""
    given = dict(zenoh or {})
    for key in given:
        if key not in ZENOH_OPTIONS:
            raise BadInput(f"zenoh option {key!r}: unknown (use {', '.join(ZENOH_OPTIONS)})")
    return {k: v for k, v in given.items() if v is not None}


def _log_dir(sc: Scenario, log_dir: str | os.PathLike[str] | None, procs: Sequence[str]) -> Path:
    """The launch's log directory, made, with no log of an earlier launch left in it."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    where = Path(log_dir) if log_dir is not None else Path("logs") / f"{sc.name}-{stamp}"
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise IOFailure(f"cannot create log dir {str(where)!r}: {exc.strerror}") from None
    stale = [where / f"{u}.mcap" for u in sc.units] + [where / "launch.mcap"]
    for path in [*stale, *(where.glob("proc-*.mcap"))]:
        with contextlib.suppress(FileNotFoundError):  # never merge an earlier launch's log
            path.unlink()
    return where


def loopback(port: int, tls: bool) -> str:
    """The zenoh endpoint of ``port`` on loopback: ``tls/127.0.0.1:<port>`` over TLS, else
    ``tcp/...``."""
    return f"{'tls' if tls else 'tcp'}/127.0.0.1:{port}"


def _networks(
    procs: list[str],
    net_given: dict[str, Any],
    router_ep: str | None,
    ports: list[int],
    tls: bool = False,
) -> dict[str, tuple[dict[str, Any], list[str]]]:
    """Each process's zenoh options, and the processes it waits for to listen first: the
    options given (the same for every process); a client of the router; or a full mesh (its
    endpoints TLS ones with ``tls``)."""
    out: dict[str, tuple[dict[str, Any], list[str]]] = {}
    for i, name in enumerate(procs):
        if net_given:
            out[name] = (dict(net_given), [])
        elif router_ep is not None:
            out[name] = ({"mode": "client", "connect": [router_ep]}, [])
        else:  # each listens on its port and connects to those before it
            net = {
                "listen": [loopback(ports[i], tls)],
                "connect": [loopback(p, tls) for p in ports[:i]],
            }
            out[name] = (net, procs[:i])
    return out


def launch(
    scenario: str | os.PathLike[str] | Scenario,
    *,
    procs: int | None = None,
    seed: int | None = None,
    log_dir: str | os.PathLike[str] | None = None,
    zenoh: Mapping[str, Any] | None = None,
    key_file: str | os.PathLike[str] | None = None,
    realtime: float | None = None,
    timeout: float | None = None,
    engine: str = "event",
    traces: bool = False,
    router: bool | None = None,
    tls: str | os.PathLike[str] | None = None,
    control: bool = False,
) -> RunResult:
    """Run every unit of ``scenario`` as OS processes over zenoh (see the module docstring)
    and return the run's ``RunResult``: its summary (that of ``rgtbus.run`` but for wall time
    and paths), its merged log (``log_dir/run.mcap``), every failure it names
    (``failures``, root causes first; the first is the summary's ``error``), and whether a
    SIGINT or SIGTERM stopped it (``interrupted``: its units stopped, their logs finished and
    merged).

    ``procs``: the number of processes (default one a unit); ``seed`` overrides the
    scenario's; ``log_dir``: where each process's log and the merged one go (default
    ``logs/<scenario>-<time>/``); ``zenoh``: options for every process (``mode``,
    ``connect``, ``listen``, ``multicast``, ``config``; default a mesh on loopback);
    ``key_file``: the run's shared secret (every frame signed and checked);
    ``realtime``: pace the run; ``timeout``: give up when no member has news for that many
    seconds (default ``default_timeout``: longer when the processes outnumber the cores);
    ``engine``, ``traces``: as for ``rgtbus.run``; ``router``: connect the units through a
    zenoh router process (True) or a full mesh (False); by default a mesh up to
    ``ROUTER_ABOVE`` processes, a router above (a mesh of n processes opens n(n-1)/2 links);
    ``tls``: the run's directory of TLS identities (``rgtbus certs``): every process proves
    itself with its own certificate (one unit a process), the mesh or router on ``tls/``
    endpoints, under the run's access control; ``control``: the run may be steered through
    ``rgtbus watch --control`` (docs/foxglove.md). Bad arguments, and every bad TLS file,
    raise ``RgtbusError`` before a process starts."""
    from rgtbus.bus.auth import load_key
    from rgtbus.bus.certs import ROUTER, check_tls, process_tls

    t0 = time.perf_counter()
    fork = _may_fork()  # asked before anything here loads zenoh
    sc = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    if seed is not None:
        sc = sc.with_seed(seed)
    checks.choice(engine, checks.ENGINES, "engine")
    if realtime is not None:
        checks.realtime(realtime)
    key = None if key_file is None else load_key(key_file)
    groups = process_groups(sc.units, procs)
    timeout = default_timeout(len(groups)) if timeout is None else timeout
    checks.seconds(timeout, "timeout")
    net_given = zenoh_given(zenoh)
    if router is None:
        router = not net_given and len(groups) > ROUTER_ABOVE
    if net_given.get("listen") and len(groups) > 1:
        raise BadInput(
            f"-l/--listen with {len(groups)} processes: each would listen on the same "
            "endpoint (give --procs 1, or -e/--connect to a router, or no endpoint at all)"
        )
    if tls is not None:
        for units in groups.values():
            process_tls(tls, units)
        if router:
            check_tls(tls, ROUTER)
    where = _log_dir(sc, log_dir, list(groups))
    # one process per unit: its log is <unit>.mcap; several units a process: proc-<i>.mcap
    logs = {p: where / f"{p}.mcap" for p in groups}
    run_id = f"{default_run_id(sc)}-{os.getpid()}"  # never mixes with another launch's traffic
    opts = {"run_id": run_id, "timeout": timeout, "engine": engine, "realtime": realtime,
            "key": key, "traces": traces, "tls": tls, "control": control}  # fmt: skip
    results, stopped, interrupted = _run_processes(fork, sc, groups, logs, net_given, router, opts)
    by_unit: dict[str, dict[str, Any]] = {}
    for p, said in results.items():
        for u in groups[p]:
            by_unit[u] = said["units"][u] if "units" in said else said
    unit_logs = {u: logs[p] for p, us in groups.items() for u in us}
    failures, outputs = unit_failures(
        list(sc.units), by_unit, unit_logs, sc.timing.window, stopped=stopped
    )
    if interrupted is not None:
        failures.insert(0, interrupted)
    result, misreads = _summarised(sc, outputs, failures, time.perf_counter() - t0, engine)
    failures.extend(_merged(sc, run_id, where, result, failures, logs, key))
    result["log"] = str(where / "run.mcap")
    merged = where / "run.mcap"
    return RunResult(
        summary_json(result), sc, merged, result, failures, interrupted is not None, misreads
    )


def _run_processes(
    fork: bool,
    sc: Scenario,
    groups: dict[str, list[str]],
    logs: dict[str, Path],
    net_given: dict[str, Any],
    router: bool,
    opts: dict[str, Any],
) -> tuple[dict[str, dict[str, Any]], set[str], str | None]:
    """Start every process, collect what each says, stop what is left, reap them all; a
    SIGINT or SIGTERM (as ``KeyboardInterrupt``) stops the units. Returns what each process
    said, the units the launcher had to stop, and why it was interrupted (None if not)."""
    processes = LaunchProcesses(fork)
    if fork:  # forks start with the plan laid out once here (a fork server's do not)
        from rgtbus.units.unit import lay_out_plan

        lay_out_plan(sc)
    results: dict[str, dict[str, Any]] = {}
    interrupted: str | None = None
    procs = list(groups)
    running: list[str] = []
    with interrupted_by(signal.SIGTERM, signal.SIGINT):  # SIGTERM ends a launch like Ctrl-C
        try:
            try:
                ports = free_ports(len(procs) + 1)
                tls = opts["tls"]
                timeout = opts["timeout"]
                router_ep = loopback(ports[-1], tls is not None) if router else None
                if router_ep is not None:
                    over_tls = {"tls": tls, "roster": sc.units, "run_id": opts["run_id"]}
                    processes.start_router(
                        router_ep, 10.0, patience=timeout, **(over_tls if tls else {})
                    )
                nets = _networks(procs, net_given, router_ep, ports, tls is not None)
                for name, (net, after) in nets.items():
                    processes.start_process(name, groups[name], sc, logs[name], net, after,
                                            **opts)  # fmt: skip
                # A process moves its world on within its timeout, or gives up and says so
                # (then the others end within theirs): stalled only past both and some more.
                # Before its first move: the join, and a paced run's whole length.
                stall_after = 2 * timeout + 30.0
                paced = sc.timing.max_seconds / opts["realtime"] if opts["realtime"] else 0.0
                first = join_seconds(len(sc.units)) + paced + stall_after
                results = processes.collect(first, stall_after, timeout, paced=bool(paced))
            except KeyboardInterrupt:
                interrupted = "launch interrupted (SIGINT or SIGTERM): units stopped"
            running = [p for p in procs if p not in results and p in processes.procs]
            processes.stop(running)
            late = processes.late_results(running, timeout=_STOP_SECONDS)
            # a process asked to stop reports what its units knew (their share of the
            # summary); one that could not say even that is named as stalled
            results.update({p: out for p, out in late.items() if "units" in out})
        finally:
            processes.reap()
    stopped = set() if interrupted is not None else {u for p in running for u in groups[p]}
    return results, stopped, interrupted


def _summarised(
    sc: Scenario,
    outputs: dict[str, dict[str, Any]],
    failures: list[str],
    wall_seconds: float,
    engine: str,
) -> tuple[dict[str, Any], DecodeErrors]:
    """The run's summary from what every unit reported, its error the first failure, and
    its misreads."""
    from rgtbus.engine.sim import WorldResult

    reports = [outputs[u]["report"] for u in sc.units if u in outputs]
    first = next((outputs[u] for u in sc.units if u in outputs), None)
    ended = WorldResult(
        steps=first["steps"] if first else 0,
        sim_seconds=max((o["sim_seconds"] for o in outputs.values()), default=0.0),
        wall_seconds=wall_seconds,
        failure=failures[0] if failures else None,
        bus_stats={u: o["bus"] for u, o in outputs.items()},
        sync={u: o.get("sync", {}) for u, o in outputs.items()},
    )
    misreads = decode_errors_of(reports)
    return summarise(sc, reports, ended, engine=engine, misreads=misreads), misreads


def _merged(
    sc: Scenario,
    run_id: str,
    where: Path,
    summary: dict[str, Any],
    failures: list[str],
    process_logs: Mapping[str, Path],
    key: bytes | None,
) -> list[str]:
    """Write ``launch.mcap`` (metadata, every failure, the run's summary) and merge it with
    every process log that has anything in it into ``run.mcap``. Returns the logs it had to
    leave out, as failures."""
    from rgtbus.units.group import auth_name, write_metadata

    from rgtbus.telemetry import records
    from rgtbus.telemetry.logfile import close_log, open_log
    from rgtbus.telemetry.merge import merge_logs
    from rgtbus.telemetry.scan import scan_log
    from rgtbus.timebase import ns

    f, rec = open_log(where / "launch.mcap")
    try:
        write_metadata(rec, sc, cross_process_kind(), run_id, process="launch", auth=auth_name(key))
        for msg in failures:
            rec.log("error", msg, ns(summary["sim_seconds"]), name="launch")
        rec.write(records.RUN, records.run_record(summary), ns(summary["sim_seconds"]))
    finally:
        close_log(f, rec)
    left_out: list[str] = []
    logs = []
    for path in [*process_logs.values(), where / "launch.mcap"]:
        if not path.exists() or path.stat().st_size == 0:
            continue  # a unit that died before its log's first byte: named in the failures
        try:
            logs.append(scan_log(path))
        except RgtbusError as exc:
            left_out.append(f"log {path.name} left out of run.mcap: {exc}")
    merged = where / "run.mcap"
    try:
        with open(merged, "wb") as out:
            merge_logs(logs, out)
    except RgtbusError:  # already one line (an IOFailure is an OSError too)
        raise
    except OSError as exc:
        raise IOFailure(f"cannot write log {str(merged)!r}: {exc.strerror}") from None
    return left_out
