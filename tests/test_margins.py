"""The suite passes on any CPU (issue 66): a relabelling is never named, a figure within the arithmetic's precision of
a threshold takes the conservative side and says so, and the consistent fit's "almost solved" is judged by its
measured residuals, never taken on the solver's word.

Another CPU's BLAS kernels move every fitted figure by far more than a float's last bit (benchmarks/
bench_pinned_spread.py, benchmarks/bench_verdict_sweep.py): these tests build the situations such a CPU meets (a
candidate whose term is the model's own relabelled, figures either side of a threshold by less than that move, a
solve Clarabel stops short of its tolerances) on purpose, on this one.
"""

from __future__ import annotations

import copy
import dataclasses

import clarabel
import numpy as np
import pytest

from diagnosis_rows import evidence
from sim2real.identification.diagnosis import candidates as ranking
from sim2real.identification.diagnosis import margins
from sim2real.identification.diagnosis.caveats import caveat_notes, recommend, relabelling
from sim2real.identification.inertial import InertialBlock, conic, physically_consistent
from sim2real.identification.inertial.judged import ACCEPTED
from sim2real.identification.records import Note, NoteKind, Status
from sim2real.report.verdicts import NOTE_TEXT

JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
LIMITS = ranking.DEFAULT_DIAGNOSIS


def candidate(effect: str, explained: float, beyond: float, joints: list[str], x_after: float) -> dict:
    """A decisive candidate as the ranking holds it (diagnosis.candidates._candidate)."""
    return {"effect": effect, "link": "body", "joints": joints, "decided_on": "joints", "explained": explained,
            "explained_beyond_noise": beyond, "decisive": True, "add": f"- {effect}",
            "evidence": evidence(x_floor_after=x_after, parameters=7)}


def words(note: Note) -> str:
    return NOTE_TEXT[note.kind](note, "panda")


def test_a_candidate_that_relabels_the_models_own_term_is_never_recommended():
    """The sensor_gains arm on a Haswell CPU: load_friction named on panda_joint5, its own term given back by the
    asymmetric friction already held (1x its size, correlation -1.00). It is no line to add, on any CPU."""
    relabel = candidate("load_friction", 0.04, 0.35, ["panda_joint5"], 1.02)
    real = candidate("viscous_friction", 0.03, 0.31, ["panda_joint7"], 1.03)
    trades = {"load_friction": [{"effect": "asymmetric_friction", "moved_x_own_term": 1.0, "correlation": -0.998,
                                 "net_x_floor": 0.3}],
              # the real Panda log's trade: part of the term is new, the named candidate is only cautioned
              "viscous_friction": [{"effect": "coulomb_friction", "moved_x_own_term": 0.89, "correlation": -0.83,
                                    "net_x_floor": 0.4}]}
    assert relabelling(trades["load_friction"]) and not relabelling(trades["viscous_friction"])
    # the lab's sensor_gains arm: a torque gain trades as closely with the link inertias' scale, but moves the
    # prediction by several floors: a change the data resolve, no relabelling
    assert not relabelling([{"effect": "link_inertia", "moved_x_own_term": 0.93, "correlation": -0.997,
                             "net_x_floor": 3.1}])
    for alone in ([relabel], [relabel, real]):
        tried = copy.deepcopy(alone)
        demoted = {c["effect"]: list(c["evidence"].relabels) for c in tried
                   if ranking.demote_relabelling(c, trades[c["effect"]])}
        assert set(demoted) == {"load_friction"}
        ranked, recommended = recommend(ranking._rank(tried, 0.1), [])
        status = ranking._status(ranked[0], recommended, above=[])
        assert recommended is None or recommended["effect"] != "load_friction"
        if len(alone) == 1:
            assert status == Status.AT_NOISE_FLOOR and recommended is None, (status, recommended)
        else:  # the real one is still named, with its trade said as a caution
            assert status == Status.ADD_EFFECT and recommended["effect"] == "viscous_friction"
            recommended["evidence"] = dataclasses.replace(recommended["evidence"],
                                                          trades_with=tuple(trades["viscous_friction"]))
            assert "Caution: it trades places with coulomb_friction" in "".join(map(words, caveat_notes(
                recommended, [])))
        said = words(Note(NoteKind.RELABELLED, figures={"relabelled": demoted}))
        assert "Not named: load_friction (asymmetric_friction's term moves against its own, 1x its size, " \
               "correlation -1.00, the prediction moving by 0.3x the floor)" in said and "never a line to add" in said, said


def scores(explained: float, beyond: float, joint_beyond: float) -> dict:
    """A trial's scores (diagnosis.candidates._scores): ``joint_beyond`` of panda_joint5's excess, none elsewhere."""
    per_joint = np.zeros(len(JOINTS))
    per_joint[4] = joint_beyond
    return {"explained": explained, "beyond": beyond, "per_joint_beyond": per_joint, "gain": 1.0,
            "harmed": [False] * len(JOINTS)}


@pytest.mark.parametrize(("this_cpu", "other_cpu", "decisive"), [
    # arm-wide share of the excess, 0.3 named: 0.004 either side of it, less than another kernel moves it
    ((0.2, 0.304, 0.0), (0.2, 0.296, 0.0), False),
    # clear of the margin: named on both
    ((0.2, 0.33, 0.0), (0.2, 0.325, 0.0), True),
    # panda_joint5's share of its excess, 0.5 names it there
    ((0.02, 0.1, 0.505), (0.02, 0.1, 0.497), False),
])
def test_a_decision_does_not_flip_between_cpus_at_the_solvers_precision(this_cpu, other_cpu, decisive):
    x_floor = np.full(len(JOINTS), 1.2)
    x_floor[4] = 2.0
    own = np.ones(len(JOINTS))
    read = [margins.decide(scores(*figures), x_floor, own, JOINTS, LIMITS, ranking.OWN_TERM_MIN, margins.CONSERVATIVE)
            for figures in (this_cpu, other_cpu)]
    assert read[0].decisive == read[1].decisive == decisive
    for figures in (this_cpu, other_cpu):
        near = margins.near_thresholds(scores(*figures), x_floor, own, JOINTS, LIMITS, ranking.OWN_TERM_MIN)
        permissive = margins.decide(scores(*figures), x_floor, own, JOINTS, LIMITS, ranking.OWN_TERM_MIN,
                                    margins.PERMISSIVE)
        assert bool(near) == (permissive.decisive != decisive), near  # said exactly where the margin decided


def test_a_joint_within_the_margin_of_its_floor_is_counted_within_it_and_said_so():
    for worst in (1.49, 1.51):  # one CPU's panda_joint2 and another's
        x_floor = np.array([1.1, worst, 1.0, 1.0, 1.0, 1.0, 1.0])
        assert margins.above_floor(JOINTS, x_floor, 1.5) == []
        near = margins.joints_near_floor(JOINTS, x_floor, 1.5)
        assert [n.joint for n in near] == ["panda_joint2"]
        said = words(margins.near_threshold_notes([], [], near)[0])
        assert f"counted within the floor: panda_joint2: {worst:.3g} the joint's residual, x its floor, against 1.5" \
               in said, said
    assert margins.above_floor(JOINTS, np.array([1.1, 1.6, 1, 1, 1, 1, 1.0]), 1.5) == ["panda_joint2"]
    assert margins.tie_near(2.05, 1.0, 2.0) and margins.tie_near(1.95, 1.0, 2.0) and not margins.tie_near(2.5, 1.0, 2.0)


ANCHOR = np.array([2.0, 0.1, 0.0, 0.05, 0.02, 0.0, 0.03, 0.0, 0.0, 0.025])  # one body: m, m*c, I (Pinocchio order)


@pytest.fixture(scope="module")
def program() -> tuple:
    """One body's consistent fit: a 30 % heavier body seen through a random design, with noise."""
    rng = np.random.default_rng(0)
    design = rng.normal(size=(400, 10)) / np.maximum(np.abs(ANCHOR), 0.05) / 20
    target = design @ (0.3 * ANCHOR) + 0.0025 * rng.normal(size=400)
    form = conic.ConicForm(10, np.full(10, -np.inf), InertialBlock(slice(0, 10), ANCHOR[None, :], [None]))
    return form, design, target


def stopping_early(monkeypatch, iterations: int, every_solve: bool) -> None:
    """Clarabel stopped after ``iterations`` on the precise solve (on every solve: ``every_solve``), as it stalls on
    a CPU whose factorisations end otherwise."""
    solver = clarabel.DefaultSolver

    def stopped(p, q, a, b, cones, settings):  # noqa: ANN001, ANN202  (Clarabel's own signature)
        if every_solve or settings.tol_feas == conic.PRECISE_TOLERANCE:
            settings.max_iter = iterations
        return solver(p, q, a, b, cones, settings)

    monkeypatch.setattr(clarabel, "DefaultSolver", stopped)


def test_an_almost_solved_fit_is_polished_or_kept_with_its_residuals_never_silently(program, monkeypatch):
    form, design, target = program
    reference = form.solve(design, target, 1e-4, np.ones(10))
    assert reference.check.clarabel == "Solved" and reference.check.plain
    assert reference.check.residuals.worst <= 10 * conic.PRECISE_TOLERANCE

    # tolerances no arithmetic reaches: Clarabel says AlmostSolved; measured, the solution meets its defaults
    unreachable = form.solve(design, target, 1e-4, np.ones(10), tolerance=1e-16)
    assert unreachable.check.clarabel == "AlmostSolved" and unreachable.check.kept == "measured"
    assert unreachable.status == "optimal" and unreachable.check.residuals.worst <= ACCEPTED
    np.testing.assert_allclose(unreachable.z, reference.z, rtol=1e-6, atol=1e-9)

    # the precise solve stopped short: Clarabel says AlmostSolved, its residuals fall short, and it is polished
    stopping_early(monkeypatch, 9, every_solve=False)
    polished = form.solve(design, target, 1e-4, np.ones(10))
    assert polished.check.clarabel == "AlmostSolved" and polished.check.kept == "polished"
    assert polished.status == "optimal" and polished.check.residuals.worst <= ACCEPTED
    np.testing.assert_allclose(polished.z, reference.z, rtol=1e-5, atol=1e-8)

    # every solve stopped short: kept, as inaccurate, with the residuals that say how far
    stopping_early(monkeypatch, 9, every_solve=True)
    kept = form.solve(design, target, 1e-4, np.ones(10))
    assert kept.status == "optimal_inaccurate" and kept.check.kept == "inaccurate"
    assert kept.check.residuals.worst > ACCEPTED
    document = kept.check.as_document()
    assert set(document["residuals"]) == {"primal", "dual", "gap"} and document["accepted_within"] == ACCEPTED
    assert physically_consistent(ANCHOR + kept.z), "stopped short, the solution is still inside the physical set"


def test_a_stalled_solve_is_solved_again_with_a_shorter_step_not_handed_to_scs(program, monkeypatch):
    """Clarabel stalls (InsufficientProgress) at its default step on some held-out blocks of real-arm-like data
    (the UR5's, the Panda's: within 5-30 iterations); a shorter step solves them, where SCS took ~100x as long."""
    form, design, target = program
    reference = form.solve(design, target, 1e-4, np.ones(10), precise=False)
    solver = clarabel.DefaultSolver
    steps = []

    class Stalled:
        status = "InsufficientProgress"

    def stalling(p, q, a, b, cones, settings):  # noqa: ANN001, ANN202  (Clarabel's own signature)
        steps.append(settings.max_step_fraction)
        if settings.max_step_fraction != 0.9:
            return type("StallingSolver", (), {"solve": lambda self: Stalled()})()
        return solver(p, q, a, b, cones, settings)

    monkeypatch.setattr(clarabel, "DefaultSolver", stalling)
    for precise in (False, True):
        steps.clear()
        solved = form.solve(design, target, 1e-4, np.ones(10), precise=precise)
        assert steps[-1] == conic.SHORT_STEP_FRACTION and len(steps) == (3 if precise else 2), steps
        assert solved.status == "optimal"
        np.testing.assert_allclose(solved.z, reference.z, rtol=1e-3, atol=1e-6)
    # stalled at every step too: SolverFailed, and the program goes on to SCS
    monkeypatch.setattr(conic, "SHORT_STEP_FRACTION", 0.5)
    with pytest.raises(conic.SolverFailed, match="InsufficientProgress"):
        form.solve(design, target, 1e-4, np.ones(10), precise=False)


def test_a_rung_states_the_residuals_where_clarabel_did_not_say_solved(monkeypatch):
    """The rung's consistent fit at tolerances no CPU reaches: Clarabel says AlmostSolved on every solve, and the
    rung's record says so, with the residuals measured and the solution physically consistent."""
    from sim2real.identification import fitting
    from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run

    nominal = fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")
    data = fitting.stack_runs([make_run("fit", {}, 5, duration=6.0, noise=0.01)], PANDA_JOINTS, 100.0)
    settings = {"fit_rate_hz": 100.0, "bootstrap_replicates": 20, "refine_max_samples": 1500,
                "inertia_regularization": 0.01}
    monkeypatch.setattr(conic, "PRECISE_TOLERANCE", 1e-16)
    result = fitting.fit(["link_inertia"], nominal, data, settings, uncertainty=False)
    solver = result.consistency["solver"]
    assert solver["clarabel"] == "AlmostSolved" and solver["kept"] in ("measured", "polished"), solver
    assert max(solver["residuals"].values()) <= solver["accepted_within"] == ACCEPTED
    assert result.consistency["status"] == "optimal"
    assert result.values["link_inertia"]["physically_consistent"]
