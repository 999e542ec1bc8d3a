"""Closing a run to outsiders: a shared secret authenticates every frame and hello.

With a key, every payload on the bus carries an HMAC-SHA256 tag (docs/security.md)::

    tag = HMAC-SHA256(key, ctx(kind) ‖ ctx(run id) ‖ ctx(unit) ‖ ctx(nonce) ‖ ctx(body))

where ``ctx(x)`` is the 8-byte little-endian length of ``x`` followed by ``x`` (no two
different field lists give the same message) and ``nonce`` is the 16 random bytes the sending
process drew when it opened its bus. A frame's body holds its sequence number, so a frame
replayed within a run is a duplicate and one replayed from an earlier run (same run id, same
key) fails its tag: that process's nonce is not the one its hello announced this time. Hellos
prove they are fresh by holding the hearer's nonce in their view (rgtbus.bus.hello).

Pure: no transport, no I/O but ``load_key``.
"""

from __future__ import annotations

import os

from rgtbus.errors import BadInput, IOFailure

TAG_SIZE = 32
NONCE_SIZE = 16
KEY_MIN = 16  # bytes: below this a guessed key is a real risk
KEY_MAX = 4096


class AuthError(BadInput):
    """A payload without a valid tag (dropped and counted, never raised out of a bus)."""


def _field(b: bytes) -> bytes:
    return len(b).to_bytes(8, "little") + b


def tag(key: bytes, kind: str, run_id: str, unit: str, nonce: bytes, body: bytes) -> bytes:
    """The HMAC-SHA256 tag of ``body`` sent by ``unit`` (its process's ``nonce``) in a run."""
    import hmac  # loaded when first needed (with hashlib): an open run (no key) never tags
    from hashlib import sha256

    msg = b"".join(_field(x) for x in (kind.encode(), run_id.encode(), unit.encode(), nonce, body))
    return hmac.new(key, msg, sha256).digest()


def check_tag(
    key: bytes, kind: str, run_id: str, unit: str, nonce: bytes, body: bytes, got: bytes
) -> None:
    """AuthError unless ``got`` is the tag of ``body`` (compared in constant time)."""
    import hmac

    if not hmac.compare_digest(tag(key, kind, run_id, unit, nonce, body), got):
        raise AuthError(
            f"{kind} of {unit!r}: bad authentication tag (wrong key, forged or replayed)"
        )


def load_key(path: str | os.PathLike[str]) -> bytes:
    """The shared secret in the file at ``path``: its bytes, without trailing whitespace (a key
    written by ``head -c 32 /dev/urandom | base64 > FILE`` and by an editor read the same).
    RgtbusError (one line, naming the file) if unreadable, shorter than 16 bytes or over 4 KiB."""
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            raw = f.read(KEY_MAX + 1)
    except OSError as e:
        raise IOFailure(f"key file {name!r}: {e.strerror or e}") from None
    if len(raw) > KEY_MAX:
        raise BadInput(f"key file {name!r}: more than {KEY_MAX} bytes (is it a key?)")
    key = raw.rstrip(b" \t\r\n")
    if len(key) < KEY_MIN:
        raise BadInput(
            f"key file {name!r}: {len(key)} bytes of key, need at least {KEY_MIN} "
            "(e.g. head -c 32 /dev/urandom | base64 > FILE)"
        )
    return key


def check_key(key: object) -> bytes | None:
    """A bus's ``key`` option: None (an open run) or at least 16 bytes."""
    if key is None:
        return None
    if not isinstance(key, bytes | bytearray) or len(key) < KEY_MIN:
        raise BadInput(f"bus key must be None or at least {KEY_MIN} bytes")
    return bytes(key)
