"""``/scene``: a spatial scenario's units and links as Foxglove's own ``foxglove.SceneUpdate``
(docs/foxglove.md, "Units where they stand"). Foxglove's side is the judge: every message is
built again as the foxglove SDK's ``foxglove.messages`` objects (generated from
``@foxglove/schemas``: an unknown field or a wrong type is refused) and encoded, every field of
the official schema is written, and the shipped layout's 3D panel is the SDK's own config."""

from __future__ import annotations

import io
import json
import math
import re
from functools import cache
from pathlib import Path
from typing import Any

import foxglove.layouts as fl
import foxglove.messages as fm
import pytest
from mcap.reader import make_reader
from rgtbus.units.group import run_group
from same_run import plain

from rgtbus.scenario import load_scenario, parse_scenario
from rgtbus.telemetry import McapRecorder, read_log, records, topics
from rgtbus.telemetry.scene import RELATION_COLOURS, SCENE_FRAME, scene_update
from rgtbus.telemetry.validate import errors

ROOT = Path(__file__).resolve().parents[1]
SPATIAL = ("robots_on_a_plane", "robots_in_a_field")

# a field of each official message type -> the type of its value (a list: of each item)
_NESTED: dict[str, dict[str, Any]] = {
    "SceneUpdate": {"deletions": ["SceneEntityDeletion"], "entities": ["SceneEntity"]},
    "SceneEntity": {
        "timestamp": "Timestamp", "lifetime": "Duration", "metadata": ["KeyValuePair"],
        "arrows": ["ArrowPrimitive"], "cubes": ["CubePrimitive"], "spheres": ["SpherePrimitive"],
        "cylinders": ["CylinderPrimitive"], "lines": ["LinePrimitive"],
        "triangles": ["TriangleListPrimitive"], "texts": ["TextPrimitive"],
        "models": ["ModelPrimitive"],
    },
    "SceneEntityDeletion": {"timestamp": "Timestamp", "type": "SceneEntityDeletionType"},
    "SpherePrimitive": {"pose": "Pose", "size": "Vector3", "color": "Color"},
    "LinePrimitive": {
        "type": "LinePrimitiveLineType", "pose": "Pose", "points": ["Point3"], "color": "Color",
        "colors": ["Color"],
    },
    "TextPrimitive": {"pose": "Pose", "color": "Color"},
    "Pose": {"position": "Vector3", "orientation": "Quaternion"},
}  # fmt: skip
_ENUMS = {
    "LinePrimitiveLineType": ("LineStrip", "LineLoop", "LineList"),
    "SceneEntityDeletionType": ("MatchingId", "All"),
}


def _official_fields(type_name: str) -> list[str]:
    """The fields of an official message type, as its SDK class documents them (generated
    from @foxglove/schemas)."""
    return re.findall(r":param (\w+):", getattr(fm, type_name).__doc__)


def official(type_name: str, value: Any) -> Any:
    """``value`` (a message as logged) built as the SDK's ``foxglove.messages.<type_name>``:
    every field the official schema has must be there, and nothing else."""
    if type_name in _ENUMS:
        return getattr(getattr(fm, type_name), _ENUMS[type_name][value])
    if type_name in ("Timestamp", "Duration"):
        return getattr(fm, type_name)(sec=value["sec"], nsec=value["nsec"])
    assert sorted(value) == sorted(_official_fields(type_name)), type_name
    nested = _NESTED.get(type_name, {})
    kwargs = {}
    for name, v in value.items():
        kind = nested.get(name)
        if isinstance(kind, list):
            kwargs[name] = [official(kind[0], item) for item in v]
        elif kind is not None:
            kwargs[name] = official(kind, v)
        else:
            kwargs[name] = v
    return getattr(fm, type_name)(**kwargs)


@cache
def scene_of(name: str) -> tuple[list[tuple[int, dict[str, Any]]], Any]:
    """A scenario's ``/scene`` messages (log time, message) and the scenario."""
    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    run_group(sc, "memory", rec)
    rec.close()
    log = read_log(io.BytesIO(buf.getvalue()))
    scene = [(t, m) for topic, t, m in log.messages if topic == records.SCENE]
    summary = make_reader(io.BytesIO(buf.getvalue())).get_summary()
    assert summary is not None
    schemas = {s.name: s for s in summary.schemas.values()}
    return scene, (sc, schemas)


@pytest.mark.parametrize("name", SPATIAL)
def test_every_scene_message_is_foxgloves_own_scene_update(name):
    scene, (_, schemas) = scene_of(name)
    assert scene
    schema = schemas["foxglove.SceneUpdate"]
    assert schema.encoding == topics.SCHEMA_ENCODING
    assert json.loads(schema.data)["title"] == "foxglove.SceneUpdate"
    for _, message in scene:
        assert errors(message, topics.load_schema("foxglove.SceneUpdate")) == []
        encoded = official("SceneUpdate", message).encode()  # the SDK takes every field
        assert len(encoded) > 0


def test_the_official_schema_refuses_what_is_not_in_it():
    message = scene_update("a", 1.0, {"a": [0, 0], "b": [1, 0]}, {"a-b": "alliance"})
    bad = json.loads(json.dumps(message))
    bad["entities"][0]["spheres"][0]["colour"] = bad["entities"][0]["spheres"][0].pop("color")
    with pytest.raises(AssertionError):
        official("SceneUpdate", bad)
    wrong = json.loads(json.dumps(message))
    wrong["entities"][0]["frame_id"] = 7
    with pytest.raises(TypeError):
        official("SceneUpdate", wrong)


@pytest.mark.parametrize("name", SPATIAL)
def test_each_unit_is_a_sphere_with_its_name_then_its_half_of_each_link(name):
    scene, (sc, _) = scene_of(name)
    positions = sc.channel.positions
    by_unit: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for t, m in scene:
        (entity,) = m["entities"]
        by_unit.setdefault(entity["id"].removeprefix("unit/"), []).append((t, entity))
    assert sorted(by_unit) == sorted(sc.units)
    for unit, entities in by_unit.items():
        (t0, first), (t1, last) = entities  # begun, then its table installed
        assert t0 == 0 < t1
        assert (last["timestamp"]["sec"] * 10**9 + last["timestamp"]["nsec"]) == t1
        for e in (first, last):
            (sphere,) = e["spheres"]
            where = sphere["pose"]["position"]
            assert [where["x"], where["y"], where["z"]] == pytest.approx(
                list(positions[unit]) + [0.0] * (3 - len(positions[unit]))
            )
            assert [t["text"] for t in e["texts"]] == [unit]
        assert first["lines"] == []
    # every pair's two halves meet at its midpoint in the colour of the relation both hold
    halves: dict[frozenset[str], list[tuple[str, tuple[float, ...]]]] = {}
    for unit, entities in by_unit.items():
        last = entities[-1][1]
        for line in last["lines"]:
            colour = next(k for k, c in RELATION_COLOURS.items()
                          if tuple(line["color"].values()) == c)  # fmt: skip
            pts = [(p["x"], p["y"], p["z"]) for p in line["points"]]
            for start, end in zip(pts[::2], pts[1::2], strict=True):
                other = min((u for u in sc.units if u != unit),
                            key=lambda u: math.dist(end, _mid(positions, unit, u)))  # fmt: skip
                assert end == pytest.approx(_mid(positions, unit, other))
                halves.setdefault(frozenset((unit, other)), []).append((colour, start))
    n = len(sc.units)
    assert len(halves) == n * (n - 1) // 2
    assert all(len(h) == 2 and h[0][0] == h[1][0] for h in halves.values())


def _mid(positions: Any, a: str, b: str) -> tuple[float, ...]:
    pa = list(positions[a]) + [0.0] * (3 - len(positions[a]))
    pb = list(positions[b]) + [0.0] * (3 - len(positions[b]))
    return tuple((x + y) / 2 for x, y in zip(pa, pb, strict=True))


def test_a_pair_held_differently_is_drawn_in_two_colours():
    positions = {"a": [0.0, 0.0], "b": [4.0, 0.0]}
    a = scene_update("a", 2.0, positions, {"a-b": "alliance"})["entities"][0]
    b = scene_update("b", 2.0, positions, {"a-b": "conflict"})["entities"][0]
    (la,), (lb,) = a["lines"], b["lines"]
    assert la["points"] == [{"x": 0.0, "y": 0.0, "z": 0.0}, {"x": 2.0, "y": 0.0, "z": 0.0}]
    assert lb["points"] == [{"x": 4.0, "y": 0.0, "z": 0.0}, {"x": 2.0, "y": 0.0, "z": 0.0}]
    assert la["color"] != lb["color"]
    assert a["spheres"][0]["size"]["x"] == 1.0  # a quarter of the closest distance


def test_a_scenario_without_positions_logs_no_scene():
    text = (ROOT / "scenarios" / "gate.toml").read_text()
    sc = parse_scenario(text, "gate.toml")
    assert not sc.channel.positions
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    run_group(sc, "memory", rec)
    rec.close()
    log = read_log(io.BytesIO(buf.getvalue()))
    assert records.SCENE not in {topic for topic, _, _ in log.messages}


def test_the_shipped_layouts_3d_panel_is_the_sdks_own_config():
    layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    config = dict(layout["configById"]["3D!rgtbus-scene"])
    config.pop("foxglovePanelTitle")
    sdk = fl.ThreeDeeConfig(
        topics={records.SCENE: fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
        camera_state=fl.ThreeDeeCameraState(
            distance=30.0, perspective=False, phi=0.0, target=(0.0, 0.0, 0.0),
            target_offset=(-0.75, 0.75, 0.0), theta_offset=0.0,
        ),
        follow_tf=SCENE_FRAME,
        follow_mode="follow-none",
    )  # fmt: skip
    panel = json.loads(fl.Layout(content=fl.ThreeDeePanel(config=sdk)).to_json())["content"]
    assert config == panel["config"]
    scene, _ = scene_of("robots_on_a_plane")
    assert {e["frame_id"] for _, m in scene for e in m["entities"]} == {config["followTf"]}


def test_verify_compares_the_scene_and_reads_a_log_written_before_it():
    """``replay --verify`` holds every ``/scene`` message to the re-run's; a log of an rgtbus
    before ``/scene`` (none at all) verifies all the same."""
    from rgtbus.units.rerun import verify_log

    sc = load_scenario(ROOT / "scenarios" / "robots_on_a_plane.toml")
    buf = io.BytesIO()
    rec = McapRecorder(buf)
    run_group(sc, "memory", rec)
    rec.close()
    data = buf.getvalue()
    report = verify_log(io.BytesIO(data))
    assert report.ok and report.checked[records.SCENE] == 8

    def rewritten(keep) -> bytes:
        messages, metadata = read_log(io.BytesIO(data))
        out = io.BytesIO()
        w = McapRecorder(out)
        for name, values in metadata.items():
            w.metadata(name, values)
        for topic, t, m in messages:
            m = keep(topic, json.loads(json.dumps(m, default=plain)))
            if m is not None:
                w.write(topic, m, t)
        w.close()
        return out.getvalue()

    older = rewritten(lambda topic, m: None if topic == records.SCENE else m)
    assert verify_log(io.BytesIO(older)).ok

    def moved(topic: str, m: Any) -> Any:
        if topic == records.SCENE and m["entities"][0]["id"] == "unit/b":
            m["entities"][0]["spheres"][0]["pose"]["position"]["x"] += 1.0
        return m

    bad = verify_log(io.BytesIO(rewritten(moved)))
    assert not bad.ok and {x.topic for x in bad.mismatches} == {records.SCENE}
