"""The README and the pages of docs/ as commands (issues 21 and 31), and one fast copy of the project in which
they ran as written: the built tree the tests that need one share.

The command list comes from the README and docs/*.md themselves (in that order): each line of their ``bash`` blocks
(continuations joined, ``&&`` chains split, comments dropped) must match one entry of COVERAGE, which says how the
tests run it or why they cannot here. The commands run as written, in the order the README gives them, in a copy of
the project at fast settings (coarse CoACD, short lab runs, few bootstrap replicates) with the tests' interpreter.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from buildtree import SNAKEMAKE, copy_repo, make_fast

ROOT = Path(__file__).resolve().parents[1]
# The README first, then every page of docs/: what a newcomer reads, and every command they may type.
README = "\n".join(path.read_text(encoding="utf-8")
                   for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
RUN, HELP, SKIP = "run", "help", "skip"
# (pattern, how, why): the first entry whose pattern matches a README command decides.
COVERAGE: list[tuple[str, str, str]] = [
    (r"python3 -m venv \.venv", SKIP, "makes the environment this test runs in"),
    (r"\.venv/bin/pip install -q uv", SKIP, "installs the installer of the next command"),
    (r"\.venv/bin/uv pip install (-q )?-p \.venv/bin/python --compile-bytecode -e (\.|'\.\[test\]')", SKIP,
     "installs the project: test_install_holds_what_the_readme_needs checks what it brings"),
    (r"(\.venv/bin/)?python -m pytest", SKIP, "the suite this test is part of"),
    (r"python -m mujoco\.viewer .*", SKIP, "needs a display"),
    (r"snakemake all --profile profiles/(slurm|kubernetes)( .*)?", SKIP,
     "needs a cluster: tests/test_slurm.py (local SLURM) and tests/test_scaleout.py (dry runs) cover them"),
    (r"export SNAKEMAKE_STORAGE_S3_.*", SKIP, "credentials of the Kubernetes profile"),
    (r"python benchmarks/(bench_build|bench_gap)\.py( panda)?", SKIP,
     "minutes of cold builds and full-length lab runs; no smaller setting"),
    (r"python benchmarks/(bench_collision_usd|bench_sysid|bench_fleet|bench_real_arm_loop|bench_excitation|bench_loop|bench_runs|bench_cold_build|bench_pinned_spread|bench_verdict_sweep|fuzz_inputs)\.py", HELP,
     "minutes at their smallest setting: their command line is checked (--help)"),
    (r"python benchmarks/(bench_dr|bench_resources)\.py", RUN, "seconds, on the built results"),
    (r"snakemake results/arm3/gap\.json", SKIP,
     "docs/new-robot.md's example arm: tests/test_new_robot.py writes it into a copy of the project and runs these"),
    (r"(\.venv/bin/)?snakemake [^|;&]*", RUN, "Snakemake targets"),
    (r"cat results/\S+", RUN, "a built report"),
]


def readme_blocks(language: str, text: str = README) -> list[str]:
    """The ``language`` code blocks of ``text`` (default: the README and every page of docs/), in order."""
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)


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
        return [*SNAKEMAKE, *words[1:]]
    if program == "python":
        return [sys.executable, *words[1:]]
    return words




README_LAB_DURATION_S = 4.0  # s: what the fits find is not what the commands' test checks


@dataclass(frozen=True)
class ReadmeRun:
    tree: Path        # read-only for the tests: copy it (copy_built) before building or editing in it
    ran: list[str]    # the commands run, in order


def run_readme(root: Path, workdir: Path) -> ReadmeRun:
    """The README's commands, as written and in order, in a fast copy of the project; fails on the first that
    fails, with its output."""
    tree = copy_repo(root, workdir / "repo")
    make_fast(tree, lab_duration_s=README_LAB_DURATION_S)
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
    return ReadmeRun(tree, ran)


def copy_built(built: Path, dest: Path, shipped: Sequence[str] = ()) -> Path:
    """A copy of a built tree that Snakemake sees as built: file times and .snakemake's metadata kept.
    ``shipped``: config files (relative paths) put back as the repository ships them, for a test that needs the
    shipped lab runs or fit settings rather than the shared tree's fast ones (their files are written anew, so
    Snakemake sees them changed and reruns what depends on them)."""
    shutil.copytree(built, dest, symlinks=True)
    for name in shipped:
        (dest / name).write_text((ROOT / name).read_text(encoding="utf-8"), encoding="utf-8")
    return dest
