"""Each named file format has one reader and one writer, in one module, and what it writes it reads back: ladder.json,
params.yaml and residuals.npz (sim2real.identification.formats), prepared_runs.npz (sim2real.measurements.store)."""

from __future__ import annotations

import dataclasses
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sim2real.identification import formats
from sim2real.identification.records import Side
from sim2real.measurements import store

JOINTS = ("panda_joint1", "panda_joint2")


def test_the_ladder_round_trips_with_stable_bytes(tmp_path):
    document = {"robot": "panda", "joints": list(JOINTS), "ladder": [{"effects": [], "metrics": {"torque_rmse": {
        "overall": 0.125, "per_joint": {"panda_joint1": 0.1, "panda_joint2": 0.15}}}}], "links": {"mode": "one"}}
    formats.write_ladder(tmp_path / "ladder.json", document)
    assert formats.read_ladder(tmp_path / "ladder.json") == document
    first = (tmp_path / "ladder.json").read_bytes()
    formats.write_ladder(tmp_path / "ladder.json", dict(reversed(list(document.items()))))  # keys in another order
    assert (tmp_path / "ladder.json").read_bytes() == first


def test_params_round_trip_and_an_empty_file_holds_none(tmp_path):
    params = {"effects": {"viscous_friction": {"damping": {"panda_joint1": 0.5, "panda_joint2": 0.25}}},
              "order": ["viscous_friction"], "joints": list(JOINTS)}
    formats.write_params(tmp_path / "params.yaml", params)
    assert formats.read_params(tmp_path / "params.yaml") == params
    (tmp_path / "empty.yaml").write_text("", encoding="utf-8")
    assert formats.read_params(tmp_path / "empty.yaml") == {}


def _role(rng: np.random.Generator, runs: tuple[tuple[str, int, int], ...]) -> formats.RoleResiduals:
    rows = runs[-1][2]
    return formats.RoleResiduals(runs, np.array([0.05, 0.02]), np.arange(rows) * 0.01,
                                 *(rng.normal(size=(rows, len(JOINTS))) for _ in range(5)))


def test_the_residuals_round_trip_whole_and_by_role(tmp_path):
    rng = np.random.default_rng(3)
    written = formats.ModelResiduals(
        side=Side.BODY, effects=("link_inertia", "viscous_friction"), joints=JOINTS, torque_source="tau",
        torque_sensor="motor",
        roles={"fit": _role(rng, (("a", 0, 30), ("b", 30, 50))), "holdout": _role(rng, (("c", 0, 20),))})
    path = tmp_path / "residuals.npz"
    formats.write_model_residuals(path, written)
    back = formats.read_model_residuals(path)
    assert dataclasses.replace(back, roles={}) == dataclasses.replace(written, roles={})
    for role, part in written.roles.items():
        assert back.roles[role].runs == part.runs
        for name in ("noise_floor", *formats.RESIDUAL_ARRAYS):
            assert np.array_equal(getattr(back.roles[role], name), getattr(part, name)), (role, name)
    holdout = formats.read_model_residuals(path, roles=("holdout",))
    assert list(holdout.roles) == ["holdout"]
    assert [name for name, _ in holdout.roles["holdout"].by_run()] == ["c"]
    formats.write_model_residuals(tmp_path / "again.npz", back)
    assert (tmp_path / "again.npz").read_bytes() == path.read_bytes()


def test_prepared_runs_round_trip(tmp_path):
    from sim2real.measurements import MeasurementEntry, RunSet, load_run, prepare_run, write_run

    t = np.arange(2000) * 0.001
    q = np.column_stack([0.5 * np.sin(1.3 * t), -0.3 + 0.4 * np.cos(0.9 * t)])
    tau = np.column_stack([0.2 * np.sin(1.3 * t), 0.1 * np.cos(0.9 * t)]) + 0.1
    write_run(tmp_path / "r.parquet", t, list(JOINTS), {"q": q, "tau": tau},
              {"robot": "panda", "source": "real", "control_mode": "torque"})
    run = dataclasses.replace(prepare_run(load_run(tmp_path / "r.parquet")),
                              entry=MeasurementEntry("r", Path("r.parquet"), "holdout"))
    path = tmp_path / "prepared_runs.npz"
    store.write_prepared_runs(path, RunSet((run,), {"fit_rate_hz": 200.0}))
    back = store.read_prepared_runs(path)
    assert back.settings == {"fit_rate_hz": 200.0} and len(back) == 1
    for field in dataclasses.fields(run):
        mine, theirs = getattr(run, field.name), getattr(back[0], field.name)
        if isinstance(mine, np.ndarray):
            assert np.array_equal(mine, theirs), field.name
        else:
            assert mine == theirs, field.name


def test_a_file_of_another_kind_is_no_residuals(tmp_path):
    (tmp_path / "residuals.npz").write_text("not an archive", encoding="utf-8")
    with pytest.raises(zipfile.BadZipFile):
        formats.read_model_residuals(tmp_path / "residuals.npz")


def test_the_diagnosis_rows_round_trip_with_and_without_their_optional_figures():
    """ladder.json's diagnosis: each typed row (a candidate's evidence, a joint's standing, the model-free ceiling and
    its reading of a joint) writes its document and reads it back, an optional figure present or not."""
    from diagnosis_rows import evidence
    from sim2real.identification.diagnosis.ceiling_records import CeilingReading, EffectAdvice, ModelFreeCeiling
    from sim2real.identification.diagnosis.result import Candidate, Diagnosis, JointStanding
    from sim2real.identification.records import Note, NoteKind, Status

    plain = evidence(JOINTS, x_floor_after=1.4, fitted={"damping": {"panda_joint1": 0.5}})
    full = dataclasses.replace(plain, lag_s={"panda_joint1": 0.004, "panda_joint2": 0.0},
                               per_joint_own_term_x_floor={"panda_joint1": 0.7, "panda_joint2": 0.1},
                               fit_failed={"fit_x_floor": 9.0}, near_threshold=({"kind": "near_threshold"},),
                               relabels=({"effect": "coulomb_friction"},), trades_with=(),
                               tie_with_best={"difference": 0.1, "spread": 0.2, "blocks": 8},
                               implausible_bodies=({"body": "panda_link3", "reasons": ["mass"]},),
                               bounds_pushed={"panda_link4": ("hull",)}, bounds_released={"panda_link2": ("mass",)})
    at_floor = CeilingReading(0.05, 0.05, 1.0, 1.0, 1.0, 0.0, "at_floor", False)
    motion = CeilingReading(0.3, 0.1, 6.0, 2.0, 0.33, 0.8, "motion", True, learner="trees on the motion",
                            gains_most_with=({"feature": "velocity", "joint": "panda_joint2"},), gains_most_in=None,
                            effect="base_mount", beyond_motion={"time": 0.9, "run": 0.1}, follows="time",
                            imitated=True)
    still = CeilingReading(0.3, 0.29, 6.0, 5.8, 0.97, 0.02, "not_motion", True, learner="trees on the motion",
                           beyond_motion={"time": 0.0, "run": 0.0, "history": 0.0}, follows=None)
    ceiling = ModelFreeCeiling("trees", 0.2, {"panda_joint1": 0.05, "panda_joint2": 0.1}, 0.8,
                               {"panda_joint1": at_floor, "panda_joint2": motion},
                               declare=EffectAdvice("sensor_drift", ("panda_joint2",), "- sensor_drift"))
    for row in (plain, full):
        assert type(row).from_document(row.as_document()) == row
    # a declared drift held to the no-raise rule: kept on the joints it helps, or withheld
    kept = dataclasses.replace(ceiling, declare=EffectAdvice(
        "sensor_drift", ("panda_joint2",), "- sensor_drift: {joints: [panda_joint1]}", kept_to=("panda_joint1",),
        raised={"panda_joint2": (2.1, 5.3)}))
    withheld = dataclasses.replace(ceiling, declare=None, withheld=EffectAdvice(
        "sensor_drift", ("panda_joint2",), "- sensor_drift", raised={"panda_joint2": (2.1, 5.3)}))
    for advised in (kept, withheld):
        assert ModelFreeCeiling.from_document(advised.as_document()) == advised
    assert "kept_to" not in ceiling.as_document()["declare"] and "withheld" not in ceiling.as_document()
    for reading in (at_floor, motion, still):
        assert CeilingReading.from_document(reading.as_document()) == reading
    diagnosis = Diagnosis(
        side=Side.BODY, status=Status.ADD_EFFECT,
        candidates=(Candidate("viscous_friction", Side.BODY, ("panda_joint1",), "joints", 0.4, 0.6, True, full,
                              "- viscous_friction", ("payload",)),),
        confounded=(), tied=(), residual_rmse=0.2, noise_floor_ratio=2.5, noise_rmse=0.08, noise_floor_factor=1.5,
        min_explained=0.3, above_floor=("panda_joint1",),
        per_joint={"panda_joint1": JointStanding(2.5, "viscous_friction", 0.6, 1.4),
                   "panda_joint2": JointStanding(1.1, None, 0.0, 1.1, judged=False)},
        notes=(Note(NoteKind.FAILED_TRIALS, figures={"failed": {}}),), model_free=ceiling, joints=JOINTS)
    document = diagnosis.as_document()
    assert Diagnosis.from_document(document) == diagnosis
    assert "judged" not in document["per_joint"]["panda_joint1"] and document["per_joint"]["panda_joint2"]["judged"] is False
    assert "imitated" not in still.as_document() and still.as_document()["follows"] is None
    assert "points_to" not in document["model_free"] and "follows" not in at_floor.as_document()
