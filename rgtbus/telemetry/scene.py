"""The ``/scene`` record: a unit's place and its half of each link, as Foxglove's own
``foxglove.SceneUpdate`` (spheres and lines), for the 3D panel."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

from rgtbus.pairs import relation_key
from rgtbus.telemetry.records import SceneUpdateRecord
from rgtbus.timebase import NS_PER_SECOND, ns

# -- the scene (foxglove.SceneUpdate) ---------------------------------------------------------

SCENE_FRAME = "world"  # the frame every entity is in: the scenario's positions, in metres
RELATION_COLOURS: dict[str, tuple[float, float, float, float]] = {
    "alliance": (0.18, 0.72, 0.35, 1.0),  # green
    "conflict": (0.86, 0.20, 0.18, 1.0),  # red
}
_UNIT_COLOUR = (0.25, 0.47, 0.85, 1.0)
_LABEL_COLOUR = (1.0, 1.0, 1.0, 1.0)


def scene_entity_id(unit: str) -> str:
    """The id of ``unit``'s entity on ``/scene`` (each update replaces the unit's last)."""
    return f"unit/{unit}"


def _xyz(p: Sequence[float]) -> dict[str, float]:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2]) if len(p) > 2 else 0.0}


def _rgba(c: Sequence[float]) -> dict[str, float]:
    return {"r": c[0], "g": c[1], "b": c[2], "a": c[3]}


def _pose(p: Sequence[float]) -> dict[str, Any]:
    return {"position": _xyz(p), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


@functools.lru_cache(maxsize=8)
def _sphere_size(points: tuple[tuple[float, ...], ...]) -> float:
    """A sphere's diameter: a quarter of the closest two units' distance (every unit finds the
    same), so no two spheres touch; 0.25 m where units share a place. Worked out once a group
    (n² distances), not once a message."""
    gaps = [math.dist(a, b) for i, a in enumerate(points) for b in points[i + 1 :]]
    closest = min((g for g in gaps if g > 0), default=0.0)
    return 0.25 * closest if closest > 0 else 0.25


def _list3(p: Sequence[float]) -> list[float]:
    return [float(p[0]), float(p[1]), float(p[2]) if len(p) > 2 else 0.0]


def scene_update(
    unit: str,
    t: float,
    positions: Mapping[str, Sequence[float]],
    installed: Mapping[str, str] | None = None,
) -> SceneUpdateRecord:
    """A ``/scene`` message: ``unit``'s entity (id ``scene_entity_id``) at time ``t``, a sphere
    at its position with its name above it, and, once it holds its relationship table
    (``installed``, ``{"a-b": "alliance" | "conflict"}``), a line from it to the midpoint
    towards each other unit, green for an alliance and red for a conflict as *it* holds it: where
    every unit agrees, each pair's two halves make one line of one colour; a pair drawn in two
    colours is a pair its two units hold differently. ``positions``: every unit's place in metres
    (x y, or x y z) in the frame ``SCENE_FRAME``."""
    here = _list3(positions[unit])
    size = _sphere_size(tuple(tuple(_list3(p)) for p in positions.values()))
    halves: dict[str, list[dict[str, float]]] = {kind: [] for kind in RELATION_COLOURS}
    table = installed or {}
    mine = []  # its pairs, found by their keys (n lookups, not a pass over the n² pairs)
    for other in positions:
        keys = (relation_key(unit, other), relation_key(other, unit))  # either unit first
        key = next((k for k in keys if k in table), None)
        if other != unit and key is not None and table[key] in halves:
            mine.append((key, other))
    for key, other in sorted(mine):  # in the order of the keys
        kind = table[key]
        there = _list3(positions[other])
        middle = [(x + y) / 2 for x, y in zip(here, there, strict=True)]
        halves[kind] += [_xyz(here), _xyz(middle)]
    lines = [
        {
            "type": 2,  # LINE_LIST: each two points a segment
            "pose": _pose((0.0, 0.0, 0.0)),
            "thickness": 4.0,  # pixels (scale_invariant)
            "scale_invariant": True,
            "points": points,
            "color": _rgba(RELATION_COLOURS[kind]),
            "colors": [],
            "indices": [],
        }
        for kind, points in halves.items()
        if points
    ]
    t_ns = ns(t)
    entity = {
        "timestamp": {"sec": t_ns // NS_PER_SECOND, "nsec": t_ns % NS_PER_SECOND},
        "frame_id": SCENE_FRAME,
        "id": scene_entity_id(unit),
        "lifetime": {"sec": 0, "nsec": 0},  # until replaced
        "frame_locked": False,
        "metadata": [{"key": "unit", "value": unit}],
        "arrows": [],
        "cubes": [],
        "spheres": [
            {"pose": _pose(here), "size": _xyz((size, size, size)), "color": _rgba(_UNIT_COLOUR)}
        ],
        "cylinders": [],
        "lines": lines,
        "triangles": [],
        "texts": [
            {
                "pose": _pose((here[0], here[1], here[2] + size)),
                "billboard": True,
                "font_size": 14.0,  # pixels (scale_invariant)
                "scale_invariant": True,
                "color": _rgba(_LABEL_COLOUR),
                "text": unit,
            }
        ],
        "models": [],
    }
    return {"deletions": [], "entities": [entity]}
