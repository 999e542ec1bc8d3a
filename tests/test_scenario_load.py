"""Loading a scenario by path, by TOML text or by a shipped scenario's name; ``rgtbus
scenarios`` lists the shipped ones."""

import json
from pathlib import Path

import pytest

from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.scenario import (
    ShippedScenario,
    find_shipped,
    load_scenario,
    parse_scenario,
    shipped_dir,
    shipped_scenarios,
)
from rgtbus.scenario import shipped as shipped_module

ROOT = Path(__file__).resolve().parent.parent
GATE = ROOT / "scenarios" / "gate.toml"
SHIPPED = sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))

SMALL = """name = "small"
units = ["a", "b"]
actions = ["go"]
[influences]
policy = "uniform"
value = 1
"""


# -- TOML text ---------------------------------------------------------------------------------


def test_text_loads_as_the_file_does():
    by_text, by_path = load_scenario(GATE.read_text()), load_scenario(GATE)
    assert by_text.path == "<text>" and by_text.text == by_path.text
    assert by_text.units == by_path.units and by_text.influences.pairs == by_path.influences.pairs
    assert by_text.frequencies == by_path.frequencies and by_text.timing == by_path.timing
    assert load_scenario(SMALL).units == ("a", "b")


def test_text_errors_name_text_and_line():
    text = 'name = "t"\nunits = ["a", "b"]\nactions = ["go"]\n[timing]\nsample_rate = -5\n'
    with pytest.raises(RgtbusError) as err:
        load_scenario(text)
    assert str(err.value) == "<text>:5: timing.sample_rate: must be positive, got -5"
    with pytest.raises(RgtbusError, match=r"^<text>:2: not valid TOML"):
        load_scenario('name = "t"\nunits = = 1\n')


# -- shipped names -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["gate", "gate.toml"])
def test_shipped_name_loads_from_any_directory(tmp_path, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    sc = load_scenario(name)
    assert sc.name == "gate" and sc.text == GATE.read_text()
    assert Path(sc.path).resolve() == GATE.resolve()
    assert load_scenario(Path(name)).text == sc.text


def test_a_file_of_that_name_comes_first(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "gate.toml").write_text(SMALL)
    assert load_scenario("gate.toml").name == "small"  # the file here, not the shipped gate
    assert load_scenario("gate").name == "gate"  # no file called "gate": the shipped one


def test_unknown_name_is_one_line_naming_the_command(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RgtbusError) as err:
        load_scenario("no_such_scenario")
    msg = str(err.value)
    assert msg.startswith("cannot read scenario 'no_such_scenario': No such file or directory")
    assert "rgtbus scenarios" in msg and "\n" not in msg
    # A path, not a name: today's message, no hint.
    with pytest.raises(RgtbusError) as err:
        load_scenario("no/such/dir.toml")
    assert str(err.value) == "cannot read scenario 'no/such/dir.toml': No such file or directory"


def test_a_shipped_sweep_is_not_a_scenario(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert find_shipped("sweeps/noise") == shipped_dir() / "sweeps" / "noise.toml"
    with pytest.raises(RgtbusError, match=r"^cannot read scenario 'sweeps/noise': .* sweep file"):
        load_scenario("sweeps/noise")


@pytest.mark.parametrize("name", ["../gate", "/gate", "gate/", "ga te", "", "sweeps/../gate"])
def test_only_plain_names_are_looked_up(name):
    assert find_shipped(name) is None


def test_shipped_dir_installed_or_source_checkout(tmp_path, monkeypatch):
    fake = tmp_path / "site" / "rgtbus" / "scenario" / "shipped.py"
    monkeypatch.setattr(shipped_module, "__file__", str(fake))
    assert shipped_dir() is None and find_shipped("gate") is None and shipped_scenarios() == []
    checkout = tmp_path / "site" / "scenarios"  # a source checkout: next to rgtbus/
    checkout.mkdir(parents=True)
    (checkout / "mine.toml").write_text(SMALL)
    assert find_shipped("mine") == checkout / "mine.toml"
    installed = tmp_path / "site" / "rgtbus" / "scenarios"  # installed package data: first
    installed.mkdir(parents=True)
    (installed / "mine.toml").write_text(SMALL)
    assert shipped_dir() == installed and find_shipped("mine.toml") == installed / "mine.toml"
    assert [s.name for s in shipped_scenarios()] == ["mine"]


# -- the list ----------------------------------------------------------------------------------


def test_shipped_scenarios_are_the_scenario_files():
    found = shipped_scenarios()
    assert [s.name for s in found] == SHIPPED and "noise" not in SHIPPED
    gate = next(s for s in found if s.name == "gate")
    assert gate == ShippedScenario(
        "gate", gate.path, 4, "serial", "Example 3: abc+d, robot d asks for help and the gate opens"
    )
    assert gate.path.resolve() == GATE.resolve()


@pytest.mark.parametrize("entry", shipped_scenarios(), ids=lambda s: s.name)
def test_every_listed_scenario_loads_by_name(entry):
    sc = load_scenario(entry.name)
    assert sc.name == entry.name and Path(sc.path) == entry.path
    assert len(sc.units) == entry.units and sc.protocol.schedule == entry.schedule


def test_scenarios_command_text(capsys):
    assert main(["scenarios"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["NAME", "UNITS", "SCHEDULE", "PATH"]
    rows = {line.split()[0]: line.split() for line in lines[1:]}
    assert sorted(rows) == SHIPPED
    assert rows["gate"][1:3] == ["4", "serial"]
    assert Path(rows["gate"][3]).resolve() == GATE.resolve()


def test_scenarios_command_json(capsys):
    assert main(["scenarios", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [d["name"] for d in data] == SHIPPED
    gate = next(d for d in data if d["name"] == "gate")
    assert set(gate) == {"name", "path", "units", "schedule", "description"}
    assert gate["units"] == 4 and gate["schedule"] == "serial"
    assert gate["description"].startswith("Example 3")


def test_run_by_name_from_another_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    log = tmp_path / "g.mcap"
    assert main(["run", "gate", "--bus", "memory", "--log", str(log), "--check"]) == 0
    assert log.exists() and "gate" in capsys.readouterr().out


def _group(n: int, codebook: str = "") -> str:
    units = ", ".join(f'"u{i}"' for i in range(n))
    return (f'name = "g{n}"\nunits = [{units}]\nactions = ["alpha", "beta"]\n{codebook}\n'
            '[relations]\npolicy = "random"\n[influences]\npolicy = "random"\n')  # fmt: skip


def test_the_codebook_a_run_uses_is_said_and_one_that_cannot_fit_is_refused(tmp_path, capsys):
    """Unnamed, the plan lengthens the codebook to fit the units (12 units, two actions:
    generated-k2-N5) and the summary and info say so; the paper's codebook named on 12 units is
    refused naming the codebook and what fits, and what it names runs."""
    import rgtbus

    sc = parse_scenario(_group(12))
    assert sc.codebook.name == "generated-k2-N5-seed0"
    result = rgtbus.run(sc, log=tmp_path / "g12.mcap")
    assert result.summary["codebook"] == "generated-k2-N5-seed0"
    capsys.readouterr()
    assert main(["info", str(tmp_path / "g12.mcap"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["codebook"] == "generated-k2-N5-seed0"
    assert rgtbus.run("gate").summary["codebook"] == "paper"
    with pytest.raises(RgtbusError) as refused:
        parse_scenario(_group(12, 'codebook = "paper"'), "g12.toml")
    said = str(refused.value)
    assert said.startswith("g12.toml:4: codebook: 'paper' has 3 pulses a code"), said
    assert "at most 8 units" in said and 'pulses = 5}' in said
    fits = parse_scenario(_group(12, 'codebook = {kind = "generated", pulses = 5}'))
    assert fits.codebook.pulses == 5


@pytest.mark.parametrize("name", ["Ärger", "ロボット", "β2"])
def test_a_name_outside_the_rule_is_refused_stating_the_rule(name):
    """Names in three scripts: refused for a unit and for an action, the rule stated."""
    units = f'units = ["a", "{name}"]\nactions = ["alpha"]\n'
    with pytest.raises(RgtbusError) as refused:
        parse_scenario(f'name = "n"\n{units}', "n.toml")
    said = str(refused.value)
    assert f"bad unit name {name!r}" in said and "ASCII letters A-Z a-z, digits 0-9 and _" in said
    actions = f'units = ["a", "b"]\nactions = ["{name}"]\n'
    with pytest.raises(RgtbusError) as refused:
        parse_scenario(f'name = "n"\n{actions}', "n.toml")
    said = str(refused.value)
    assert f"bad action name {name!r}" in said and "ASCII letters A-Z a-z" in said


def _checked_at(name: str, seed: int | None) -> list[tuple[str, bool | None, str]]:
    import rgtbus
    from rgtbus.summary import check_expectations

    sc = load_scenario(name)
    if seed is not None:
        sc = sc.with_seed(seed)
    return check_expectations(sc, rgtbus.run(sc).summary)


def test_expectations_of_the_own_seed_only_are_left_out_at_another_saying_so():
    """crowd10's polynomial holds for its own seed: judged there, at seed 1 left out on a
    line that says so, and the rest still judged."""
    own = _checked_at("crowd10", None)
    assert ("polynomial", True, "got 'abf+(c+d+gj+h)e+i', expected 'abf+(c+d+gj+h)e+i'") in own
    other = _checked_at("crowd10", 1)
    skipped = [x for x in other if x[1] is None]
    assert skipped == [("polynomial (left out)", None,
                        "it holds for the scenario's own seed 5 only, not seed 1")]  # fmt: skip
    assert all(ok for _, ok, _ in other if ok is not None) and len(other) > 1


@pytest.mark.slow  # every shipped scenario, twenty seeds
def test_every_shipped_scenario_passes_its_own_check_at_seeds_1_to_20():
    failed = []
    for entry in shipped_scenarios():
        for seed in range(1, 21):
            for what, ok, detail in _checked_at(entry.name, seed):
                if ok is False:
                    failed.append(f"{entry.name} seed {seed}: {what}: {detail}")
    assert not failed, failed[:10]
