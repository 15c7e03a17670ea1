"""Names of excitation designs that the report and the experiment design share: a run that separates two
candidates the diagnosis could not tell apart is the design ``separate-<a>-vs-<b>`` (``rules/excitation.smk``)."""

from __future__ import annotations

SEPARATION_PREFIX = "separate-"


def separation_name(first: str, second: str) -> str:
    """The design that tells ``first`` from ``second``: what gap.md asks the user to build and record."""
    return f"{SEPARATION_PREFIX}{first}-vs-{second}"


def confounded_pair(name: str) -> tuple[str, str] | None:
    """The two effects a design name ``separate-<a>-vs-<b>`` separates, or None for an ordinary design."""
    if not name.startswith(SEPARATION_PREFIX) or "-vs-" not in name:
        return None
    first, second = name[len(SEPARATION_PREFIX):].split("-vs-", 1)
    return first, second
