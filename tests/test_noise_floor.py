"""The noise floor knows when differences cannot measure it (sim2real.measurements.noise.measured_noise_floor): a
torque smoothed or held before it is logged gets its floor from its spectrum or its own updates, gap.md says so with
the figures, and the floor is judged against the lab's known sensor noise (truth.yaml, which the floor never reads)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import yaml

from gap_fixtures import build_dev_iiwa14, build_dev_panda, short_lab_config
from sim2real.errors import InputError
from sim2real.lab import run_lab_scenario_run, write_truth
from sim2real.measurements import load_prepared_runs
from sim2real.measurements.noise import (
    command_floor_of, floor_method_document, floor_methods, measured_noise_floor, stated_noise_floor, white_noise_sigma,
)
from sim2real.report.gap import GapInputs, compute_gap
from sim2real.report.markdown import render_gap_markdown
from sim2real.report.verdicts import floor_sentences

JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    directory = tmp_path_factory.mktemp("noise_floor")
    urdf, mjcf = build_dev_panda(directory)
    return {"urdf": urdf, "scenario": _scenarios(directory, mjcf, "panda")}


def _scenarios(directory: Path, mjcf: Path, robot: str):
    """A lab scenario's fit and holdout runs on 8 s runs (made once), their measurement list and the lab's truth."""
    config = short_lab_config(directory, duration_s=8.0, robot=robot)

    def scenario(name: str) -> tuple[Path, dict]:
        entries = []
        for run in ("fit", "holdout"):
            out = directory / name / f"{run}.csv"
            if not out.exists():
                run_lab_scenario_run(mjcf, config, robot, name, run, out)
            entries.append({"name": f"{name}_{run}", "path": out.as_posix(), "role": run})
        listing = directory / f"{name}_measurements.yaml"
        listing.write_text(yaml.safe_dump({"runs": entries}))
        truth = directory / name / "truth.yaml"
        write_truth(config, mjcf, name, truth)
        return listing, yaml.safe_load(truth.read_text())

    return scenario


@pytest.mark.parametrize("name, method", [("real_arm_like_smoothed_200hz", "spectrum"),
                                          ("real_arm_like_smoothed_1khz", "spectrum"),
                                          ("real_arm_like_held", "updates")])
def test_a_smoothed_or_held_torque_gets_its_floor_elsewhere_within_1_5x_of_the_sensor_noise(lab, name, method):
    listing, truth = lab["scenario"](name)
    prepared = load_prepared_runs(listing, JOINTS, "/")
    noise = truth["sensor_noise"]["as_logged"]
    for run in prepared:
        assert floor_methods(run) == (method,) * len(JOINTS), (run.name, floor_methods(run))
        ratio = run.raw_torque_sigma / noise
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), (run.name, ratio)
        # differences alone would have been far off (smoothed: too low; held: about zero)
        assert np.any(white_noise_sigma(run.tau) < noise / 1.5) or method == "updates"
        # the actuator link's floor is that one too: the command's differences do not measure such a log's noise
        assert np.array_equal(command_floor_of(run), run.raw_torque_sigma)
    gap, _ = compute_gap(GapInputs("panda", lab["urdf"], None, listing))
    assert gap["noise_floor"]["method"] == dict.fromkeys(JOINTS, method)
    words = " ".join(floor_sentences(gap["noise_floor"]))
    assert "the floor could not be taken from differences on " + ", ".join(JOINTS) in words
    assert ("keep falling with the order" in words) == (method == "spectrum")
    assert ("most consecutive torque samples are equal" in words) == (method == "updates")
    assert words in render_gap_markdown(gap, defaultdict(lambda: "figure.png"))


@pytest.mark.parametrize("name", ["real_arm_like_positions_held", "real_arm_like_run_offsets"])
def test_held_positions_and_per_run_offsets_leave_the_white_floor_from_differences(lab, name):
    listing, truth = lab["scenario"](name)
    prepared = load_prepared_runs(listing, JOINTS, "/")
    for run in prepared:
        assert floor_methods(run) == ("differences",) * len(JOINTS) and run.filter.noise_floor is None
        ratio = run.raw_torque_sigma / truth["sensor_noise"]["as_logged"]
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), (run.name, ratio)
    document = floor_method_document(prepared, JOINTS)
    assert document == {"method": dict.fromkeys(JOINTS, "differences")}
    assert floor_sentences(document) == ["The noise floor is the white part of the raw torque (differences of orders 2 "
                                         "to 5 agree), on every joint."]


def _torque(rate: float, seconds: float, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A slow motion's torque on two joints and white noise of 0.05 N m."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(rate * seconds)) / rate
    motion = np.column_stack([3.0 * np.sin(0.9 * t), 1.5 * np.cos(1.7 * t + 0.3)])
    return motion, 0.05 * rng.standard_normal(motion.shape)


def test_a_white_torque_keeps_its_floor_from_differences_to_the_last_digit():
    motion, noise = _torque(1000.0, 10.0)
    torque = motion + noise
    distinct = np.ones(len(torque), dtype=bool)
    floor = measured_noise_floor(torque, distinct, 1000.0, 10.0)
    assert floor.record is None and np.array_equal(floor.sigma, white_noise_sigma(torque))


def test_a_low_passed_torque_is_measured_by_its_spectrum():
    from scipy import signal

    motion, noise = _torque(1000.0, 10.0)
    b, a = signal.butter(1, 30.0, fs=1000.0)
    torque = signal.lfilter(b, a, motion + noise, axis=0)
    logged = signal.lfilter(b, a, noise, axis=0).std(axis=0)
    floor = measured_noise_floor(torque, np.ones(len(torque), dtype=bool), 1000.0, 10.0)
    assert floor.record is not None and floor.record.method == ("spectrum", "spectrum")
    assert np.all(np.abs(np.log(floor.sigma / logged)) < np.log(1.2)), (floor.sigma, logged)
    assert np.all(white_noise_sigma(torque) < logged / 2)  # what differences would have said


def test_a_stated_floor_replaces_the_measured_one_and_names_its_reason(tmp_path):
    motion, noise = _torque(200.0, 10.0)
    stated, reason = stated_noise_floor({"torque_nm": {"a": 0.1, "b": 0.2}, "reason": "repeatability test"},
                                        ["a", "b"], tmp_path / "run.yaml")
    floor = measured_noise_floor(motion + noise, np.ones(len(motion), dtype=bool), 200.0, 10.0, stated, reason)
    assert floor.record is not None and floor.record.method == ("stated", "stated")
    assert floor.sigma.tolist() == [0.1, 0.2] and floor.record.stated_reason == "repeatability test"
    with pytest.raises(InputError, match="noise_floor/torque_nm"):
        stated_noise_floor({"torque_nm": {"a": 0.1}, "reason": "x"}, ["a", "b"], tmp_path / "run.yaml")


def test_a_torque_smoothed_then_held_is_measured_by_the_spectrum_of_its_own_updates():
    """As a real arm's chain may do both: a 25 Hz low-pass, then each joint updated every 5 ms in turn, at 1 kHz."""
    from scipy import signal

    from sim2real.lab.sensor_chain import held_per_joint

    motion, noise = _torque(1000.0, 20.0)
    b, a = signal.butter(1, 25.0, fs=1000.0)
    logged = signal.lfilter(b, a, noise, axis=0).std(axis=0)
    torque = held_per_joint(signal.lfilter(b, a, motion + noise, axis=0), 5, staggered=True)
    distinct = np.concatenate([[True], np.any(torque[1:] != torque[:-1], axis=1)])
    floor = measured_noise_floor(torque, distinct, 1000.0, 10.0)
    assert floor.record is not None and floor.record.method == ("spectrum", "spectrum")
    assert min(floor.record.equal_steps) > 0.7  # held: most consecutive samples equal
    assert np.all(np.abs(np.log(floor.sigma / logged)) < np.log(1.2)), (floor.sigma, logged)


def test_a_floor_stated_in_the_run_metadata_is_validated_and_used(lab, tmp_path):
    import shutil

    listing, _ = lab["scenario"]("real_arm_like_run_offsets")
    runs = yaml.safe_load(listing.read_text())["runs"]
    for run in runs:
        path = tmp_path / Path(run["path"]).name
        shutil.copy(run["path"], path)
        meta = yaml.safe_load(Path(run["path"]).with_suffix(".yaml").read_text())
        meta["noise_floor"] = {"torque_nm": 0.04, "reason": "the arm's repeatability test"}
        path.with_suffix(".yaml").write_text(yaml.safe_dump(meta))
        run["path"] = path.as_posix()
    stated = tmp_path / "measurements.yaml"
    stated.write_text(yaml.safe_dump({"runs": runs}))
    prepared = load_prepared_runs(stated, JOINTS, "/")
    assert all(floor_methods(p) == ("stated",) * 7 and np.all(p.raw_torque_sigma == 0.04) for p in prepared)
    words = " ".join(floor_sentences(floor_method_document(prepared, JOINTS)))
    assert "the floor the runs' metadata state" in words and "the arm's repeatability test" in words
    meta = yaml.safe_load(Path(runs[0]["path"]).with_suffix(".yaml").read_text())
    del meta["noise_floor"]["reason"]
    Path(runs[0]["path"]).with_suffix(".yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(InputError, match="reason"):
        load_prepared_runs(stated, JOINTS, "/")


IIWA_JOINTS = [f"iiwa_joint_{i}" for i in range(1, 8)]


@pytest.fixture(scope="module")
def iiwa_lab(tmp_path_factory):
    """The shipped iiwa 14's lab arm (configs/iiwa14/lab.yaml) on 8 s runs: its link-side sensors, per-run offsets
    and wrist torques a hundred times smaller than the shoulder's, logged through a sensor chain."""
    directory = tmp_path_factory.mktemp("noise_floor_iiwa")
    _, mjcf = build_dev_iiwa14(directory)
    return _scenarios(directory, mjcf, "iiwa14")


@pytest.mark.parametrize("name, methods", [("real_arm_like_smoothed_200hz", {"spectrum"}),
                                           ("real_arm_like_held_1khz", {"spectrum", "updates"}),
                                           ("real_arm_like_positions_held", {"differences"})])
def test_the_iiwa_logs_floor_is_its_sensors_noise_joint_by_joint(iiwa_lab, name, methods):
    """A real iiwa's log, smoothed at 200 Hz or held at 1 kHz by its drive: the floor is not the differences', and on
    every joint, wrist included, it lies within 1.5x of the noise the log holds."""
    listing, truth = iiwa_lab(name)
    prepared = load_prepared_runs(listing, IIWA_JOINTS, "/")
    noise = truth["sensor_noise"]["as_logged"]
    for run in prepared:
        assert set(floor_methods(run)) <= methods, (run.name, floor_methods(run))
        ratio = run.raw_torque_sigma / noise
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), (run.name, dict(zip(IIWA_JOINTS, ratio)))
    if methods != {"differences"}:
        words = " ".join(floor_sentences(floor_method_document(prepared, IIWA_JOINTS)))
        assert "the floor could not be taken from differences on" in words
