"""Command line entry point (``sim2real <command> ...``) and the entry of every Snakemake script."""

from __future__ import annotations

import atexit
import contextlib
import logging
import re
import sys
import traceback
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from sim2real.errors import InputError


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = {"gap-diff": "sim2real.report.gapdiff"}
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


# --------------------------------------------------------------------------------------------
# Snakemake: an InputError reaches the user as its one-line message, the last thing printed.
#
# A rule's script runs its package call inside `rule_entry(snakemake)`: the traceback goes to the
# rule's log, stderr gets the message alone and the log's last line carries it after INPUT_ERROR_MARK.
# The Snakefile's `onerror:` hands Snakemake's own log to `input_errors_last`, which reads the failed
# jobs' logs for those lines and prints them when the process exits, after Snakemake's summary;
# `one_line_input_errors()` does the same for an InputError raised while Snakemake parses the workflow
# or builds its DAG. Any other exception (a bug) keeps its traceback.

INPUT_ERROR_MARK = "sim2real: input error: "
_PENDING: list[str] = []


def one_line(error: BaseException | str) -> str:
    """The error's message on one line (a YAML parser's multi-line problem joined by spaces)."""
    return " ".join(str(error).split())


def _print_pending() -> None:
    if _PENDING:
        sys.stderr.flush()
        sys.stdout.flush()
        print("\n".join(_PENDING), file=sys.stderr, flush=True)


def _defer(lines: Sequence[str]) -> None:
    new = [line for line in dict.fromkeys(lines) if line not in _PENDING]
    if new and not _PENDING:
        atexit.register(_print_pending)  # once: _PENDING is never emptied
    _PENDING.extend(new)


def _input_error_in(error: BaseException | None) -> InputError | str | None:
    """The InputError an exception is or wraps, or its message where Snakemake kept only the text (an
    input function's error: "InputError: <message>" on a line of its InputFunctionException)."""
    seen: set[int] = set()
    stack = [error]
    while stack:
        current = stack.pop()
        if current is None or id(current) in seen:
            continue
        seen.add(id(current))
        if isinstance(current, InputError):
            return current
        quoted = re.search(r"^\s*InputError: (.+)$", str(current), flags=re.MULTILINE)
        if quoted:
            return quoted.group(1)
        stack += [current.__cause__, current.__context__]
        stack += [a for a in getattr(current, "args", ()) if isinstance(a, BaseException)]
        stack += list(getattr(current, "_include", ()) or ())
    return None


@contextlib.contextmanager
def rule_entry(snakemake: Any) -> Iterator[None]:
    """The entry of every ``scripts/*.py``: log to the rule's log; an InputError as its message alone.

    ``logging`` (and Python warnings) go to ``snakemake.log[0]``. An ``InputError`` writes its traceback
    and then ``INPUT_ERROR_MARK + message`` to the log, prints the message to stderr and exits with
    status 1; any other exception is logged with its traceback and propagates.
    """
    log_path = snakemake.log[0] if len(snakemake.log) else None
    logging.basicConfig(filename=log_path, filemode="w", level=logging.INFO,
                        format="%(levelname)s %(message)s", force=True)
    logging.captureWarnings(True)
    try:
        yield
    except InputError as exc:
        logging.error("input error\n%s", "".join(traceback.format_exception(exc)).rstrip())
        logging.shutdown()
        if log_path:
            with open(log_path, "a", encoding="utf-8") as log:
                log.write(f"{INPUT_ERROR_MARK}{one_line(exc)}\n")
        print(one_line(exc), file=sys.stderr, flush=True)
        raise SystemExit(1) from None
    except Exception:
        logging.exception("failed")
        raise


def failed_job_logs(snakemake_log: str | Path) -> list[Path]:
    """The log files of the jobs Snakemake's own log reports as failed, in its order."""
    text = Path(snakemake_log).read_text(encoding="utf-8", errors="replace")
    logs: list[Path] = []
    for block in re.split(r"^.*Error in rule ", text, flags=re.MULTILINE)[1:]:
        match = re.search(r"^\s+log: (.+?) \(check log file", block, flags=re.MULTILINE)
        if match:
            logs += [Path(p.strip()) for p in match.group(1).split(",") if Path(p.strip()) not in logs]
    return logs


def input_error_lines(snakemake_log: str | Path) -> list[str]:
    """The one-line InputError messages the failed jobs left in their logs."""
    lines: list[str] = []
    for path in failed_job_logs(snakemake_log):
        if path.is_file():
            for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
                if line.startswith(INPUT_ERROR_MARK) and line[len(INPUT_ERROR_MARK):] not in lines:
                    lines.append(line[len(INPUT_ERROR_MARK):])
    return lines


def input_errors_last(snakemake_log: str | Path | Sequence[str | Path] | None) -> None:
    """For the Snakefile's ``onerror:``: print the failed jobs' InputError messages as Snakemake's last lines.

    ``snakemake_log``: the ``log`` Snakemake hands ``onerror`` (a path, or a list of paths).
    """
    paths = [snakemake_log] if isinstance(snakemake_log, (str, Path)) else list(snakemake_log or [])
    for path in paths:
        if Path(path).is_file():
            _defer(input_error_lines(path))


class _InputErrorFilter(logging.Filter):
    """Sees Snakemake report the exception it is handling; defers an InputError's message to the exit."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR:
            error = _input_error_in(sys.exc_info()[1])
            if error is not None:
                _defer([one_line(error)])
        return True


def one_line_input_errors() -> None:
    """For the top of the Snakefile: an InputError raised while Snakemake parses the workflow or builds
    its DAG (a config read by an input function) is also repeated alone as the last line."""
    logger = logging.getLogger("snakemake.logging")
    if not any(isinstance(f, _InputErrorFilter) for f in logger.filters):
        logger.addFilter(_InputErrorFilter())


if __name__ == "__main__":
    raise SystemExit(main())
