"""Gap report on lab data: numbers, where it fails, noise floor, skipped state domain, schema."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from gap_fixtures import PANDA_JOINTS, build_dev_panda, short_lab_config
from sim2real.errors import InputError
from sim2real.report.gap import GapInputs, build_gap_report, compute_gap
from sim2real.report.metrics import reality_gap
from sim2real.files import validate
from sim2real.lab import run_lab_scenario_run
from sim2real.report.figures import FIGURES
from sim2real.measurements import load_run, write_run


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    directory = tmp_path_factory.mktemp("gap")
    urdf, mjcf = build_dev_panda(directory)
    config = short_lab_config(directory, duration_s=8.0)

    def scenario(name: str, runs=("fit", "holdout")) -> Path:
        entries = []
        for run in runs:
            out = directory / name / f"{run}.parquet"
            if not out.exists():
                run_lab_scenario_run(mjcf, config, "panda", name, run, out)
            entries.append({"name": f"{name}_{run}", "path": out.as_posix(), "role": run})
        listing = directory / f"{name}_measurements.yaml"
        listing.write_text(yaml.safe_dump({"runs": entries, "replay": {"horizon_s": 0.25}}))
        return listing

    return {"urdf": urdf, "mjcf": mjcf, "scenario": scenario, "dir": directory}


def test_demo_report_points_at_friction_in_slow_motion_and_reversals(lab):
    listing = lab["scenario"]("demo")
    out = lab["dir"] / "demo_report"
    figures = {k: out / "gap" / f"{k}.png" for k in FIGURES}
    inputs = GapInputs("panda", lab["urdf"], lab["mjcf"], listing)
    gap = build_gap_report(inputs, out / "gap.json", out / "gap.md", figures)
    findings = gap["where"]["findings"]
    assert findings, "friction must show up somewhere"
    assert {f["regime"] for f in findings} == {"slow_reversal"}
    assert len({f["joint"] for f in findings}) >= 5  # every Panda joint has friction
    assert gap["metrics"]["torque_rmse"]["overall"] > 4 * gap["noise_floor"]["torque_rmse"]["overall"]
    sd = gap["metrics"]["state_domain"]
    assert sd["status"] == "computed" and sd["reality_gap"]["grade"] in {"low", "medium", "high", "very_high"}
    assert set(gap["metrics"]["position_rmse"]["per_joint"]) == set(PANDA_JOINTS)
    assert gap["where"]["worst_windows"][0]["run"].startswith("demo_")
    md = (out / "gap.md").read_text()
    assert "slow motion and velocity reversals" in md and "gap/torque.png" in md
    for path in figures.values():
        assert path.stat().st_size > 1000
    # deterministic: a rebuild is byte-identical
    first = {p: p.read_bytes() for p in [out / "gap.json", out / "gap.md", *figures.values()]}
    build_gap_report(inputs, out / "gap.json", out / "gap.md", figures)
    assert all(p.read_bytes() == b for p, b in first.items())


def test_clean_lab_nominal_model_lands_at_the_noise_floor(lab):
    gap, _ = compute_gap(GapInputs("panda", lab["urdf"], lab["mjcf"], lab["scenario"]("clean")))
    floor = gap["noise_floor"]["torque_rmse"]
    for joint in PANDA_JOINTS:
        assert gap["metrics"]["torque_rmse"]["per_joint"][joint] < 1.5 * floor["per_joint"][joint]
    assert gap["where"]["findings"] == []
    assert gap["metrics"]["state_domain"]["reality_gap"]["grade"] == "low"


def test_payload_points_at_gravity_loaded_poses(lab):
    gap, _ = compute_gap(GapInputs("panda", lab["urdf"], lab["mjcf"], lab["scenario"]("payload")))
    regimes = {f["regime"] for f in gap["where"]["findings"]}
    assert "gravity_loaded" in regimes and "slow_reversal" not in regimes


def test_log_without_commands_skips_state_domain_and_says_why(lab, tmp_path):
    run = load_run(lab["dir"] / "demo" / "holdout.parquet")
    write_run(tmp_path / "real.parquet", run.time, run.joint_names, {"q": run.q, "tau": run.tau},
              {"robot": "panda", "source": "real", "control_mode": "torque"})
    listing = tmp_path / "m.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "real", "path": (tmp_path / "real.parquet").as_posix(),
                                                 "role": "holdout"}]}))
    gap, _ = compute_gap(GapInputs("panda", lab["urdf"], lab["mjcf"], listing))
    sd = gap["metrics"]["state_domain"]
    assert sd["status"] == "skipped" and "tau_cmd" in sd["reason"]
    assert "position_rmse" not in gap["metrics"]


def test_unknown_joint_in_a_run_is_reported_against_the_model(lab, tmp_path):
    t = np.arange(3000) * 0.001
    motion = np.column_stack([np.sin(t), np.cos(t)])  # a run that is fine but for its joint's name
    write_run(tmp_path / "x.csv", t, ["panda_joint1", "wrist_9"], {"q": 0.1 * motion, "tau": motion},
              {"robot": "panda", "source": "real", "control_mode": "torque"})
    listing = tmp_path / "m.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "x", "path": (tmp_path / "x.csv").as_posix(), "role": "fit"}]}))
    with pytest.raises(InputError, match="wrist_9"):
        compute_gap(GapInputs("panda", lab["urdf"], lab["mjcf"], listing))


def test_precomputed_ladder_is_merged_and_validated(lab, tmp_path):
    """The sysid rule's ladder.json, data without words, merged into gap.json with its verdict."""
    from sim2real.identification.diagnosis import Diagnosis
    from sim2real.identification.diagnosis.result import JointStanding
    from sim2real.identification.records import Side, Status
    from sim2real.report.verdicts import verdict

    diagnosis = Diagnosis(side=Side.BODY, status=Status.AT_NOISE_FLOOR, candidates=(), confounded=(), tied=(),
                          residual_rmse=0.1, noise_floor_ratio=1.1, noise_rmse=0.09, noise_floor_factor=1.5,
                          min_explained=0.3, per_joint={"panda_joint7": JointStanding(1.1, None, 0.0, 1.1)},
                          above_floor=())
    ladder = {
        "ladder": [{"effects": [], "params": {}, "metrics": {"torque_rmse": {"overall": 0.3, "per_joint": {"a": 0.3}}}}],
        "diagnosis": json.loads(json.dumps(diagnosis.as_document())),
    }
    gap, _ = compute_gap(GapInputs("panda", lab["urdf"], lab["mjcf"], lab["scenario"]("clean")), precomputed=ladder)
    rung = gap["ladder"][0]
    assert rung["effects"] == [] and rung["metrics"]["torque_rmse"] == ladder["ladder"][0]["metrics"]["torque_rmse"]
    assert gap["diagnosis"]["verdict"] == verdict(diagnosis, "panda")
    # Each rung is replayed in MuJoCo with its fitted effects: the nominal model on clean lab data tracks closely.
    assert rung["metrics"]["position_rmse"]["overall"] < 1e-3
    assert set(rung["metrics"]["position_rmse"]["per_joint"]) == set(PANDA_JOINTS)
    broken = json.loads(json.dumps(gap))
    broken["diagnosis"]["link"] = "wrist"
    with pytest.raises(InputError, match="link"):
        validate(broken, "gap.schema.json")


def test_reality_gap_metric_matches_source_chapter():
    # all-perfect with contacts -> 0; the chapter's weights with contact F1 given
    assert reality_gap(0.0, 0.0, 0.0, 1.0, 0.0, 1.0)["score"] == pytest.approx(0.0)
    g = reality_gap(0.05, 0.5, 2.5, 0.9, 0.5, 0.5)
    assert g["score"] == pytest.approx(0.3 * 0.5 + 0.2 * 0.5 + 0.15 * 0.5 + 0.15 * 0.1 + 0.1 * 0.5 + 0.1 * 0.5)
    assert g["grade"] == "high"
    assert reality_gap(1.0, 5.0, 50.0, 0.0, 3.0, None)["grade"] == "very_high"


def test_replay_models_drop_only_meshes_that_change_nothing(lab):
    """The replay's models leave out the mesh geoms of bodies with explicit inertias: same motion, to the bit."""
    import mujoco

    from sim2real.assets.arm import arm_spec, compile_arm
    from sim2real.report.replay import ReplayModels

    full, qadr, dadr = compile_arm(arm_spec(lab["mjcf"], PANDA_JOINTS), PANDA_JOINTS)
    models = ReplayModels(lab["mjcf"])
    lean, lean_qadr, lean_dadr = models.get(PANDA_JOINTS)
    assert models.get(PANDA_JOINTS)[0] is lean  # compiled once per distinct model
    assert lean.nmesh < full.nmesh  # a body without an explicit inertia keeps its meshes (they give its mass)
    assert np.array_equal(qadr, lean_qadr) and np.array_equal(dadr, lean_dadr)
    trajectories = []
    for model in (full, lean):
        data = mujoco.MjData(model)
        data.qpos[qadr] = np.linspace(-0.5, 0.5, len(PANDA_JOINTS))
        rows = []
        for step in range(300):
            data.ctrl[:] = 5.0 * np.sin(0.05 * step + np.arange(model.nu))
            mujoco.mj_step(model, data)
            rows.append(np.concatenate([data.qpos, data.qvel]))
        trajectories.append(np.array(rows))
    assert np.array_equal(trajectories[0], trajectories[1])


def test_a_report_kept_replays_and_figures_are_read_back_and_a_changed_rung_replayed_alone(lab, tmp_path, monkeypatch):
    """The next round of the loop changes one rung: the gap report replays that rung alone and draws only the
    figure that shows the ladder; everything it writes is the same bytes as a report without the cache."""
    from sim2real.report import figures as report
    from sim2real.report import replay as gap_module

    listing = lab["scenario"]("demo")
    ladder = {"torque_source": "tau", "ladder": [
        {"effects": [], "params": {}, "metrics": {"torque_rmse": {"overall": 0.3, "per_joint": {j: 0.3 for j in PANDA_JOINTS}}}},
        {"effects": ["viscous_friction"], "params": {"viscous_friction": {"damping": {j: 0.5 for j in PANDA_JOINTS}}},
         "metrics": {"torque_rmse": {"overall": 0.2, "per_joint": {j: 0.2 for j in PANDA_JOINTS}}}}]}
    replays, drawn = [], []
    real_shooting, real_draw = gap_module._multiple_shooting, report._draw
    monkeypatch.setattr(gap_module, "_multiple_shooting", lambda *a: replays.append(a[3].name) or real_shooting(*a))
    monkeypatch.setattr(report, "_draw", lambda name, *args: drawn.append(name) or real_draw(name, *args))

    def build(ladder_document, out, kept):
        (out / "ladder.json").parent.mkdir(parents=True, exist_ok=True)
        (out / "ladder.json").write_text(json.dumps(ladder_document))
        figures = {k: out / "gap" / f"{k}.png" for k in FIGURES}
        inputs = GapInputs("panda", lab["urdf"], lab["mjcf"], listing, ladder=out / "ladder.json")
        build_gap_report(inputs, out / "gap.json", out / "gap.md", figures, cache_dir=kept)
        return {p.name: p.read_bytes() for p in [out / "gap.json", out / "gap.md", *figures.values()]}

    kept = tmp_path / "kept"
    first = build(ladder, tmp_path / "first", kept)
    # the nominal model on both runs (its rung's replay is that one), the second rung on the holdout run
    assert replays == ["demo_fit", "demo_holdout", "demo_holdout"] and len(drawn) == len(FIGURES)
    replays.clear(), drawn.clear()
    assert build(ladder, tmp_path / "again", kept) == first and replays == [] and drawn == []
    changed = json.loads(json.dumps(ladder))
    changed["ladder"][1]["params"]["viscous_friction"]["damping"]["panda_joint1"] = 0.7  # the rung refitted
    changed["ladder"][1]["metrics"]["torque_rmse"]["overall"] = 0.19
    with_cache = build(changed, tmp_path / "changed", kept)
    assert replays == ["demo_holdout"] and drawn == ["ladder"]
    assert with_cache == build(changed, tmp_path / "fresh", None)  # a kept replay is the replay, to the bit


def test_a_candidate_that_replaces_a_line_says_so_in_gap_md():
    """A named effect that spans a line of the model (link_inertia a payload) is listed with the line to add and the
    line to remove; the schema takes the list of lines it replaces, and nothing else there."""
    from sim2real.report.markdown import _diagnosis_markdown

    from diagnosis_rows import evidence_document

    candidate = {"effect": "link_inertia", "link": "body", "joints": ["panda_joint7"], "decided_on": "arm",
                 "explained": 0.9, "explained_beyond_noise": 0.9, "decisive": True, "evidence": evidence_document(),
                 "add": "- link_inertia", "replaces": ["payload"]}
    lines = _diagnosis_markdown({"verdict": "v", "candidates": [candidate]})
    listed = next(line for line in lines if line.startswith("- `link_inertia`"))
    assert listed.endswith("add `- link_inertia`, remove `- payload`"), lines
    schema_part = json.loads((Path(__file__).resolve().parents[1] / "schemas/gap.schema.json").read_text())
    items = schema_part["properties"]["diagnosis"]["properties"]["candidates"]["items"]["properties"]
    assert items["replaces"]["items"] == {"type": "string"}


def test_gap_md_says_the_torque_figures_are_of_what_each_runs_drift_leaves():
    """A model that estimates each run's sensor drift on the run itself (sensor_drift) is judged without it: gap.md
    says so beside the torque figures; a model without it gets no such sentence."""
    from sim2real.report.markdown import _per_run_lines

    lines = _per_run_lines(["link_inertia", "sensor_drift"])
    assert lines[0].startswith("Each run's sensor drift (`sensor_drift`") and "holdout runs included" in lines[0]
    assert _per_run_lines(["link_inertia", "torque_bias"]) == []
