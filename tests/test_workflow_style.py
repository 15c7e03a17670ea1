"""Workflow hygiene: snakefmt formatting and Snakemake's linter (the one accepted lint is justified in the README)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ACCEPTED_LINTS = {"Specify a conda environment or container for each rule."}


def test_snakefile_and_rules_are_snakefmt_formatted() -> None:
    snakefmt = Path(sys.executable).with_name("snakefmt")
    result = subprocess.run([str(snakefmt), "--check", "Snakefile", "rules"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_snakemake_lint_reports_only_the_justified_lint() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "snakemake", "--lint", "--dry-run"], cwd=ROOT, capture_output=True, text=True
    )
    output = result.stdout + result.stderr
    lints = set(re.findall(r"^\s+\* (.+?):?$", output, flags=re.MULTILINE))
    assert lints <= ACCEPTED_LINTS, f"new lints: {lints - ACCEPTED_LINTS}"
    readme = (ROOT / "README.md").read_text()
    for lint in ACCEPTED_LINTS:
        assert lint.rstrip(".") in readme, "every accepted lint is justified in the README"


def test_the_snakefile_is_short_and_the_helpers_live_in_common() -> None:
    """As the snakemake-workflows exemplars: the config validated in rules/common.smk, a global report with the
    workflow's caption, the targets listed in one place, and no rules file keeping state of its own."""
    snakefile = (ROOT / "Snakefile").read_text()
    assert 'report: "report/workflow.rst"' in snakefile and (ROOT / "report" / "workflow.rst").is_file()
    assert "validate(" not in snakefile
    common = (ROOT / "rules" / "common.smk").read_text()
    assert 'validate(config, "../schemas/config.schema.yaml")' in common
    assert "def all_targets():" in common
    for rules in sorted((ROOT / "rules").glob("*.smk")):
        text = rules.read_text()
        if rules.name != "common.smk":
            assert not re.search(r"^\w+\.(append|extend)\(", text, flags=re.MULTILINE), rules.name
            assert "raise ValueError" not in text and "def " not in text, f"{rules.name}: helpers belong in common.smk"
        assert "ValueError" not in text, f"{rules.name}: bad input is an InputError (file, key, fix)"


def test_the_rules_take_their_inputs_and_params_from_get_functions() -> None:
    """As snakemake-workflows' common.smk: what a rule's input or params section calls by name is an input function
    of common.smk named ``get_*``; where files are lives in the tested package sim2real.workflow."""
    common = (ROOT / "rules" / "common.smk").read_text()
    assert "import sim2real.workflow" in common or "from sim2real.workflow" in common
    assert len(common.splitlines()) <= 200, "common.smk keeps validation, wildcards, targets and scheduling"
    defined = set(re.findall(r"^(get_\w+) = of_wildcards\(", common, flags=re.MULTILINE))
    defined |= set(re.findall(r"^def (get_\w+)\(", common, flags=re.MULTILINE))
    called = set()
    for rules in sorted((ROOT / "rules").glob("*.smk")):
        section = None
        for line in rules.read_text().splitlines():
            if re.match(r"^    \w+:", line):
                section = line.strip().rstrip(":")
            elif section in ("input", "params") and (name := re.match(r"^        (?:\w+=)?([A-Za-z_]\w*)(?:\(.*\))?,$",
                                                                        line)):
                called.add(name.group(1))
    assert called, "the parser sees the rules' input functions"
    assert called <= defined, f"not an input function of common.smk named get_*: {sorted(called - defined)}"
