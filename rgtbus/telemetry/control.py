"""Steering a live run from Foxglove (``--control``): the parameters and services a paced run
advertises on its live view, and the run's side of them (docs/foxglove.md, "Steer a live run").

A ``Controller`` is the bridge. The live view's server calls it from its own threads, for a
client's ``setParameters`` and service calls; it checks each at once against the scenario
(``rgtbus.steering``: a bad name or value is answered with one line of why not), and hands it
to the run as a ``Request``, refused or not: the run applies it (or refuses it, when the
run's state says so) at its next window boundary, and logs it there (``/control/parameter``,
``/control/service``). The run takes requests with ``take`` and ``wait`` and tells the view
its clock (``clock``: paused, resumed, another pace). Nothing here ever blocks the server.

Who may steer: any client of an unkeyed run. A keyed run's (``--key-file``) only a client
that proved it holds the key, by calling ``/control/auth`` with ``{"proof": HEX}``, where
HEX = HMAC-SHA256(key, "rgtbus-control:" + the server's session id) (``control_proof``);
every other client's calls are refused, and logged as refused.

Services (each takes a JSON object, answers ``{"ok": true, "text": ...}`` or fails with one
line): ``/control/pause``, ``/control/resume``, ``/control/step`` ``{"by": "window" | "turn" |
"round"}``, ``/control/relation`` ``{"unit", "pair": "a>b", "relation": "alliance" |
"conflict"}``, ``/control/influence`` ``{"influence": "SRC>DST=VALUE"}``, ``/control/mark``
``{"label"}``, ``/control/auth`` ``{"proof"}``.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import secrets
import threading
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import foxglove
from foxglove.websocket import (
    Client,
    MessageSchema,
    Parameter,
    Service,
    ServiceRequest,
    ServiceSchema,
)

from rgtbus.pairs import pair_key
from rgtbus.scenario import Scenario
from rgtbus.steering import (
    BUDGET,
    DRIFT_PREFIX,
    GAIN_PREFIX,
    NOISE,
    PACE,
    SERVICES,
    Refused,
    Request,
    check_call,
    check_setting,
)
from rgtbus.telemetry.records import KEPT_BYTES, loggable

SERVICE_PREFIX = "/control/"
AUTH = "auth"
MAX_PENDING = 1024  # requests not yet taken by the run (beyond: refused at once)
MAX_REQUEST = KEPT_BYTES  # bytes of a service call's request

_SCHEMAS: dict[str, dict[str, Any]] = {
    "pause": {"type": "object", "properties": {}, "additionalProperties": False},
    "resume": {"type": "object", "properties": {}, "additionalProperties": False},
    "step": {
        "type": "object",
        "properties": {"by": {"enum": ["window", "turn", "round"]}},
        "additionalProperties": False,
    },
    "relation": {
        "type": "object",
        "properties": {
            "unit": {"type": "string", "description": "the unit that holds it"},
            "pair": {"type": "string", "description": "the relation code a>b, as it holds it"},
            "relation": {"enum": ["alliance", "conflict"]},
        },
        "required": ["unit", "pair", "relation"],
        "additionalProperties": False,
    },
    "influence": {
        "type": "object",
        "properties": {"influence": {"type": "string", "description": "SRC>DST=VALUE"}},
        "required": ["influence"],
        "additionalProperties": False,
    },
    "mark": {
        "type": "object",
        "properties": {"label": {"type": "string"}},
        "additionalProperties": False,
    },
    AUTH: {
        "type": "object",
        "properties": {
            "proof": {
                "type": "string",
                "description": 'HMAC-SHA256(key, "rgtbus-control:" + session id), hex',
            }
        },
        "required": ["proof"],
        "additionalProperties": False,
    },
}


def control_proof(key: bytes, session: str) -> str:
    """What a client sends ``/control/auth`` to steer a keyed run: HMAC-SHA256 of
    ``"rgtbus-control:" + session`` (the server's session id, in its serverInfo) under the
    run's key, in hex."""
    return hmac.new(key, b"rgtbus-control:" + session.encode(), hashlib.sha256).hexdigest()


class ClockView(Protocol):
    """What a controller drives of a live view: its paced clock."""

    def set_clock(self, t_ns: int, realtime: float | None, running: bool) -> None: ...


class Controller:
    """A live run's steering, between the Foxglove server and the run (module docstring).
    ``key``: the run's shared secret (None: any client may steer)."""

    def __init__(
        self,
        sc: Scenario,
        *,
        key: bytes | None = None,
        pace: float | None = None,
        paced: bool | None = None,
    ):
        """``pace``: the run's (None: unpaced); ``paced``: whether it is paced, where its
        pace is not known here (a watcher's: the run's processes have it)."""
        self.sc = sc
        self.paced = pace is not None if paced is None else paced
        self.key = key
        self.session = secrets.token_hex(16)  # the server's session id: what a proof signs
        self.view: ClockView | None = None  # set by the live view it serves on
        self._lock = threading.Condition()
        self._pending: list[Request] = []
        self._allowed: set[int] = set()
        self._closed = False
        self.values: dict[str, Any] = {NOISE: sc.channel.noise, PACE: pace}
        for a, b in sc.pairs():
            self.values[GAIN_PREFIX + pair_key(a, b)] = sc.channel.gains.get((a, b), 1.0)
        if sc.channel.timed:
            for u in sc.units:
                clock = sc.channel.clocks.get(u)
                self.values[DRIFT_PREFIX + u] = 0.0 if clock is None else clock.drift
        if sc.protocol.repairs_per_phase:
            self.values[BUDGET] = sc.protocol.repairs_per_phase
        self.received = 0  # requests handed to the run
        self.refused = 0  # of which refused before they reached it
        self.publish: Callable[[list[Parameter]], None] | None = None  # to every client

    # -- the server's side (its threads; never blocks) ----------------------------------------

    def services(self) -> list[Service]:
        """Every service, its request's JSON Schema, and its handler."""
        out = []
        for name in (*SERVICES, AUTH):
            schema = foxglove.Schema(
                name=f"rgtbus.control.{name}",
                encoding="jsonschema",
                data=json.dumps(_SCHEMAS[name]).encode(),
            )
            request = MessageSchema(encoding="json", schema=schema)
            out.append(
                Service(
                    name=SERVICE_PREFIX + name,
                    schema=ServiceSchema(name=f"rgtbus.control.{name}", request=request),
                    handler=self._handler(name),
                )
            )
        return out

    def parameters(self, names: list[str] | None = None) -> list[Parameter]:
        """The current values of ``names`` (every parameter: None or empty)."""
        with self._lock:
            want = names or list(self.values)
            return [
                Parameter(n, value=self.values[n])
                for n in want
                if n in self.values and self.values[n] is not None
            ]

    def on_get_parameters(
        self, client: Client, param_names: list[str], request_id: str | None = None
    ) -> list[Parameter]:
        return self.parameters(param_names)

    def on_set_parameters(
        self, client: Client, parameters: list[Parameter], request_id: str | None = None
    ) -> list[Parameter]:
        """Each parameter set: checked, handed to the run (refused ones too, to be logged);
        the answer is every parameter's value as it will be."""
        who = _who(client)
        for p in parameters:
            value = p.get_value()
            name = str(loggable(p.name, 200))
            req = Request("parameter", name, loggable(value), who)  # bounded while it waits
            why = self._not_allowed(client)
            if why is None:
                try:
                    s = check_setting(self.sc, name, value)
                    if s.kind == "pace" and not self.paced:
                        raise Refused(f"{PACE}: this run is not paced (--realtime)")
                    req = Request("parameter", s.name, value, who)
                    with self._lock:
                        self.values[s.name] = s.value
                except Refused as exc:
                    why = str(exc)
            self._hand(req if why is None else req.refuse(why))
        out = self.parameters()
        if self.publish is not None:
            self.publish(out)
        return out

    def _handler(self, service: str) -> Callable[[ServiceRequest], bytes]:
        def handle(request: ServiceRequest) -> bytes:
            return self.call(service, request.client_id, bytes(request.payload))

        return handle

    def call(self, service: str, client_id: int, payload: bytes) -> bytes:
        """A service call by client ``client_id``: its answer (JSON bytes); a refusal raises
        ``Refused`` (the client gets its line as the call's failure), logged by the run."""
        who = f"client {client_id}"
        try:
            if len(payload) > MAX_REQUEST:
                raise Refused(f"{service}: a request of more than {MAX_REQUEST} bytes")
            try:
                args = json.loads(payload.decode() or "{}")
            except (UnicodeDecodeError, ValueError):
                raise Refused(f"{service}: the request is not JSON") from None
            if not isinstance(args, dict):
                raise Refused(f"{service}: the request is not a JSON object")
        except Refused as exc:
            self._hand(Request("service", service, {}, who, refused=str(exc)))
            raise
        if service == AUTH:
            return self._auth(client_id, who, args)
        req = Request("service", service, args, who)
        why = self._not_allowed_id(client_id)
        if why is None:
            try:
                check_call(self.sc, service, args)
            except Refused as exc:
                why = str(exc)
        if why is not None:
            self._hand(req.refuse(why))
            raise Refused(why)
        self._hand(req)
        text = f"{service}: taken; the run applies it at its next window boundary (its log says)"
        return json.dumps({"ok": True, "text": text}).encode()

    def _auth(self, client_id: int, who: str, args: dict[str, Any]) -> bytes:
        proof = args.get("proof")
        if self.key is None:
            text = "this run is not keyed: every client may steer"
        elif isinstance(proof, str) and hmac.compare_digest(
            proof.encode(), control_proof(self.key, self.session).encode()
        ):
            with self._lock:
                self._allowed.add(client_id)
            text = f"{who} may steer (it proved the run's key)"
        else:
            why = "auth: wrong proof of the run's key"
            self._hand(Request("service", AUTH, {}, who, refused=why))
            raise Refused(why)
        self._hand(Request("service", AUTH, {}, who))  # the proof itself is never logged
        return json.dumps({"ok": True, "text": text}).encode()

    def _not_allowed(self, client: Client) -> str | None:
        return self._not_allowed_id(client.id)

    def _not_allowed_id(self, client_id: int) -> str | None:
        if self.key is None:
            return None
        with self._lock:
            if client_id in self._allowed:
                return None
        return (
            "not allowed: this run is keyed; steer after /control/auth with the proof of its "
            "key (docs/foxglove.md)"
        )

    def _hand(self, req: Request) -> None:
        with self._lock:
            if self._closed:
                raise Refused(f"{req.name}: the run is stopping")
            if len(self._pending) >= MAX_PENDING:
                raise Refused(f"{req.name}: {MAX_PENDING} requests are waiting already")
            self._pending.append(req)
            self.received += 1
            self.refused += req.refused is not None
            self._lock.notify_all()

    # -- the run's side (``rgtbus.engine.steering.Requests``) ---------------------------------

    def take(self) -> list[Request]:
        """The requests that came since the last call, in order."""
        with self._lock:
            out, self._pending = self._pending, []
            return out

    def wait(self, timeout: float) -> None:
        """Wait (wall time) for a request, at most ``timeout`` s."""
        with self._lock:
            if not self._pending:
                self._lock.wait(timeout)

    def clock(self, t_ns: int, pace: float | None, running: bool) -> None:
        """The run's clock: the view's follows it."""
        if pace is not None:
            with self._lock:
                self.values[PACE] = pace
        if self.view is not None:
            self.view.set_clock(t_ns, pace, running)

    def announce(self, req: Request) -> None:
        """A one-process run's: no other process to tell."""

    def settle(self, seqs: Sequence[int], timeout: float) -> list[str]:
        """A one-process run's: no other process to wait for."""
        return []

    def close(self) -> None:
        """The run is stopping: calls from now on are refused (said to the client)."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()


def _who(client: Client) -> str:
    return f"client {client.id}"
