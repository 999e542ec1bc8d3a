"""A hot topic's rows three ways: the log's JSON today, the protobuf library, the block codec.

    python -m benchmarks.bench_codec [--rows 1000000] [--block 10000] [--repeat 5]

The rows are a table of decodes as a 100-unit run writes them (issue 51: ``/rx/decodes`` is
most of the log's bytes and CPU): time (double), unit, sender and code (fixed32 indexes),
margin (float), accepted (bool), cut into blocks of ``--block`` rows. Each form encodes every
block to bytes and decodes the bytes back to NumPy columns of the same dtypes:

- **JSON**: today's writer (``message_json.encode_json`` of the columns) and reader (orjson, then
  ``np.asarray`` per column);
- **protobuf library**: a message class built from the codec's own descriptor set, its
  repeated fields ``extend``-ed from the arrays and ``SerializeToString``; back through
  ``FromString`` and ``np.asarray`` per column;
- **codec**: ``rgtbus.telemetry.codec.encode`` / ``decode`` (views of the message's bytes).

The table gives, median of the repeats: seconds to encode and to decode every block, rows a
second, the bytes written, and each figure as a ratio to JSON's, measured in the same run on
the same rows. Every form's decoded columns are checked equal to the rows.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import orjson

from rgtbus.telemetry.codec import BlockSchema, Field, decode, encode, file_descriptor_set
from rgtbus.telemetry.message_json import encode_json

DECODES = BlockSchema(
    "rgtbus.bench.Decodes",
    (
        Field("t", 1, "double", repeated=True, table="rows"),
        Field("unit", 2, "fixed32", repeated=True, table="rows"),
        Field("sender", 3, "fixed32", repeated=True, table="rows"),
        Field("code", 4, "fixed32", repeated=True, table="rows"),
        Field("margin", 5, "float", repeated=True, table="rows"),
        Field("accepted", 6, "bool", repeated=True, table="rows"),
    ),
)
DTYPES = {f.name: (np.dtype("?") if f.kind == "bool" else f.dtype) for f in DECODES.fields}

Columns = dict[str, np.ndarray]


def rows(n: int, seed: int = 0) -> Columns:
    """``n`` decode rows, 100 units hearing 100 senders, in time order."""
    rng = np.random.default_rng(seed)
    return {
        "t": np.sort(rng.uniform(0, 3600, n)),
        "unit": rng.integers(0, 100, n).astype("<u4"),
        "sender": rng.integers(0, 100, n).astype("<u4"),
        "code": rng.integers(0, 8, n).astype("<u4"),
        "margin": rng.uniform(0, 1, n).astype("<f4"),
        "accepted": rng.uniform(0, 1, n) < 0.97,
    }


def blocks_of(table: Columns, size: int) -> list[Columns]:
    n = len(table["t"])
    return [{k: v[i : i + size] for k, v in table.items()} for i in range(0, n, size)]


def _library() -> Any:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set(DECODES))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(DECODES.name))


def forms() -> dict[str, tuple[Callable[[Columns], bytes], Callable[[bytes], Columns]]]:
    library = _library()

    def json_out(block: Columns) -> bytes:
        return encode_json(block)

    def json_in(data: bytes) -> Columns:
        got = orjson.loads(data)
        return {k: np.asarray(got[k], DTYPES[k]) for k in DTYPES}

    def pb_out(block: Columns) -> bytes:
        message = library()
        for k, v in block.items():
            getattr(message, k).extend(v.tolist())
        return bytes(message.SerializeToString())

    def pb_in(data: bytes) -> Columns:
        message = library.FromString(data)
        return {k: np.asarray(getattr(message, k), DTYPES[k]) for k in DTYPES}

    def codec_out(block: Columns) -> bytes:
        return encode(DECODES, block)

    def codec_in(data: bytes) -> Columns:
        got = decode(DECODES, data, max_rows=1 << 24)
        return {k: got[k] for k in DTYPES}  # type: ignore[misc]

    return {
        "JSON (today's log)": (json_out, json_in),
        "protobuf library": (pb_out, pb_in),
        "codec (packed fixed-width)": (codec_out, codec_in),
    }


def measure(blocks: list[Columns], repeat: int) -> list[dict[str, Any]]:
    out = []
    for name, (write, read) in forms().items():
        enc, dec = [], []
        for _ in range(repeat):
            t0 = time.perf_counter()
            data = [write(b) for b in blocks]
            t1 = time.perf_counter()
            back = [read(d) for d in data]
            t2 = time.perf_counter()
            enc.append(t1 - t0)
            dec.append(t2 - t1)
        for b, got in zip(blocks, back, strict=True):
            for k, v in b.items():
                if not np.array_equal(got[k], v) or got[k].dtype != DTYPES[k]:
                    raise SystemExit(f"{name}: column {k} read back differently")
        out.append(
            {
                "form": name,
                "encode_s": statistics.median(enc),
                "decode_s": statistics.median(dec),
                "bytes": sum(len(d) for d in data),
            }
        )
    return out


def table(results: list[dict[str, Any]], n: int) -> str:
    base = results[0]
    lines = [
        "| form | encode s | encode rows/s | vs JSON | decode s | decode rows/s | vs JSON "
        "| MB written | vs JSON |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['form']} | {r['encode_s']:.3f} | {n / r['encode_s']:,.0f} "
            f"| {r['encode_s'] / base['encode_s']:.2f}x | {r['decode_s']:.3f} "
            f"| {n / r['decode_s']:,.0f} | {r['decode_s'] / base['decode_s']:.2f}x "
            f"| {r['bytes'] / 1e6:.1f} | {r['bytes'] / base['bytes']:.2f}x |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--block", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    blocks = blocks_of(rows(args.rows), args.block)
    results = measure(blocks, args.repeat)
    print(
        f"## {args.rows:,} decode rows in blocks of {args.block:,}, median of {args.repeat} "
        f"({platform.machine()}, one core, numpy {np.__version__})\n"
    )
    print(table(results, args.rows))


if __name__ == "__main__":
    main()
