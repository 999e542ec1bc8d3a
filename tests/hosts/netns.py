"""Several hosts on one machine: Linux network namespaces joined by veth pairs (needs root or
CAP_NET_ADMIN, and ``ip`` from iproute2).

``topology(k)`` makes a router namespace R and ``k`` host namespaces H0..H(k-1); host i is
joined to R by its own veth pair, 10.77.<i+1>.1/30 in R (the host's gateway) and
10.77.<i+1>.2/30 in the host, with a default route via R; ``lo`` is up everywhere. Names
start with ``rgt<pid>x<n>`` (``PREFIX`` is ``rgt<pid>x``): this process's, told apart from any
other's. Each veth is created straight inside its namespaces, so nothing is ever made in the
machine's own namespace, and deleting a namespace deletes its links with it.

Everything is removed when the ``with`` ends, whatever happened inside it: first every process
started through the topology (and anything else still running in its namespaces) is killed,
then the namespaces are deleted. An ``atexit`` hook removes what a failed removal left.
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent
PREFIX = f"rgt{os.getpid()}x"
SUBNET = "10.77"  # 10.77.<i+1>.0/30 for host i: a private range no test machine routes
IP_TIMEOUT = 30.0  # seconds for one ``ip``/``tc`` command (a loaded machine)
_counter = itertools.count()
_live: dict[str, Topology] = {}


def _ip(*argv: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        list(argv), capture_output=True, text=True, timeout=IP_TIMEOUT, stdin=subprocess.DEVNULL
    )
    if check and proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: exit {proc.returncode}: {proc.stderr.strip()}")
    return proc


def namespaces() -> list[str]:
    """The network namespaces that exist now (``ip netns list``)."""
    out = _ip("ip", "netns", "list").stdout
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def probe() -> str | None:
    """``None`` when this process may make network namespaces; otherwise why not, in one line
    (a namespace is made and deleted to find out)."""
    if not sys.platform.startswith("linux"):
        return f"not Linux ({sys.platform})"
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    name = f"{PREFIX}probe"
    try:
        made = _ip("ip", "netns", "add", name, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"`ip netns add` failed: {exc}"
    if made.returncode != 0:
        why = made.stderr.strip().splitlines()[-1] if made.stderr.strip() else "no message"
        return f"`ip netns add` exit {made.returncode} ({why}; euid {os.geteuid()})"
    gone = _ip("ip", "netns", "del", name, check=False)
    if gone.returncode != 0:
        return f"`ip netns del` exit {gone.returncode} ({gone.stderr.strip()})"
    return None


@dataclass(frozen=True)
class Host:
    """Host namespace ``ns``, joined to the router namespace by ``dev`` (its side, address
    ``addr``) and ``peer`` (R's side, address ``gateway``)."""

    index: int
    ns: str
    dev: str
    addr: str
    peer: str
    gateway: str


@dataclass
class Topology:
    name: str
    router_ns: str
    hosts: list[Host]
    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)
    closed: bool = False

    def exec_argv(self, ns: str, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside namespace ``ns`` (``ip netns exec`` execs it: the process's pid
        is the command's own)."""
        return ["ip", "netns", "exec", ns, *argv]

    def spawn(
        self,
        ns: str,
        argv: Sequence[str],
        *,
        stdout: Path,
        stderr: Path,
        env: dict[str, str] | None = None,
    ) -> subprocess.Popen[bytes]:
        """Start ``argv`` in ``ns``, its output to files (no pipe to fill); killed when the
        topology is removed if it is still running."""
        assert not self.closed, "the topology was removed"
        with open(stdout, "wb") as out, open(stderr, "wb") as err:
            p = subprocess.Popen(
                self.exec_argv(ns, argv),
                stdout=out,
                stderr=err,
                stdin=subprocess.DEVNULL,
                env=env,
                cwd=ROOT,
            )
        self.procs.append(p)
        return p

    def run(self, ns: str, *argv: str) -> subprocess.CompletedProcess[str]:
        """A short command in ``ns`` (``ip``, ``tc``), bounded, failing loudly."""
        return _ip(*self.exec_argv(ns, argv))

    def link_bytes(self) -> dict[str, int]:
        """Bytes each host sent and received over its link so far (R's side of the veth)."""
        out = _ip("ip", "-n", self.router_ns, "-j", "-s", "link", "show").stdout
        stats = {link["ifname"]: link["stats64"] for link in json.loads(out)}
        return {
            h.ns: stats[h.peer]["rx"]["bytes"] + stats[h.peer]["tx"]["bytes"] for h in self.hosts
        }

    # -- impairments -------------------------------------------------------------------------

    def set_link(self, host: Host, up: bool) -> None:
        """Take host's link down (or bring it up): its side of the veth pair."""
        _ip("ip", "-n", host.ns, "link", "set", host.dev, "up" if up else "down")

    def shape(self, host: Host, rate: str, burst: str, latency: str) -> None:
        """A ``tbf`` rate limit on both ends of host's link (each shapes what it sends)."""
        for ns, dev in ((host.ns, host.dev), (self.router_ns, host.peer)):
            _ip("tc", "-n", ns, "qdisc", "add", "dev", dev, "root", "tbf", "rate", rate,
                "burst", burst, "latency", latency)  # fmt: skip

    def shaped(self) -> dict[str, int]:
        """What the ``tbf`` qdiscs did so far, summed over every link's ends: packets
        ``dropped`` and ``overlimits`` (held back: the rate limit bit)."""
        counts = {"dropped": 0, "overlimits": 0}
        for host in self.hosts:
            for ns, dev in ((host.ns, host.dev), (self.router_ns, host.peer)):
                out = _ip("tc", "-n", ns, "-s", "qdisc", "show", "dev", dev).stdout
                for m in re.finditer(r"dropped (\d+), overlimits (\d+)", out):
                    counts["dropped"] += int(m.group(1))
                    counts["overlimits"] += int(m.group(2))
        return counts

    # -- removal -----------------------------------------------------------------------------

    def kill_all(self) -> None:
        """Kill every process started here, then any other still in the namespaces (a child
        of one of them); each reaped, each wait bounded."""
        for p in self.procs:
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    p.send_signal(signal.SIGCONT)
                    p.kill()
        for p in self.procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(timeout=30)
        for ns in self.all_ns():
            listed = _ip("ip", "netns", "pids", ns, check=False).stdout.split()
            for pid in listed:
                with contextlib.suppress(ProcessLookupError, ValueError):
                    os.kill(int(pid), signal.SIGKILL)

    def all_ns(self) -> list[str]:
        return [self.router_ns, *(h.ns for h in self.hosts)]

    def close(self) -> None:
        """Kill, then delete every namespace (and with them the veths); raises when any is
        left behind."""
        if self.closed:
            return
        try:
            self.kill_all()
        finally:
            errors = []
            for ns in self.all_ns():
                for _ in range(3):  # a namespace whose last process is still exiting: retry
                    gone = _ip("ip", "netns", "del", ns, check=False)
                    if gone.returncode == 0 or ns not in namespaces():
                        break
                    time.sleep(0.5)
                else:
                    errors.append(f"{ns}: {gone.stderr.strip()}")
            self.closed = True
            _live.pop(self.name, None)
            if errors:
                raise RuntimeError("namespaces left behind: " + "; ".join(errors))


def _make(name: str, k: int) -> Topology:
    topo = Topology(name, f"{name}r", [])
    _live[name] = topo  # from here on, removed even if making it fails half-way
    _ip("ip", "netns", "add", topo.router_ns)
    _ip("ip", "-n", topo.router_ns, "link", "set", "lo", "up")
    for i in range(k):
        net = f"{SUBNET}.{i + 1}"
        host = Host(i, f"{name}h{i}", f"up{i}", f"{net}.2", f"h{i}", f"{net}.1")
        topo.hosts.append(host)
        _ip("ip", "netns", "add", host.ns)
        _ip("ip", "-n", host.ns, "link", "set", "lo", "up")
        # both ends made where they live: nothing ever appears in this machine's namespace
        _ip("ip", "link", "add", host.peer, "netns", topo.router_ns, "type", "veth",
            "peer", "name", host.dev, "netns", host.ns)  # fmt: skip
        _ip("ip", "-n", topo.router_ns, "addr", "add", f"{host.gateway}/30", "dev", host.peer)
        _ip("ip", "-n", host.ns, "addr", "add", f"{host.addr}/30", "dev", host.dev)
        _ip("ip", "-n", topo.router_ns, "link", "set", host.peer, "up")
        _ip("ip", "-n", host.ns, "link", "set", host.dev, "up")
        _ip("ip", "-n", host.ns, "route", "add", "default", "via", host.gateway)
    return topo


@contextlib.contextmanager
def topology(k: int) -> Iterator[Topology]:
    """A router namespace and ``k`` host namespaces (module docstring), removed at the end."""
    assert 1 <= k <= 200
    name = f"{PREFIX}{next(_counter)}"
    try:
        topo = _make(name, k)
        yield topo
    finally:
        live = _live.get(name)
        if live is not None:
            live.close()


def leftovers() -> list[str]:
    """This process's namespaces that still exist (none once every topology was removed)."""
    return [ns for ns in namespaces() if ns.startswith(PREFIX)]


@atexit.register
def _remove_all() -> None:
    for topo in list(_live.values()):
        with contextlib.suppress(Exception):
            topo.close()
    with contextlib.suppress(Exception):
        for ns in leftovers():
            _ip("ip", "netns", "del", ns, check=False)


def python_env() -> dict[str, str]:
    """The environment for ``python -m rgtbus`` in a namespace: this checkout's code first
    (where the package is installed from it, the same code)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def wait_for_line(path: Path, start: str, proc: subprocess.Popen[bytes], timeout: float) -> str:
    """The first line of file ``path`` that starts with ``start``, once written (bounded);
    fails when ``proc`` ends first."""
    deadline = time.monotonic() + timeout
    while True:
        with contextlib.suppress(FileNotFoundError):
            for line in path.read_text(errors="replace").splitlines():
                if line.startswith(start):
                    return line
        if proc.poll() is not None:
            raise AssertionError(f"{proc.args!r} ended (exit {proc.returncode}) before {start!r}")
        if time.monotonic() > deadline:
            raise AssertionError(f"no {start!r} from {proc.args!r} within {timeout:g} s")
        time.sleep(0.05)
