"""The GitHub Actions workflow: valid against the published workflow schema, and doing what CI promises."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
WORKFLOW = ROOT / ".github" / "workflows" / "build.yml"


def _steps() -> list[dict]:
    data = yaml.safe_load(WORKFLOW.read_text())
    return data["jobs"]["build"]["steps"]


def test_workflow_is_valid_against_the_github_workflow_schema() -> None:
    # check-jsonschema ships the SchemaStore schema of GitHub workflows: a real linter, run as users would.
    result = subprocess.run(
        [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.github-workflows", str(WORKFLOW)],
        capture_output=True, text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_workflow_caches_results_with_metadata_keyed_on_every_build_input() -> None:
    steps = _steps()
    restore = next(s for s in steps if s.get("uses", "").startswith("actions/cache/restore") and "results" in s["with"]["path"])
    save = next(s for s in steps if s.get("uses", "").startswith("actions/cache/save") and "results" in s["with"]["path"])
    for step in (restore, save):
        assert ".snakemake/metadata" in step["with"]["path"]
        assert step["with"]["key"] == restore["with"]["key"]
    keys = next(s for s in steps if s.get("id") == "keys")["run"]
    for feed in ("Snakefile", "rules/**", "scripts/**", "src/**", "pyproject.toml", "robots/**", "configs/**", "schemas/**"):
        assert f"'{feed}'" in keys, f"cache key ignores {feed}"
    names = [s.get("name", s.get("uses", "")) for s in steps]
    order = [names.index(n) for n in ("Restore build outputs", "Make restored outputs count as up to date", "Build", "Save build outputs")]
    assert order == sorted(order)
    assert next(s for s in steps if s.get("name") == "Build")["run"] == "snakemake all"


def test_workflow_publishes_report_and_one_updated_gap_comment() -> None:
    steps = _steps()
    runs = "\n".join(s.get("run", "") for s in steps)
    assert "--report results/report.html" in runs
    assert "sim2real gap-diff" in runs
    comment = next(s for s in steps if s.get("uses", "").startswith("actions/github-script"))
    script = comment["with"]["script"]
    assert "updateComment" in script and "createComment" in script
    assert "<!-- sim2real-gap-report -->" in script
    assert any(s.get("uses", "").startswith("actions/upload-artifact") for s in steps)


def test_workflow_installs_as_ci_run_does_and_puts_the_environment_on_path() -> None:
    # One install for the README, .ci/run and GitHub: the workflow's may not drift from the one tested here.
    ci_run = (ROOT / ".ci" / "run").read_text()
    install_line = next(line for line in ci_run.splitlines() if line.startswith("python3 -m venv"))
    install = install_line.split(" && .venv/bin/python -m pytest")[0]
    step = next(s for s in _steps() if s.get("name") == "Install")["run"]
    assert install in step.splitlines()
    assert 'echo "$PWD/.venv/bin" >> "$GITHUB_PATH"' in step
