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
import shutil
import subprocess
from pathlib import Path

import pytest

from buildtree import comparable_outputs, copy_repo, make_fast, run_snakemake
from readme import README_LAB_DURATION_S

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ["results/panda/mjcf/panda.xml", "results/panda/gap.json"]
# At fast settings a mesh or CoACD job takes seconds, far less than a SLURM job's start and status
# polling: the test sends the whole mesh stage as one SLURM job (a Snakemake job group).
FAST_GROUPS = ["--groups", "visual_mesh=meshes", "coacd=meshes", "--group-components", "meshes=1000"]
pytestmark = pytest.mark.slow


def _slurm_config() -> dict[str, str]:
    """`scontrol show config` as a dict; skips the test (saying why) where SLURM is not usable."""
    missing = [tool for tool in ("sbatch", "squeue", "scontrol", "sinfo") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"SLURM is not installed ({', '.join(missing)} not found): run .ci/slurm-setup as root")
    done = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        pytest.skip(f"SLURM is installed but slurmctld does not answer ({done.stderr.strip()}): run .ci/slurm-setup")
    config = dict(re.findall(r"^(\S+)\s*=\s*(.*?)\s*$", done.stdout, flags=re.MULTILINE))
    state = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True, timeout=30).stdout.split()
    if not {"idle", "mixed", "allocated"} & set(state):
        pytest.skip(f"SLURM runs but no node takes jobs (sinfo: {state or 'no node'}): run .ci/slurm-setup")
    if config.get("JobCompType") != "jobcomp/filetxt" or not Path(config.get("JobCompLoc", "")).is_file():
        pytest.skip("SLURM keeps no job completion log (JobCompType=jobcomp/filetxt) to check the jobs against: "
                    "run .ci/slurm-setup")
    return config


def _completed_jobs(jobcomp_log: Path) -> dict[str, dict[str, str]]:
    """SLURM's record of every finished job: {JobId: {JobState, Name, NodeList, Partition, ...}}."""
    jobs = {}
    for line in jobcomp_log.read_text().splitlines():
        fields = dict(re.findall(r"(\w+)=(\S*)", line))
        if "JobId" in fields:
            jobs[fields["JobId"]] = fields
    return jobs


def test_panda_mjcf_and_gap_report_through_the_slurm_profile(tmp_path: Path, built_tree: Path) -> None:
    config = _slurm_config()
    # The settings of the suite's shared tree, built locally by the README's commands: the reference to compare with.
    tree = copy_repo(ROOT, tmp_path / "slurm")
    make_fast(tree, README_LAB_DURATION_S)
    log = run_snakemake(tree, *TARGETS, "--profile", "profiles/slurm", *FAST_GROUPS,
                        "--slurm-init-seconds-before-status-checks", "2", timeout=1800)

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
    _slurm_config()
    if os.geteuid() != 0:
        pytest.skip(".ci/slurm-setup needs root (it installs packages and starts daemons)")
    done = subprocess.run(["bash", str(ROOT / ".ci" / "slurm-setup")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.findall(r"^slurm-setup: (\w+)", done.stdout, flags=re.MULTILINE) == ["ready"], done.stdout
