"""The wire format of one unit's samples for one window.

Layout (little-endian, 32-byte header so the samples start 8-byte aligned):

    offset  size  field
    0       4     magic b"RGTB"
    4       1     version (1)
    5       1     dtype code (b"d" = float64)
    6       1     flags: bit 0 FINAL (the unit has finished), bit 1 FAILED (it has failed)
    7       5     reserved, zero
    12      8     window index, u64
    20      8     sample rate, f64 (samples per second)
    28      4     count, u32
    32      8*n   samples, float64
"""

from __future__ import annotations

import math
import struct

import numpy as np

from rgtbus.errors import RgtbusError

MAGIC = b"RGTB"
VERSION = 1
DTYPE_F64 = b"d"
_HEADER = struct.Struct("<4sBcB5sQdI")
HEADER_SIZE = _HEADER.size  # 32
_RESERVED = bytes(5)
FINAL = 0x01
FAILED = 0x02
_KNOWN_FLAGS = FINAL | FAILED
_U64_MAX = 2**64 - 1
_U32_MAX = 2**32 - 1


def encode(window: int, sample_rate: float, samples: np.ndarray, flags: int = 0) -> bytes:
    """Header + little-endian float64 samples; refuses what ``decode`` would refuse."""
    if isinstance(flags, bool) or not isinstance(flags, int) or flags & ~_KNOWN_FLAGS:
        raise RgtbusError(f"payload flags {flags!r}: only FINAL (1) and FAILED (2) are defined")
    if isinstance(window, bool) or not isinstance(window, int | np.integer):
        raise RgtbusError(f"payload window must be an int, got {window!r}")
    if not 0 <= window <= _U64_MAX:
        raise RgtbusError(f"payload window {window} out of range 0..2**64-1")
    rate = float(sample_rate)
    if not (math.isfinite(rate) and rate > 0):
        raise RgtbusError(f"payload sample rate must be finite and > 0, got {sample_rate!r}")
    arr = np.asarray(samples)
    if arr.ndim != 1:
        raise RgtbusError(f"payload samples must be 1-D, got shape {arr.shape}")
    if arr.dtype != np.float64:
        raise RgtbusError(f"payload samples must be float64, got {arr.dtype}")
    if arr.size > _U32_MAX:
        raise RgtbusError(f"payload holds at most 2**32-1 samples, got {arr.size}")
    if not np.isfinite(arr).all():
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise RgtbusError(f"payload sample {bad} is not finite: {float(arr[bad])!r}")
    header = _HEADER.pack(MAGIC, VERSION, DTYPE_F64, flags, _RESERVED, int(window), rate, arr.size)
    return header + arr.astype("<f8", copy=False).tobytes()


def decode(data: bytes) -> tuple[int, float, np.ndarray]:
    """Inverse of ``encode``: ``(window, sample_rate, samples)``; samples are a fresh float64
    array. Raises RgtbusError (one line, what is wrong) on anything malformed."""
    window, rate, samples, _ = decode_frame(data)
    return window, rate, samples


def decode_frame(data: bytes) -> tuple[int, float, np.ndarray, int]:
    """``decode`` plus the flags byte: ``(window, sample_rate, samples, flags)``."""
    if not isinstance(data, bytes | bytearray):
        raise RgtbusError(f"payload must be bytes, got {type(data).__name__}")
    if len(data) < HEADER_SIZE:
        raise RgtbusError(f"payload too short: {len(data)} bytes, header needs {HEADER_SIZE}")
    magic, version, dtype, flags, reserved, window, rate, count = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise RgtbusError(f"payload bad magic {magic!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise RgtbusError(f"payload version {version} unsupported, expected {VERSION}")
    if dtype != DTYPE_F64:
        raise RgtbusError(f"payload dtype code {dtype!r} unsupported, expected {DTYPE_F64!r}")
    if flags & ~_KNOWN_FLAGS:
        raise RgtbusError(f"payload flags 0x{flags:02x} hold unknown bits")
    if reserved != _RESERVED:
        raise RgtbusError(f"payload reserved bytes not zero: {reserved.hex()}")
    if not (math.isfinite(rate) and rate > 0):
        raise RgtbusError(f"payload sample rate {rate!r} not finite and > 0")
    expected = HEADER_SIZE + 8 * count
    if len(data) != expected:
        raise RgtbusError(
            f"payload length {len(data)} bytes does not match count {count} (expected {expected})"
        )
    samples = np.frombuffer(data, dtype="<f8", count=count, offset=HEADER_SIZE).astype(
        np.float64
    )  # astype copies: the caller owns a writable array
    if not np.isfinite(samples).all():
        bad = int(np.flatnonzero(~np.isfinite(samples))[0])
        raise RgtbusError(f"payload sample {bad} is not finite: {float(samples[bad])!r}")
    return window, rate, samples, flags
