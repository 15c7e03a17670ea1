"""Every command the README and the pages of docs/ show works (issues 21 and 31).

tests/readme.py reads the commands and says how each is covered (COVERAGE); the conftest's ``readme_run`` runs
them as written, in order, in a fast copy of the project, once for the suite (the tests that need a built tree
copy it). The environment is the one the README's install of ``-e '.[test]'`` made, which holds
everything the install of ``-e .`` brings (checked below). The ``python`` blocks of the README and docs run after them
in the tree they built (docs/python.md's fits the demo's runs, and its test reads what it prints); the ``yaml`` blocks
that name a file are that file.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from readme import ReadmeRun, coverage, readme_blocks, readme_commands

ROOT = Path(__file__).resolve().parents[1]
PYTHON_PAGE = ROOT / "docs" / "python.md"
# what docs/python.md prints after its ladder: each link's diagnosis, "<status> - <verdict>"
STATUSES = ("add_effect", "not_told_apart", "at_noise_floor", "unexplained")
pytestmark = pytest.mark.slow


def run_python_block(block: str, tree: Path) -> str:
    """A documented ``python`` block run in a built tree, as a reader would paste it; what it printed."""
    env = {**os.environ, "PYTHONHASHSEED": "0", "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, "-c", block], cwd=tree, capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, f"documented python block failed:\n{block}\n{done.stderr[-3000:]}"
    return done.stdout


def test_every_readme_command_is_covered() -> None:
    commands = readme_commands()
    assert "snakemake all --report results/report.html" in commands
    for command in commands:
        coverage(command)
    with pytest.raises(AssertionError, match="not covered"):
        coverage("snakemake all && rm -rf results")  # a chain the parser would have split; never a pattern


def test_install_holds_what_the_readme_needs() -> None:
    """The README's install of `-e .` alone brings the report's pygments (snakemake[reports]) and the USD validators."""
    requires = importlib.metadata.requires("sim2real") or []
    main = [r for r in requires if "extra ==" not in r]
    assert any(r.startswith("snakemake[reports]") for r in main), main
    assert not any(r.startswith("hypothesis") for r in main)  # the test extra stays out of the main install
    # Snakemake imports every installed executor and storage plugin at its start: the scale-out ones are an extra
    plugins = [r for r in requires if r.startswith("snakemake-") and "plugin" in r]
    assert len(plugins) == 3 and all('extra == "cluster"' in r for r in plugins), plugins
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


def test_readme_commands_run_as_written(readme_run: ReadmeRun) -> None:
    tree, ran = readme_run.tree, readme_run.ran
    assert ".venv/bin/snakemake all" in ran and "snakemake results/fleet.md" in ran
    assert (tree / "results/report.html").stat().st_size > 100_000
    # the shipped demo's two campaigns of one arm are compared (4 s lab runs cannot resolve its drift:
    # tests/test_fleet_workflow.py::test_shipped_demo_names_the_worn_joint runs it at the shipped settings)
    fleet = json.loads((tree / "results/fleet.json").read_text())
    panda = next(arm for arm in fleet["arms"] if arm["arm"] == "panda")
    assert [c["date"] for c in panda["campaigns"]] == ["2026-10", "2026-11"]
    assert panda["comparisons"][0]["values_compared"] > 50
    python_page = readme_blocks("python", PYTHON_PAGE.read_text(encoding="utf-8"))
    for block in readme_blocks("python"):
        if block not in python_page:  # the test below runs those and reads what they print
            run_python_block(block, tree)


def test_the_python_page_fits_the_demo_runs_and_prints_each_links_verdict(readme_run: ReadmeRun) -> None:
    [block] = readme_blocks("python", PYTHON_PAGE.read_text(encoding="utf-8"))
    lines = run_python_block(block, readme_run.tree).splitlines()
    rungs = [found.groups() for line in lines if (found := re.match(r"(nominal|\+ \w+) +([0-9.]+) N\*m", line))]
    assert [name for name, _ in rungs] == ["nominal", "+ link_inertia", "+ viscous_friction"], lines
    # most of the demo arm's gap to its URDF is in its link inertias and friction
    assert float(rungs[-1][1]) < float(rungs[0][1]) / 2, lines
    verdicts = [line.split(" - ", 1) for line in lines if line.startswith(STATUSES)]
    # the lab's runs log the measured and the commanded torque: the body link and the actuator link are judged apart
    assert len(verdicts) == 2, lines
    for (status, verdict), link in zip(verdicts, ("body link", "actuator link"), strict=True):
        assert status in STATUSES and f"the {link}" in verdict, (status, verdict)
        if status == "add_effect":
            assert "Add the line '- " in verdict and "configs/panda/model.yaml" in verdict, verdict
