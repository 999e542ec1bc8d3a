"""``rgtbus completion SHELL``: the shell code that completes rgtbus's commands, options and
file names as you type (argcomplete: bash, zsh and fish)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers

SHELLS = ("bash", "zsh", "fish")


def register(subparsers: SubParsers) -> None:
    """Add ``completion``."""
    p = subparsers.add_parser(
        "completion",
        help="print the shell code that completes rgtbus's commands and options",
        description="Print the code that makes SHELL complete rgtbus's commands, options and "
        'file names. Once a session: eval "$(rgtbus completion bash)" (bash, zsh), '
        "rgtbus completion fish | source (fish); or put that line in ~/.bashrc, ~/.zshrc or "
        "~/.config/fish/config.fish (docs/install.md).",
    )
    p.add_argument("shell", choices=SHELLS, metavar="SHELL", help="bash, zsh or fish")
    p.set_defaults(func=print_completion)


def print_completion(args: argparse.Namespace) -> int:
    """``rgtbus completion SHELL``: the shell code, on stdout."""
    from argcomplete.shell_integration import shellcode

    print(shellcode(["rgtbus"], shell=args.shell), end="")
    return 0
