"""gap.md's first screen: the verdict in at most three sentences, the ladder and the current model joint by joint
within the first 30 lines, each thing said once; the Snakemake report's HTML item carries the same."""

from __future__ import annotations

import json
import re
from pathlib import Path

from sim2real.report.first_screen import first_screen
from sim2real.report.verdicts import first_screen_verdict

SCREEN = 30


def _sentences(text: str) -> list[str]:
    return [s for s in re.split(r"(?<=[.])\s+(?=[A-Z])", text.strip()) if s]


def test_the_demos_first_screen_holds_verdict_ladder_and_joints(built_tree: Path) -> None:
    gap = json.loads((built_tree / "results/panda/gap.json").read_text())
    md = (built_tree / "results/panda/gap.md").read_text()
    top = md.splitlines()[:SCREEN]
    verdict = next(line for line in top if line.startswith("**Verdict.** "))
    sentences = _sentences(verdict.removeprefix("**Verdict.** "))
    assert 1 <= len(sentences) <= 3, sentences
    assert any(line.startswith("| rung | effects |") for line in top)
    for k, rung in enumerate(gap["ladder"]):
        assert any(line.startswith(f"| {k} | {', '.join(rung['effects']) or 'nominal'} |") for line in top), k
    assert "| joint | RMSE [N m] | noise floor [N m] | x floor |" in "\n".join(top)
    for joint in gap["joints"]:
        assert any(line.startswith(f"| {joint} |") for line in top), joint
    # Said once: the prose names no joint but the worst, which the table lists with what is left on each.
    named = [j for j in gap["joints"] if re.search(rf"\b{re.escape(j)}\b", verdict)]
    assert len(named) <= 1, named
    assert md.count(gap["diagnosis"]["verdict"]) == 1  # the verdict in full, once, further down
    lines = md.splitlines()
    last_joint = max(k for k, line in enumerate(lines[:SCREEN]) if line.startswith(f"| {gap['joints'][-1]} |"))
    assert lines.index("<details>") > last_joint  # nothing collapsed before the table ends
    # The Snakemake report's item: the same first screen.
    html = (built_tree / "results/panda/gap/first_screen.html").read_text()
    screen = first_screen(gap)
    assert " ".join(screen.verdict).split(":")[0] in html
    assert all(f"<td>{joint}</td>" in html for joint in gap["joints"])


def _evidence(x_floor_after: float) -> dict:
    """A candidate's evidence as ladder.json holds it: nothing implausible, no bound pushed, no trade."""
    from diagnosis_rows import evidence_document

    return evidence_document(("j1", "j2", "j3", "j4"), x_floor_after=x_floor_after)


def _reading(kind: str, follows: str | None = None, gains: tuple[str, ...] = ()):
    """A joint's ceiling reading as gap.json holds it (its features in words)."""
    from sim2real.identification.diagnosis.ceiling_records import CeilingReading

    return CeilingReading(
        rung_rmse=0.2, ceiling_rmse=0.1 if kind == "motion" else 0.19, rung_x_floor=4.0, ceiling_x_floor=2.0,
        ratio=0.5, explained_beyond_noise=0.6, kind=kind, fitted=kind != "at_floor",
        learner=None if kind == "at_floor" else "trees on the motion",
        gains_most_with=gains if kind == "motion" else None,
        beyond_motion={"time": 0.7, "run": 0.2, "history": 0.0} if kind == "not_motion" else None, follows=follows)


def _diagnosis(status: str) -> dict:
    from sim2real.identification.diagnosis.ceiling_records import ModelFreeCeiling

    readings = {"j1": _reading("motion", gains=("velocity of j1",)), "j2": _reading("not_motion", "time"),
                "j3": _reading("motion"), "j4": _reading("at_floor")}
    ceiling = ModelFreeCeiling(learner="trees", torque_rmse_overall=0.1,
                               torque_rmse_per_joint={j: r.ceiling_rmse for j, r in readings.items()},
                               close_to_rung=0.8, per_joint=readings)
    return {"link": "body", "status": status, "above_floor": ["j1", "j2", "j3"], "tied": ["a", "b"],
            "candidates": [{"effect": "viscous_friction", "link": "body", "joints": ["j1", "j3"], "decided_on": "arm",
                            "explained": 0.3, "explained_beyond_noise": 0.8, "decisive": True,
                            "add": "- viscous_friction", "evidence": _evidence(1.2), "replaces": []}],
            "model_free": ceiling.as_document()}


def test_the_verdict_says_status_action_and_worst_joint_and_names_kinds_not_joints() -> None:
    x_floor, rmse, floor = {"j1": 3.0, "j2": 2.0, "j3": 1.6, "j4": 1.0}, dict.fromkeys(["j1", "j2", "j3", "j4"], 0.1), \
        dict.fromkeys(["j1", "j2", "j3", "j4"], 0.05)
    unexplained = first_screen_verdict(_diagnosis("unexplained"), "panda", x_floor, rmse, floor)
    assert len(unexplained) == 3
    assert unexplained[0] == "No effect in the library explains what is left on the body link."
    assert unexplained[1] == ("What is left, joint by joint in the table below: a function of the motion the library "
                              "lacks (2 joints); not the motion: drifts with time (1 joint).")
    assert unexplained[2] == "Worst joint: j1, 3.00x its noise floor (0.1 N m against 0.05 N m)."
    added = first_screen_verdict(_diagnosis("add_effect"), "panda", x_floor, rmse, floor)
    assert added[:2] == ["On the body link, the model lacks viscous_friction: it removes 80% of what lies above the "
                         "noise floor, to 1.20x the floor arm-wide.",
                         "Add the line '- viscous_friction' under 'effects:' in configs/panda/model.yaml."]
    trading = _diagnosis("add_effect")
    trading["candidates"][0]["evidence"]["trades_with"] = [{"effect": "coulomb_friction", "moved_x_own_term": 0.9,
                                                             "correlation": -0.9}]
    assert first_screen_verdict(trading, "panda", x_floor, rmse, floor)[1].endswith(
        "in configs/panda/model.yaml; read its caution in the diagnosis below first.")
    on_joints = _diagnosis("add_effect")
    on_joints["candidates"][0]["decided_on"] = "joints"
    assert first_screen_verdict(on_joints, "panda", x_floor, rmse, floor)[0] == (
        "On the body link, the model lacks viscous_friction on 2 joints, where it removes most of what lies above "
        "their floors.")
    tied = first_screen_verdict(_diagnosis("not_told_apart"), "panda", x_floor, rmse, floor)
    assert "a and b each remove part" in tied[0] and "excitation/" in tied[1]
    floor_text = first_screen_verdict(_diagnosis("at_noise_floor"), "panda", x_floor, rmse, floor)
    assert len(floor_text) == 2 and floor_text[0].startswith("Nothing to add on the body link")
    for sentences in (unexplained, added, tied, floor_text):
        assert sum(bool(re.search(rf"\b{j}\b", " ".join(sentences))) for j in x_floor) == 1  # the worst joint alone


def test_gap_diff_of_the_demo_reads_the_noise(built_tree: Path) -> None:
    """The demo's report against itself moved within what the noise resolves: every joint unchanged, "no change
    beyond the noise"; one joint of the last rung worse beyond it: that rung red, with each side's verdict."""
    import copy

    from sim2real.report.gapdiff import NO_CHANGE, gap_diff_markdown, independent_samples, resolution

    base = json.loads((built_tree / "results/panda/gap.json").read_text())
    floors, samples = base["noise_floor"]["torque_rmse"]["per_joint"], independent_samples(base)
    head = copy.deepcopy(base)
    for rung in head["ladder"]:
        per_joint = rung["metrics"]["torque_rmse"]["per_joint"]
        for joint, value in per_joint.items():
            per_joint[joint] = value + 0.5 * resolution(value, floors[joint], samples)
    text = gap_diff_markdown(base, head)
    assert "🔴" not in text and "🟢" not in text and f"**{NO_CHANGE}**" in text
    for joint in base["joints"]:
        assert re.search(rf"^\| {joint} \| .* \| ⚪ within the noise \(\+", text, flags=re.MULTILINE), joint
    worst = head["ladder"][-1]["metrics"]["torque_rmse"]["per_joint"]
    joint = base["joints"][0]
    worst[joint] += 3 * resolution(worst[joint], floors[joint], samples)
    text = gap_diff_markdown(base, head)
    label = "+ " + ", ".join(base["ladder"][-1]["effects"]) if base["ladder"][-1]["effects"] else "nominal"
    assert f"- 🔴 rung `{label}` is worse beyond the noise. Base verdict: " in text and NO_CHANGE not in text
    assert re.search(rf"^\| {joint} \| .* \| 🔴 \+", text, flags=re.MULTILINE)
