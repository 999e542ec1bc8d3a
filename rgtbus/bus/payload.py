"""The wire format of one member's frame: what it transmits, and its promise of silence.

A member transmits pulses (one sample of a magnitude each: the medium stays a sampled waveform,
sent sparsely) and promises "nothing more from me before sample ``promise``" (conservative
synchronisation with null messages, docs/engine.md). A frame may carry no pulse at all (a null
message) and pulses far ahead of its promise (transmissions already planned). Magnitudes at one
sample add up in the order they were sent.

Layout (little-endian, 48-byte header, so the arrays start 8-byte aligned)::

    offset  size  field
    0       4     magic b"RGTB"
    4       1     version (2)
    5       1     flags: bit 0 FINAL (the unit has decided), bit 1 FAILED (it has failed),
                  bit 2 TAGGED (a 32-byte authentication tag follows the magnitudes)
    6       2     reserved, zero
    8       8     sequence number, u64 (1, 2, 3, ... per member)
    16      8     promise, u64 (a sample index; 2**63 - 1: silent for the rest of the run)
    24      8     done_at, u64 (the last sample the member listened to, once FINAL or FAILED)
    32      8     sample rate, f64 (samples per second)
    40      4     count n, u32
    44      4     reserved, zero
    48      8*n   sample indexes, u64, non-decreasing
    48+8n   8*n   magnitudes, f64, finite, |m| <= MAX_MAGNITUDE
    48+16n  32    TAGGED only: HMAC-SHA256 of everything before it (rgtbus.bus.auth)
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from rgtbus.bus.auth import TAG_SIZE, AuthError
from rgtbus.errors import BadInput

MAGIC = b"RGTB"
VERSION = 2
_HEADER = struct.Struct("<4sBBHQQQdII")
HEADER_SIZE = _HEADER.size  # 48
FINAL = 0x01
FAILED = 0x02
TAGGED = 0x04  # on the wire only: never in Frame.flags
_KNOWN_FLAGS = FINAL | FAILED
NEVER = 2**63 - 1  # a promise of silence for the rest of the run
MAX_MAGNITUDE = 1e6  # far above any code; keeps a resonator's sums finite whatever a peer sends
MAX_PULSES = 2**24  # one frame; a run's whole schedule of one unit is far below this
# What a live bus receives (and lets its own units send) in one frame: the pulses a unit plans
# at once (its codes to every other member), with a wide margin. Larger frames are dropped
# before any other work (``dropped_oversize``).
FRAME_PULSES_MIN = 4096
FRAME_PULSES_PER_MEMBER = 256
_EMPTY_I = np.zeros(0, dtype=np.int64)
_EMPTY_F = np.zeros(0, dtype=np.float64)


@dataclass(frozen=True)
class Frame:
    """One frame of one member (see the module docstring)."""

    seq: int
    promise: int
    samples: np.ndarray = field(default_factory=lambda: _EMPTY_I)
    values: np.ndarray = field(default_factory=lambda: _EMPTY_F)
    flags: int = 0
    done_at: int = 0

    @property
    def done(self) -> bool:
        """Whether the member is done (FINAL or FAILED)."""
        return bool(self.flags & (FINAL | FAILED))


def _u64(value: object, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise BadInput(f"frame {what} must be an int, got {value!r}")
    if not 0 <= int(value) <= NEVER:
        raise BadInput(f"frame {what} {value} out of range 0..2**63-1")
    return int(value)


def _check_pulses(samples: np.ndarray, values: np.ndarray) -> None:
    if samples.size != values.size:
        raise BadInput(f"frame has {samples.size} sample indexes for {values.size} values")
    if samples.size > MAX_PULSES:
        raise BadInput(f"frame holds at most {MAX_PULSES} pulses, got {samples.size}")
    if samples.size:
        if samples.min() < 0 or samples.max() > NEVER:
            raise BadInput("frame sample index out of range 0..2**63-1")
        if (samples[1:] < samples[:-1]).any():
            raise BadInput("frame sample indexes are not in order")
        bad = ~np.isfinite(values) | (np.abs(values) > MAX_MAGNITUDE)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise BadInput(
                f"frame magnitude {float(values[k])!r} at sample {int(samples[k])} is not finite "
                f"or beyond ±{MAX_MAGNITUDE:g}"
            )


def encode(
    frame: Frame, sample_rate: float, *, sign: Callable[[bytes], bytes] | None = None
) -> bytes:
    """Header + arrays (+ ``sign(everything before)``, the TAGGED flag set); refuses what
    ``decode`` would refuse."""
    flags = frame.flags
    if isinstance(flags, bool) or not isinstance(flags, int) or flags & ~_KNOWN_FLAGS:
        raise BadInput(f"frame flags {flags!r}: only FINAL (1) and FAILED (2) are defined")
    seq = _u64(frame.seq, "sequence number")
    promise = _u64(frame.promise, "promise")
    done_at = _u64(frame.done_at, "done_at")
    rate = float(sample_rate)
    if not (math.isfinite(rate) and rate > 0):
        raise BadInput(f"frame sample rate must be finite and > 0, got {sample_rate!r}")
    samples = np.asarray(frame.samples)
    values = np.asarray(frame.values)
    if samples.ndim != 1 or values.ndim != 1:
        raise BadInput("frame samples and values must be 1-D")
    if samples.size and not np.issubdtype(samples.dtype, np.integer):
        raise BadInput(f"frame sample indexes must be integers, got {samples.dtype}")
    if values.size and values.dtype != np.float64:
        raise BadInput(f"frame magnitudes must be float64, got {values.dtype}")
    samples = samples.astype(np.int64, copy=False)
    values = values.astype(np.float64, copy=False)
    _check_pulses(samples, values)
    if sign is not None:
        flags |= TAGGED
    header = _HEADER.pack(MAGIC, VERSION, flags, 0, seq, promise, done_at, rate, samples.size, 0)
    body = header + samples.astype("<u8").tobytes() + values.astype("<f8").tobytes()
    if sign is None:
        return body
    tag = sign(body)
    if len(tag) != TAG_SIZE:
        raise BadInput(f"frame tag must be {TAG_SIZE} bytes, got {len(tag)}")
    return body + tag


def max_frame_pulses(members: int) -> int:
    """The most pulses one frame of a run of ``members`` units may carry (see
    ``FRAME_PULSES_PER_MEMBER``): what every bus of the run receives and sends."""
    return max(FRAME_PULSES_MIN, FRAME_PULSES_PER_MEMBER * members)


def frame_size(count: int, *, tagged: bool) -> int:
    """The length in bytes of a frame of ``count`` pulses."""
    return HEADER_SIZE + 16 * count + (TAG_SIZE if tagged else 0)


class Header(NamedTuple):
    """A frame's header, checked on its own (``check_header``): what a receiver can learn of a
    frame without reading its pulses or its tag."""

    flags: int  # without TAGGED
    tagged: bool
    seq: int
    promise: int
    done_at: int
    rate: float
    pulses: int  # the count field


def check_header(data: bytes) -> Header:
    """The header of the frame in ``data``, every header rule checked (magic, version, flags,
    reserved fields, ranges, the length matching the count): O(1), no pulse read. Raises
    RgtbusError (one line) like ``decode``."""
    if not isinstance(data, bytes | bytearray):
        raise BadInput(f"frame must be bytes, got {type(data).__name__}")
    if len(data) < HEADER_SIZE:
        raise BadInput(f"frame too short: {len(data)} bytes, header needs {HEADER_SIZE}")
    magic, version, flags, res1, seq, promise, done_at, rate, count, res2 = _HEADER.unpack_from(
        data
    )
    if magic != MAGIC:
        raise BadInput(f"frame bad magic {magic!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise BadInput(f"frame version {version} unsupported, expected {VERSION}")
    if flags & ~(_KNOWN_FLAGS | TAGGED):
        raise BadInput(f"frame flags 0x{flags:02x} hold unknown bits")
    tagged = bool(flags & TAGGED)
    flags &= ~TAGGED
    if res1 or res2:
        raise BadInput("frame reserved fields not zero")
    if not (math.isfinite(rate) and rate > 0):
        raise BadInput(f"frame sample rate {rate!r} not finite and > 0")
    for what, v in (("sequence number", seq), ("promise", promise), ("done_at", done_at)):
        if v > NEVER:
            raise BadInput(f"frame {what} {v} out of range 0..2**63-1")
    expected = frame_size(count, tagged=tagged)
    if len(data) != expected:
        raise BadInput(
            f"frame length {len(data)} bytes does not match count {count} (expected {expected})"
        )
    return Header(flags, tagged, seq, promise, done_at, rate, count)


def decode(
    data: bytes, *, check: Callable[[bytes, bytes], None] | None = None
) -> tuple[Frame, float]:
    """Inverse of ``encode``: ``(frame, sample_rate)`` with fresh arrays. Raises RgtbusError
    (one line, what is wrong) on anything malformed. With ``check`` (a keyed run) a frame must
    be TAGGED and ``check(body, tag)`` pass (it raises AuthError otherwise); without, a TAGGED
    frame is refused (AuthError: this run has no key to check it with)."""
    flags, tagged, seq, promise, done_at, rate, count = check_header(data)
    expected = len(data)
    if check is not None:
        if not tagged:
            raise AuthError("frame not authenticated (no tag) on a run with a key")
        body = bytes(data[: expected - TAG_SIZE])
        check(body, bytes(data[expected - TAG_SIZE :]))
    elif tagged:
        raise AuthError("frame authenticated with a key this run does not have")
    raw = np.frombuffer(data, dtype="<u8", count=count, offset=HEADER_SIZE)
    if count and raw.max() > NEVER:
        raise BadInput("frame sample index out of range 0..2**63-1")
    samples = raw.astype(np.int64)
    values = np.frombuffer(data, dtype="<f8", count=count, offset=HEADER_SIZE + 8 * count).astype(
        np.float64
    )  # astype copies: the caller owns writable arrays
    _check_pulses(samples, values)
    return Frame(seq, promise, samples, values, flags, done_at), rate


# -- telemetry frames: a unit process's log messages for watchers --------------------------------

_TELEMETRY = struct.Struct("<4sQHH")  # magic, log time ns, topic length, schema length
_TELEMETRY_MAGIC = b"RGT1"


def encode_telemetry(topic: str, schema: str, data: bytes, t_ns: int) -> bytes:
    """One logged message as a zenoh payload: header, topic, schema name, the JSON as logged."""
    tb, sb = topic.encode(), schema.encode()
    return _TELEMETRY.pack(_TELEMETRY_MAGIC, t_ns, len(tb), len(sb)) + tb + sb + data


def decode_telemetry(payload: bytes) -> tuple[str, str, bytes, int]:
    """``(topic, schema, data, t_ns)``; a payload that is not a telemetry frame: ValueError."""
    if len(payload) < _TELEMETRY.size:
        raise ValueError(f"telemetry frame of {len(payload)} bytes: too short")
    magic, t_ns, nt, ns_ = _TELEMETRY.unpack_from(payload)
    if magic != _TELEMETRY_MAGIC:
        raise ValueError(f"not a telemetry frame (magic {magic!r})")
    at = _TELEMETRY.size
    if len(payload) < at + nt + ns_:
        raise ValueError("telemetry frame cut short")
    try:
        topic = payload[at : at + nt].decode()
        schema = payload[at + nt : at + nt + ns_].decode()
    except UnicodeDecodeError:
        raise ValueError("telemetry frame: topic or schema is not UTF-8") from None
    return topic, schema, bytes(payload[at + nt + ns_ :]), t_ns


# -- signed telemetry: a keyed run's telemetry frames ---------------------------------------------
#
# On a run with a key each telemetry frame is wrapped (docs/security.md)::
#
#     offset  size  field
#     0       4     magic b"RGS1"
#     4       16    nonce of the publishing process (its bus's)
#     20      8     sequence number, u64 (1, 2, 3, ... per process and unit)
#     28      ...   the telemetry frame (encode_telemetry)
#     end-32  32    HMAC-SHA256 of everything before it (rgtbus.bus.auth, kind "telemetry")

_SIGNED_TELEMETRY = struct.Struct("<4s16sQ")
_SIGNED_TELEMETRY_MAGIC = b"RGS1"


def sign_telemetry(frame: bytes, nonce: bytes, seq: int, sign: Callable[[bytes], bytes]) -> bytes:
    """``frame`` (an ``encode_telemetry`` frame) wrapped with ``nonce``, ``seq`` and its tag
    ``sign(everything before the tag)``."""
    body = _SIGNED_TELEMETRY.pack(_SIGNED_TELEMETRY_MAGIC, nonce, seq) + frame
    return body + sign(body)


def is_signed_telemetry(payload: bytes) -> bool:
    """Whether ``payload`` starts as a signed telemetry frame (``sign_telemetry``) does."""
    return payload[:4] == _SIGNED_TELEMETRY_MAGIC


def open_signed_telemetry(
    payload: bytes, check: Callable[[bytes, bytes, bytes], None]
) -> tuple[bytes, int, bytes]:
    """``(nonce, seq, telemetry frame)`` of a signed telemetry payload once ``check(nonce,
    body, tag)`` passed (it raises AuthError otherwise); ValueError if ``payload`` is not one."""
    if len(payload) < _SIGNED_TELEMETRY.size + TAG_SIZE or not is_signed_telemetry(payload):
        raise ValueError("not a signed telemetry frame")
    _, nonce, seq = _SIGNED_TELEMETRY.unpack_from(payload)
    body = bytes(payload[:-TAG_SIZE])
    check(nonce, body, bytes(payload[-TAG_SIZE:]))
    return nonce, seq, body[_SIGNED_TELEMETRY.size :]


# -- resend requests: a member asks another for the frames it missed ------------------------------
#
# A receiver that misses frames of a member (a gap before frames it holds, or a member that
# holds the horizon and has said nothing for a while) asks for them again on its own key
# ``rgtbus/<run>/resend/<asker>`` (docs/engine.md, "A frame lost is asked for again")::
#
#     offset  size  field
#     0       4     magic b"RGTQ"
#     4       1     version (1)
#     5       1     flags: bit 2 TAGGED (a 32-byte tag follows, kind "resend", the asker's)
#     6       2     length L of the member's name, u16
#     8       8     the first sequence number missing, u64
#     16      L     the member asked (UTF-8)
#     16+L    32    TAGGED only: HMAC-SHA256 of everything before it (rgtbus.bus.auth)

_RESEND = struct.Struct("<4sBBHQ")
_RESEND_MAGIC = b"RGTQ"
_RESEND_VERSION = 1
MAX_NAME = 255  # bytes of a unit name in a resend request


class ResendAsk(NamedTuple):
    """A request for ``unit``'s frames from sequence number ``first`` on."""

    unit: str
    first: int


def max_resend_size() -> int:
    """The largest resend request a member can send (larger ones are dropped unread)."""
    return _RESEND.size + MAX_NAME + TAG_SIZE


def encode_resend(ask: ResendAsk, *, sign: Callable[[bytes], bytes] | None = None) -> bytes:
    """A resend request (see above), signed when ``sign`` is given."""
    name = ask.unit.encode()
    if not name or len(name) > MAX_NAME:
        raise BadInput(f"resend request: unit name of {len(name)} bytes (1..{MAX_NAME})")
    first = _u64(ask.first, "sequence number")
    flags = TAGGED if sign is not None else 0
    body = _RESEND.pack(_RESEND_MAGIC, _RESEND_VERSION, flags, len(name), first) + name
    return body if sign is None else body + sign(body)


def decode_resend(data: bytes, *, check: Callable[[bytes, bytes], None] | None = None) -> ResendAsk:
    """Inverse of ``encode_resend``; RgtbusError (AuthError for the tag, as ``decode``) on
    anything else."""
    if len(data) < _RESEND.size or len(data) > max_resend_size():
        raise BadInput(f"resend request of {len(data)} bytes")
    magic, version, flags, n, first = _RESEND.unpack_from(data)
    if magic != _RESEND_MAGIC or version != _RESEND_VERSION or flags & ~TAGGED:
        raise BadInput(f"not a resend request (magic {magic!r}, version {version})")
    tagged = bool(flags & TAGGED)
    end = _RESEND.size + n
    if len(data) != end + (TAG_SIZE if tagged else 0):
        raise BadInput(f"resend request of {len(data)} bytes for a name of {n}")
    if check is not None:
        if not tagged:
            raise AuthError("resend request not authenticated (no tag) on a run with a key")
        check(bytes(data[:end]), bytes(data[end:]))
    elif tagged:
        raise AuthError("resend request authenticated with a key this run does not have")
    if first > NEVER:
        raise BadInput(f"resend request: sequence number {first} out of range")
    try:
        unit = bytes(data[_RESEND.size : end]).decode()
    except UnicodeDecodeError:
        raise BadInput("resend request: the unit's name is not UTF-8") from None
    return ResendAsk(unit, first)
