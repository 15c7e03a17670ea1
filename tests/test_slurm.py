"""The Panda's MJCF and gap report built through `--profile profiles/slurm` on a real SLURM cluster.

`.ci/slurm-setup` (run by `.ci/run` before pytest) installs Debian's slurm-wlm and munge and starts
slurmctld + slurmd on localhost. Where SLURM is not there or not running, the test is skipped and
says why. The assertions read SLURM's own records: every job Snakemake submitted is in SLURM's job
completion log (JobCompType=jobcomp/filetxt) as COMPLETED on node localhost under this run's job
name, `scontrol show job` names its rule, and the outputs equal the local build of the suite's shared tree
(tests/readme.py, the same settings) byte for byte.
"""

from __future__ import annotations

import filecmp
import os
import re
import subprocess
from pathlib import Path

import pytest

from buildtree import comparable_outputs, run_snakemake
from slurm_cluster import ROOT, TARGETS, SlurmBuild, slurm_config

pytestmark = pytest.mark.slow


def _completed_jobs(jobcomp_log: Path) -> dict[str, dict[str, str]]:
    """SLURM's record of every finished job: {JobId: {JobState, Name, NodeList, Partition, ...}}."""
    jobs = {}
    for line in jobcomp_log.read_text().splitlines():
        fields = dict(re.findall(r"(\w+)=(\S*)", line))
        if "JobId" in fields:
            jobs[fields["JobId"]] = fields
    return jobs


def test_panda_mjcf_and_gap_report_through_the_slurm_profile(slurm_build: SlurmBuild, built_tree: Path) -> None:
    config, _ = slurm_config()
    # At the settings of the suite's shared tree, built locally by the README's commands: the reference to compare with.
    tree = slurm_build.tree
    log = slurm_build.log()

    submitted = re.findall(r"^Job (\d+) has been submitted with SLURM jobid (\d+)", log, flags=re.MULTILINE)
    run_names = set(re.findall(r"^\s*(?:rule|checkpoint) (\w+):", log, flags=re.MULTILINE))
    local_names = set(re.findall(r"^\s*localrule (\w+):", log, flags=re.MULTILINE))
    assert {"urdf", "visual_mesh", "coacd", "mjcf", "lab_run", "sysid", "gap_report"} <= run_names, run_names
    assert len(submitted) >= 6, submitted  # urdf, the mesh group, mjcf, two lab runs, sysid, gap report
    assert local_names <= {"collision_mesh", "collision_report", "lab_truth", "dr_resolve", "dr_summary", "fleet"}
    assert "Nothing to be done" in run_snakemake(tree, "--dry-run", *TARGETS), "the SLURM build left jobs undone"

    records = _completed_jobs(Path(config["JobCompLoc"]))
    run_uuid = {records[slurm_id]["Name"] for _, slurm_id in submitted if slurm_id in records}
    for _, slurm_id in submitted:
        record = records.get(slurm_id)
        assert record is not None, f"SLURM job {slurm_id} is not in SLURM's job completion log"
        assert record["JobState"] == "COMPLETED" and record["NodeList"] == "localhost", record
    assert len(run_uuid) == 1, f"one Snakemake run submits every job under its run id, got {run_uuid}"
    # scontrol still holds the finished jobs (MinJobAge): the comment names the rule that ran. Every
    # job of these rules that Snakemake started is one SLURM job (the mesh group's are one group job).
    comments: list[str] = []
    for _, slurm_id in submitted:
        shown = subprocess.run(["scontrol", "show", "job", slurm_id], capture_output=True, text=True).stdout
        comments += re.findall(r"Comment=rule_(\w+?)(?:_wildcards_\S*)?\s", shown)
    started = re.findall(r"^\s*(?:rule|checkpoint) (\w+):", log, flags=re.MULTILINE)
    for rule in ("urdf", "mjcf", "lab_run", "sysid", "gap_report"):
        assert comments.count(rule) == started.count(rule) >= 1, (rule, comments, started)

    # Every output is the bytes the local build of the shared tree wrote (a build of both robots: the Panda's
    # outputs do not depend on which robots are built, tests/test_build_cache.py).
    files = comparable_outputs(tree / "results")
    assert {Path(t).relative_to("results") for t in TARGETS} <= set(files)
    assert set(files) <= set(comparable_outputs(built_tree / "results")), "an output the local build has not"
    differing = [str(f) for f in files if not filecmp.cmp(tree / "results" / f, built_tree / "results" / f, shallow=False)]
    assert differing == []


def test_slurm_setup_is_idempotent() -> None:
    """.ci/slurm-setup run again on a running cluster installs, rewrites and restarts nothing."""
    _, unusable = slurm_config()
    if unusable:
        pytest.skip(unusable)
    if os.geteuid() != 0:
        pytest.skip(".ci/slurm-setup needs root (it installs packages and starts daemons)")
    done = subprocess.run(["bash", str(ROOT / ".ci" / "slurm-setup")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.findall(r"^slurm-setup: (\w+)", done.stdout, flags=re.MULTILINE) == ["ready"], done.stdout
