"""Entry point of ``nrmpc``: builds the argparse tree from the subcommand modules.

Each subcommand module defines ``register(subparsers)`` which adds its parser
and sets ``func`` to a ``run(args) -> int`` callable. Errors the user can fix
(:class:`~nrmpc_ros.errors.NrmpcError`) print one clear line and exit 2; a
library option's error names the flag that set it
(:func:`nrmpc_ros.cli.common.flag_error`).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .. import threads  # noqa: F401  (first of the package: one BLAS thread, before numpy is imported)
from ..errors import InputError, NrmpcError
from .common import flag_error

# Subcommand modules, in the order `nrmpc --help` lists them.
COMMANDS = [
    "solve", "solve_sequence", "demo", "simulate", "experiment", "observability", "bench", "import_kalibr",
    "make_bag", "replay", "report", "compare", "play", "calibrate_bars",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nrmpc",
        description="Relative pose and gravity for non-rigid multi-perspective cameras (nrmpc_ros).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"nrmpc_ros.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"nrmpc_ros.cli.{name}":
                continue  # not part of this build
            raise
        module.register(sub)
    for command_parser in sub.choices.values():
        command_parser.set_defaults(command_parser=command_parser)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except NrmpcError as exc:
        if isinstance(exc, InputError):
            exc = flag_error(exc, args.command_parser, getattr(args, "field_flags", None))
        print(f"nrmpc {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nrmpc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
