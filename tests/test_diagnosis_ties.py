"""Ties are called ties (issue 30 item 3): two candidates that remove the same residual on the same joints.

A wrist whose friction is part dry, part viscous, on a motion that spends most of its time at moderate speed:
a Coulomb law (its smoothing refined) and a viscous law each remove about the same share of the residual. The
diagnosis must not present one of them as a decision: it says the two are not told apart on these runs,
within the spread of their scores over blocks of the holdout, recommends one for a stated reason (the
best-scoring, both being plausible), and names the run the experiment design builds to separate them.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from diagnosis_rows import evidence
from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run
from sysid_lab import side_ladder
from sim2real.identification import fitting
from sim2real.identification.diagnosis.caveats import (
    bound_changes, caveat_notes, implausible_bodies, nested_pair, recommend, tied,
)
from sim2real.report.verdicts import NOTE_TEXT
from sim2real.excitation.names import separation_name

def caveats(best: dict, group: list) -> str:
    """The words the report gives a named candidate's caveats (sim2real.report.verdicts)."""
    return "".join(NOTE_TEXT[note.kind](note, "panda") for note in caveat_notes(best, group))


FAST = {"fit": {"fit_rate_hz": 100.0, "bootstrap_replicates": 20, "refine_max_samples": 1500}}


@pytest.fixture(scope="module")
def wrist_friction() -> dict:
    nominal = fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")
    dry, viscous = np.zeros(len(PANDA_JOINTS)), np.zeros(len(PANDA_JOINTS))
    dry[-1], viscous[-1] = 0.03, 0.15  # N*m and N*m*s/rad on joint 7, the noise 0.01 N*m
    hidden = {"coulomb_friction": dry, "viscous_friction": viscous}
    data = [fitting.stack_runs([make_run(name, hidden, seed, duration=12.0, noise=0.01)], PANDA_JOINTS, 100.0)
            for name, seed in (("fit", 5), ("holdout", 6))]
    document, _ = side_ladder([], nominal, data[0], data[1], FAST["fit"])
    return document["diagnosis"]


def test_two_candidates_that_remove_the_same_residual_are_called_not_told_apart(wrist_friction):
    diagnosis = wrist_friction
    assert set(diagnosis["tied"]) >= {"coulomb_friction", "viscous_friction"}, diagnosis["verdict"]
    assert diagnosis["status"] == "add_effect"
    named = diagnosis["candidates"][0]
    assert named["effect"] in ("coulomb_friction", "viscous_friction") and "panda_joint7" in named["joints"]
    other = ({"coulomb_friction", "viscous_friction"} - {named["effect"]}).pop()
    verdict = diagnosis["verdict"]
    assert f"On these runs it is not told apart from {other}" in verdict, verdict
    assert "it scores best of them and keeps the model plausible" in verdict, "both plausible: the best-scoring"
    # the run the experiment design builds for the pair, as a command the user can run
    run = separation_name(named["effect"], other)
    assert f"`snakemake results/panda/excitation/{run}.csv`" in verdict, verdict
    # the test's numbers ride with the candidate that was tied with the best-scoring one
    tie = next(c["evidence"]["tie_with_best"] for c in diagnosis["candidates"] if "tie_with_best" in c["evidence"])
    assert abs(tie["difference"]) <= 2.0 * tie["spread"], tie


def test_a_clear_winner_is_not_called_a_tie():
    rng = np.random.default_rng(0)
    better = rng.normal(10.0, 1.0, size=20)
    worse = better + 3.0 + rng.normal(0.0, 0.2, size=20)  # worse on every block
    same = better + rng.normal(0.0, 1.0, size=20)  # differs by noise only
    assert not tied(worse, better)[0]
    assert tied(same, better)[0]


def test_nested_effects_are_parsimony_not_a_tie():
    assert nested_pair("coulomb_friction", "asymmetric_friction") and nested_pair("link_inertia", "payload")
    assert not nested_pair("torque_gain", "rotor_inertia")


def _fit(bodies: dict) -> SimpleNamespace:
    """A fit whose link inertias hold ``bodies`` (name -> its binding bounds and implausible reasons)."""
    return SimpleNamespace(values={"link_inertia": {"bodies": {
        name: {"binding": list(bounds), "implausible": list(reasons)} for name, (bounds, reasons) in bodies.items()}}})


def _candidate(effect: str, trial: SimpleNamespace, current: SimpleNamespace, x_floor: float) -> dict:
    return {"effect": effect, "decisive": True, "joints": ["panda_joint2"], "explained": 0.5,
            "evidence": evidence(x_floor_after=x_floor, trades_with=(), parameters=7,
                                 implausible_bodies=tuple(implausible_bodies(trial, current)),
                                 bounds_pushed=bound_changes(trial, current)["pushes"],
                                 bounds_released=bound_changes(trial, current)["releases"])}


def test_a_candidate_is_judged_on_what_it_changes_never_on_the_state_it_inherits():
    """The current model holds panda_link2 at its mass bound (and, fitted without bands, bent link 3): a candidate
    whose trial keeps that state and lowers the residual is recommended, tied or not; one that pushes a new bound
    is the one cautioned, and loses a tie to one that does not; a condition every tied candidate shares tells none
    of them apart."""
    current = _fit({"panda_link2": (["mass_upper"], []), "panda_link3": ([], ["mass changed by +80%"])})
    same = _fit({"panda_link2": (["mass_upper"], []), "panda_link3": ([], ["mass changed by +80%"])})
    assert implausible_bodies(same, current) == [] and bound_changes(same, current) == {"pushes": {}, "releases": {}}
    assert implausible_bodies(same) == [{"body": "panda_link3", "reasons": ["mass changed by +80%"]}], "judged alone, the state is there"

    keeps = _candidate("rotor_inertia", same, current, 1.2)
    released = _fit({"panda_link3": ([], ["mass changed by +80%"])})
    releases = _candidate("torque_gain", released, current, 1.25)
    assert releases["evidence"].bounds_pushed == {} and releases["evidence"].bounds_released == {
        "panda_link2": ["mass_upper"]}
    pushed = _fit({"panda_link2": (["mass_upper"], []), "panda_link4": (["hull"], []),
                   "panda_link3": ([], ["mass changed by +80%"])})
    pushes = _candidate("viscous_friction", pushed, current, 1.1)

    ranked, chosen = recommend([keeps, releases], [releases])
    assert chosen is keeps and ranked[0] is keeps, "a tie of two that each keep or improve the state: the best"
    ranked, chosen = recommend([pushes, keeps], [keeps])
    assert chosen is keeps, "of a tie, the one that pushes no new bound"
    assert "pushes link inertias to their bounds (panda_link4 (centre of mass on its hull))" in caveats(pushes, [pushes])
    assert "Caution" not in caveats(keeps, [keeps])
    both = _candidate("stribeck_friction", pushed, current, 1.12)
    ranked, chosen = recommend([pushes, both], [both])
    assert chosen is pushes, "the same new bound on every tied candidate: the best, cautioned"
    assert recommend([pushes], [])[1] is pushes, "untied, the best is recommended and its trouble said"
