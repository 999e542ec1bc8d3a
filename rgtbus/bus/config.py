"""Every zenoh configuration rgtbus makes, and every zenoh config key it writes, here and nowhere
else: the sessions of units, routers and watchers (``make_config``).

What a process's config holds, first to last (a later one overrides an earlier one):

1. zenoh's defaults (made quieter: peer mode, no endpoints, no multicast scouting, no shared
   memory), or a JSON5 file: ``-c/--config FILE``, else the file the environment variable
   ``ZENOH_CONFIG`` names;
2. the options given (``-m``, ``-e``, ``-l``, ``--multicast``);
3. with ``--tls DIR`` (``TlsRun``): mutual TLS with the process's own certificate under the
   run's CA (rgtbus.bus.certs), and an access control generated from the roster, deny by
   default, that lets each unit put only on its own keys (``access_control``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from collections.abc import Sequence
from typing import Any

import zenoh

from rgtbus.bus import keys
from rgtbus.bus.certs import ROUTER, WATCH, TlsFiles
from rgtbus.errors import BadInput

MODES = ("peer", "client", "router")
ENV = "ZENOH_CONFIG"  # the base config file when no -c/--config is given
TLS = "transport/link/tls"
ACL = "access_control"

_RUST_AT = re.compile(r"\s+at /\S+\.rs:\d+\.?")
_JSON5_MSG = re.compile(r'msg: "(.*?)", location')


def zenoh_reason(exc: BaseException) -> str:
    """A zenoh error in one readable line: the JSON5 parser's own message if wrapped in one,
    without the Rust source paths zenoh appends."""
    text = str(exc)
    m = _JSON5_MSG.search(text)
    if m:
        text = m.group(1)
    text = " ".join(_RUST_AT.sub("", text).split())
    return text or type(exc).__name__


@dataclasses.dataclass(frozen=True)
class TlsRun:
    """What a process's TLS config is made of: its own files (``check_tls``), the run's roster
    (``units``) and its id (``run_id``; None: any run, as a router not told which)."""

    files: TlsFiles
    units: tuple[str, ...]
    run_id: str | None = None


def tls_settings(files: TlsFiles) -> dict[str, Any]:
    """The ``transport/link/tls`` block of a process with ``files``: its certificate on both the
    links it accepts and those it opens, the peer's certificate required (mutual TLS) and
    checked against the run's CA, not against a host name (the endpoints are the addresses of
    many hosts; who a process is, is its certificate's common name, held by the access
    control); a link closes when a certificate expires."""
    return {
        "root_ca_certificate": str(files.ca),
        "listen_certificate": str(files.cert),
        "listen_private_key": str(files.key),
        "connect_certificate": str(files.cert),
        "connect_private_key": str(files.key),
        "enable_mtls": True,
        "verify_name_on_connect": False,
        "close_link_on_expiration": True,
    }


# What the processes of a run do on zenoh (rgtbus.bus.zenoh, rgtbus.telemetry.watch): put (frames,
# hellos, telemetry), declare a liveliness token, subscribe, and subscribe to the run's tokens.
# Nothing else is allowed.
PUT, TOKEN, SUBSCRIBE = "put", "liveliness_token", "declare_subscriber"
WATCH_TOKENS = "declare_liveliness_subscriber"  # a unit learns at once that a member left
OWN_PUTS = (keys.TX, keys.HELLO, keys.TELEMETRY, keys.RESEND, keys.CHANGE, keys.HAVE)


def _subject(identity: str) -> str:
    return f"cn {identity}"


def access_control(units: Sequence[str], run_id: str | None = None) -> dict[str, Any]:
    """The ``access_control`` block of every process of a run with roster ``units`` (``run_id``
    None: any run), deny by default. Subjects are certificate common names (rgtbus.bus.certs).

    From unit U (ingress): ``put`` only on its own keys
    ``rgtbus/<run>/{tx,hello,telemetry,resend}/U``,
    a ``liveliness_token`` only on ``rgtbus/<run>/alive/U``, and ``declare_subscriber`` and
    ``declare_liveliness_subscriber`` on the run's keys (and on every run's frames and
    telemetry: a unit counts foreign frames, a watcher may watch every run). To a unit, the
    router and a watcher (egress): all four on the run's keys. The router (``@router``) may
    do all four on the run's keys, both ways: it forwards the others' traffic, and its own
    copy of these rules holds each of its clients to its own keys. A watcher (``@watch``) may
    subscribe, and put only the requests of a steered run (``rgtbus/<run>/steer/watch``):
    no one else may. A unit's own keys include its changes and receipts of them."""
    run = "*" if run_id is None else run_id
    run_keys = [f"{keys.ROOT}/{run}/**"]
    # a unit counts foreign frames, a watcher may watch every run: their subscriptions
    subscriptions = [*run_keys, *(keys.every_unit(k, None) for k in (keys.TX, keys.TELEMETRY))]
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []

    def rule(rid: str, flow: str, messages: list[str], key_exprs: list[str]) -> str:
        rules.append(
            {
                "id": rid,
                "permission": "allow",
                "flows": [flow],
                "messages": messages,
                "key_exprs": key_exprs,
            }
        )
        return rid

    subscribe = rule("subscribe", "ingress", [SUBSCRIBE, WATCH_TOKENS], subscriptions)
    deliver = rule("deliver", "egress", [PUT, TOKEN, SUBSCRIBE, WATCH_TOKENS], subscriptions)
    for u in units:
        own = [keys.key(kind, run, u) for kind in OWN_PUTS]
        subjects.append({"id": _subject(u), "cert_common_names": [u]})
        policies.append(
            {
                "id": f"unit {u}",
                "subjects": [_subject(u)],
                "rules": [
                    rule(f"puts of {u}", "ingress", [PUT], own),
                    rule(f"token of {u}", "ingress", [TOKEN], [keys.key(keys.ALIVE, run, u)]),
                    subscribe,
                    deliver,
                ],
            }
        )
    forwarded = rule("forwarded", "ingress", [PUT, TOKEN, SUBSCRIBE, WATCH_TOKENS], subscriptions)
    subjects.append({"id": _subject(ROUTER), "cert_common_names": [ROUTER]})
    policies.append({"id": "router", "subjects": [_subject(ROUTER)], "rules": [forwarded, deliver]})
    subjects.append({"id": _subject(WATCH), "cert_common_names": [WATCH]})
    steer = rule(
        "requests of the watcher", "ingress", [PUT], [keys.key(keys.STEER, run, keys.WATCHER)]
    )
    policies.append(
        {"id": "watcher", "subjects": [_subject(WATCH)], "rules": [subscribe, deliver, steer]}
    )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _base(
    config: zenoh.Config | str | os.PathLike[str] | None,
) -> tuple[zenoh.Config | None, str | None]:
    """The config to start from: ``config`` (a Config, or a file), else the file ``ZENOH_CONFIG``
    names, else None (zenoh's defaults); and where it came from, for messages."""
    if isinstance(config, zenoh.Config):
        return config, "config"
    where = None
    if config is None:
        env = os.environ.get(ENV)
        if not env:
            return None, None
        path, where = env, f"zenoh config {env!r} (from {ENV})"
    else:
        path = os.fspath(config)
        where = f"zenoh config {path!r}"
    try:
        return zenoh.Config.from_file(path), where
    except Exception as e:  # zenoh raises ZError; keep one line
        raise BadInput(f"{where}: {zenoh_reason(e)}") from None


def _insert(cfg: zenoh.Config, key: str, value: object, what: str) -> None:
    """``cfg[key] = value`` (as JSON); zenoh refusing it is one line naming ``what``."""
    try:
        cfg.insert_json5(key, json.dumps(value))
    except Exception as e:
        raise BadInput(f"{what}: {zenoh_reason(e)}") from None


def _endpoints(cfg: zenoh.Config, name: str) -> tuple[list[str], str | None]:
    """The ``connect`` or ``listen`` endpoints ``cfg`` uses in its mode, and that mode when
    they are given by mode (as zenoh's defaults are)."""
    raw = json.loads(cfg.get_json(f"{name}/endpoints"))
    if isinstance(raw, dict):
        mode = json.loads(cfg.get_json("mode")) or "peer"  # zenoh's default mode
        return [str(e) for e in raw.get(mode) or []], mode
    return [str(e) for e in raw or []], None


def make_config(
    *,
    mode: str | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    multicast: bool | None = None,
    config: zenoh.Config | str | os.PathLike[str] | None = None,
    tls: TlsRun | None = None,
    send_patience: float | None = None,
) -> zenoh.Config:
    """A zenoh Config: the given file/Config (else the file ``ZENOH_CONFIG`` names, else zenoh's
    defaults), then the explicit options, then ``tls`` (see the module docstring).

    Without a config (given or from the environment), unset options mean: peer mode, no
    endpoints, multicast scouting off, no shared-memory pools, 16 batches of queue for data a
    link. With ``tls`` every endpoint must be ``tls/...``. ``send_patience``: how many seconds
    a send may wait on a peer that does not read (its queue full) before zenoh closes the link
    (zenoh's own: 5 s); a run's frames are sent without ever being dropped, so a closed link
    loses frames and stalls the run: give a starved peer as long as the run's timeout."""
    cfg, where = _base(config)
    if cfg is None:
        cfg = zenoh.Config()
        mode = "peer" if mode is None else mode
        connect = () if connect is None else connect
        listen = () if listen is None else listen
        multicast = False if multicast is None else multicast
        # Frames are small and few: zenoh's shared-memory pools (16 MB mapped a process)
        # buy nothing here and cost every unit process their pages.
        cfg.insert_json5("transport/shared_memory/enabled", "false")
        # A burst (every member's first frames at once) should not block a sender: room for
        # 16 batches a link rather than zenoh's 2.
        cfg.insert_json5("transport/link/tx/queue/size/data", "16")
    if mode is not None:
        if mode not in MODES:
            raise BadInput(f"zenoh mode {mode!r} unknown (use {', '.join(MODES)})")
        cfg.insert_json5("mode", json.dumps(mode))
    for name, eps in (("connect", connect), ("listen", listen)):
        if eps is None:
            continue
        if isinstance(eps, str):
            raise BadInput(f"zenoh {name} endpoints must be a list, got the string {eps!r}")
        try:
            cfg.insert_json5(f"{name}/endpoints", json.dumps([str(e) for e in eps]))
        except Exception as e:
            # Name the endpoint at fault, not the whole list.
            bad: object = list(eps)
            reason = zenoh_reason(e)
            for ep in eps:
                try:
                    zenoh.Config().insert_json5(f"{name}/endpoints", json.dumps([str(ep)]))
                except Exception as one:
                    bad, reason = str(ep), zenoh_reason(one)
                    break
            raise BadInput(f"zenoh {name} endpoint {bad!r}: {reason}") from None
    if multicast is not None:
        cfg.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    if send_patience is not None:
        if not send_patience > 0 or send_patience == float("inf"):
            raise BadInput(f"zenoh send patience must be seconds > 0, got {send_patience!r}")
        cfg.insert_json5(
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            str(int(send_patience * 1e6)),
        )
    if where is None and connect and mode == "peer":
        # Peers of one run start together and connect to each other before all listen:
        # retry an endpoint that is not up yet soon (zenoh's default backoff starts at 1 s
        # and would dominate a short run's start-up).
        cfg.insert_json5(
            "connect/retry",
            json.dumps({"period_init_ms": 50, "period_max_ms": 500, "period_increase_factor": 1.5}),
        )
        # Nor let open() wait to reach the peers it learns about, which can hold a start-up
        # back; the run's join barrier waits for every member anyway.
        cfg.insert_json5("open/return_conditions/connect_scouted", "false")
    if tls is not None:
        _add_tls(cfg, tls, where)
    return cfg


def _add_tls(cfg: zenoh.Config, tls: TlsRun, where: str | None) -> None:
    """``tls``'s settings and access control into ``cfg``; every endpoint must be TLS."""
    for name in ("connect", "listen"):
        endpoints, by_mode = _endpoints(cfg, name)
        for ep in endpoints:
            if not ep.startswith("tls/"):
                whence = [f"in {where}"] if where else []
                if by_mode:
                    whence.append(f"zenoh's default for a {by_mode}")
                origin = f" ({', or '.join(whence)})" if whence else ""
                raise BadInput(
                    f"zenoh {name} endpoint {ep!r}{origin}: with --tls every endpoint must be "
                    "tls/HOST:PORT"
                )
    for key, value in tls_settings(tls.files).items():
        _insert(cfg, f"{TLS}/{key}", value, f"TLS setting {key}")
    _insert(cfg, ACL, access_control(tls.units, tls.run_id), "access control")
