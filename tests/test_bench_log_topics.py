"""``benchmarks.bench_log_topics``: its split is of the log the run wrote (not timed here)."""

from __future__ import annotations

from benchmarks.bench_log_topics import child


def test_the_split_holds_every_topic_of_the_log_and_no_more():
    got = child(6, True)
    topics = got["topics"]
    assert {"/tx/pulse", "/rx/decodes", "/rx/spike", "/unit/report", "/run"} <= set(topics)
    assert all(r["messages"] > 0 and r["zstd_mb"] > 0 for r in topics.values())
    # compressed alone, each topic takes less room than its bytes, and the file (chunks of
    # every topic, with their indexes and schemas) more than the sum of those
    assert all(r["zstd_mb"] <= r["raw_mb"] + 1e-4 for r in topics.values())
    assert got["file_mb"] >= sum(r["zstd_mb"] for r in topics.values()) * 0.5
    assert child(6, False)["topics"] == {}  # no log: nothing split
