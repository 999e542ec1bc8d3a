"""What the core leaves to extras: plots need ``matplotlib`` (``rgtbus[plot]``), a sweep on a
Dask cluster needs ``distributed`` (``rgtbus[dask]``), TLS identities (``rgtbus certs``,
``--tls``) need ``cryptography`` (``rgtbus[tls]``), a sweep's Parquet tables need ``pyarrow``
(``rgtbus[parquet]``; without it a sweep writes and reads its JSON Lines and CSV tables);
``rgtbus[all]`` has them all. A command or
function that needs a missing one says which, in one line (``RgtbusError``: exit 2)."""

from __future__ import annotations

import importlib.util

from rgtbus.errors import BadInput

# module -> the extra that installs it
EXTRAS = {
    "matplotlib": "plot",
    "distributed": "dask",
    "cryptography": "tls",
    "pyarrow": "parquet",
}


def require(module: str, what: str) -> None:
    """Refuse, in one line, ``what`` (e.g. ``"--plot"``) when ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        extra = EXTRAS[module]
        raise BadInput(
            f"{what} needs {module}, which rgtbus leaves to its {extra!r} extra: "
            f"pip install 'rgtbus[{extra}]'"
        )
