"""The errors rgtbus raises on purpose, each explained in one line, and their kinds.

Every one is an ``RgtbusError``; a caller that needs to tell them apart catches the kind:

* ``BadInput``: a value given is wrong (a scenario file and its keys, an argument, a sweep file,
  a key file's contents, a frame a peer sent);
* ``BadLog``: a log cannot be read as one (not MCAP, cut where nothing is whole, corrupt, a
  record that breaks its schema or the run's bounds, a format ``rgtbus convert`` must update);
* ``PeerSilent``: a peer said nothing within the timeout (also a ``TimeoutError``);
* ``IOFailure``: a file, directory or service cannot be read or written (also an ``OSError``).

The CLI turns any ``RgtbusError`` into a single line on stderr and exit code 2; its message must
name the bad value and where it came from (token, file, key).
"""


class RgtbusError(ValueError):
    """Bad input or an impossible request, explained in one line (its kinds: the module
    docstring)."""


class BadInput(RgtbusError):
    """A value given is wrong: a scenario, an argument, a file's contents, a peer's frame."""


class BadLog(RgtbusError):
    """A log cannot be read as one: not MCAP, corrupt, cut where nothing is whole, a record
    that breaks its schema or the run's bounds, or a format to convert first."""


class PeerSilent(RgtbusError, TimeoutError):
    """A peer (a member of a cross-process run, a router) said nothing within the timeout."""


class IOFailure(RgtbusError, OSError):
    """A file, directory or service cannot be read or written. Its ``strerror`` is its one
    line, so code that reports an ``OSError`` by its ``strerror`` says it whole."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.strerror = message


class NotDecomposable(BadInput):
    """The relationship graph holds an induced P4, so it has no RGT polynomial. In a random
    group this is a result (no decisions), not bad input; ``p4`` names the path a-b-c-d."""

    def __init__(self, message: str, p4: tuple[str, str, str, str]) -> None:
        super().__init__(message)
        self.p4 = p4


class MembersSilent(PeerSilent):
    """No news from ``silent`` (members of a cross-process run) within the timeout: each is
    stalled or gone, or this process is cut off from them."""

    def __init__(self, message: str, silent: tuple[str, ...]) -> None:
        super().__init__(message)
        self.silent = silent
