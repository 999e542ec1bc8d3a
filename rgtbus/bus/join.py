"""Joining a run, apart from any transport: how often a joining process says its hello
(``hello_period``, ``hello_gap``), how long a unit's claimant may go unheard
(``claim_silence``), and the join barrier (``JoinBarrier``): who has been heard, with which
view of the run, who is ready, and whether two processes claim one unit. A transport hands the
barrier each hello it hears and says what the barrier asks it to (``JoinPeer``); the zenoh
adapter is one (``rgtbus.bus.zenoh``), and a new transport joins the same way. The protocol:
docs/security.md, "Joining".
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Protocol

from rgtbus.bus.hello import Hello, view_digest
from rgtbus.errors import BadInput


class JoinPeer(Protocol):
    """What a join barrier uses of its transport: the run, its members, this process's nonce
    and name, when each member last said its hello again unchanged (``repeated_at``: the
    transport's gate need not read it again), how to say a local unit's hello, and whom to
    accept frames from (a member heard fresh: its frames are checked with this nonce)."""

    @property
    def run_id(self) -> str: ...
    @property
    def members(self) -> Sequence[str]: ...
    @property
    def nonce(self) -> bytes: ...
    @property
    def process(self) -> str: ...
    @property
    def repeated_at(self) -> dict[str, float]: ...

    def say_hello(self, unit: str, digest: str, view: bytes, *, ready: bool) -> None: ...
    def accept(self, unit: str, nonce: bytes) -> None: ...


_FIRST_HELLO_GAP = 0.05  # s: the first unprompted hellos, each gap twice the last


def hello_period(members: int) -> float:
    """How often a joining process says its hello unprompted once it has said a few: 50 ms,
    and longer in a large run (every member's hello reaches every process): 10 ms a member."""
    return max(_FIRST_HELLO_GAP, 0.01 * members)


def hello_gap(period: float, said: int) -> float:
    """The wait before unprompted hello number ``said`` + 1: 50 ms, 100 ms, 200 ms ... up to
    ``period``. A hello said before a peer's subscription has reached this session is lost,
    and the first ones of a run are; the next comes soon, not a whole period later."""
    return min(period, _FIRST_HELLO_GAP * 2.0 ** min(said, 30))


# s: the least silence after which a unit's claimant no longer counts (it died, or was
# replaced). Processes starting together on a loaded machine go unheard for hundreds of ms
# (starved of CPU); a second claimant heard meanwhile is a conflict, not the replacement of
# the first. A restarted process takes longer than this to say its first hello.
CLAIM_SILENCE = 1.0


def claim_silence(period: float) -> float:
    """How long a claimant of a unit may go unheard and still count: three hello periods,
    and at least ``CLAIM_SILENCE``."""
    return max(3.0 * period, CLAIM_SILENCE)


class JoinBarrier:
    """One join's state (a transport's join: ``ZenohBus.join``): the latest nonce heard of
    each member (``nonces``, ours among them), each member's latest view and readiness,
    whether a hello brought news since we last spoke (``news``: we answer at the next round,
    once for all of it), and who claims each unit (``claims``: nonce -> (process, when last
    heard)).

    **Ready is a promise** (``committed``): once we have said we are ready with view V, another
    member may open its barrier with V at any moment, so our view no longer changes. A claimant
    heard after that whose nonce V lacks is a late joiner (``hear`` passes it by, and once the
    run starts it is told so), not a conflict; a conflict it would have made is kept
    (``rival``). The promise ends only when a member of V says a view other than V
    (``_release``): the first member of V to do so never said it was ready with V, and each
    later one had seen a member that never did, so nobody can open with V (opening needs every
    other member ready with it); we take up the join again, and stop for the kept conflict if
    there is one. So a second claimant heard by some members before they were ready and by
    others after cannot leave a member running alone: either every member opens with one view,
    or every member that heard both claims stops (docs/security.md)."""

    def __init__(self, bus: JoinPeer, mine: list[str], digest: str, period: float) -> None:
        self.bus, self.mine, self.digest, self.period = bus, mine, digest, period
        self.local = set(mine)
        self.others = set(bus.members) - self.local
        self.nonces: dict[str, bytes] = dict.fromkeys(mine, bus.nonce)
        self.views: dict[str, bytes] = {}  # each other member's latest view
        self.readies: dict[str, bool] = {}  # ... and whether it said it was ready
        self.news = False
        self.claims: dict[str, dict[bytes, tuple[str, float]]] = {}
        self.conflict: str | None = None  # two live processes claim one unit
        self.committed = b""  # the view we said we are ready with (b"": not said)
        self.rival: str | None = None  # a conflict heard once committed: a late claimant

    def view(self) -> bytes:
        """Our view of the run (``view_digest``), or b"" while a member is unheard."""
        if len(self.nonces) < len(self.bus.members):
            return b""
        return view_digest(self.bus.run_id, self.digest, self.nonces)

    def fresh(self) -> set[str]:
        """The other members whose latest hello holds our view: said after our nonce, and
        having heard everyone as we did."""
        ours = self.view()
        return {u for u, v in self.views.items() if ours and v == ours}

    def done(self) -> bool:
        """Every other member is fresh and ready: the barrier opens."""
        fresh = self.fresh()
        return fresh >= self.others and all(self.readies.get(u) for u in self.others)

    def missing(self) -> list[str]:
        """Who holds the barrier: members unheard, else those not fresh, else not ready."""
        unheard = sorted(self.others - self.nonces.keys())
        if unheard:
            return unheard
        return sorted(self.others - self.fresh()) or sorted(
            u for u in self.others if not self.readies.get(u)
        )

    def say(self, *, ready: bool | None = None) -> None:
        """Each of our units' hello (ready: once every other member is fresh, and never while
        the join stops for a conflict: a member that is ready may be opened with)."""
        if ready is None:
            ready = self.conflict is None and self.fresh() >= self.others
        view = self.view()
        if ready and view:
            self.committed = view
        for u in self.mine:
            self.bus.say_hello(u, self.digest, view, ready=ready)
        self.news = False

    def claim(self, h: Hello, heard_at: float) -> None:
        """``h``'s process claims ``h.unit``: ``conflict`` set when another process claims it
        too and still says so (its last hello within ``claim_silence``: a claimant that died,
        or was replaced, falls silent), naming the unit and both claimants. Our own units'
        claims are ours. ``heard_at``: when it arrived (monotonic)."""
        now = time.monotonic()
        claims = self.claims.setdefault(h.unit, {})
        if h.unit in self.local:
            claims[self.bus.nonce] = (self.bus.process, now)
        # the claimant read last on this unit's key repeats itself unread (the gate drops a
        # hello said again unchanged): its repeats keep its claim alive
        latest = self.nonces.get(h.unit)
        if latest in claims and latest != h.nonce:
            proc, at = claims[latest]
            claims[latest] = (proc, max(at, self.bus.repeated_at.get(h.unit, at)))
        claims[h.nonce] = (h.process, max(heard_at, claims.get(h.nonce, ("", heard_at))[1]))
        silence = claim_silence(self.period)
        for nonce in [n for n, (_, at) in claims.items() if now - at > silence]:
            if nonce != self.bus.nonce:
                del claims[nonce]
        if len(claims) > 1:
            who = " and ".join(
                f"{proc or '(unnamed)'} (nonce {nonce.hex()[:8]})"
                for nonce, (proc, _) in sorted(claims.items(), key=lambda c: c[1][1])
            )
            said = (
                f"two processes claim unit {h.unit!r} of run {self.bus.run_id!r}: {who}: "
                "the join stops for both"
            )
            if self.committed:  # the later claimant is late, unless the promise ends
                self.rival = self.rival or said
            else:
                self.conflict = self.conflict or said

    def late(self, h: Hello) -> bool:
        """Whether ``h`` (not ours) claims its unit too late: we are committed to a view that
        holds another nonce for it."""
        return bool(self.committed) and self.nonces.get(h.unit) != h.nonce

    def _release(self, h: Hello) -> None:
        """Member ``h.unit`` of our committed view says another view: it never said it was
        ready with ours, so nobody opens with it; the promise ends, and a conflict kept while
        it held stops the join."""
        if self.committed and h.view != self.committed:
            self.committed = b""
            self.conflict = self.conflict or self.rival

    def hear(self, h: Hello, heard_at: float) -> bool:
        """One member's hello (not ours, arrived at ``heard_at``); whether the barrier opens
        with it. RgtbusError for a member on another scenario, or a run already started."""
        run_id = self.bus.run_id
        if h.digest != self.digest:
            raise BadInput(
                f"unit {h.unit!r} of run {run_id!r} runs another scenario or "
                f"seed (digest {h.digest[:12]}, ours {self.digest[:12]})"
            )
        self.claim(h, heard_at)
        if h.started:
            if h.to == self.bus.nonce:  # an answer to us: the run started without us
                raise BadInput(
                    f"run {run_id!r} already started (unit {h.unit!r} is at sample "
                    f"{h.sample}): {self.mine[0]!r} joined too late"
                )
            return False  # an answer to someone else
        if self.late(h):
            return False  # a later claimant of a unit we promised to run with
        self._release(h)
        was_fresh = h.unit in self.fresh() and self.readies.get(h.unit) == h.ready
        if self.nonces.get(h.unit) != h.nonce:  # our view changes: say so
            self.nonces[h.unit] = h.nonce
            self.news = True
        self.views[h.unit], self.readies[h.unit] = h.view, h.ready
        if h.unit in self.fresh():
            # Its frames are checked with this nonce from now on (at the gate): it sends its
            # first only after our ready, which says we heard it fresh.
            self.bus.accept(h.unit, h.nonce)
            if not was_fresh:
                self.news = True
        return self.done()
