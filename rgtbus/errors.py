"""The one error type every layer raises for bad input.

The CLI turns any ``RgtbusError`` into a single line on stderr and exit code 2; its message must
name the bad value and where it came from (token, file, key).
"""


class RgtbusError(ValueError):
    """Bad input or an impossible request, explained in one line."""


class NotDecomposable(RgtbusError):
    """The relationship graph holds an induced P4, so it has no RGT polynomial. In a random
    group this is a result (no decisions), not bad input; ``p4`` names the path a-b-c-d."""

    def __init__(self, message: str, p4: tuple[str, str, str, str]) -> None:
        super().__init__(message)
        self.p4 = p4


class MembersSilent(RgtbusError):
    """No news from ``silent`` (members of a cross-process run) within the timeout: each is
    stalled or gone, or this process is cut off from them."""

    def __init__(self, message: str, silent: tuple[str, ...]) -> None:
        super().__init__(message)
        self.silent = silent
