"""Every command the README and the pages of docs/ show works (issues 21 and 31).

The command list comes from the README and docs/*.md themselves (in that order): each line of their ``bash`` blocks (continuations joined,
``&&`` chains split, comments dropped) must match one entry of COVERAGE, which says how this test runs
it or why it cannot here; a command the README gains without an entry fails the test. The commands run
as written, in the order the README gives them, in a copy of the project at fast settings (coarse
CoACD, short lab runs, few bootstrap replicates) with this test's interpreter: the environment that
``pip install -e '.[test]'`` made, which holds everything ``pip install -e .`` installs (checked below).
The README's ``python`` block runs after them; its ``yaml`` blocks that name a file are that file.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from buildtree import copy_repo, make_fast

ROOT = Path(__file__).resolve().parents[1]
# The README first, then every page of docs/: what a newcomer reads, and every command they may type.
README = "\n".join(path.read_text(encoding="utf-8")
                   for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
pytestmark = pytest.mark.slow

RUN, HELP, SKIP = "run", "help", "skip"
# (pattern, how, why): the first entry whose pattern matches a README command decides.
COVERAGE: list[tuple[str, str, str]] = [
    (r"python3 -m venv \.venv", SKIP, "makes the environment this test runs in"),
    (r"\.venv/bin/pip install (-q )?-e (\.|'\.\[test\]')", SKIP,
     "installs the project: test_install_holds_what_the_readme_needs checks what it brings"),
    (r"(\.venv/bin/)?python -m pytest", SKIP, "the suite this test is part of"),
    (r"python -m mujoco\.viewer .*", SKIP, "needs a display"),
    (r"snakemake all --profile profiles/(slurm|kubernetes)( .*)?", SKIP,
     "needs a cluster: tests/test_slurm.py (local SLURM) and tests/test_scaleout.py (dry runs) cover them"),
    (r"export SNAKEMAKE_STORAGE_S3_.*", SKIP, "credentials of the Kubernetes profile"),
    (r"python benchmarks/(bench_build|bench_gap)\.py( panda)?", SKIP,
     "minutes of cold builds and full-length lab runs; no smaller setting"),
    (r"python benchmarks/(bench_collision_usd|bench_sysid|bench_fleet|bench_real_arm_loop|bench_excitation|bench_loop|fuzz_inputs)\.py", HELP,
     "minutes at their smallest setting: their command line is checked (--help)"),
    (r"python benchmarks/(bench_dr|bench_resources)\.py", RUN, "seconds, on the built results"),
    (r"(\.venv/bin/)?snakemake [^|;&]*", RUN, "Snakemake targets"),
    (r"cat results/\S+", RUN, "a built report"),
]


def readme_blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", README, flags=re.MULTILINE | re.DOTALL)


def readme_commands() -> list[str]:
    """Every shell command of the README's bash blocks, in order."""
    commands = []
    for block in readme_blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"(^|\s)#.*$", "", line).strip()
            commands += [part.strip() for part in line.split("&&") if part.strip()]
    return commands


def coverage(command: str) -> tuple[str, str]:
    for pattern, how, why in COVERAGE:
        if re.fullmatch(pattern, command):
            return how, why
    raise AssertionError(f"README command not covered by tests/test_readme_commands.py: {command!r}; "
                         "add an entry to COVERAGE (run it, or say why it cannot run here)")


def argv(command: str) -> list[str]:
    words = shlex.split(command)
    program = words[0].removeprefix(".venv/bin/")
    if program == "snakemake":
        return [sys.executable, "-m", "snakemake", *words[1:]]
    if program == "python":
        return [sys.executable, *words[1:]]
    return words


def test_every_readme_command_is_covered() -> None:
    commands = readme_commands()
    assert "snakemake all --report results/report.html" in commands
    for command in commands:
        coverage(command)
    with pytest.raises(AssertionError, match="not covered"):
        coverage("snakemake all && rm -rf results")  # a chain the parser would have split; never a pattern


def test_install_holds_what_the_readme_needs() -> None:
    """`pip install -e .` alone brings the report's pygments (snakemake[reports]) and the USD validators."""
    requires = importlib.metadata.requires("sim2real") or []
    main = [r for r in requires if "extra ==" not in r]
    assert any(r.startswith("snakemake[reports]") for r in main), main
    assert not any(r.startswith("hypothesis") for r in main)  # the test extra stays out of the main install
    import pygments  # noqa: F401

    from sim2real.assets.usd_validation import validator_names

    assert validator_names()


def test_readme_yaml_blocks_are_the_files_they_name() -> None:
    named = 0
    for block in readme_blocks("yaml"):
        first = block.splitlines()[0]
        if first.startswith("# configs/"):
            path = ROOT / first[2:].strip()
            assert path.is_file(), f"the README shows {path.relative_to(ROOT)}, which does not exist"
            assert yaml.safe_load(block) == yaml.safe_load(path.read_text()), path
            named += 1
    assert named >= 1


def test_readme_commands_run_as_written(tmp_path: Path) -> None:
    tree = copy_repo(ROOT, tmp_path / "repo")
    make_fast(tree, lab_duration_s=4.0)
    env = {**os.environ, "PYTHONHASHSEED": "0", "MPLBACKEND": "Agg"}
    ran = []
    for command in readme_commands():
        how, _ = coverage(command)
        if how == SKIP:
            continue
        args = argv(command) + (["--help"] if how == HELP else [])
        done = subprocess.run(args, cwd=tree, capture_output=True, text=True, timeout=900, env=env)
        assert done.returncode == 0, f"README command failed: {command}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        ran.append(command)
    assert ".venv/bin/snakemake all" in ran and "snakemake results/fleet.md" in ran
    assert (tree / "results/report.html").stat().st_size > 100_000
    # the shipped demo's two campaigns of one arm are compared (4 s lab runs cannot resolve its drift:
    # tests/test_fleet_workflow.py::test_shipped_demo_names_the_worn_joint runs it at the shipped settings)
    fleet = json.loads((tree / "results/fleet.json").read_text())
    panda = next(arm for arm in fleet["arms"] if arm["arm"] == "panda")
    assert [c["date"] for c in panda["campaigns"]] == ["2026-10", "2026-11"]
    assert panda["comparisons"][0]["values_compared"] > 50
    for block in readme_blocks("python"):
        done = subprocess.run([sys.executable, "-c", block], cwd=tree, capture_output=True, text=True, timeout=300, env=env)
        assert done.returncode == 0, f"README python block failed:\n{block}\n{done.stderr[-3000:]}"
