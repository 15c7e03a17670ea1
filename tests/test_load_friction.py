"""Friction that grows with the load (issue 62): the library's load_friction, its honest mappings, the lab's hidden
one followed from an empty ``effects:``, and a model-free ceiling that sees it when the library lacks it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml

from gap_fixtures import build_dev_panda

from sim2real import dr
from sim2real.errors import InputError
from sim2real.identification.diagnosis.caveats import NESTED_IN, SPANNED_BY
from sim2real.identification.effects import EFFECTS, apply_to_spec, calibration_from_params, get_effect
from sim2real.identification.effects.base import Signals
from sim2real.identification.records import Side
from sim2real.identification.sides import candidates_of_side
from sysid_lab import Lab

FACTOR = 1.5
JOINTS = ["j1", "j2"]
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dev_mjcf_path(tmp_path_factory) -> Path:
    return build_dev_panda(tmp_path_factory.mktemp("load_friction"))[1]


@pytest.fixture
def dev_mjcf(dev_mjcf_path: Path):
    return mujoco.MjSpec.from_file(str(dev_mjcf_path))


def signals_of(tau_nominal: np.ndarray, qd: np.ndarray) -> Signals:
    count = len(qd)
    return Signals(joint_names=JOINTS, time=np.arange(count) * 0.01, q=np.zeros_like(qd), qd=qd,
                   qdd=np.zeros_like(qd), tau_nominal=tau_nominal, segments=[slice(0, count)],
                   nominal={"friction": np.array([0.1, 0.0])})


def test_its_columns_are_linear_in_the_unloaded_level_and_the_load_coefficient():
    """A friction F_0 + mu |tau| with the columns' own shape is recovered exactly by least squares on them; the values
    carry the mean level over these samples (what MuJoCo's constant frictionloss gets)."""
    rng = np.random.default_rng(0)
    qd = rng.normal(scale=0.5, size=(400, 2))
    tau = rng.normal(scale=10.0, size=(400, 2)) + np.array([0.0, 20.0])
    signals = signals_of(tau, qd)
    effect = get_effect("load_friction")
    smoothing = np.array([0.02, 0.05])
    columns, labels = effect.columns(signals, {}, smoothing)
    assert [(label.param, label.joint) for label in labels] == [
        ("static", "j1"), ("static", "j2"), ("load_coefficient", "j1"), ("load_coefficient", "j2")]
    static, mu = np.array([0.3, 0.2]), np.array([0.03, 0.05])
    friction = (static + mu * np.abs(tau)) * np.tanh(qd / smoothing)
    theta = np.concatenate([np.linalg.lstsq(columns[:, j, :], friction[:, j], rcond=None)[0][[j, j + 2]]
                            for j in range(2)]).reshape(2, 2).T.ravel()
    assert theta == pytest.approx(np.concatenate([static, mu]), abs=1e-9)
    values = effect.values(theta - np.array([0.1, 0.0, 0.0, 0.0]), smoothing, signals, {})  # the URDF holds 0.1 on j1
    assert values["static"] == pytest.approx({"j1": 0.3, "j2": 0.2})
    mean = np.abs(tau).mean(axis=0)
    assert values["mean_level"] == pytest.approx({j: static[k] + mu[k] * mean[k] for k, j in enumerate(JOINTS)}, abs=1e-5)
    assert effect.theta_lower(signals, 4) == pytest.approx([-0.1, 0.0, 0.0, 0.0])


def test_it_holds_coulomb_friction_and_replaces_its_line():
    assert "coulomb_friction" in NESTED_IN["load_friction"] and "coulomb_friction" in SPANNED_BY["load_friction"]
    assert "load_friction" in candidates_of_side(Side.BODY)
    assert get_effect("load_friction").needs_model_torque  # designs compute the nominal torque it reads


def test_mujoco_and_urdf_get_its_mean_level(dev_mjcf):
    params = {"effects": {"load_friction": {
        "static": {"panda_joint4": 0.3}, "load_coefficient": {"panda_joint4": 0.04},
        "smoothing_velocity": {"panda_joint4": 0.02}, "mean_torque": {"panda_joint4": 10.0},
        "mean_level": {"panda_joint4": 0.7}}}}
    spec = dev_mjcf.copy()
    apply_to_spec(spec, params, include_urdf_effects=True)
    model = spec.compile()
    assert model.dof_frictionloss[model.joint("panda_joint4").dofadr[0]] == pytest.approx(0.7)
    assert EFFECTS["load_friction"].in_urdf
    assert calibration_from_params(params) == {"joints": {"panda_joint4": {"friction": 0.7}}}
    # The calibrated MJCF is built from the calibrated URDF, which holds it: the default edit writes nothing more.
    spec = dev_mjcf.copy()
    before = spec.compile().dof_frictionloss.copy()
    apply_to_spec(spec, params)
    assert np.array_equal(spec.compile().dof_frictionloss, before)


def test_domain_randomization_covers_its_mean_level_as_frictionloss(tmp_path: Path):
    from test_dr import _standin_mjcf

    resolved = dr.resolve_files(REPO / "configs/panda/dr.yaml", _standin_mjcf("panda", tmp_path / "panda.xml"),
                                robot="panda")
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({
        "robot": "panda",
        "effects": {"load_friction": {"static": {"panda_joint1": 0.2}, "load_coefficient": {"panda_joint1": 0.03},
                                      "mean_level": {"panda_joint1": 0.42, "panda_joint2": 50.0}}},
        "intervals": {"load_friction": {"mean_level": {"panda_joint1": [0.40, 0.44], "panda_joint2": [49.0, 51.0]}}},
    }))
    records = [r for r in dr.coverage_summary(resolved, params)["records"] if r["channel"] == "frictionloss"]
    assert [(r["element"], r["covered"], r["interval"]) for r in records] == [
        ("panda_joint1", True, [0.40, 0.44]), ("panda_joint2", False, [49.0, 51.0])]


@pytest.mark.parametrize("hidden, key", [({"static": 0.2}, "load_coefficient"),
                                         ({"static": -0.2, "load_coefficient": 0.03}, "load_friction")])
def test_a_bad_hidden_load_friction_is_a_clear_error(tmp_path: Path, dev_mjcf_path: Path, hidden, key):
    from sim2real.lab import simulate_run
    from sim2real.lab.config import DEFAULTS

    scenario = {**DEFAULTS, "duration_s": 0.01, "effects": {"load_friction": hidden}}
    with pytest.raises((InputError, KeyError), match=key):
        simulate_run(dev_mjcf_path, [f"panda_joint{i}" for i in range(1, 8)], scenario, 0, tmp_path / "lab.yaml")


@pytest.fixture(scope="module")
def lab(shared_lab: Lab) -> Lab:
    return shared_lab


def test_the_lab_s_load_friction_is_named_and_the_loop_reaches_the_floor(lab):
    """A harmonic drive's friction in every joint (the lab's ``load_friction``), followed from an empty ``effects:``:
    load_friction is named (no Coulomb friction follows a level that moves with the load), the loop ends within 1.5x
    every joint's floor, and no rung bends an inertia beyond its band."""
    documents = lab.follow("load_friction")
    named = [d["diagnosis"]["candidates"][0]["effect"] for d in documents if d["diagnosis"]["status"] == "add_effect"]
    assert named and named[0] == "load_friction", [d["diagnosis"]["verdict"] for d in documents]
    last = documents[-1]
    assert "load_friction" in last["ladder"][-1]["effects"]
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= FACTOR for x in last["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values())
    for document in documents:
        for rung in document["ladder"]:
            link = (rung.get("params") or {}).get("link_inertia")
            assert not (link and link["implausible_bodies"]), link["implausible_bodies"]


LOADED = ["panda_joint2", "panda_joint3", "panda_joint4"]  # the shoulder and elbow, which hold the arm up


def test_with_load_friction_withheld_the_ceiling_calls_the_rest_a_function_of_the_motion(lab):
    """The same arm with load_friction withheld from the candidates (the library as it was): the loop names
    coulomb_friction and then nothing; the ceiling, which sees each joint's predicted torque and velocity sign, calls
    what the loaded joints keep a function of the motion and names the torque."""
    candidates = [e for e in candidates_of_side(Side.BODY) if e != "load_friction"]
    first = lab.ladder("load_friction", [], candidates=candidates)
    assert first["diagnosis"]["status"] == "add_effect"
    assert first["diagnosis"]["candidates"][0]["effect"] == "coulomb_friction", first["diagnosis"]["verdict"]
    document = lab.ladder("load_friction", ["coulomb_friction"], candidates=candidates)
    diagnosis = document["diagnosis"]
    assert diagnosis["status"] == "unexplained", diagnosis["verdict"]
    ceiling: dict[str, Any] = diagnosis["model_free"]
    assert "a function of the motion" in ceiling["text"]
    rows = ceiling["per_joint"]
    assert all(rows[j]["kind"] == "motion" for j in LOADED), {j: rows[j]["kind"] for j in LOADED}
    assert any("the torque the model predicts" in feature for j in LOADED for feature in rows[j]["gains_most_with"]), \
        {j: rows[j]["gains_most_with"] for j in LOADED}
