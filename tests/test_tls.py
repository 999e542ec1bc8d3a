"""Runs over zenoh's own TLS and access control (``--tls DIR``, rgtbus.bus.config): the same
summary as the single-process run; a process with c's certificate cannot speak as b; a process
without a certificate of the run's CA cannot join.

Every spawned process is reaped by the ``procs`` fixture; every wait is bounded.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh
from rgtbus.units.launch import free_ports
from test_cross_process import EXE, launch_equals_single, single

from rgtbus.bus import keys
from rgtbus.bus.certs import ROUTER, WATCH, check_tls, make_certs
from rgtbus.bus.config import TlsRun, make_config

ROOT = Path(__file__).parent.parent
GATE = str(ROOT / "scenarios" / "gate.toml")
UNITS = ("a", "b", "c", "d")
RUN = "tls-run"


@pytest.fixture(scope="module")
def ids(tmp_path_factory) -> Path:
    """The gate's identities."""
    d = tmp_path_factory.mktemp("ids") / "gate"
    make_certs(UNITS, d)
    return d


@pytest.fixture(scope="module")
def other_ids(tmp_path_factory) -> Path:
    """Another run's identities: the same names under another CA."""
    d = tmp_path_factory.mktemp("other") / "gate"
    make_certs(UNITS, d)
    return d


def until(done: Callable[[], bool], seconds: float = 30.0) -> bool:
    """Whether ``done()`` came true within ``seconds`` (asked every 20 ms)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if done():
            return True
        time.sleep(0.02)
    return done()


def session(ids: Path, identity: str, mode: str = "peer", **endpoints: list[str]) -> zenoh.Session:
    """A zenoh session proving ``identity`` with the run's generated config."""
    tls = TlsRun(check_tls(ids, identity), UNITS, None if identity == ROUTER else RUN)
    return zenoh.open(make_config(mode=mode, tls=tls, **endpoints))


class Heard:
    """What a session hears on every key a unit's bus subscribes to (rgtbus.bus.zenoh)."""

    def __init__(self, s: zenoh.Session) -> None:
        self.keys: list[str] = []
        self._lock = threading.Lock()
        self.subs = [
            s.declare_subscriber(k, self._on)
            for k in (
                keys.every_unit(keys.TX, None),
                keys.every_unit(keys.HELLO, RUN),
                keys.every_unit(keys.TELEMETRY, RUN),
            )
        ]

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.keys.append(str(sample.key_expr))

    def __contains__(self, key: str) -> bool:
        with self._lock:
            return key in self.keys

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


class Leaving:
    """The run's liveliness tokens a session sees end (as a unit's bus watches them, to know at
    once that a member left)."""

    def __init__(self, s: zenoh.Session) -> None:
        self.alive: list[str] = []
        self.gone: list[str] = []
        # history: the tokens already up when the router takes this subscription are reported
        # too (without it, a token declared while the subscription is on its way is never seen)
        self.sub = s.liveliness().declare_subscriber(
            keys.every_unit(keys.ALIVE, RUN), self._on, history=True
        )

    def _on(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            self.gone.append(str(sample.key_expr))
        else:
            self.alive.append(str(sample.key_expr))


def closes_and_is_seen_gone(c: zenoh.Session, leaving: Leaving, heard: Heard) -> None:
    """c declares its token, is heard (the link and the token's route are up), and closes: the
    session watching sees its token end, through the access control."""
    token = c.liveliness().declare_token(keys.key(keys.ALIVE, RUN, "c"))
    forge_then_speak(c, heard)
    # the token's route is up once the watcher has seen it: a token closed before that ends
    # unseen (a race the test would lose now and then on a loaded machine)
    assert until(lambda: keys.key(keys.ALIVE, RUN, "c") in leaving.alive), leaving.alive
    del token
    c.close()
    assert until(lambda: keys.key(keys.ALIVE, RUN, "c") in leaving.gone), leaving.gone


def forge_then_speak(intruder: zenoh.Session, heard: Heard) -> None:
    """c puts on every key of b's, then on its own: again and again until its own put is heard
    (the link is up, the subscriptions known). b's keys went first on the same link, so had
    any been let through, they would have been heard before it."""

    def spoken() -> bool:
        for kind in (keys.TX, keys.HELLO, keys.TELEMETRY):
            intruder.put(keys.key(kind, RUN, "b"), b"c speaking as b")
        intruder.put(keys.key(keys.TX, RUN, "c"), b"c as c")
        return keys.key(keys.TX, RUN, "c") in heard

    assert until(spoken), "c's own frames never arrived"


def test_c_cannot_speak_as_b_on_a_tls_mesh(ids):
    """Two peers on the run's generated config: a listens, c (c's certificate) connects. a
    hears c's puts on c's keys, none on b's: a's access control refuses them at the door. c's
    liveliness token as b is refused too, its own is not; when c closes, a sees its token end
    (how a unit knows at once that a member left)."""
    port = free_ports(1)[0]
    a = session(ids, "a", listen=[f"tls/127.0.0.1:{port}"])
    c = None
    try:
        heard = Heard(a)
        c = session(ids, "c", connect=[f"tls/127.0.0.1:{port}"])
        tokens = [c.liveliness().declare_token(keys.key(keys.ALIVE, RUN, u)) for u in "bc"]
        forge_then_speak(c, heard)
        assert [k for k in heard.keys if k.endswith("/b")] == []

        def alive() -> list[str]:
            replies = a.liveliness().get(keys.every_unit(keys.ALIVE, RUN), timeout=1.0)
            return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

        assert until(lambda: keys.key(keys.ALIVE, RUN, "c") in alive())
        assert alive() == [keys.key(keys.ALIVE, RUN, "c")]
        for token in tokens:
            token.undeclare()
        leaving = Leaving(a)
        closes_and_is_seen_gone(c, leaving, heard)
        c = None
        leaving.sub.undeclare()
        heard.close()
    finally:
        if c is not None:
            c.close()
        a.close()


def test_only_the_watchers_certificate_puts_steering_requests(ids):
    """A steered run's requests (``rgtbus/<run>/steer/watch``): a's access control lets the
    watcher's certificate put them, and refuses c's at the door (docs/security.md)."""
    port = free_ports(1)[0]
    a = session(ids, "a", listen=[f"tls/127.0.0.1:{port}"])
    opened: list[zenoh.Session] = []
    heard: list[bytes] = []
    sub = a.declare_subscriber(
        keys.key(keys.STEER, RUN, keys.WATCHER), lambda s: heard.append(s.payload.to_bytes())
    )
    try:
        c = session(ids, "c", connect=[f"tls/127.0.0.1:{port}"])
        opened.append(c)
        w = session(ids, WATCH, connect=[f"tls/127.0.0.1:{port}"])
        opened.append(w)
        key = keys.key(keys.STEER, RUN, keys.WATCHER)

        def said() -> bool:
            c.put(key, b"from c")
            w.put(key, b"from the watcher")
            return b"from the watcher" in heard

        assert until(said)
        assert b"from c" not in heard
    finally:
        sub.undeclare()
        for s in opened:
            s.close()
        a.close()


@pytest.mark.slow  # three sessions and a router
def test_c_cannot_speak_as_b_through_a_tls_router(ids):
    """The same through a router (``@router``): its own copy of the access control holds each
    client to its own keys, and a sees c's token end when c closes."""
    port = free_ports(1)[0]
    ep = [f"tls/127.0.0.1:{port}"]
    router = session(ids, ROUTER, "router", listen=ep)
    opened: list[zenoh.Session] = []
    try:
        a = session(ids, "a", "client", connect=ep)
        opened.append(a)
        heard = Heard(a)
        c = session(ids, "c", "client", connect=ep)
        opened.append(c)
        forge_then_speak(c, heard)
        assert [k for k in heard.keys if k.endswith("/b")] == []
        leaving = Leaving(a)
        closes_and_is_seen_gone(c, leaving, heard)
        leaving.sub.undeclare()
        heard.close()
    finally:
        for s in opened:
            s.close()
        router.close()


def _no_certificate(ids: Path, port: int) -> zenoh.Session:
    """A peer that trusts the run's CA but shows no certificate of its own."""
    cfg = zenoh.Config()
    for key, value in {
        "connect/endpoints": [f"tls/127.0.0.1:{port}"],
        "scouting/multicast/enabled": False,
        "transport/link/tls/root_ca_certificate": str(ids / "run" / "ca.crt"),
        "transport/link/tls/verify_name_on_connect": False,
    }.items():
        cfg.insert_json5(key, json.dumps(value))
    return zenoh.open(cfg)


@pytest.mark.slow  # waits a while to see nothing come
def test_a_peer_without_a_certificate_of_the_run_ca_cannot_connect(ids, other_ids):
    """A TLS listener with the run's config: a peer with no client certificate, and one with
    c's name under another CA, are refused by TLS; c itself gets in."""
    port = free_ports(1)[0]
    a = session(ids, "a", listen=[f"tls/127.0.0.1:{port}"])
    opened: list[zenoh.Session] = []
    try:
        heard = Heard(a)
        bare = _no_certificate(ids, port)
        opened.append(bare)
        foreign = session(other_ids, "c", connect=[f"tls/127.0.0.1:{port}"])
        opened.append(foreign)
        c = session(ids, "c", connect=[f"tls/127.0.0.1:{port}"])
        opened.append(c)
        assert until(lambda: [str(z) for z in a.info.peers_zid()] == [str(c.zid())])
        deadline = time.monotonic() + 2.0  # the intruders keep trying meanwhile
        while time.monotonic() < deadline:
            for s in (bare, foreign):
                s.put(keys.key(keys.TX, RUN, "c"), b"intruder")
            time.sleep(0.05)
        assert keys.key(keys.TX, RUN, "c") not in heard
        assert [str(z) for z in a.info.peers_zid()] == [str(c.zid())]
        assert list(bare.info.peers_zid()) == list(foreign.info.peers_zid()) == []
        heard.close()
    finally:
        for s in opened:
            s.close()
        a.close()


@pytest.mark.slow
@pytest.mark.parametrize("router", [False, True])
def test_a_launch_over_tls_gives_the_single_process_summary(tmp_path, router):
    """``rgtbus certs`` then ``rgtbus launch --tls``: the summary and log of the one-process
    run, over a TLS mesh and through a TLS router."""
    ids = tmp_path / "ids"
    made = subprocess.run(
        [*EXE, "certs", GATE, "--out", str(ids)], capture_output=True, text=True, timeout=120
    )
    assert made.returncode == 0, made.stderr
    logs = tmp_path / "logs"
    argv = [*EXE, "launch", GATE, "--tls", str(ids), "--log-dir", str(logs), "--json"]
    launch_equals_single(argv + (["--router"] if router else []), "gate", logs)


@pytest.mark.slow
def test_the_library_launch_over_tls_gives_the_summary_of_run(ids, tmp_path):
    import rgtbus

    ran = rgtbus.run("gate")
    launched = rgtbus.launch("gate", log_dir=tmp_path, tls=ids, router=True, timeout=30.0)
    assert launched.failures == [] and launched.ok

    def same(summary):
        return {k: v for k, v in summary.items() if k not in ("wall_seconds", "log")}

    assert same(launched.summary) == same(ran.summary)


@pytest.mark.slow  # waits out a join timeout
def test_a_unit_without_a_certificate_of_the_run_ca_cannot_join(procs, ids, other_ids, tmp_path):
    """Units a, b and c of the run on a TLS mesh; d with a certificate of another CA (its own
    files are well-formed: nothing refuses them before it starts). TLS refuses d's links, so
    the others time out naming d, and d times out naming them."""
    ports = free_ports(4)
    started = {}
    for i, u in enumerate(UNITS):
        net = ["-l", f"tls/127.0.0.1:{ports[i]}"]
        for j in range(i):
            net += ["-e", f"tls/127.0.0.1:{ports[j]}"]
        d = other_ids if u == "d" else ids
        started[u] = procs(
            "unit", u, GATE, *net, "--tls", str(d), "--log", str(tmp_path / f"{u}.mcap"),
            "--run-id", RUN, "--join-timeout", "8",
        )  # fmt: skip
    for u, p in started.items():
        _, err = p.communicate(timeout=120)
        assert p.returncode == 2, (u, err)
        last = err.strip().splitlines()[-1]
        assert f"joining run '{RUN}' timed out after 8 s: no answer from" in last, last
        missing, _, hint = last.rsplit("no answer from ", 1)[1].partition("; ")
        assert missing == ("a, b, c" if u == "d" else "d"), (u, last)
        # d heard nobody (its certificate is of another CA): the line says how units connect
        assert ("no other unit was heard at all" in hint) == (u == "d"), (u, last)


def host_files(ids: Path, host: Path, *files: str) -> Path:
    """What docs/hosts.md copies to one host: the run's CA certificate and the host's own pair,
    in the layout of ``rgtbus certs``, nothing else."""
    for name in ("run/ca.crt", *files):
        (host / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ids / name, host / name)
    return host


@pytest.mark.slow
def test_units_on_their_hosts_files_through_a_router_equal_the_single_run(procs, ids, tmp_path):
    """docs/hosts.md's star, on loopback: a router and a ``rgtbus unit`` process a unit, each
    with only the CA's certificate and its own pair."""
    port = free_ports(1)[0]
    router_ids = host_files(ids, tmp_path / "R", "run/router.crt", "run/router.key")
    router = procs(
        "router", "-l", f"tls/127.0.0.1:{port}", "--tls", str(router_ids), "--scenario", GATE,
        "--run-id", RUN,
    )  # fmt: skip
    assert router.stdout.readline().startswith("router listening")  # bounded by its start
    started = {}
    for u in UNITS:
        own = host_files(ids, tmp_path / u, f"{u}.crt", f"{u}.key")
        started[u] = procs(
            "unit", u, GATE, "-m", "client", "-e", f"tls/127.0.0.1:{port}", "--tls", str(own),
            "--log", str(tmp_path / f"{u}.mcap"), "--run-id", RUN, "--json",
        )  # fmt: skip
    ref, _ = single("gate")
    for u, p in started.items():
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, (u, err)
        got = json.loads(out)
        assert got["report"]["result"] == ref["units"][u] and got["error"] is None
        assert got["sim_seconds"] == ref["sim_seconds"]


@pytest.mark.slow
def test_a_process_with_c_s_certificate_sending_junk_as_c_gets_c_named_by_every_member(
    procs, ids, tmp_path
):
    """Through a TLS router, a process holding c's own certificate (the access control rightly
    lets it speak on c's keys) puts well-formed frames of its own as c, over and over, while the
    paced run goes: two different frames under one number from an identified member. Every
    other unit ends within its timeout, in one line naming c, its result so far kept; none
    hangs."""
    from rgtbus.bus.payload import NEVER, Frame, encode
    from rgtbus.scenario import load_scenario

    rate = load_scenario(GATE).timing.sample_rate
    port = free_ports(1)[0]
    router = procs(
        "router", "-l", f"tls/127.0.0.1:{port}", "--tls", str(ids), "--scenario", GATE,
        "--run-id", RUN,
    )  # fmt: skip
    assert router.stdout.readline().startswith("router listening")
    started = {}
    for u in UNITS:
        started[u] = procs(
            "unit", u, GATE, "-m", "client", "-e", f"tls/127.0.0.1:{port}", "--tls", str(ids),
            "--log", str(tmp_path / f"{u}.mcap"), "--run-id", RUN, "--json", "--realtime", "25",
            "--timeout", "10",
        )  # fmt: skip
    impostor = session(ids, "c", mode="client", connect=[f"tls/127.0.0.1:{port}"])
    stop = threading.Event()

    def speak_as_c() -> None:
        seq = 0
        while not stop.is_set():
            seq = seq % 400 + 1
            impostor.put(keys.key(keys.TX, RUN, "c"), encode(Frame(seq, NEVER - seq), rate))
            time.sleep(0.002)

    speaker = threading.Thread(target=speak_as_c, daemon=True)
    speaker.start()
    try:
        for u, p in started.items():
            out, err = p.communicate(timeout=180)  # never a hang
            if u == "c":
                continue  # c itself hears two of itself: it may stop, or finish
            assert p.returncode == 1 and out, (u, p.returncode, err)
            got = json.loads(out)
            assert "c is not trusted" in got["error"], (u, got["error"])
            assert "\n" not in got["error"]
            assert got["report"] is not None  # what it knew is kept
    finally:
        stop.set()
        speaker.join(timeout=30)
        impostor.close()
