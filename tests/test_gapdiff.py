"""The reviewer-facing diff of two gap reports: each side's verdict, what changed beyond the noise, what to look at."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from sim2real.errors import InputError
from sim2real.report.gapdiff import NO_CHANGE, gap_diff_markdown, load_gap, resolution

JOINTS = ["j1", "j2"]
ADD = "On the body link, the model is missing {}: it explains 80% of the holdout residual. Add the line."
FLOOR = "Nothing to add on the body link: every joint's holdout residual is within 1.5x its own noise floor."


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
        "runs": [{"name": "h", "role": "holdout", "duration_s": 20.0, "filter": {"cutoff_hz": 10.0}}],
        "ladder": ladder,
        "noise_floor": {"torque_rmse": {"overall": 0.05, "per_joint": {"j1": 0.04, "j2": 0.06}}},
        "diagnosis": {"status": "add_effect" if top else "at_noise_floor", "candidates": candidates,
                      "verdict": ADD.format(top) if top else FLOOR},
    }


def test_fits_that_differ_within_the_noise_mark_every_joint_unchanged() -> None:
    base = _report([([], [1.0, 2.0]), (["link_inertia"], [0.05, 0.07])], top="coulomb_friction")
    head = copy.deepcopy(base)
    for rung in head["ladder"]:  # 1e-4 N m on floors of 0.04-0.06 N m: what the issue saw marked red and green
        rung["metrics"]["torque_rmse"]["per_joint"] = {j: v + 8.4e-5 for j, v in rung["metrics"]["torque_rmse"]["per_joint"].items()}
        rung["metrics"]["torque_rmse"]["overall"] += 8.4e-5
    text = gap_diff_markdown(base, head)
    assert "🔴" not in text and "🟢" not in text
    assert f"**{NO_CHANGE}**" in text and "Look at" not in text
    assert "| j1 | 0.05 | 0.05008 | ⚪ within the noise (+8.4e-05) | 0.04 |" in text
    assert "| + link_inertia | 0.06 N·m | 0.06008 N·m | ⚪ within the noise |" in text
    assert "Base: the same verdict." in text and "this branch: On the body link, the model is missing coulomb_friction" in text


def test_a_rung_worse_beyond_the_noise_is_red_with_each_sides_verdict() -> None:
    base = _report([([], [1.0, 2.0]), (["link_inertia"], [0.05, 0.07])], top="coulomb_friction")
    head = _report([([], [1.0, 2.0]), (["link_inertia"], [0.05, 0.09])], top=None)
    text = gap_diff_markdown(base, head)
    look = text[text.index("**Look at:**"):text.index("| rung |")]
    assert "- 🔴 rung `+ link_inertia` is worse beyond the noise. Base verdict: On the body link, the model is " \
           "missing coulomb_friction: it explains 80% of the holdout residual. This branch: Nothing to add" in look
    assert "- The verdict changed (above)." in look
    assert "What changed: the status went from an effect to add to at the noise floor." in text
    assert "| j2 | 0.07 | 0.09 | 🔴 +0.02 (+28.6%) | 0.06 |" in text
    assert "| j1 | 0.05 | 0.05 | ⚪ within the noise (+0) | 0.04 |" in text
    assert "| nominal | 1.5 N·m | 1.5 N·m | ⚪ within the noise |" in text
    assert NO_CHANGE not in text
    better = gap_diff_markdown(head, base)
    assert "| j2 | 0.09 | 0.07 | 🟢 -0.02 (-22.2%) | 0.06 |" in better and "🔴" not in better


def test_what_the_noise_resolves_grows_with_the_floor_and_shrinks_with_the_holdout() -> None:
    assert resolution(0.05, 0.05, None) == pytest.approx(0.025 * 0.05)  # reproducibility alone
    short, long = resolution(0.05, 0.05, 100.0), resolution(0.05, 0.05, 10000.0)
    assert short > long >= 0.025 * 0.05
    assert resolution(0.5, 0.05, 400.0) > resolution(0.05, 0.05, 400.0)  # a model error adds to the spread
    assert resolution(2.0, None, None) == pytest.approx(0.02)


def test_a_body_newly_held_at_a_bound_or_implausible_is_named() -> None:
    base = _report([([], [1.0, 2.0]), (["link_inertia"], [0.05, 0.07])], top=None)
    head = copy.deepcopy(base)
    bodies = {"link3": {"binding": [], "implausible": []}}
    base["ladder"][-1]["params"] = {"link_inertia": {"bodies": copy.deepcopy(bodies)}}
    bodies["link3"] = {"binding": ["mass_upper"], "implausible": ["mass 80% above CAD"]}
    head["ladder"][-1]["params"] = {"link_inertia": {"bodies": bodies}}
    text = gap_diff_markdown(base, head)
    assert "- **link3** newly held at a bound: mass at its band's upper edge." in text
    assert "- **link3** newly implausible: mass 80% above CAD." in text
    assert NO_CHANGE not in text


def test_a_changed_line_to_add_is_the_change_of_the_verdict() -> None:
    base = _report([([], [1.0, 2.0])], top="coulomb_friction")
    head = _report([([], [1.0, 2.0])], top="viscous_friction")
    text = gap_diff_markdown(base, head)
    assert "What changed: the line to add went from `- coulomb_friction` to `- viscous_friction`." in text
    assert "Base: On the body link, the model is missing coulomb_friction" in text


def test_diff_shows_each_rung_joint_and_the_new_rung() -> None:
    base = _report([([], [1.0, 2.0])], top="coulomb_friction")
    head = _report([([], [1.0, 2.0]), (["coulomb_friction"], [0.1, 0.2])], top=None)
    text = gap_diff_markdown(base, head)
    assert "| + coulomb_friction | – | 0.15 N·m | new |" in text
    # per joint, the model each branch ends with: the base's nominal against this branch's new last rung
    assert "the model it calibrates (base nominal, this branch + coulomb_friction)" in text
    assert "| j2 | 2 | 0.2 | 🟢 -1.8 (-90.0%) | 0.06 |" in text


def test_diff_shows_the_actuator_link_when_the_runs_have_one() -> None:
    base = _report([([], [1.0, 2.0])], top=None)
    head = _report([([], [1.0, 2.0])], top=None)
    base["actuator"] = _report([([], [0.08, 0.09])], top="actuation_delay")
    head["actuator"] = _report([([], [0.08, 0.09]), (["actuation_delay"], [0.02, 0.02])], top=None)
    text = gap_diff_markdown(base, head)
    link = text[text.index("Ladder (actuator link)"):]
    assert "| + actuation_delay | – | 0.02 N·m | new |" in link
    assert "**Verdict (actuator link)** — this branch: Nothing to add" in text
    assert "Base: On the body link, the model is missing actuation_delay" in text
    assert "actuator link" not in gap_diff_markdown(base, _report([([], [1.0, 2.0])], top=None))


def test_cli_without_base_report(tmp_path: Path) -> None:
    head = tmp_path / "gap.json"
    head.write_text(json.dumps(_report([([], [1.0, 2.0])], top="payload")))
    out = subprocess.run(
        [sys.executable, "-m", "sim2real.cli", "gap-diff", str(tmp_path / "missing.json"), str(head)],
        check=True, capture_output=True, text=True,
    ).stdout
    assert "No gap report on the base branch" in out
    assert "this branch: On the body link, the model is missing payload" in out
    assert NO_CHANGE not in out  # nothing to compare with is not "no change"


def test_not_a_gap_report_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "gap.json"
    bad.write_text("{\"runs\": []}")
    with pytest.raises(InputError, match="gap.json: top level: has no 'robot' key"):
        load_gap(bad)
