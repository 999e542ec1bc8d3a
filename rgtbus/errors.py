"""The one error type every layer raises for bad input.

The CLI turns any ``RgtbusError`` into a single line on stderr and exit code 2; its message must
name the bad value and where it came from (token, file, key).
"""


class RgtbusError(ValueError):
    """Bad input or an impossible request, explained in one line."""
