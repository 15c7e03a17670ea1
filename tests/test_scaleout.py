"""Scale out: every rule says what it needs, and the cluster profiles plan the DAG on their executors."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import yaml

from buildtree import SNAKEMAKE, copy_repo

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "benchmarks") not in sys.path:  # the declared resources and measured peaks: bench_resources.py's helper
    sys.path.insert(0, str(ROOT / "benchmarks"))
from resources import declared_resources, exceeded, measured_resources, resource_table, undeclared  # noqa: E402

TINY_RULES = {"collision_mesh", "collision_report", "lab_truth", "dr_resolve", "dr_summary", "fleet"}


def _snakemake(*args: str, stdout_only: bool = False, cwd: Path = ROOT, scale_out: bool = False) -> str:
    """``scale_out``: with the executor and storage plugins a scale-out profile needs (else as buildtree.SNAKEMAKE)."""
    command = [sys.executable, "-m", "snakemake"] if scale_out else SNAKEMAKE
    done = subprocess.run([*command, *args], cwd=cwd, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONHASHSEED": "0"})
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout if stdout_only else done.stdout + done.stderr


def test_every_rule_declares_threads_memory_and_runtime() -> None:
    declared = declared_resources(ROOT / "rules")
    listed = set(_snakemake("--list-rules", stdout_only=True).split()) - {"all"}
    assert set(declared) == listed, "the rules files and Snakemake list the same rules"
    assert undeclared(declared) == []
    assert {name for name, d in declared.items() if d["local"]} == TINY_RULES
    heaviest = max(declared, key=lambda name: declared[name]["mem_mb"])
    assert heaviest == "coacd", "CoACD jobs take the most"


def _planned_threads(log: str, rule: str) -> list[int]:
    """The threads a dry run plans for each job of ``rule`` (Snakemake prints them when more than one)."""
    jobs = re.split(r"^(?:local)?rule ", log, flags=re.MULTILINE)[1:]
    return [int(m[1]) if (m := re.search(r"^\s+threads: (\d+)$", job, re.MULTILINE)) else 1
            for job in jobs if job.startswith(f"{rule}:")]


def test_fits_and_reports_ask_one_core_in_a_first_build_and_two_in_a_round(tmp_path: Path, built_tree: Path) -> None:
    """A first build's fits and reports run beside its other jobs on one core each (asking for two, they waited
    until every CoACD job had ended); a round of the loop, with the fits and replays kept, splits its work on two."""
    fresh = copy_repo(ROOT, tmp_path / "repo")
    first = _snakemake("-n", "results/panda/gap.json", cwd=fresh)
    assert _planned_threads(first, "sysid") == [1] and _planned_threads(first, "gap_report") == [1], first[-3000:]
    assert (built_tree / "results/panda/sysid/fits").is_dir() and (built_tree / "results/panda/gap/kept").is_dir()
    round_ = _snakemake("-n", "--nolock", "results/panda/gap.json", "--forcerun", "sysid", cwd=built_tree)
    assert _planned_threads(round_, "sysid") == [2] and _planned_threads(round_, "gap_report") == [2], round_[-3000:]


def test_declared_resources_cover_what_benchmarks_measured(tmp_path: Path) -> None:
    results = tmp_path / "results"
    bench = results / "panda" / "benchmarks"
    rows = {"coacd/link3.tsv": (233.9, 1433.0), "sysid.tsv": (16.2, 417.0), "panda_2-2026-10/sysid.tsv": (20.0, 1800.0),
            "collision_summary.tsv": None}
    for rel, figures in rows.items():
        path = bench / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if figures is None:  # a report table that lives under benchmarks/, not a benchmark
            path.write_text("mesh\tparts\nlink3\t12\n")
            continue
        path.write_text("s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
                        f"{figures[0]}\t0:00:10\t{figures[1]}\t1\t1\t1\t0\t0\t90\t{figures[0] * 0.9}\n")
    declared = declared_resources(ROOT / "rules")
    measured = measured_resources(results, declared)
    assert measured["coacd"] == {"jobs": 1, "max_s": 233.9, "max_rss_mb": 1433.0, "max_cpu_s": 233.9 * 0.9}
    assert measured["sysid"]["jobs"] == 2 and measured["sysid"]["max_rss_mb"] == 1800.0  # a campaign's job counts
    # a campaign whose fit needed more memory than sysid declares is reported, naming the rule and the file
    assert exceeded(declared, measured) == [f"{ROOT}/rules/sysid.smk: rule sysid: measured 1800 MB > mem_mb=1536"]
    table = resource_table(declared, measured)
    assert table.splitlines()[2].startswith("| coacd |  | 1 | 2048 | 15 | 1 | 233.9 | 1433 |")


def test_slurm_profile_plans_every_job_on_the_slurm_executor(tmp_path: Path) -> None:
    profile = yaml.safe_load((ROOT / "profiles/slurm/config.yaml").read_text())
    assert profile["executor"] == "slurm"
    # In a clean copy: a checkout where `snakemake all` has run plans nothing (the README's first command, then
    # its second, in one clone).
    log = _snakemake("-n", "--profile", "profiles/slurm", "all", cwd=copy_repo(ROOT, tmp_path / "repo"),
                     scale_out=True)
    assert "Using profiles profiles/slurm" in log
    assert re.search(r"^total\s+\d+", log, flags=re.MULTILINE)
    # what sbatch will be asked for comes from the rule (the dry run stops at the URDF checkpoint)
    urdf_jobs = re.findall(r"^checkpoint urdf:\n(?:    .*\n)*?    resources: (.*)$", log, flags=re.MULTILINE)
    assert urdf_jobs and all("mem_mb=512" in r and "runtime=2" in r for r in urdf_jobs), urdf_jobs


def test_kubernetes_profile_dry_run_against_local_s3(tmp_path: Path) -> None:
    """The Kubernetes profile plans the whole DAG with its S3 default storage (a local S3 endpoint, moto):
    every output in the bucket, every job sized by its rule."""
    import boto3
    from moto.server import ThreadedMotoServer

    profile = yaml.safe_load((ROOT / "profiles/kubernetes/config.yaml").read_text())
    assert profile["executor"] == "kubernetes" and profile["default-storage-provider"] == "s3"
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        endpoint = f"http://{host}:{port}"
        s3 = boto3.client("s3", endpoint_url=endpoint, aws_access_key_id="test", aws_secret_access_key="test",
                          region_name="us-east-1")
        bucket = profile["default-storage-prefix"].removeprefix("s3://").split("/")[0]
        s3.create_bucket(Bucket=bucket)
        sources = subprocess.run(["git", "ls-files", "robots", "configs", "schemas"], cwd=ROOT, check=True,
                                 capture_output=True, text=True).stdout.split()
        for source in sources:  # the README's step: the sources the DAG reads, mirrored into the bucket
            s3.upload_file(str(ROOT / source), bucket, source)
        done = subprocess.run(
            [sys.executable, "-m", "snakemake", "all", "--dry-run", "--profile", "profiles/kubernetes",
             f"--storage-s3-endpoint-url={endpoint}"],
            cwd=ROOT, capture_output=True, text=True, timeout=600,
            env={**os.environ, "SNAKEMAKE_STORAGE_S3_ACCESS_KEY": "test", "SNAKEMAKE_STORAGE_S3_SECRET_KEY": "test"},
        )
    finally:
        server.stop()
    log = done.stdout + done.stderr
    assert "Using profiles profiles/kubernetes" in log
    assert done.returncode == 0, log[-3000:]
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", log, flags=re.MULTILINE))
    assert {"urdf", "mjcf", "lab_run", "sysid", "gap_report", "fleet"} <= set(counts), counts
    assert re.search(r"s3://sim2real/results/panda/gap\.json \(in storage\)", log), "outputs live in the bucket"
    urdf_jobs = re.findall(r"^checkpoint urdf:\n(?:    .*\n)*?    resources: (.*)$", log, flags=re.MULTILINE)
    assert urdf_jobs and all("mem_mb=512" in r and "runtime=2" in r for r in urdf_jobs), urdf_jobs
