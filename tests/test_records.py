"""The log's records (rgtbus.telemetry.records): every topic has one record type, each
builder's output is what its schema allows (the recorder validates every message), and the
TypedDicts name the schemas' fields."""

from __future__ import annotations

from rgtbus.telemetry import blocks, pulse_blocks, records, topics
from rgtbus.telemetry.record_rows import decode_rows
from rgtbus.telemetry.recorder import MemoryRecorder
from rgtbus.telemetry.scene import scene_update


def built() -> dict[str, dict]:
    ref = records.message_ref(3, "payload", "{go}", "a", "b")
    return {
        "/medium": records.medium_window(2, 0.2, 200.0, [0.0, 0.4]),
        "/tx/pulse": pulse_blocks.pulse_block_of(
            [records.pulse("a", "b", 4.71, 0.4, 0.005, 40, ref)], 0.005
        ),
        "/rx/spike": records.spikes("b", 0.005, [41, 41, 44], [0, 1, 1], ["a", "b"]),
        "/rx/decode": records.decode("b", 3, "a", "b", "b", "influence", "{go}", 0.3, 9.5, True),
        "/rx/decodes": records.decodes(
            "b",
            [
                (3, "a", "b", "b", "influence", "{go}", 0.3, 9.5, True),
                (3, "c", "a", "b", "influence", "{}", 0.1, 9.5, False),
            ],
        ),
        "/unit/relations": records.relations(
            "b", 9.0, {"a>b": "alliance", "b>a": "alliance"}, {"a-b": "alliance"}, "ab", None
        ),
        "/unit/influences": records.influences("b", 9.5, {"a>b": ["go"], "b>a": []}, 1),
        "/unit/decision": records.decision(
            "b",
            "b",
            9.5,
            {"interval": [[], ["go"]], "frustrated": False, "choice": ["go"], "A": ["go"], "B": []},
            "b = b + not(b)",
            1,
        ),
        "/unit/goal": records.goal(
            "a",
            9.0,
            1,
            3,
            "b",
            [["go"], ["go"]],
            "exact",
            {},
            {},
            "robust",
            1,
            1,
            1,
            ["go"],
            ["go"],
            "b: exactly 1",
        ),
        "/unit/report": {
            "unit": "b",
            "installed": {},
            "polynomial": None,
            "p4": None,
            "sent_relations": {},
            "influences": {},
            "result": {
                "interval": None,
                "frustrated": False,
                "choice": None,
                "canonical": None,
                "A": None,
                "B": None,
                "decided": False,
            },
            "decisions": [],
            "sends": [[0, "id", "a", "id"]],
            "sent_influences": [{}],
            "failure": "b: turn 0: the ID of a decoded as 'x'",
            "failed_at": 12,
            "done_at": None,
            "mind_error": None,
        },
        "/scene": scene_update(
            "b", 9.0, {"a": [0.0, 0.0], "b": [2.0, 0.0, 1.0]}, {"a-b": "conflict"}
        ),
        "/control/parameter": records.control_parameter(
            0.5, 100, 0, "client 1", "channel.noise", 0.1, 0.0, 0.1, True, "channel.noise: 0 -> 0.1"
        ),
        "/control/service": records.control_service(
            0.5,
            100,
            1,
            "client 1",
            "influence",
            {"influence": "a>b=1"},
            True,
            "influence",
            rnd=1,
            turn=3,
            value=1,
        ),
        "/run": records.run_record(
            {
                "scenario": "s",
                "seed": 1,
                "outcome": None,
                "agree": True,
                "sim_seconds": 9.5,
                "error": None,
            }
        ),
    }


def test_every_topic_has_one_record_type_and_builder():
    assert set(records.RECORD_TYPES) == set(topics.TOPICS) - {"/log"}
    assert set(built()) == set(records.RECORD_TYPES)


def test_every_built_record_passes_its_schema():
    rec = MemoryRecorder(validate=True)
    for topic, message in built().items():
        rec.write(topic, message, 1)  # raises on a field the schema does not allow
    rec.write("/trace/a", records.trace("a", 5, 0.025, [0.1], [0.2]), 2)


def test_the_types_name_the_schemas_fields():
    for topic, cls in records.RECORD_TYPES.items():
        block = blocks.schema_of(topic)
        if block is not None:  # a hot topic's protobuf block
            fields = {f.name for f in block.fields}
        else:
            fields = set(topics.load_schema(topics.schema_for(topic))["properties"])
        assert set(cls.__annotations__) == fields, topic  # names only


def test_a_decodes_record_reads_back_as_the_records_of_one_decode_each():
    rows = [
        (1, "a", "b", "a", "id", "id", 0.5, 1.25, True),
        (2, "a", "c", "c", "relation", "conflict", 0.25, 2.5, True),
        (5, "c", "b", "d", "influence", "{go}", 0.0, 2.5, False),
    ]
    rec = MemoryRecorder(validate=True)
    rec.write("/rx/decodes", records.decodes("b", rows), 2_500_000_000)
    ((_, t_ns, back),) = rec.messages
    assert t_ns == 2_500_000_000 and back["t"] == 2.5  # the last decode's time
    assert list(decode_rows(back)) == [records.decode("b", *row) for row in rows]


def test_a_decodes_record_of_indexes_reads_back_as_names():
    """A batch's record holds sender, addressee and channel as indexes into its unit names,
    kind into its kinds and code into its codes (integer arrays): it validates, and reads
    back as the record of names would; a bad index or table is one line naming it."""
    import numpy as np
    import pytest

    from rgtbus.errors import RgtbusError

    rows = [
        (1, "a", "b", "a", "id", "id", 0.5, 1.25, True),
        (2, "a", "c", "c", "relation", "conflict", 0.25, 2.5, True),
    ]
    tables = (("a", "b", "c"), ("id", "relation", "influence"), ("conflict", "id"))
    cols = [
        np.array([1, 2]), np.array([0, 0]), np.array([1, 2]), np.array([0, 2]),
        np.array([0, 1]), np.array([1, 0]), np.array([0.5, 0.25]), np.array([1.25, 2.5]),
        np.array([True, True]),
    ]  # fmt: skip
    rec = MemoryRecorder(validate=True)
    rec.write("/rx/decodes", records.decodes_of_columns("b", cols, tables), 2_500_000_000)
    ((_, _, back),) = rec.messages
    assert back["names"] == ["a", "b", "c"] and back["sender"].tolist() == [0, 0]
    assert list(decode_rows(back)) == [records.decode("b", *row) for row in rows]
    for change, says in (
        ({"code": [1, 2]}, "code 2 is no index into its 2 codes"),
        ({"sender": [0, -1]}, "sender -1 is no index into its 3 names"),
        ({"kind": [0, True]}, "kind True is no index into its 3 kinds"),
        ({"kinds": "id"}, "'kinds' is not a list of names"),
        ({"names": None}, "'names' is not a list of names"),
    ):
        with pytest.raises(RgtbusError, match="/rx/decodes of 'b' at t = 2.5: " + says):
            list(decode_rows({**back, **change}))


def test_a_damaged_decodes_record_is_named():
    import pytest

    from rgtbus.errors import RgtbusError

    good = records.decodes("b", [(1, "a", "b", "a", "id", "id", 0.5, 1.25, True)])
    for column, value, says in (
        ("code", [], "column 'code' is 0 entries, not 1"),
        ("margin", None, "column 'margin' is missing"),
        ("kind", "id", "column 'kind' is str"),
        ("times", None, "column 'times' is missing, not a list"),
        ("times", 1.25, "column 'times' is float, not a list"),
    ):
        bad = {**good}
        if value is None:
            del bad[column]  # type: ignore[misc]
        else:
            bad[column] = value  # type: ignore[literal-required]
        with pytest.raises(RgtbusError, match="/rx/decodes of 'b' at t = 1.25: " + says):
            list(decode_rows(bad))
    with pytest.raises(RgtbusError, match="no decode to log"):
        records.decodes("b", [])


def test_a_report_leaves_out_the_tables_its_last_records_hold_and_a_reader_puts_them_back():
    """``/unit/report`` holds a unit's tables only where they changed since its last
    ``/unit/relations`` or ``/unit/influences`` record (a group's n² tables once a unit, not
    twice); ``full_report`` gives back the report as the unit held it, either way."""
    sent, installed = {"a>b": "alliance"}, {"a-b": "alliance"}
    infl = {"a>b": ["go"]}
    report = {
        **{"unit": "a", "installed": installed, "polynomial": "a+b", "p4": None},
        **{"sent_relations": sent, "influences": infl, "result": {}, "decisions": []},
    }
    rel = records.relations("a", 3.0, dict(sent), dict(installed), "a+b", None)
    table = records.influences("a", 9.0, dict(infl), 1)
    slim = records.slim_report(report, rel, table)
    assert set(slim) == {"unit", "result", "decisions"}
    assert records.full_report(slim, rel, table) == report
    # a table that changed after its record (or no record at all) stays in the report
    later = {**report, "influences": {"a>b": ["stop"]}}
    kept = records.slim_report(later, rel, table)
    assert kept["influences"] == {"a>b": ["stop"]} and "installed" not in kept
    assert records.full_report(kept, rel, table) == later
    other = records.relations("a", 3.0, dict(sent), {"a-b": "conflict"}, "a+b", None)
    assert records.slim_report(report, other, None) == report  # all relations fields or none
    cut = records.full_report(slim, None, None)  # a log cut before the records: empty tables
    assert cut["installed"] == {} and cut["influences"] == {} and cut["polynomial"] is None
