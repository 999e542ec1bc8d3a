"""Every zenoh key expression of a run, built here and nowhere else.

    rgtbus/<run>/tx/<unit>          a member's frames (pulses and promises)
    rgtbus/<run>/hello/<unit>       join hellos
    rgtbus/<run>/alive/<unit>       liveliness tokens
    rgtbus/<run>/telemetry/<unit>   what a unit logs, for ``rgtbus watch``
    rgtbus/<run>/resend/<unit>      a member's requests for frames it missed
    rgtbus/<run>/steer/watch        a watcher's requests to steer the run (``--control``)
    rgtbus/<run>/change/<unit>      the changes the steering process placed
    rgtbus/<run>/have/<unit>        a process's receipt of a change

``run=None`` in a subscription means every run (``*``): a bus that counts foreign traffic.
"""

from __future__ import annotations

ROOT = "rgtbus"
TX, HELLO, ALIVE, TELEMETRY, RESEND = "tx", "hello", "alive", "telemetry", "resend"
STEER, CHANGE, HAVE = "steer", "change", "have"  # steering across processes (bus.steer_link)
WATCHER = "watch"  # the name a watcher's requests go under (a key chunk: no "@")


def key(kind: str, run_id: str, unit: str) -> str:
    """One member's key of ``kind`` (``TX``, ``HELLO``, ``ALIVE``, ``TELEMETRY``, ``RESEND``)."""
    return f"{ROOT}/{run_id}/{kind}/{unit}"


def every_unit(kind: str, run_id: str | None) -> str:
    """The subscription to ``kind`` of every unit of run ``run_id`` (of every run: None)."""
    return f"{ROOT}/{'*' if run_id is None else run_id}/{kind}/*"


def prefix(kind: str, run_id: str) -> str:
    """``rgtbus/<run>/<kind>/``: what every key of ``kind`` of the run starts with."""
    return f"{ROOT}/{run_id}/{kind}/"


def tx_key(run_id: str, unit: str) -> str:
    """The key of ``unit``'s frames in run ``run_id``."""
    return key(TX, run_id, unit)


def tx_prefix(run_id: str) -> str:
    """What every frame key of run ``run_id`` starts with."""
    return prefix(TX, run_id)


def matches_subscription(key_expr: str, run_id: str | None) -> bool:
    """Would a subscriber on ``every_unit(TX, run_id)`` see ``key_expr``? The memory bus uses
    this to deliver exactly what zenoh would."""
    parts = key_expr.split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[2] != TX:
        return False
    if not parts[1] or not parts[3]:
        return False
    return run_id is None or parts[1] == run_id
