"""Command line entry point: ``sim2real <command> ...``."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from sim2real.errors import InputError


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = {"gap-diff": "sim2real.gapdiff"}
    if not argv or argv[0] not in commands:
        print(f"usage: sim2real {{{','.join(commands)}}} ...", file=sys.stderr)
        return 2
    import importlib

    module = importlib.import_module(commands[argv[0]])
    try:
        return int(module.main(argv[1:]))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
