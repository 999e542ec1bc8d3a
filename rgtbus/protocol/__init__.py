"""The timed protocol (docs/protocol.md), as a pure state machine (one per unit).

All units hear the whole medium. To send code X to unit r, unit s

1. sends the ID-code on its own frequency ω_s, starting at the turn's start time t0;
2. when its ω_s resonator spikes (sample k), waits the reaction delay D;
3. sends X on ω_r, starting at t = k·τ + D.

Medium access (paper mode): one transmission at a time, in a fixed order known to every unit
(phase 1, relationships: every s to every r ≠ s, sender-major; phase 3, influences: the same
order), separated by a guard gap G. The timing chain is therefore decided by ID spikes alone::

    pulse m of a code starting at t on ω:  sample round((t + m·2π/ω) / τ),  m = 0..N-1
    payload start      p = max(k_spike, k_last)·τ + D  (k_last: the ID's last pulse)
    next turn's start  t0' = p + (N-1)·2π/ω_r + G

Every unit runs the same machine on what it hears, so every unit knows when each turn starts,
and the turn's sender additionally acts on it. The machine does not decode: it says what to
decode and when (``Listen``); the unit decodes and reasons.

Anchor ``spike`` (the paper, the default) is the chain above. Anchor ``schedule`` counts each
reaction from the ID's last pulse instead, ``p = k_last·τ + D``: on a clean channel the paper's
ID-code fires its resonator exactly there, so nothing changes, but the whole run is then known
from the start and no unit depends on its own (noise-prone) attention spike: spikes still give
attention and are logged, decoding alone carries the messages. It keeps noisy channels decoding
far past the point where attention spikes fail (see the README).
"""

from rgtbus.protocol.state import ProtocolState
from rgtbus.protocol.timetable import (
    MAX_STAGGER,
    Placed,
    Plan,
    Reaction,
    RoundTiming,
    place_rounds,
    plan_of,
    repair_blocks,
)
from rgtbus.protocol.turns import (
    ANCHORS,
    ATTENTIONS,
    MAX_INFLUENCE_ROUNDS,
    NEVER,
    NOTHING,
    PHASES,
    SCHEDULES,
    Actions,
    Listen,
    ListenQueue,
    RepairBlock,
    RepairSlot,
    Send,
    Turn,
    choice_sample,
    code_samples,
    phases,
    rounds,
    turns,
)

__all__ = [
    "ANCHORS",
    "ATTENTIONS",
    "MAX_INFLUENCE_ROUNDS",
    "MAX_STAGGER",
    "NEVER",
    "NOTHING",
    "PHASES",
    "SCHEDULES",
    "Actions",
    "Listen",
    "ListenQueue",
    "Placed",
    "Plan",
    "ProtocolState",
    "Reaction",
    "RepairBlock",
    "RepairSlot",
    "RoundTiming",
    "Send",
    "Turn",
    "choice_sample",
    "code_samples",
    "phases",
    "place_rounds",
    "plan_of",
    "repair_blocks",
    "rounds",
    "turns",
]
