"""docs/new-robot.md followed from nothing to a gap report: its files written as it shows them into a copy of the
project that has no such arm, its commands run as written (fast settings: short lab runs, few bootstrap replicates),
and the report's sections the page describes found in the report."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import mujoco
import pytest

from buildtree import copy_repo, make_fast, run_snakemake
from sim2real.dr import resolve_files
from readme import readme_blocks

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "new-robot.md"
ARM = "arm3"


def documented_files(text: str) -> dict[str, str]:
    """{path: content} of the page's blocks whose first lines say ``file <path>`` (a YAML or an XML comment)."""
    files = {}
    for language in ("xml", "yaml"):
        for block in readme_blocks(language, text):
            for line in block.splitlines()[:2]:
                named = re.fullmatch(r"(?:#|<!--) file (\S+)(?: -->)?", line.strip())
                if named:
                    files[named.group(1)] = block
                    break
    return files


def documented_commands(text: str) -> list[list[str]]:
    """The page's shell commands, each as its words."""
    return [shlex.split(line) for block in readme_blocks("bash", text) for line in block.splitlines() if line.strip()]


def report_sections(text: str) -> list[str]:
    """The sections the page's last part names, in bold: **Runs**, **Torque domain**, ..."""
    part = text[text.index("## 8. What the report says"):]
    return re.findall(r"^- \*\*([^*]+)\*\*", part, flags=re.MULTILINE)


@pytest.mark.slow
def test_the_page_takes_a_new_arm_from_nothing_to_its_gap_report(tmp_path: Path) -> None:
    text = PAGE.read_text(encoding="utf-8")
    tree = copy_repo(ROOT, tmp_path / "repo")
    assert not (tree / "robots" / ARM).exists() and not (tree / "configs" / ARM).exists()
    files = documented_files(text)
    assert {f"robots/{ARM}/{ARM}.urdf.xacro", "configs/config.yaml"} | {
        f"configs/{ARM}/{name}.yaml" for name in ("robot", "lab", "measurements", "model", "dr")} <= set(files)
    for path, content in files.items():
        (tree / path).parent.mkdir(parents=True, exist_ok=True)
        (tree / path).write_text(content, encoding="utf-8")
    make_fast(tree, lab_duration_s=4.0)
    commands = documented_commands(text)
    assert commands and all(words[0] == "snakemake" for words in commands)
    for words in commands:
        run_snakemake(tree, *words[1:])
    results = tree / "results" / ARM
    gap = json.loads((results / "gap.json").read_text())
    assert gap["robot"] == ARM
    assert gap["joints"] == [f"{ARM}_joint{i}" for i in (1, 2, 3)]
    # the lab hides the drives' viscous friction and links heavier and lighter than the URDF's: the diagnosis names
    # what the model lacks, the larger of them first
    assert gap["diagnosis"]["status"] == "add_effect"
    candidates = [candidate["effect"] for candidate in gap["diagnosis"]["candidates"]]
    assert candidates[0] in {"viscous_friction", "link_inertia"} and "link_inertia" in candidates, gap["diagnosis"]["verdict"]
    markdown = (results / "gap.md").read_text()
    headings = re.findall(r"^##+ (.+)$", markdown, flags=re.MULTILINE)
    for section in report_sections(text):
        assert any(h.startswith(section) for h in headings), (section, headings)
    model = mujoco.MjModel.from_xml_path(str(results / "mjcf" / f"{ARM}.xml"))
    assert model.nu == 3 and model.body("arm3_flange").mass[0] == 0.0
    # what `snakemake all` adds reads the page's dr.yaml: its selectors match the built MJCF
    resolved = resolve_files(tree / "configs" / ARM / "dr.yaml", results / "mjcf" / f"{ARM}.xml", robot=ARM)
    assert {channel["term"] for channel in resolved["physics"]} == {"body_mass", "joint_damping"}
