"""The reviewer-facing diff of two gap reports."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from sim2real.errors import InputError
from sim2real.report.gapdiff import gap_diff_markdown, load_gap

JOINTS = ["j1", "j2"]


def _report(rungs: list[tuple[list[str], list[float]]], top: str | None) -> dict:
    ladder = [
        {
            "effects": effects,
            "params": {},
            "metrics": {
                "torque_rmse": {"overall": sum(v) / len(v), "per_joint": dict(zip(JOINTS, v, strict=True))}
            },
        }
        for effects, v in rungs
    ]
    candidates = [{"effect": top, "joints": ["j2"], "explained": 0.8, "evidence": {}, "add": f"- {top}"}] if top else []
    return {
        "robot": "panda",
        "ladder": ladder,
        "noise_floor": {"torque_rmse": {"overall": 0.05, "per_joint": {"j1": 0.04, "j2": 0.06}}},
        "diagnosis": {"candidates": candidates, "verdict": "residual at the noise floor" if not top else "missing effect"},
    }


def test_diff_shows_each_rung_joint_and_the_new_rung() -> None:
    base = _report([([], [1.0, 2.0])], top="coulomb_friction")
    head = _report([([], [1.0, 2.0]), (["coulomb_friction"], [0.1, 0.2])], top=None)
    text = gap_diff_markdown(base, head)
    assert "| nominal | 1.5 N·m | 1.5 N·m | ⚪ +0 (+0.0%) |" in text
    assert "| + coulomb_friction | – | 0.15 N·m | new |" in text
    # per joint, the model each branch ends with: the base's nominal against this branch's new last rung
    assert "the model it calibrates (base nominal, this branch + coulomb_friction)" in text
    assert "| j2 | 2 | 0.2 | 🟢 -1.8 (-90.0%) | 0.06 |" in text
    assert "base: `coulomb_friction` on j2 (explains 80%)" in text
    assert "this branch: residual at the noise floor" in text


def test_diff_marks_regressions_and_improvements() -> None:
    base = _report([([], [1.0, 2.0])], top=None)
    head = _report([([], [1.0, 3.0])], top=None)
    text = gap_diff_markdown(base, head)
    assert "| j2 | 2 | 3 | 🔴 +1 (+50.0%) | 0.06 |" in text
    better = gap_diff_markdown(head, base)
    assert "| j2 | 3 | 2 | 🟢 -1 (-33.3%) | 0.06 |" in better


def test_diff_shows_the_actuator_link_when_the_runs_have_one() -> None:
    base = _report([([], [1.0, 2.0])], top=None)
    head = _report([([], [1.0, 2.0])], top=None)
    base["actuator"] = _report([([], [0.08, 0.09])], top="actuation_delay")
    head["actuator"] = _report([([], [0.08, 0.09]), (["actuation_delay"], [0.02, 0.02])], top=None)
    text = gap_diff_markdown(base, head)
    link = text[text.index("Actuator link"):]
    assert "| + actuation_delay | – | 0.02 N·m | new |" in link
    assert "actuator link** — base: `actuation_delay` on j2 (explains 80%); this branch: residual at the noise floor" in link
    assert "Actuator link" not in gap_diff_markdown(base, _report([([], [1.0, 2.0])], top=None))


def test_cli_without_base_report(tmp_path: Path) -> None:
    head = tmp_path / "gap.json"
    head.write_text(json.dumps(_report([([], [1.0, 2.0])], top="payload")))
    out = subprocess.run(
        [sys.executable, "-m", "sim2real.cli", "gap-diff", str(tmp_path / "missing.json"), str(head)],
        check=True, capture_output=True, text=True,
    ).stdout
    assert "No gap report on the base branch" in out
    assert "this branch: `payload`" in out


def test_not_a_gap_report_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "gap.json"
    bad.write_text("{\"runs\": []}")
    with pytest.raises(InputError, match="gap.json: top level: has no 'robot' key"):
        load_gap(bad)
