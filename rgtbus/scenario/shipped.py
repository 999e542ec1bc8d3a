"""The scenarios shipped with rgtbus, found by name (``rgtbus run gate``).

In a source checkout they are ``scenarios/`` next to the ``rgtbus/`` package directory;
installed, the package data ``rgtbus/scenarios/`` (setup.py maps the repository's
``scenarios/`` there). Sweep files (``scenarios/sweeps/``) are not scenarios: ``rgtbus
sweeps`` lists them (``shipped_sweeps``) and ``rgtbus sweep NAME`` runs one (``find_sweep``)."""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# A name, not a path: letters, digits, _ and -, ".toml" optional, "sweeps/" for a sweep file.
NAME = re.compile(r"((sweeps|studies)/)?[A-Za-z0-9_-]+(\.toml)?\Z")


@dataclass(frozen=True)
class ShippedScenario:
    """A scenario shipped with the package, as ``rgtbus scenarios`` lists it."""

    name: str  # what to type: rgtbus run NAME
    path: Path
    units: int | None  # None: the file is not a readable scenario
    schedule: str | None
    description: str  # its description, else its first comment line

    def to_json(self) -> dict[str, Any]:
        """The entry as JSON-ready values."""
        return {
            "name": self.name,
            "path": str(self.path),
            "units": self.units,
            "schedule": self.schedule,
            "description": self.description,
        }


def shipped_dir() -> Path | None:
    """Where the shipped scenarios are: installed package data first, then a source checkout."""
    package = Path(__file__).resolve().parent.parent  # rgtbus/
    for where in (package / "scenarios", package.parent / "scenarios"):
        if where.is_dir():
            return where
    return None


def is_name(name: str) -> bool:
    """Whether ``name`` is a plain name a shipped scenario could have (not a path)."""
    return NAME.match(name) is not None


def find_shipped(name: str) -> Path | None:
    """The shipped file called ``name`` (``gate``, ``gate.toml``, ``sweeps/noise``), if any."""
    where = shipped_dir()
    if where is None or not is_name(name):
        return None
    path = where / f"{name.removesuffix('.toml')}.toml"
    return path if path.is_file() else None


def find_sweep(name: str) -> Path | None:
    """The shipped sweep file called ``name`` (``noise``, ``noise.toml``, ``sweeps/noise``)."""
    if not is_name(name):
        return None
    return find_shipped(name if name.startswith("sweeps/") else f"sweeps/{name}")


def find_study(name: str) -> Path | None:
    """The shipped study file called ``name`` (``control_gate``, ``studies/control_gate``)."""
    if not is_name(name) or name.startswith("sweeps/"):
        return None
    return find_shipped(name if name.startswith("studies/") else f"studies/{name}")


def shipped_studies() -> list[Path]:
    """Every shipped study file (``scenarios/studies/*.toml``), by name."""
    where = shipped_dir()
    if where is None or not (where / "studies").is_dir():
        return []
    return sorted((where / "studies").glob("*.toml"))


def shipped_sweeps() -> list[ShippedScenario]:
    """Every shipped sweep file (``scenarios/sweeps/*.toml``), by name (``units`` and
    ``schedule`` are the sweep's base scenario's when it names a shipped one)."""
    where = shipped_dir()
    if where is None or not (where / "sweeps").is_dir():
        return []
    out = []
    for path in sorted((where / "sweeps").glob("*.toml")):
        entry = _summary(path)
        base = _base_of(path)
        out.append(
            ShippedScenario(
                entry.name,
                path,
                base.units if base else None,
                base.schedule if base else None,
                entry.description,
            )
        )
    return out


def _base_of(sweep: Path) -> ShippedScenario | None:
    """The shipped scenario a shipped sweep file runs, if its ``scenario`` names one."""
    try:
        scen = tomllib.loads(sweep.read_text(encoding="utf-8")).get("scenario")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    if not isinstance(scen, str):
        return None
    path = (sweep.parent / scen).resolve()
    if not path.is_file():
        path = find_shipped(scen) or path
    return _summary(path) if path.is_file() else None


def shipped_scenarios() -> list[ShippedScenario]:
    """Every shipped scenario (``scenarios/*.toml``, not the sweeps), by name."""
    where = shipped_dir()
    if where is None:
        return []
    return [_summary(p) for p in sorted(where.glob("*.toml")) if p.is_file()]


def _summary(path: Path) -> ShippedScenario:
    """Read without the full check: one broken file must not hide the others."""
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return ShippedScenario(path.stem, path, None, None, "")
    units = data.get("units")
    proto = data.get("protocol", {})
    schedule = proto.get("schedule", "serial") if isinstance(proto, dict) else None
    description = data.get("description")
    if not isinstance(description, str) or not description.strip():
        description = next(
            (s.lstrip("#").strip() for s in text.splitlines() if s.startswith("#")), ""
        )
    return ShippedScenario(
        name=path.stem,
        path=path,
        units=len(units) if isinstance(units, list) else None,
        schedule=schedule if isinstance(schedule, str) else None,
        description=description,
    )
