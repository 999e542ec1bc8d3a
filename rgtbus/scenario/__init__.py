"""Scenario files: TOML data -> a validated, typed ``Scenario``.

A scenario names its units, actions, frequencies (or ``"auto"``), codebook, resonator mode,
policies (relationships, influences, decisions), timing, channel noise and seed, and may carry an
``[expect]`` table that ``rgtbus run --check`` verifies. Every refusal names the file, the line
(where it can be found) and the key, and says why.

``load_scenario`` takes a file's path, TOML text or the name of a shipped scenario
(``shipped_scenarios`` lists them). One module per section of the file; ``load`` runs them in
order. Pure: no bus, no log, no simulation.
"""

from rgtbus.scenario.channel import CHANNEL_KEYS
from rgtbus.scenario.codebook_section import CODEBOOK_KINDS, MAX_PULSES, MODES
from rgtbus.scenario.decisions import DECISION_KEYS, DECISION_POLICIES
from rgtbus.scenario.expect import DYNAMICS, EXPECT_KEYS
from rgtbus.scenario.goals import GOAL_KEYS, GOAL_MODES, GOAL_TARGET_KEYS
from rgtbus.scenario.influences import INFLUENCE_KEYS, INFLUENCE_POLICIES
from rgtbus.scenario.load import MAX_SCENARIO_BYTES, TOP_KEYS, load_scenario, parse_scenario
from rgtbus.scenario.model import Goal, Outcome, Scenario, Timing
from rgtbus.scenario.outcome import OUTCOME_KEYS
from rgtbus.scenario.relations import RELATION_KEYS, RELATION_POLICIES
from rgtbus.scenario.schedule import PROTOCOL_KEYS
from rgtbus.scenario.shipped import (
    ShippedScenario,
    find_shipped,
    shipped_dir,
    shipped_scenarios,
)
from rgtbus.scenario.timing import TIMING_KEYS
from rgtbus.scenario.values import MAX_LEVEL

__all__ = [
    "CHANNEL_KEYS",
    "CODEBOOK_KINDS",
    "DECISION_KEYS",
    "DECISION_POLICIES",
    "DYNAMICS",
    "EXPECT_KEYS",
    "GOAL_KEYS",
    "GOAL_MODES",
    "GOAL_TARGET_KEYS",
    "INFLUENCE_KEYS",
    "INFLUENCE_POLICIES",
    "MAX_LEVEL",
    "MAX_PULSES",
    "MAX_SCENARIO_BYTES",
    "MODES",
    "OUTCOME_KEYS",
    "PROTOCOL_KEYS",
    "RELATION_KEYS",
    "RELATION_POLICIES",
    "TIMING_KEYS",
    "TOP_KEYS",
    "Goal",
    "Outcome",
    "Scenario",
    "ShippedScenario",
    "Timing",
    "find_shipped",
    "load_scenario",
    "parse_scenario",
    "shipped_dir",
    "shipped_scenarios",
]
