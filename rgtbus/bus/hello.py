"""The hello of the join barrier: who a process is, on which scenario, and whom it has heard.

Wire form: one UTF-8 JSON object, at most ``MAX_HELLO`` bytes, the same size however many
members the run has::

    {"unit": "b", "digest": <64 hex: scenario text + seed>, "nonce": <32 hex>,
     "view": <64 hex, or "": the run's view as b has it>, "ready": false,
     "started": false, "sample": 0, "process": "<host>:<pid>",
     "to": <32 hex, or "": the nonce of the late joiner this answers>,
     "tag": <64 hex, only on a run with a key>}

``view`` is ``view_digest`` of the nonce of every member as the sender has heard it (its own
among them), or empty while it has not heard every member. A hello whose view is *ours*
holds our nonce, so it was said after ours: it cannot be a recording of an earlier run
(docs/security.md); its sender has heard everyone we heard, as we heard them. ``ready``: the
sender has such a hello from every member (the barrier can open). ``started``: the sender's
run has started (at ``sample``); such an answer to a late joiner names the joiner's nonce in
``to``, which proves it fresh to that joiner. ``process``: where the sender runs, as it says it
(printable, at most ``MAX_PROCESS`` characters): what names two processes that claim one unit
(it proves nothing: the nonce tells them apart).

``tag`` is HMAC-SHA256 (rgtbus.bus.auth) over the object without it, in its canonical form
(sorted keys, no spaces). ``read_hello`` checks every field (type, range, length, membership)
and raises RgtbusError (AuthError for a missing or bad tag) on anything else: nothing a peer
says reaches the barrier unchecked. Pure: no transport.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

from rgtbus.bus.auth import NONCE_SIZE, TAG_SIZE, AuthError, check_tag, tag
from rgtbus.errors import BadInput

MAX_HELLO = 4 * 1024
MAX_PROCESS = 128
VIEW_SIZE = 32
_HEX = re.compile(r"[0-9a-f]*")  # used with fullmatch: "$" would let a trailing newline in
_FIELDS = frozenset(
    {"unit", "digest", "nonce", "view", "ready", "started", "sample", "process", "to"}
)
_NEVER = 2**63 - 1


@dataclass(frozen=True)
class Hello:
    """One hello, every field checked (see the module docstring)."""

    unit: str
    digest: str
    nonce: bytes
    view: bytes = b""
    started: bool = False
    sample: int = 0
    ready: bool = False
    process: str = ""
    to: bytes = b""


def view_digest(run_id: str, digest: str, nonces: Mapping[str, bytes]) -> bytes:
    """The view of a run: SHA-256 over its id, its scenario digest and every member's nonce
    (by member name), in one canonical order."""
    h = hashlib.sha256(f"rgtbus-view\0{run_id}\0{digest}".encode())
    for unit in sorted(nonces):
        h.update(b"\0" + unit.encode() + b"\0" + nonces[unit])
    return h.digest()


def _canonical(obj: Mapping[str, Any]) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()


def encode_hello(h: Hello, run_id: str, key: bytes | None) -> bytes:
    """The hello's wire form, tagged with ``key`` on a keyed run."""
    obj: dict[str, Any] = {
        "unit": h.unit,
        "digest": h.digest,
        "nonce": h.nonce.hex(),
        "view": h.view.hex(),
        "ready": h.ready,
        "started": h.started,
        "sample": h.sample,
        "process": h.process,
        "to": h.to.hex(),
    }
    if key is not None:
        obj["tag"] = tag(key, "hello", run_id, h.unit, h.nonce, _canonical(obj)).hex()
    return _canonical(obj)


def check_digest(digest: object) -> str:
    """A scenario digest: 64 lowercase hex digits (SHA-256), as every hello carries."""
    if not isinstance(digest, str) or len(digest) != 64 or not _HEX.fullmatch(digest):
        raise BadInput(f"hello digest must be 64 lowercase hex digits, got {str(digest)[:70]!r}")
    return digest


def _hex(obj: Mapping[str, Any], name: str, size: int, *, empty: bool = False) -> bytes:
    """Field ``name``: ``size`` bytes as lowercase hex (or "" where ``empty`` allows it)."""
    v = obj.get(name)
    if empty and v == "":
        return b""
    if not isinstance(v, str) or len(v) != 2 * size or not _HEX.fullmatch(v):
        also = ' or ""' if empty else ""
        raise BadInput(f"hello {name} must be {2 * size} lowercase hex digits{also}")
    return bytes.fromhex(v)


def _parsed(raw: bytes) -> dict[str, Any]:
    """The hello's JSON object, its size and form checked."""
    if not isinstance(raw, bytes | bytearray):
        raise BadInput(f"hello must be bytes, got {type(raw).__name__}")
    if len(raw) > MAX_HELLO:
        raise BadInput(f"hello of {len(raw)} bytes, at most {MAX_HELLO}")
    try:
        obj = json.loads(bytes(raw).decode("utf-8"))
    except (ValueError, RecursionError) as e:  # UnicodeDecodeError is a ValueError
        raise BadInput(f"hello is not JSON: {type(e).__name__}") from None
    if not isinstance(obj, dict):
        raise BadInput(f"hello must be a JSON object, got {type(obj).__name__}")
    return obj


def read_hello(raw: bytes, run_id: str, members: Collection[str], key: bytes | None) -> Hello:
    """The hello in ``raw``, every field checked; RgtbusError (one line) if anything is off."""
    obj = _parsed(raw)
    got_tag = obj.pop("tag", None)
    if set(obj) != _FIELDS:
        extra, missing = sorted(set(obj) - _FIELDS), sorted(_FIELDS - set(obj))
        raise BadInput(f"hello fields: unknown {extra}, missing {missing}")
    unit = obj["unit"]
    if not isinstance(unit, str) or unit not in members:
        raise BadInput(f"hello from {str(unit)[:40]!r}, not a member")
    digest = check_digest(obj["digest"])
    nonce = _hex(obj, "nonce", NONCE_SIZE)
    view = _hex(obj, "view", VIEW_SIZE, empty=True)
    to = _hex(obj, "to", NONCE_SIZE, empty=True)
    started, sample, ready = obj["started"], obj["sample"], obj["ready"]
    if not isinstance(started, bool) or not isinstance(ready, bool):
        raise BadInput("hello started and ready must be true or false")
    if isinstance(sample, bool) or not isinstance(sample, int) or not 0 <= sample <= _NEVER:
        raise BadInput("hello sample must be an integer 0..2**63-1")
    process = obj["process"]
    if not isinstance(process, str) or len(process) > MAX_PROCESS or not process.isprintable():
        raise BadInput(f"hello process must be printable text of at most {MAX_PROCESS}")
    if key is not None:
        if (
            not isinstance(got_tag, str)
            or len(got_tag) != 2 * TAG_SIZE
            or not _HEX.fullmatch(got_tag)
        ):
            raise AuthError(f"hello of {unit!r} not authenticated (no tag) on a run with a key")
        check_tag(key, "hello", run_id, unit, nonce, _canonical(obj), bytes.fromhex(got_tag))
    elif got_tag is not None:
        raise AuthError(f"hello of {unit!r} authenticated with a key this run does not have")
    return Hello(unit, digest, nonce, view, started, sample, ready, process, to)


def join_seconds(members: int) -> float:
    """How long the processes of a run have to join, by default: 20 s, and a second more a
    member (every process hears every other's hellos and says its own less often in a larger
    run, ``hello_period``; a hundred processes starting at once on a few cores take their
    time)."""
    return 20.0 + 1.0 * members
