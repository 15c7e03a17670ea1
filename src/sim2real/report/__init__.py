"""The gap report and what builds on it: how far the model is from the measurements, and where it fails.

Each module does one job of the rules ``gap_report`` and ``fleet`` (``rules/gap.smk``, ``rules/fleet.smk``):

* :mod:`~sim2real.report.gap`: the report's orchestration (gap.json, gap.md, the figures);
* :mod:`~sim2real.report.gap_document`: gap.json's top level as a typed record (its keys written and read there
  alone);
* :mod:`~sim2real.report.metrics`: torque-domain metrics, the reality-gap score and fidelity grade;
* :mod:`~sim2real.report.replay`: the commands replayed in MuJoCo (multiple shooting), the state domain;
* :mod:`~sim2real.report.regimes`: the regimes an error can live in, where the model fails, the worst windows;
* :mod:`~sim2real.report.figures`, :mod:`~sim2real.report.first_screen` and :mod:`~sim2real.report.markdown`: what a
  reviewer sees (gap.md's first screen: the verdict, the ladder, the joints; then the rest; its runs section,
  :mod:`~sim2real.report.runs_section`);
* :mod:`~sim2real.report.verdicts`: every word of the diagnosis;
* :mod:`~sim2real.report.gapdiff`: the pull-request comment, two reports compared;
* :mod:`~sim2real.report.fleet`: every arm and campaign side by side, what drifted.

The report reads the sysid rule's outputs (the ladder, its residuals); it never imports the fit.
"""

from __future__ import annotations

from collections.abc import Sequence


def rung_label(effects: Sequence[str], whole: bool = False) -> str:
    """How a rung of the ladder is named: ``nominal``, or ``+`` its own effect (``whole``: every effect of it,
    which tells rungs of two ladders apart)."""
    if not effects:
        return "nominal"
    return "+ " + (", ".join(effects) if whole else effects[-1])


def details(summary: str, body: Sequence[str]) -> list[str]:
    """A collapsible block (GitHub renders the Markdown inside it)."""
    return ["<details>", f"<summary>{summary}</summary>", "", *body, "", "</details>", ""]
