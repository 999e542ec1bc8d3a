"""What a run SHOULD give: the noise-free forward task of a scenario, round by round (pure).

On a perfect medium every unit reads every code exactly as it was sent, so every unit knows the
group the units intended (the relationship each sends each other, ``rgtbus.mind.intents``) and,
in every influence round, the influences they send: the policy's, or a goal-driven unit's
choice by the inverse task, made exactly as the unit makes it (on the influences decoded before
its choice sample, in the schedule's order of decodes and choices). The forward task on those
gives each unit's interval, frustration and choice after each round:

    truth(round r) = { u: forward(F, influences_r)[u], choose(policy_u, ...) }

where F is the decision function of the intended group's polynomial. A group with no polynomial
(an induced P4) gives no decisions. ``rgtbus.summary`` judges a run against this; the units'
minds never call it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from rgtbus.mind import Mind, Pair, choose, intents, mind_of, result_fields
from rgtbus.protocol import PHASES, Listen, ProtocolState, choice_sample
from rgtbus.rgt import SubjectResult
from rgtbus.scenario import Scenario
from rgtbus.steering import Steered

UnitDecisions = dict[str, dict[str, Any]]  # unit -> its decision (``result_fields``)


@dataclass
class Truth:
    """A scenario's noise-free run, worked out on first use: ``group``, a mind that knows every
    relationship the units intend (phase 2 done on them); ``trajectory``, the influences sent
    in each round; ``rounds``, every unit's decision after each round (round 1 first, at least
    one entry); ``decisions``, after the last."""

    scenario: Scenario
    steered: Steered | None = None  # the changes a steered run made (``rgtbus.steering``)

    @cached_property
    def intended(self) -> tuple[dict[Pair, bool], dict[Pair, int]]:
        """Every relationship (alliance?) and policy influence the units intend, by pair."""
        return intended(self.scenario)

    @cached_property
    def group(self) -> Mind:
        return group_of(self.scenario, self.intended[0])

    @cached_property
    def trajectory(self) -> list[dict[Pair, int]]:
        return sent_in_rounds(
            self.scenario, self.group, self.intended[1], self.steered, self.intended[0]
        )

    @cached_property
    def rounds(self) -> list[UnitDecisions]:
        return decided_in_rounds(
            self.scenario, self.group, self.trajectory, self.steered, self.intended[0]
        )

    @property
    def decisions(self) -> UnitDecisions:
        return self.rounds[-1]

    def goal_prospects(self, last_round: Mapping[Pair, int] | None) -> list[dict[str, Any]]:
        """Each goal of the scenario as the intended group allows it: ``reachable`` (some
        influence of the unit's own meets it, given what the others sent the target in
        ``last_round``: the inverse task with everything known; ``None`` without that round or
        a group) and ``share`` (the share of the others' joint influences for which it could:
        ``steerable_share``; ``None`` without a group)."""
        sc = self.scenario
        if not sc.goals:
            return []
        from rgtbus.rgt.control import steer, steerable_share  # a run without goals never loads it

        u = sc.universe
        df = self.group.df
        out: list[dict[str, Any]] = []
        for g in sc.goals:
            reachable = share = None
            if df is not None:
                share = float(steerable_share(df, u, g.unit, g.target, g.lo, g.hi, g.mode))
                heard = _heard_by_target(last_round, g.target, g.unit)
                if heard is not None and len(heard) == len(sc.units) - 2:
                    got = steer(df, u, g.unit, g.target, g.lo, g.hi, g.mode, heard)
                    reachable = got.value is not None
            out.append({"unit": g.unit, "target": g.target, "reachable": reachable, "share": share})
        return out


def _heard_by_target(
    last_round: Mapping[Pair, int] | None, target: str, unit: str
) -> dict[str, int] | None:
    """What the others sent ``target`` in ``last_round`` (``None`` without it)."""
    if last_round is None:
        return None
    return {s: v for (s, t), v in last_round.items() if t == target and s != unit}


def intended(sc: Scenario) -> tuple[dict[Pair, bool], dict[Pair, int]]:
    """Every relationship (alliance?) and policy influence the units intend, by pair."""
    relations: dict[Pair, bool] = {}
    influences: dict[Pair, int] = {}
    for s in sc.units:
        rel, infl = intents(sc, s)
        for r, code in rel.items():
            relations[(s, r)] = code == "alliance"
        for r, text in infl.items():
            influences[(s, r)] = sc.universe.parse_alternative(text)
    return relations, influences


def group_of(sc: Scenario, relations: Mapping[Pair, bool]) -> Mind:
    """A mind that knows every relationship in ``relations`` (phase 2 done on them)."""
    known = mind_of(sc, sc.units[0])
    known.sent = dict(relations)
    known.build_group()
    return known


def intended_group(sc: Scenario) -> Mind:
    """A mind that knows every relationship the units intend."""
    return Truth(sc).group


def clean_timeline(sc: Scenario) -> tuple[ProtocolState, Sequence[Listen]]:
    """The run's schedule and every decode as a perfect medium times them (anchored on the
    schedule: on a clean channel an ID fires its resonator at its last pulse, where the
    schedule puts it)."""
    me = sc.units[0]
    relations, influences = intents(sc, me)
    plan = ProtocolState(
        me,
        sc.units,
        dict(sc.frequencies),
        sc.timing.tau,
        pulses=sc.codebook.pulses,
        start=sc.timing.start,
        reaction_delay=sc.timing.reaction_delay,
        guard=sc.timing.guard,
        search=sc.timing.search,
        anchor="schedule",
        kind=sc.protocol.schedule,
        influence_rounds=sc.protocol.influence_rounds,
        repair_rounds=sc.protocol.repairs_per_phase,
    )
    acts = plan.begin(relations, influences)
    return plan, acts.queue.listens if acts.queue is not None else acts.listens


# (boundary, rank, turn, kind): a decode is done once its ready sample is heard (rank 0); a goal's
# choice once every sample before its choice sample is heard, after the decodes then due
_Event = tuple[int, int, int, str]


def _decodes_and_choices(sc: Scenario) -> tuple[ProtocolState, list[_Event]]:
    """The schedule, and its payload decodes and goal-driven choices in the order a unit
    takes them."""
    plan, listens = clean_timeline(sc)
    tau, delay = sc.timing.tau, sc.timing.reaction_delay
    goals = {(g.unit, g.target) for g in sc.goals}
    events: list[_Event] = []
    for listen in listens:
        if listen.kind == "id":
            continue
        events.append((listen.ready_sample + 1, 0, listen.turn, listen.kind))
        t = plan.schedule[listen.turn]
        if listen.kind == "influence" and (t.sender, t.addressee) in goals:
            events.append((choice_sample(listen.start, delay, tau), 1, listen.turn, "choice"))
    events.sort()
    return plan, events


def _held_group(
    sc: Scenario,
    known: Mind,
    relations: Mapping[Pair, bool] | None,
    held: Mapping[Pair, bool],
    cache: dict[frozenset[tuple[Pair, bool]], Mind],
) -> Mind:
    """The group a unit decides on: ``known``, or, where a steered run made it hold some
    relations otherwise (``held``), the group of the intended ``relations`` with those."""
    if not held or relations is None:
        return known
    key = frozenset(held.items())
    if key not in cache:
        cache[key] = group_of(sc, {**relations, **held})
    return cache[key]


def sent_in_rounds(
    sc: Scenario,
    known: Mind,
    policy: Mapping[Pair, int],
    steered: Steered | None = None,
    relations: Mapping[Pair, bool] | None = None,
) -> list[dict[Pair, int]]:
    """What every unit would send in every influence round on a perfect medium: the policy's
    influences, and a goal-driven unit's choices made exactly as the unit makes them (each
    with the influences decoded before its choice sample). ``known``: the intended group;
    ``steered``: a steered run's changes (an injected influence is sent instead of the
    policy's or the choice; a goal-driven unit made to hold other ``relations`` chooses on
    its group from the round it holds them)."""
    k = sc.protocol.influence_rounds
    injected = steered.injected if steered else {}
    if not sc.goals:
        trajectory = [dict(policy) for _ in range(k)]
        if injected:
            schedule = clean_timeline(sc)[0].schedule
            for index, value in injected.items():
                t = schedule[index]
                trajectory[t.round - 1][(t.sender, t.addressee)] = value
        return trajectory
    plan, events = _decodes_and_choices(sc)
    groups: dict[frozenset[tuple[Pair, bool]], Mind] = {}
    goals = {(g.unit, g.target): g for g in sc.goals}
    sent: dict[int, int] = {}
    minds = {u: mind_of(sc, u) for u in {g.unit for g in sc.goals}}
    relation_turns = len(sc.units) * (len(sc.units) - 1)
    relations_heard = 0
    for _, _, index, kind in events:
        t = plan.schedule[index]
        pair = (t.sender, t.addressee)
        if kind == "relation":
            relations_heard += 1
            if relations_heard == relation_turns:  # every goal-driven unit knows the group
                for m in minds.values():
                    m.df, m.p4, m.error = known.df, known.p4, known.error
        elif kind == "choice":
            if index in injected:
                sent[index] = injected[index]
                continue
            m = minds[t.sender]
            if steered and relations_heard == relation_turns:
                held = steered.held_by(t.sender, t.round)
                g = _held_group(sc, known, relations, held, groups)
                m.df, m.p4, m.error = g.df, g.p4, g.error
            got = m.steer(goals[pair], t.round)
            chosen = None if isinstance(got, str) else got.value
            sent[index] = policy[pair] if chosen is None else chosen
        else:
            value = sent.get(index, injected.get(index, policy[pair]))
            for m in minds.values():
                m.heard_in(t.round)[pair] = value
    out: list[dict[Pair, int]] = [{} for _ in range(k)]
    for t in plan.schedule:
        if t.phase == PHASES[1]:
            pair = (t.sender, t.addressee)
            out[t.round - 1][pair] = sent.get(t.index, injected.get(t.index, policy[pair]))
    return out


def decided_in_rounds(
    sc: Scenario,
    known: Mind,
    trajectory: Sequence[Mapping[Pair, int]],
    steered: Steered | None = None,
    relations: Mapping[Pair, bool] | None = None,
) -> list[UnitDecisions]:
    """Every unit's decision (``result_fields``) after each round of ``trajectory``, on the
    group ``known``: ``[{unit: result_fields}, ...]`` (round 1 first; at least one entry). The
    forward task is the same for every unit that knows everything: it is solved once a
    distinct round and group; each unit then chooses by its own policy (a random one draws
    each round). A unit a steered run made hold other ``relations`` decides on their group
    from the round it held them (``Steered.held_by``)."""
    solved: dict[tuple[Any, ...], dict[str, SubjectResult] | None] = {}
    groups: dict[frozenset[tuple[Pair, bool]], Mind] = {}

    def forward_of(group: Mind, infl: Mapping[Pair, int]) -> dict[str, SubjectResult] | None:
        key = (id(group), tuple(sorted(infl.items())))
        if key not in solved:
            group.influences = infl
            group.results = None
            group.decide()
            solved[key] = group.results
        return solved[key]

    out: list[UnitDecisions] = [{} for _ in trajectory] or [{}]
    for me in sc.units:
        mind = mind_of(sc, me)
        mind.df, mind.polynomial, mind.p4 = known.df, known.polynomial, known.p4
        if not trajectory:
            out[0][me] = result_fields(mind)
        for i, infl in enumerate(trajectory):
            group = known
            if steered:
                group = _held_group(sc, known, relations, steered.held_by(me, i + 1), groups)
                mind.df, mind.polynomial, mind.p4 = group.df, group.polynomial, group.p4
            results = forward_of(group, infl)
            mind.results = results
            if results is not None:
                mind.choice = choose(mind.policy, results[me], mind.universe, mind.rng)
            out[i][me] = result_fields(mind)
    return out


def clean_rounds(sc: Scenario) -> tuple[Mind, list[dict[Pair, int]]]:
    """The intended group and the influences of each round on a perfect medium."""
    truth = Truth(sc)
    return truth.group, truth.trajectory


def noise_free_rounds(sc: Scenario) -> list[UnitDecisions]:
    """Every unit's decision after each influence round on a perfect medium."""
    return Truth(sc).rounds


def noise_free(sc: Scenario) -> UnitDecisions:
    """Every unit's decision had it read every code exactly as sent (``noise_free_rounds``'
    last round). A group with no polynomial gives no decisions (``decided`` false for all)."""
    return Truth(sc).decisions
