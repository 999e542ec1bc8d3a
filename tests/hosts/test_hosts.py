"""Several hosts (issue 34, item 5): a zenoh router in one network namespace, the units, each its
own OS process, in others (clients of the router over veth links), plain TCP or mutual TLS.

Each check makes the run the single process makes (``rgtbus run --json`` of the same scenario
and seed): every unit's result, the summary of the units' logs merged with ``rgtbus merge``
(every key but wall time and the log's path) and that log's content; the merged log verifies
(``rgtbus replay --verify``, exit 0). Impaired links (a ``tbf`` rate limit, a link taken down
for 2 s mid-run, 50 ± 10 ms added by a relay) must change nothing but the wall time, which
every run records for the table printed at the end (and logs/hosts-walls.json).

Where network namespaces are not permitted (not root, no ``ip``) every test here skips with one
line saying why. Every process is started through the topology, which kills it (and anything
left in its namespaces) before removing them, whatever happened; every wait is bounded.
"""

from __future__ import annotations

import contextlib
import functools
import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from same_run import assert_verifies, content, single

import rgtbus
from hosts import netns
from rgtbus.errors import RgtbusError
from rgtbus.telemetry import read_log

ROOT = netns.ROOT
EXE = [sys.executable, "-m", "rgtbus"]
RELAY = Path(__file__).with_name("relay.py")
PORT = 7447  # the router's, in its own namespace: no other process listens there
RELAY_PORT = 7448
START = 60.0  # seconds for a router or relay to listen (a loaded machine)
RUN = 300.0  # seconds for a whole run, start-up and join included (generous: 2 shared cores)
UNIT_ARGS = ["--join-timeout", "120", "--timeout", "30"]  # generous for the same reason
GATE_HOSTS = [["a", "b"], ["c"], ["d"]]  # the gate's 4 units over 3 hosts
GROUP10_HOSTS = [["a", "b", "c", "d"], ["e", "f", "g"], ["h", "i", "j"]]
NOT_COMPARED = ("wall_seconds", "log")  # a run's, not its result

TLS = pytest.mark.parametrize("tls", [False, True], ids=["tcp", "tls"])
pytestmark = pytest.mark.usefixtures("hosts_permitted")


# -- TLS: the one place that knows how ---------------------------------------------------------


@dataclass(frozen=True)
class Net:
    """How the processes of a run reach each other: the endpoints' scheme and the extra
    arguments of ``rgtbus router`` and ``rgtbus unit``."""

    scheme: str
    router_args: tuple[str, ...] = ()
    unit_args: tuple[str, ...] = ()


def net_of(tls: bool, scenario: Path, work: Path) -> Net:
    """Plain TCP, or mutual TLS (docs/hosts.md): ``rgtbus certs SCENARIO --out DIR`` writes
    DIR/<unit>.crt and .key, DIR/run/ca.crt and DIR/run/router.crt and .key; every process is
    given ``--tls DIR``, the router also the scenario (the roster of its access control) and
    the run id; every endpoint is ``tls/HOST:PORT``."""
    if not tls:
        return Net("tcp")
    certs = work / "certs"
    argv = [*EXE, "certs", str(scenario), "--out", str(certs)]
    made = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=netns.python_env())
    assert made.returncode == 0, f"rgtbus certs: exit {made.returncode}: {tail(made.stderr)}"
    router = ("--tls", str(certs), "--scenario", str(scenario), "--run-id", run_id_of(work))
    return Net("tls", router, ("--tls", str(certs)))


def run_id_of(work: Path) -> str:
    """The run id of the run whose files are in ``work``: one a test."""
    return f"hosts-{work.name}"[:60]


# -- a run over the hosts ----------------------------------------------------------------------


def tail(text: str, lines: int = 12) -> str:
    return "\n".join(text.strip().splitlines()[-lines:])


@dataclass
class Unit:
    name: str
    host: netns.Host
    proc: subprocess.Popen[bytes]
    out: Path
    err: Path
    log: Path

    def stderr(self) -> str:
        with contextlib.suppress(OSError):
            return tail(self.err.read_text(errors="replace"))
        return ""


@dataclass
class Run:
    units: dict[str, Unit]
    outs: dict[str, dict]
    wall: float
    link_bytes: int  # over every host's link, both ways (zenoh's traffic, TLS included)


def start_router(topo: netns.Topology, net: Net, work: Path, relay: bool) -> int:
    """The zenoh router in the router namespace (and, with ``relay``, the relay in front of
    it); the port the units connect to."""
    env = netns.python_env()
    out, err = work / "router.out", work / "router.err"
    argv = [*EXE, "router", "--listen", f"{net.scheme}/0.0.0.0:{PORT}", *net.router_args]
    router = topo.spawn(topo.router_ns, argv, stdout=out, stderr=err, env=env)
    try:
        netns.wait_for_line(out, "router listening", router, START)
    except AssertionError as exc:
        raise AssertionError(f"{exc}: {tail(err.read_text(errors='replace'))}") from None
    if not relay:
        return PORT
    argv = [sys.executable, str(RELAY), "--listen", f"0.0.0.0:{RELAY_PORT}",
            "--to", f"127.0.0.1:{PORT}", "--delay", "0.05", "--jitter", "0.01"]  # fmt: skip
    out, err = work / "relay.out", work / "relay.err"
    proc = topo.spawn(topo.router_ns, argv, stdout=out, stderr=err, env=env)
    netns.wait_for_line(out, "relay listening", proc, START)
    return RELAY_PORT


def run_over_hosts(
    topo: netns.Topology,
    scenario: Path,
    placement: list[list[str]],
    work: Path,
    net: Net,
    *,
    extra: tuple[str, ...] = (),
    relay: bool = False,
    during: Callable[[dict[str, Unit]], None] | None = None,
) -> Run:
    """Router in R, unit processes on the hosts as ``placement`` says (host i: its units),
    clients of the router; ``during(units)`` runs while they do. Every unit must end with exit
    0 within ``RUN`` seconds; the wall time is from the first unit's start to the last's end."""
    port = start_router(topo, net, work, relay)
    env = netns.python_env()
    run_id = run_id_of(work)
    units: dict[str, Unit] = {}
    t0 = time.monotonic()
    for host, names in zip(topo.hosts, placement, strict=True):
        for name in names:
            out, err, log = (work / f"{name}.{x}" for x in ("json", "err", "mcap"))
            argv = [*EXE, "unit", name, str(scenario), "--mode", "client",
                    "--connect", f"{net.scheme}/{host.gateway}:{port}", "--log", str(log),
                    "--json", "--run-id", run_id, *UNIT_ARGS, *extra, *net.unit_args]  # fmt: skip
            proc = topo.spawn(host.ns, argv, stdout=out, stderr=err, env=env)
            units[name] = Unit(name, host, proc, out, err, log)
    if during is not None:
        during(units)
    deadline = t0 + RUN
    for u in units.values():
        try:
            u.proc.wait(timeout=max(deadline - time.monotonic(), 1.0))
        except subprocess.TimeoutExpired:
            pending = [v.name for v in units.values() if v.proc.poll() is None]
            pytest.fail(f"units {pending} still running after {RUN:g} s; {u.name}: {u.stderr()}")
    wall = time.monotonic() - t0
    link_bytes = sum(topo.link_bytes().values())
    outs = {}
    for u in units.values():
        assert u.proc.returncode == 0, f"unit {u.name} exit {u.proc.returncode}: {u.stderr()}"
        outs[u.name] = json.loads(u.out.read_text())
    return Run(units, outs, wall, link_bytes)


# -- the same run as one process ---------------------------------------------------------------


@functools.cache
def reference(name: str) -> tuple[dict, tuple]:
    """The single-process run: ``rgtbus run --json`` (its summary) and its log's content."""
    argv = [*EXE, "run", str(ROOT / "scenarios" / f"{name}.toml"), "--json", "--no-log"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=netns.python_env())
    assert proc.returncode == 0, tail(proc.stderr)
    _, messages = single(name)
    return json.loads(proc.stdout), tuple(content(without_run(messages)))


def without_run(messages):
    """A run's log but its ``/run`` record (a hand merge of unit logs has none: no launcher)."""
    return [m for m in messages if m[0] != "/run"]


def assert_same_run(name: str, run: Run, work: Path) -> None:
    ref, ref_content = reference(name)
    for u, out in run.outs.items():
        assert out["error"] is None, (u, out["error"])
        assert out["report"]["result"] == ref["units"][u], u
        assert out["sim_seconds"] == ref["sim_seconds"], u
    merged = work / "run.mcap"
    argv = [*EXE, "merge", *(str(u.log) for u in run.units.values()), "-o", str(merged), "-q"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=netns.python_env())
    assert proc.returncode == 0, tail(proc.stderr)
    assert_verifies(merged)
    summary = rgtbus.open_log(merged).summary()
    differ = sorted(k for k in ref if k not in NOT_COMPARED and summary.get(k) != ref[k])
    assert not differ, {k: (summary.get(k), ref[k]) for k in differ}
    messages, _ = read_log(merged)
    assert tuple(content(without_run(messages))) == ref_content


def under_way(log: Path) -> bool:
    """The unit's log (written as it goes) holds a pulse."""
    with contextlib.suppress(RgtbusError, FileNotFoundError):
        return any(t == "/tx/pulse" for t, _, _ in read_log(log)[0])
    return False


GATE = ROOT / "scenarios" / "gate.toml"


# -- the checks --------------------------------------------------------------------------------


@pytest.mark.slow
@TLS
@pytest.mark.parametrize("paced", [False, True], ids=["fast", "paced"])
def test_the_gate_over_three_hosts_is_the_single_process_run(tmp_path, record_wall, tls, paced):
    net = net_of(tls, GATE, tmp_path)
    extra = ("--realtime", "20") if paced else ()
    with netns.topology(len(GATE_HOSTS)) as topo:
        run = run_over_hosts(topo, GATE, GATE_HOSTS, tmp_path, net, extra=extra)
    record_wall("gate-paced" if paced else "gate", tls, run)
    assert_same_run("gate", run, tmp_path)


@pytest.mark.slow
@TLS
def test_a_group_of_ten_over_three_hosts_is_the_single_process_run(tmp_path, record_wall, tls):
    scenario = ROOT / "scenarios" / "crowd10.toml"
    net = net_of(tls, scenario, tmp_path)
    with netns.topology(len(GROUP10_HOSTS)) as topo:
        run = run_over_hosts(topo, scenario, GROUP10_HOSTS, tmp_path, net)
    record_wall("group10", tls, run)
    assert_same_run("crowd10", run, tmp_path)


@pytest.mark.slow
@TLS
def test_a_rate_limit_on_every_link_changes_nothing_but_time(tmp_path, record_wall, tls):
    """512 kbit/s each way on every link (``tbf``, a 2 kB bucket): the gate's bursts are held
    back (overlimits), the run is the same. The rate leaves room for the join's hellos of
    units that start late on a loaded machine: at 128 kbit/s a unit started 5 s after the
    others may never be answered (tests/hosts/README.md)."""
    net = net_of(tls, GATE, tmp_path)
    with netns.topology(len(GATE_HOSTS)) as topo:
        try:
            for host in topo.hosts:
                topo.shape(host, rate="512kbit", burst="16kbit", latency="400ms")
        except (RuntimeError, FileNotFoundError) as exc:  # no tc, or no tbf in this kernel
            pytest.skip(f"tbf not available here: {str(exc).splitlines()[0]}")
        run = run_over_hosts(topo, GATE, GATE_HOSTS, tmp_path, net)
        shaped = topo.shaped()
    record_wall("tbf", tls, run, **shaped)
    assert shaped["overlimits"] > 0, shaped  # the limit was reached: an impairment indeed
    assert_same_run("gate", run, tmp_path)


@pytest.mark.slow
@TLS
def test_a_link_down_for_two_seconds_mid_run_changes_nothing_but_time(tmp_path, record_wall, tls):
    """Host 0 (units a and b) loses its link for 2 s once the run is under way (paced: 162 s
    simulated at 20x, about 8 s): within zenoh's 10 s lease and the units' stall timeout, so
    the run goes on where it was once the link is back."""
    net = net_of(tls, GATE, tmp_path)
    outage: dict[str, float] = {}

    def flap(units: dict[str, Unit]) -> None:
        deadline = time.monotonic() + RUN / 2
        while not under_way(units["d"].log):  # another host's unit has sent: under way
            ended = [u.name for u in units.values() if u.proc.poll() is not None]
            assert not ended, f"{ended} ended before the run was under way: " + "; ".join(
                units[u].stderr() for u in ended
            )
            assert time.monotonic() < deadline, "the run was not under way in time"
            time.sleep(0.1)
        host = units["a"].host
        topo.set_link(host, up=False)
        t = time.monotonic()
        time.sleep(2.0)
        topo.set_link(host, up=True)
        outage["down_s"] = time.monotonic() - t
        # the outage lay within the run: nobody had ended when the link came back
        outage["running"] = sum(u.proc.poll() is None for u in units.values())

    with netns.topology(len(GATE_HOSTS)) as topo:
        run = run_over_hosts(
            topo, GATE, GATE_HOSTS, tmp_path, net, extra=("--realtime", "20"), during=flap
        )
    record_wall("link-flap", tls, run)
    assert outage["down_s"] >= 2.0 and outage["running"] == 4, outage
    assert_same_run("gate", run, tmp_path)


@pytest.mark.slow
@TLS
def test_fifty_milliseconds_each_way_through_a_relay_change_nothing_but_time(
    tmp_path, record_wall, tls
):
    net = net_of(tls, GATE, tmp_path)
    with netns.topology(len(GATE_HOSTS)) as topo:
        run = run_over_hosts(topo, GATE, GATE_HOSTS, tmp_path, net, relay=True)
    record_wall("relay", tls, run)
    assert_same_run("gate", run, tmp_path)


# -- the harness itself ------------------------------------------------------------------------


def test_a_topology_is_removed_with_its_processes_even_when_a_test_fails(tmp_path):
    sleeper = [sys.executable, "-c", "import time; time.sleep(600)"]
    links = netns._ip("ip", "-o", "link", "show").stdout.count("\n")
    with pytest.raises(RuntimeError, match="a failing test"), netns.topology(2) as topo:
        names = topo.all_ns()
        assert set(names) <= set(netns.namespaces())
        # the hosts reach the router namespace, and through it each other
        assert "10.77.1.2/30" in topo.run(topo.hosts[0].ns, "ip", "-o", "addr").stdout
        route = topo.run(topo.hosts[1].ns, "ip", "route", "get", "10.77.1.2").stdout
        assert "via 10.77.2.1" in route, route
        procs = [
            topo.spawn(ns, sleeper, stdout=tmp_path / f"{i}.out", stderr=tmp_path / f"{i}.err")
            for i, ns in enumerate(names)
        ]
        raise RuntimeError("a failing test")
    assert all(p.poll() is not None for p in procs)
    assert not set(names) & set(netns.namespaces())
    assert netns._ip("ip", "-o", "link", "show").stdout.count("\n") == links  # none made here


def test_nothing_of_this_session_is_left_behind():
    """Runs last in this module: every namespace made here was removed."""
    assert netns.leftovers() == []
