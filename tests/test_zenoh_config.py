"""Every zenoh config of the product (rgtbus.bus.config): the TLS settings and the access control
are what zenoh accepts and opens a session with; ``ZENOH_CONFIG`` is the base file when no
``-c`` is given, the options given override it, ``-c`` wins over it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh
from rgtbus.units.launch import free_ports

from rgtbus.bus.certs import ROUTER, WATCH, check_tls, make_certs
from rgtbus.bus.config import (
    ENV,
    TlsRun,
    access_control,
    make_config,
    tls_settings,
    zenoh_reason,
)
from rgtbus.cli import build_parser
from rgtbus.cli.arguments import zenoh_options
from rgtbus.errors import RgtbusError

ROOT = Path(__file__).parent.parent
GATE = str(ROOT / "scenarios" / "gate.toml")
UNITS = ("a", "b", "c", "d")


@pytest.fixture(scope="module")
def ids(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("ids") / "gate"
    make_certs(UNITS, d)
    return d


def tls_run(ids: Path, identity: str, run_id: str | None = "r1") -> TlsRun:
    return TlsRun(check_tls(ids, identity), UNITS, run_id)


def by_id(items: list[dict]) -> dict[str, dict]:
    return {item["id"]: item for item in items}


def test_the_tls_block_is_the_processs_own_pair_under_the_run_ca(ids):
    cfg = make_config(listen=["tls/127.0.0.1:7447"], tls=tls_run(ids, "b"))
    got = json.loads(cfg.get_json("transport/link/tls"))
    assert {k: got[k] for k in tls_settings(check_tls(ids, "b"))} == {
        "root_ca_certificate": str(ids / "run" / "ca.crt"),
        "listen_certificate": str(ids / "b.crt"),
        "listen_private_key": str(ids / "b.key"),
        "connect_certificate": str(ids / "b.crt"),
        "connect_private_key": str(ids / "b.key"),
        "enable_mtls": True,
        "verify_name_on_connect": False,
        "close_link_on_expiration": True,
    }


def test_the_access_control_lets_each_unit_put_only_on_its_own_keys(ids):
    acl = access_control(UNITS, "r1")
    cfg = make_config(tls=tls_run(ids, "a"))
    zenoh_acl = json.loads(cfg.get_json("access_control"))
    assert zenoh_acl["enabled"] is True and zenoh_acl["default_permission"] == "deny"
    assert [r["id"] for r in zenoh_acl["rules"]] == [r["id"] for r in acl["rules"]]
    rules = by_id(acl["rules"])
    assert all(r["permission"] == "allow" for r in acl["rules"])  # deny is the default
    subjects = by_id(acl["subjects"])
    policies = {p["id"]: p for p in acl["policies"]}

    def allowed(identity: str, flow: str, message: str) -> set[str]:
        """Every key expression ``identity`` may use ``message`` on in ``flow``."""
        subject = next(s for s in subjects.values() if s["cert_common_names"] == [identity])
        out: set[str] = set()
        for p in policies.values():
            if subject["id"] in p["subjects"]:
                for r in (rules[i] for i in p["rules"]):
                    if flow in r["flows"] and message in r["messages"]:
                        out |= set(r["key_exprs"])
        return out

    every = {"rgtbus/r1/**", "rgtbus/*/tx/*", "rgtbus/*/telemetry/*"}
    for u in UNITS:
        assert allowed(u, "ingress", "put") == {
            f"rgtbus/r1/tx/{u}", f"rgtbus/r1/hello/{u}", f"rgtbus/r1/telemetry/{u}",
            f"rgtbus/r1/resend/{u}", f"rgtbus/r1/change/{u}", f"rgtbus/r1/have/{u}",
        }  # fmt: skip
        assert allowed(u, "ingress", "liveliness_token") == {f"rgtbus/r1/alive/{u}"}
        assert allowed(u, "ingress", "declare_subscriber") == every
        assert allowed(u, "egress", "put") == every
        assert allowed(u, "ingress", "delete") == allowed(u, "ingress", "query") == set()
    assert allowed(ROUTER, "ingress", "put") == every  # it forwards the others' traffic
    # a watcher says nothing but a steered run's requests (rgtbus.bus.steer_link)
    assert allowed(WATCH, "ingress", "put") == {"rgtbus/r1/steer/watch"}
    assert allowed(WATCH, "ingress", "declare_subscriber") == every
    # no run id (a router not told which run): the same rules, for any run
    anyrun = access_control(UNITS, None)
    assert by_id(anyrun["rules"])["puts of b"]["key_exprs"] == [
        "rgtbus/*/tx/b", "rgtbus/*/hello/b", "rgtbus/*/telemetry/b", "rgtbus/*/resend/b",
        "rgtbus/*/change/b", "rgtbus/*/have/b",
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("identity", "mode", "run_id"),
    [("a", "peer", "r1"), (ROUTER, "router", None), (WATCH, "client", "r1")],
)
def test_zenoh_opens_a_session_with_the_tls_config(ids, identity, mode, run_id):
    """The generated config, inserted into zenoh's and opened on a loopback TLS endpoint."""
    port = free_ports(1)[0]
    kind = "connect" if mode == "client" else "listen"
    endpoints = {kind: [f"tls/127.0.0.1:{port}"]}
    if mode == "client":  # a client needs its router up
        router = zenoh.open(
            make_config(mode="router", listen=endpoints[kind], tls=tls_run(ids, ROUTER, None))
        )
    try:
        session = zenoh.open(
            make_config(mode=mode, tls=tls_run(ids, identity, run_id), **endpoints)
        )
        try:
            assert str(session.zid())
        finally:
            session.close()
    finally:
        if mode == "client":
            router.close()


def test_tls_refuses_plain_endpoints_naming_where_they_came_from(ids, tmp_path):
    with pytest.raises(RgtbusError, match=r"^zenoh connect endpoint 'tcp/127\.0\.0\.1:7447': "):
        make_config(connect=["tcp/127.0.0.1:7447"], tls=tls_run(ids, "a"))
    path = tmp_path / "z.json5"
    path.write_text('{ listen: { endpoints: ["tcp/0.0.0.0:7447"] } }')
    with pytest.raises(RgtbusError) as err:
        make_config(config=path, tls=tls_run(ids, "a"))
    assert str(err.value) == (
        f"zenoh listen endpoint 'tcp/0.0.0.0:7447' (in zenoh config '{path}'): with --tls every "
        "endpoint must be tls/HOST:PORT"
    )
    # the options given override the file's endpoints, and those are TLS
    make_config(config=path, listen=["tls/0.0.0.0:7447"], tls=tls_run(ids, "a"))
    # a file that sets no endpoints leaves zenoh's defaults for its mode: a client's are none,
    # a peer's listen on tcp
    client = tmp_path / "client.json5"
    client.write_text('{ mode: "client", connect: { endpoints: ["tls/10.0.0.1:7447"] } }')
    cfg = make_config(config=client, tls=tls_run(ids, "a"))
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tls/10.0.0.1:7447"]
    peer = tmp_path / "peer.json5"
    peer.write_text('{ mode: "peer" }')
    with pytest.raises(RgtbusError) as err:
        make_config(config=peer, tls=tls_run(ids, "a"))
    assert str(err.value).startswith(
        f"zenoh listen endpoint 'tcp/[::]:0' (in zenoh config '{peer}', or zenoh's default for a "
        "peer): with --tls"
    )
    make_config(config=peer, listen=["tls/0.0.0.0:7448"], tls=tls_run(ids, "a"))


def _config(*argv: str) -> zenoh.Config:
    args = build_parser().parse_args(["unit", "a", GATE, *argv])
    return make_config(**zenoh_options(args))


def _file(tmp_path: Path, name: str, **values: object) -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(values))
    return path


def test_zenoh_config_from_the_environment_is_the_base(tmp_path, monkeypatch):
    env = _file(
        tmp_path,
        "env.json5",
        mode="client",
        connect={"endpoints": ["tcp/127.0.0.1:7001"]},
        scouting={"multicast": {"enabled": True}},
    )
    monkeypatch.setenv(ENV, str(env))
    cfg = _config()
    assert json.loads(cfg.get_json("mode")) == "client"
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7001"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is True
    # flags override it, key by key
    cfg = _config("-m", "peer", "-e", "tcp/127.0.0.1:7002")
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7002"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is True
    # -c wins over it: the environment's file is not read at all
    given = _file(tmp_path, "given.json5", connect={"endpoints": ["tcp/127.0.0.1:7003"]})
    cfg = _config("-c", str(given))
    assert json.loads(cfg.get_json("mode")) != "client"  # unset there, not the env file's
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7003"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is not True
    # without it, rgtbus's own defaults again
    monkeypatch.delenv(ENV)
    assert json.loads(_config().get_json("mode")) == "peer"
    assert json.loads(_config().get_json("scouting/multicast/enabled")) is False


def test_a_bad_zenoh_config_from_the_environment_is_one_line_naming_it(tmp_path, monkeypatch):
    for path, reason in [(tmp_path / "missing.json5", ""), (tmp_path / "bad.json5", "x")]:
        if reason:
            path.write_text("{ mode: ")
        monkeypatch.setenv(ENV, str(path))
        with pytest.raises(RgtbusError) as err:
            _config()
        msg = str(err.value)
        assert msg.startswith(f"zenoh config '{path}' (from ZENOH_CONFIG): "), msg
        assert "\n" not in msg and ".rs:" not in msg
    assert zenoh_reason(ValueError("")) == "ValueError"
