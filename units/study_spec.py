"""What a study runs (docs/studies.md): one unit steering another by reflexive control, over a
grid of channel points, each point a scenario and each of its runs a seed.

A study file (TOML)::

    [study]
    name = "control_gate"
    scenario = "gate"                  # a scenario file (relative to this file) or a shipped name;
                                       # or a family: units = 6, alternatives = 3 (k actions),
                                       # relations = "drawn" (or a table), schedule = "concurrent"
    controller = "a"                   # chooses its influences by the inverse task
    target = "c"
    steer_to = "open"                  # the alternative the controller wants the target to choose
    repair = true                      # [protocol] repair = "arq" (false: none; absent: as given)
    failures = 100                     # a point stops at this many target failures
    budget = 2000                      # or at this many runs
    seed = 0                           # the root of every run's seed
    [grid]
    noise = [0.0, 0.02, 0.04]          # the channel axis: σ, or snr_db = [...]
    repair = [false, true]             # more axes: repair, units, alternatives, any scenario key
    [set]
    "protocol.influence_rounds" = 2    # scenario keys set at every point

Each point's scenario is the base with the controller's goal ``[goals.CONTROLLER] TARGET =
{ want = STEER_TO, mode = "choice" }`` (its other goals dropped), ``[expect]`` dropped, the
repair, the point's keys and its noise. Run ``r`` of point ``p`` has the seed
``SeedSequence(seed, spawn_key=(p, r)).generate_state(1)[0]`` — the ``r``-th child of the
``p``-th child of ``SeedSequence(seed)`` — so any run re-runs alone to the same row:
``rgtbus run DIR/points/point-P.toml --seed SEED``.

An SNR axis gives σ from the point's codebook: SNR (dB) = 20·log10(A / σ) on a link of gain 1,
A the root-mean-square pulse amplitude of every word of the codebook (a link of gain g has the
SNR + 20·log10 g).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import math
import os
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from rgtbus.units.sweep_spec import (
    error_at,
    flatten_keys,
    plain_value,
    read_base,
    read_toml,
    set_key,
)

from rgtbus.errors import BadInput, RgtbusError
from rgtbus.rgt.diagonal import EXACT_VARS
from rgtbus.scenario import Scenario, parse_scenario
from rgtbus.scenario.shipped import find_study
from rgtbus.scenario.values import MAX_LEVEL

STUDY_KEYS = (
    "name", "description", "scenario", "units", "alternatives", "relations", "schedule",
    "controller", "target", "steer_to", "repair", "failures", "budget", "seed",
)  # fmt: skip
TABLES = ("study", "grid", "set")
AXES = ("noise", "snr_db")  # the channel axis: exactly one of them
FAMILY_KEYS = ("units", "alternatives", "relations", "schedule")
# the actions of a family's k: alternatives are their subsets (2^k of them)
ACTIONS = ("alpha", "beta", "gamma", "delta", "epsilon", "zeta")
MAX_BUDGET = 10_000_000
MAX_POINTS = 10_000
DEFAULT_FAILURES = 100
DEFAULT_BUDGET = 2000
ErrorAt = Callable[[str | None, str], RgtbusError]


@dataclass(frozen=True)
class Point:
    """A grid point: its index in the grid (file order: the other axes outer, the channel axis
    inner), its chain (the points sharing every other axis value: the channel axis runs along
    it), its settings (``(key, value)`` in grid order, the channel axis last) and the noise σ
    its runs hear."""

    index: int
    chain: int
    settings: tuple[tuple[str, Any], ...]
    sigma: float

    @property
    def axis_value(self) -> float:
        """The channel axis's value (σ, or the SNR in dB)."""
        return float(self.settings[-1][1])

    def label(self) -> str:
        """``noise=0.04, repair=true``."""
        return ", ".join(f"{k}={_text(v)}" for k, v in self.settings)


@dataclass(frozen=True)
class Study:
    """A study, checked: every point makes a valid scenario (``load_study``, ``make_study``)."""

    where: str  # the study file, or "<study>" for one built from a mapping
    text: str  # its TOML text (a mapping's, written as TOML)
    name: str
    base_path: str | None  # the base scenario file; None for a family
    base_text: str  # the base scenario's TOML text (a family's, generated)
    controller: str
    target: str
    steer_to: str
    repair: bool | None
    failures: int
    budget: int
    seed: int
    axis: str  # "noise" or "snr_db"
    grid: tuple[tuple[str, tuple[Any, ...]], ...]  # every axis, the channel axis last
    sets: tuple[tuple[str, Any], ...]
    family: tuple[tuple[str, Any], ...]  # units, alternatives, relations, schedule; () for a file
    description: str = ""
    points: tuple[Point, ...] = field(default=(), compare=False)
    point_texts: tuple[str, ...] = field(default=(), compare=False, repr=False)

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the study's text and its base scenario's: what ``--resume`` checks."""
        h = hashlib.sha256()
        for part in (self.text, self.base_text):
            h.update(part.encode())
            h.update(b"\0")
        return h.hexdigest()

    @property
    def keys(self) -> list[str]:
        """The grid's axes, the channel axis last."""
        return [k for k, _ in self.grid]

    def chains(self) -> list[list[Point]]:
        """The points of each chain, hardest channel first (σ falling, SNR rising): the order a
        study runs them in, so that a point with no failure ends the easier ones."""
        by: dict[int, list[Point]] = {}
        for p in self.points:
            by.setdefault(p.chain, []).append(p)
        sign = -1.0 if self.axis == "noise" else 1.0
        return [sorted(ps, key=lambda p: (sign * p.axis_value, p.index)) for ps in by.values()]

    def seed_of(self, point: int, run: int) -> int:
        """Run ``run`` of point ``point``'s seed (module docstring)."""
        seq = np.random.SeedSequence(self.seed, spawn_key=(point, run))
        return int(seq.generate_state(1, np.uint32)[0])

    def scenario_of(self, point: int, run: int) -> Scenario:
        """The scenario run ``run`` of point ``point`` runs: the point's, with its seed."""
        return point_scenario(self, point).with_seed(self.seed_of(point, run))

    def with_limits(self, failures: int | None = None, budget: int | None = None) -> Study:
        """The study with another stop (``--failures``, ``--budget``): the same points and
        seeds, so the runs it shares with this one are the same runs."""
        from dataclasses import replace

        return replace(
            self,
            failures=self.failures if failures is None else _count(failures, "failures"),
            budget=self.budget if budget is None else _count(budget, "budget"),
        )


@dataclass(frozen=True)
class RunTask:
    """What a worker needs to run one run of a study, and no more (a study's every point need
    not travel with each run): the point's scenario text and label, the run's seed, the target
    and what it is steered to."""

    point: int
    run: int
    seed: int
    scenario: str
    where: str
    target: str
    steer_to: str

    def scenario_of(self) -> Scenario:
        """The run's scenario: its point's (parsed once a process), with its seed."""
        return _parsed_text(self.scenario, self.where).with_seed(self.seed)


_SCENARIOS: dict[str, Scenario] = {}


def _parsed_text(text: str, where: str) -> Scenario:
    sc = _SCENARIOS.get(text)
    if sc is None:
        if len(_SCENARIOS) > 64:
            _SCENARIOS.clear()
        sc = _SCENARIOS[text] = parse_scenario(text, where)
    return sc


def point_scenario(study: Study, point: int) -> Scenario:
    """A point's scenario (its seed a placeholder: a run sets its own), parsed once a process."""
    return _parsed_text(study.point_texts[point], _where(study, point))


def _where(study: Study, point: int) -> str:
    return f"{study.where} [{study.points[point].label()}]"


def run_task(study: Study, point: int, run: int) -> RunTask:
    """Run ``run`` of point ``point`` as a worker's task."""
    return RunTask(
        point, run, study.seed_of(point, run), study.point_texts[point], _where(study, point),
        study.target, study.steer_to,
    )  # fmt: skip


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _count(value: Any, key: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= MAX_BUDGET:
        raise BadInput(f"{key}: must be an integer 1..{MAX_BUDGET}, got {value!r}")
    return value


# -- reading a study ---------------------------------------------------------------------------


def load_study(source: str | os.PathLike[str] | Mapping[str, Any]) -> Study:
    """A study from a file, the name of a shipped study (``rgtbus studies``: ``control_gate``)
    or a mapping shaped like the file (``{"study": {...}, "grid": {...}}``). Every point is
    checked: an error is one line naming the file, its line and the key (exit 2 on the
    command line)."""
    if isinstance(source, Mapping):
        data = plain_value(dict(source))
        try:
            text = tomli_w.dumps(data)
        except TypeError as exc:
            raise BadInput(f"<study>: not a TOML value: {exc}") from None
        return _study(data, text, "<study>", Path.cwd())
    p = Path(source)
    if not p.exists() and (shipped := find_study(str(source))) is not None:
        p = shipped
    text, data = read_toml(p, "study")
    return _study(data, text, str(p), p.parent)


def _study(data: dict[str, Any], text: str, where: str, here: Path) -> Study:
    def err(key: str | None, reason: str) -> RgtbusError:
        return error_at(where, text, key, reason, "study")

    for key in data:
        if key not in TABLES:
            raise err(key, f"unknown table (a study has {', '.join(f'[{t}]' for t in TABLES)})")
    head = data.get("study")
    if not isinstance(head, dict):
        raise err("study", "a study needs its [study] table")
    for key in head:
        if key not in STUDY_KEYS:
            raise err(key, f"unknown key (allowed: {', '.join(STUDY_KEYS)})")
    grid_table = data.get("grid")
    if not isinstance(grid_table, dict) or not grid_table:
        raise err("grid", "a study needs a [grid] with noise = [...] or snr_db = [...]")
    sets_table = data.get("set", {})
    if not isinstance(sets_table, dict):
        raise err("set", "must be a table of scenario keys")
    name = head.get("name", Path(where).stem if where != "<study>" else "study")
    if not isinstance(name, str) or not name:
        raise err("name", f"must be a non-empty string, got {name!r}")
    description = head.get("description", "")
    if not isinstance(description, str):
        raise err("description", f"must be a string, got {description!r}")
    grid = _grid(list(flatten_keys(grid_table)), err)
    sets = tuple(flatten_keys(sets_table))
    for key, _ in sets:
        if key in dict(grid) or key in ("seed", "units", "goals", "expect") or key in AXES:
            raise err(key, "set by the study itself or its grid, not by [set]")
    family = _family(head, grid, err)
    base_path, base_text = _base(head, family, here, err, name)
    for key in ("controller", "target", "steer_to"):
        if not isinstance(head.get(key), str) or not head[key]:
            raise err(key if key in head else "study", f"the study needs {key} = \"...\"")
    repair = head.get("repair")
    if repair is not None and not isinstance(repair, bool):
        raise err("repair", f"must be true or false, got {repair!r}")
    limits = {}
    for key, default in (("failures", DEFAULT_FAILURES), ("budget", DEFAULT_BUDGET)):
        try:
            limits[key] = _count(head.get(key, default), key)
        except BadInput as exc:
            raise err(key, str(exc).partition(": ")[2]) from None
    seed = head.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise err("seed", f"must be an integer >= 0, got {seed!r}")
    axis = grid[-1][0]
    study = Study(
        where, text, name, base_path, base_text, head["controller"], head["target"],
        head["steer_to"], repair, limits["failures"], limits["budget"], seed, axis, grid, sets,
        family, description,
    )  # fmt: skip
    points, texts = _points(study, err)
    from dataclasses import replace

    return replace(study, points=points, point_texts=texts)


def _grid(items: list[tuple[str, Any]], err: ErrorAt) -> tuple[tuple[str, tuple[Any, ...]], ...]:
    """The grid's axes in file order, the channel axis moved last; each a non-empty list."""
    axes = [k for k, _ in items if k in AXES]
    if len(axes) != 1:
        raise err(
            "grid",
            "names one channel axis: noise = [σ, ...] or snr_db = [dB, ...]"
            + (f" (it names {' and '.join(axes)})" if axes else ""),
        )
    out: list[tuple[str, tuple[Any, ...]]] = []
    for key, values in items:
        if not isinstance(values, list) or not values:
            raise err(key, f"must be a non-empty list of values, got {values!r}")
        if len(values) != len({repr(v) for v in values}):
            raise err(key, "a value is listed twice")
        if key in ("seed", "goals", "expect"):
            raise err(key, "not a grid key of a study (its seeds come from [study] seed)")
        if key in AXES:
            for v in values:
                ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                if not ok or (key == "noise" and not 0 <= v <= MAX_LEVEL):
                    what = f"a σ 0..{MAX_LEVEL:g}" if key == "noise" else "a finite number of dB"
                    raise err(key, f"must be {what}, got {v!r}")
        if key == "repair" and any(not isinstance(v, bool) for v in values):
            raise err(key, f"must be a list of true/false, got {values!r}")
        out.append((key, tuple(values)))
    out.sort(key=lambda kv: kv[0] in AXES)  # stable: the others keep their file order
    n = math.prod(len(v) for _, v in out)
    if n > MAX_POINTS:
        raise err("grid", f"{n} points: at most {MAX_POINTS}")
    return tuple(out)


def _family(
    head: dict[str, Any], grid: tuple[tuple[str, tuple[Any, ...]], ...], err: ErrorAt
) -> tuple[tuple[str, Any], ...]:
    """A family's keys (units, alternatives, relations, schedule), or () for a scenario file."""
    axes = dict(grid)
    named = [k for k in FAMILY_KEYS if k in head]
    if "scenario" in head:
        for k in (*named, *(k for k in ("units", "alternatives") if k in axes)):
            raise err(k, "a study of a scenario file takes its units and actions from it")
        return ()
    for key in ("units", "alternatives"):
        values = axes.get(key, (head.get(key),))
        if key not in head and key not in axes:
            raise err("study", f'names a scenario = "..." or a family: units = N, {key} = ...')
        if key in head and key in axes:
            raise err(key, "set in [study] and in [grid]: one of them")
        low, top = (2, EXACT_VARS) if key == "units" else (1, len(ACTIONS))
        for v in values:
            if not isinstance(v, int) or isinstance(v, bool) or not low <= v <= top:
                raise err(key, f"must be an integer {low}..{top}, got {v!r}")
    relations = head.get("relations", "drawn")
    if not (relations == "drawn" or isinstance(relations, dict)):
        raise err("relations", f'"drawn" (a random decomposable group) or a table: {relations!r}')
    schedule = head.get("schedule", "concurrent")
    if schedule not in ("serial", "concurrent"):
        raise err("schedule", f"serial or concurrent, got {schedule!r}")
    return (
        ("units", head.get("units")),
        ("alternatives", head.get("alternatives")),
        ("relations", relations),
        ("schedule", schedule),
    )


def family_data(name: str, units: int, k: int, relations: Any, schedule: str) -> dict[str, Any]:
    """A family's base scenario: units u1..uN, actions the first k of ``ACTIONS``, relations
    drawn as a random decomposable group (``cograph``) or given, every influence drawn at
    random (the controller's own chosen by its goal), frequencies placed automatically."""
    data: dict[str, Any] = {
        "name": name,
        "description": f"{units} units, {k} actions: a study's family",
        "seed": 0,
        "units": [f"u{i}" for i in range(1, units + 1)],
        "actions": list(ACTIONS[:k]),
        "frequencies": "auto",
        "protocol": {"schedule": schedule},
        "influences": {"policy": "random"},
    }
    if relations == "drawn":
        data["relations"] = {"policy": "cograph"}
    else:
        data["relations"] = {"policy": "fixed", "fixed": dict(relations)}
    return data


def _base(
    head: dict[str, Any], family: tuple[tuple[str, Any], ...], here: Path, err: ErrorAt, name: str
) -> tuple[str | None, str]:
    """The base scenario's path and text (a family's: generated, for its first point)."""
    if family:
        f = dict(family)
        text = tomli_w.dumps(
            family_data(name, f.get("units") or 2, f.get("alternatives") or 1,
                        f["relations"], f["schedule"])
        )  # fmt: skip
        return None, text
    scen = head.get("scenario")
    if not isinstance(scen, str) or not scen:
        raise err("scenario", "must name the base scenario file (or a shipped scenario)")
    path, text = read_base(scen, here, err)
    return str(path), text


def _points(study: Study, err: ErrorAt) -> tuple[tuple[Point, ...], tuple[str, ...]]:
    """Every grid point with its scenario text, each parsed (errors name the point)."""
    others = study.grid[:-1]
    axis, values = study.grid[-1]
    points: list[Point] = []
    texts: list[str] = []
    chains = list(itertools.product(*(v for _, v in others)))
    for c, combo in enumerate(chains):
        settings = tuple(zip((k for k, _ in others), combo, strict=True))
        data = _point_data(study, dict(settings), err)
        amplitude = None
        for v in values:
            if axis == "noise":
                sigma = float(v)
            else:
                if amplitude is None:
                    amplitude = _rms_amplitude(_parsed(study, data, settings, err))
                sigma = amplitude * 10.0 ** (-float(v) / 20.0)
                if not sigma <= MAX_LEVEL:
                    raise err(axis, f"{v!r} dB is σ = {sigma:g}: more than {MAX_LEVEL:g}")
            d = copy.deepcopy(data)
            set_key(d, "channel.noise", sigma)
            point = Point(len(points), c, (*settings, (axis, v)), sigma)
            sc = _parsed(study, d, point.settings, err)
            points.append(point)
            texts.append(sc.text)
    return tuple(points), tuple(texts)


def _point_data(study: Study, settings: dict[str, Any], err: ErrorAt) -> dict[str, Any]:
    """A point's scenario as TOML data, its channel noise not yet set."""
    if study.family:
        f: dict[str, Any] = dict(study.family)
        units: int = settings.get("units", f["units"])
        k: int = settings.get("alternatives", f["alternatives"])
        data = family_data(study.name, units, k, f["relations"], f["schedule"])
    else:
        data = tomllib.loads(study.base_text)
    data.pop("expect", None)
    for key, value in study.sets:
        _set(data, key, value, err)
    repair = settings.get("repair", study.repair)
    if repair is not None:
        _set(data, "protocol.repair", "arq" if repair else "none", err)
    for key, value in settings.items():
        if key not in ("units", "alternatives", "repair"):
            _set(data, key, value, err)
    goals = data.get("goals")
    if not isinstance(goals, dict):
        goals = data["goals"] = {}
    goals[study.controller] = {study.target: {"want": study.steer_to, "mode": "choice"}}
    data["seed"] = 0  # a run sets its own
    return data


def _set(data: dict[str, Any], key: str, value: Any, err: ErrorAt) -> None:
    try:
        set_key(data, key, plain_value(value))
    except BadInput as exc:
        raise err(key, str(exc).removeprefix(f"{key}: ")) from None


def _parsed(
    study: Study, data: dict[str, Any], settings: tuple[tuple[str, Any], ...], err: ErrorAt
) -> Scenario:
    units = data.get("units")
    for key in ("controller", "target"):
        name = getattr(study, key)
        if isinstance(units, list) and name not in units:
            raise err(key, f"unknown unit {name!r} (units: {', '.join(map(str, units))})")
    if study.controller == study.target:
        raise err("target", "the controller steers another unit, not itself")
    point = ", ".join(f"{k}={_text(v)}" for k, v in settings)
    label = f"{study.where} [{point}]"
    try:
        text = tomli_w.dumps(data)
        return parse_scenario(text, label)
    except TypeError as exc:
        raise err("grid", f"not a TOML value: {exc}") from None
    except RgtbusError as exc:
        # the scenario's own words, less its label and the line of the TOML made from it
        inner = str(exc)
        if inner.startswith(label):
            inner = re.sub(r"^:\d+", "", inner[len(label) :]).lstrip(": ")
        section = inner.split(":", 1)[0]
        if section.startswith(f"goals.{study.controller}"):
            key = "steer_to"
        elif study.family and section.startswith("relations"):
            key = "relations"
        else:
            key = "grid" if settings else "scenario"
        raise err(key, f"at {point}: {inner}" if point else inner) from None


def _rms_amplitude(sc: Scenario) -> float:
    """The root-mean-square pulse amplitude of every word of a scenario's codebook."""
    words = np.array(list(sc.codebook.all_words().values()), dtype=float)
    return float(np.sqrt(np.mean(words**2)))


def target_wants(sc: Scenario, steer_to: str) -> list[str]:
    """The alternative ``steer_to`` names, as a decision's ``choice`` lists it."""
    u = sc.universe
    return u.to_list(u.parse_alternative(steer_to))
