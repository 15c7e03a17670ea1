"""The local SLURM cluster of tests/test_slurm.py and the Panda's build through `--profile profiles/slurm` on it.

The build mostly waits on SLURM's scheduler and on the executor's status polls (a few CPU-seconds of jobs between
tens of seconds of waiting), so the process that will run the test starts it as soon as it starts the shared built
tree (conftest's ``readme_run``), and the tests before it run meanwhile; the test then reads its log.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from buildtree import copy_repo, make_fast
from readme import README_LAB_DURATION_S

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ["results/panda/mjcf/panda.xml", "results/panda/gap.json"]
# At fast settings a mesh or CoACD job takes seconds, far less than a SLURM job's start and status
# polling: the build sends the whole mesh stage as one SLURM job (a Snakemake job group).
FAST_GROUPS = ["--groups", "visual_mesh=meshes", "coacd=meshes", "--group-components", "meshes=1000"]
BUILD_TIMEOUT_S = 1800


def slurm_config() -> tuple[dict[str, str], str | None]:
    """`scontrol show config` as a dict, and why SLURM cannot run the test here (None: it can)."""
    missing = [tool for tool in ("sbatch", "squeue", "scontrol", "sinfo") if shutil.which(tool) is None]
    if missing:
        return {}, f"SLURM is not installed ({', '.join(missing)} not found): run .ci/slurm-setup as root"
    done = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        return {}, f"SLURM is installed but slurmctld does not answer ({done.stderr.strip()}): run .ci/slurm-setup"
    config = dict(re.findall(r"^(\S+)\s*=\s*(.*?)\s*$", done.stdout, flags=re.MULTILINE))
    state = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True, timeout=30).stdout.split()
    if not {"idle", "mixed", "allocated"} & set(state):
        return config, f"SLURM runs but no node takes jobs (sinfo: {state or 'no node'}): run .ci/slurm-setup"
    if config.get("JobCompType") != "jobcomp/filetxt" or not Path(config.get("JobCompLoc", "")).is_file():
        return config, ("SLURM keeps no job completion log (JobCompType=jobcomp/filetxt) to check the jobs against: "
                        "run .ci/slurm-setup")
    return config, None


@dataclass
class SlurmBuild:
    """The Panda's MJCF and gap report built through the SLURM profile in a fast copy of the project (the settings
    of the suite's shared tree, tests/readme.py), running in the background until :meth:`log` is asked for."""

    tree: Path
    process: subprocess.Popen

    @classmethod
    def start(cls, workdir: Path) -> SlurmBuild:
        tree = copy_repo(ROOT, workdir / "slurm")
        make_fast(tree, README_LAB_DURATION_S)
        process = subprocess.Popen(
            [sys.executable, "-m", "snakemake", "--cores", "2", *TARGETS, "--profile", "profiles/slurm", *FAST_GROUPS,
             "--slurm-init-seconds-before-status-checks", "2"],
            cwd=tree, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            env={**os.environ, "PYTHONHASHSEED": "0"},
        )
        return cls(tree, process)

    def log(self) -> str:
        """Snakemake's output once the build has finished; fails with its tail if the build failed."""
        out, _ = self.process.communicate(timeout=BUILD_TIMEOUT_S)
        assert self.process.returncode == 0, out[-8000:]
        return out

    def stop(self) -> None:
        """Stop a build nobody asked for (the suite ended first): Snakemake cancels its SLURM jobs."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                self.process.kill()
