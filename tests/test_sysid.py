"""Fit: known parameters are recovered with honest intervals; real-log mode; files out."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sysid_lab import side_ladder
from sim2real.identification import fitting
from sim2real.identification import sysid
from sim2real.errors import InputError
from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run

FAST = {"fit_rate_hz": 100.0, "bootstrap_replicates": 50, "refine_max_samples": 1500}


@pytest.fixture(scope="module")
def nominal():
    return fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")


def _data(hidden, seeds):
    return fitting.stack_runs([make_run(f"r{s}", hidden, s, duration=12.0) for s in seeds], PANDA_JOINTS)


@pytest.mark.parametrize(
    ("effect", "hidden", "param", "truth"),
    [
        ("viscous_friction", {"viscous_friction": [0.4] * 7}, "damping", 0.403),  # + URDF damping 0.003
        ("coulomb_friction", {"coulomb_friction": [0.5] * 7}, "friction", 0.5),
        ("rotor_inertia", {"rotor_inertia": [0.2] * 7}, "armature", 0.3),  # + robot.yaml armature 0.1
        ("torque_bias", {"torque_bias": [0.3] * 7}, "bias", 0.3),
        ("torque_gain", {"torque_gain": [1.1] * 7}, "gain", 1.1),
    ],
)
def test_per_joint_effects_are_recovered_inside_their_intervals(nominal, effect, hidden, param, truth):
    result = fitting.fit([effect], nominal, _data(hidden, [1, 2]), FAST)
    for joint in PANDA_JOINTS:
        value = result.values[effect][param][joint]
        lo, hi = result.intervals[effect][param][joint]
        assert value == pytest.approx(truth, rel=0.05, abs=0.01)
        assert lo <= value <= hi
        assert hi - lo < 0.2 * abs(truth) + 0.02


def test_bootstrap_intervals_widen_for_few_blocks_and_uneven_ones():
    from scipy import stats

    from sim2real.identification.fitting import small_sample_stretch

    # 20 equal blocks: the bootstrap variance is short by 19/20 and the t quantile with 19 dof replaces z.
    expected = np.sqrt(20 / 19) * stats.t.ppf(0.975, 19) / stats.norm.ppf(0.975)
    assert small_sample_stretch(np.ones(20), 0.95) == expected  # to the bit: scipy.stats' own quantiles
    kish = 1.1**2 / (1 + 0.01)  # two blocks, one a tenth of the other: 1.198 effective blocks
    assert small_sample_stretch(np.array([1.0, 0.1]), 0.9) == float(
        np.sqrt(kish / (kish - 1)) * stats.t.ppf(0.95, kish - 1) / stats.norm.ppf(0.95))
    assert small_sample_stretch(np.ones(5), 0.95) > small_sample_stretch(np.ones(20), 0.95) > \
        small_sample_stretch(np.ones(2000), 0.95) > 1.0
    assert small_sample_stretch(np.ones(2000), 0.95) == pytest.approx(1.0, abs=2e-3)
    # 20 blocks of which 10 are cut short hold less information than 20 full ones.
    uneven = np.r_[np.ones(10), np.full(10, 0.1)]
    assert small_sample_stretch(uneven, 0.95) > small_sample_stretch(np.ones(20), 0.95)
    assert small_sample_stretch(np.ones(1), 0.95) == 1.0


@settings(max_examples=40, deadline=None, derandomize=True)
@given(replicates=st.integers(1, 9), size=st.integers(1, 12), rank_deficient=st.booleans(),
       scales=st.lists(st.floats(-6, 6), min_size=12, max_size=12), seed=st.integers(0, 2**16))
def test_stacked_lstsq_is_each_replicates_own_solve_to_the_bit(replicates, size, rank_deficient, scales, seed):
    """The bootstrap solves its replicates in one call; every one is the solve np.linalg.lstsq gives it alone,
    for badly scaled and singular Gram matrices too (the intervals in gap.json depend on it)."""
    from sim2real.identification.fitting.bootstrap import stacked_lstsq

    rng = np.random.default_rng(seed)
    columns = rng.normal(size=(replicates, 3 * size, size)) * 10.0 ** np.asarray(scales[:size])
    if rank_deficient and size > 1:
        columns[:, :, -1] = 2.0 * columns[:, :, 0]
    grams = np.einsum("kij,kil->kjl", columns, columns)
    rhs = rng.normal(size=(replicates, size))
    stacked = stacked_lstsq(grams, rhs)
    for k in range(replicates):
        assert np.array_equal(stacked[k], np.linalg.lstsq(grams[k], rhs[k], rcond=1e-12)[0])
    assert stacked_lstsq(grams[:, :, :0], rhs).shape == (replicates, 0)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), replicates=st.integers(1, 300), blocks=st.integers(1, 700))
def test_the_bootstraps_one_draw_is_the_stream_of_one_draw_per_replicate(seed, replicates, blocks):
    """The bootstrap draws every replicate's blocks at once; the replicates (and the intervals in gap.json)
    are the ones drawn replicate by replicate, for odd numbers of blocks too (half a 64-bit word left over)."""
    rng = np.random.default_rng(seed)
    one_by_one = np.array([rng.integers(0, blocks, size=blocks) for _ in range(replicates)])
    assert np.array_equal(np.random.default_rng(seed).integers(0, blocks, size=(replicates, blocks)), one_by_one)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), replicates=st.integers(1, 60), with_gain=st.booleans(), forward=st.booleans())
def test_intervals_from_stacked_replicates_are_each_replicates_own_values(seed, replicates, with_gain, forward):
    """Every effect that takes its replicates stacked (values_stacked) gives the intervals that its values of
    each replicate alone give, to the bit, beside a torque gain that rescales them too."""
    from sim2real.identification.effects import EFFECTS, Signals
    from sim2real.identification.fitting import replicate_intervals
    from sim2real.identification.fitting.bootstrap import _intervals
    from sim2real.identification.fitting.problem import _values

    rng = np.random.default_rng(seed)
    joints = ["a", "b", "c"]
    samples = 50
    motion = [rng.normal(size=(samples, len(joints))) for _ in range(3)]
    nominal = {key: rng.uniform(0.0, 2.0, len(joints)) for key in ("friction", "damping", "armature")}
    gravity = rng.normal(size=(samples, len(joints), 3))  # a generalized gravity under unit gravity along x, y, z
    signals = Signals(joints, np.arange(samples) * 5e-3, *motion, np.zeros((samples, len(joints))),
                      [slice(0, samples)], tau=rng.normal(size=(samples, len(joints))), nominal=nominal, forward=forward,
                      gravity_fn=lambda: gravity)
    stacked_effects = [e for e in EFFECTS.values() if e.values_stacked]
    assert {e.name for e in stacked_effects} >= {"coulomb_friction", "viscous_friction", "rotor_inertia"}
    for effect in stacked_effects:
        effects = [effect, EFFECTS["torque_gain"]] if with_gain and effect.name != "torque_gain" else [effect]
        states = {e.name: e.prepare(signals) for e in effects}
        nonlinear = {e.name: np.asarray(e.nonlinear_init(signals), dtype=float) for e in effects}
        theta = {e.name: rng.normal(scale=0.3, size=(replicates, len(e.columns(signals, states[e.name],
                                                                                  nonlinear[e.name])[1])))
                 for e in effects}
        one_by_one = _intervals([_values(effects, {k: v[r] for k, v in theta.items()}, nonlinear, signals, states)
                                 for r in range(replicates)], 0.95)
        assert replicate_intervals(effects, theta, nonlinear, signals, states, 0.95) == one_by_one, effect.name


@settings(max_examples=10, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), samples=st.integers(1, 300))
def test_the_batched_inverse_dynamics_is_pinocchios_rnea_sample_by_sample(seed, samples):
    """The nominal torque comes from Pinocchio's batched RNEA: each sample is pin.rnea's own, to the bit, in the
    caller's joint order (reversed here), with the URDF's damping and friction on top."""
    import pinocchio as pin

    from sim2real.assets.dynamics import RigidBodyModel

    joints = list(reversed(PANDA_JOINTS))
    model = RigidBodyModel(PANDA_URDF, joints)
    rng = np.random.default_rng(seed)
    q, qd, qdd = (rng.normal(size=(samples, len(joints))) for _ in range(3))
    order = [model.model.joints[model.model.getJointId(j)].idx_v for j in joints]
    expected = np.empty_like(q)
    for k in range(samples):
        state = [np.empty(len(joints)) for _ in range(3)]
        for x, sample in zip(state, (q, qd, qdd)):
            x[order] = sample[k]
        expected[k] = pin.rnea(model.model, model.data, *state)[order]
    expected += model.damping * qd + model.friction * np.sign(qd)
    assert np.array_equal(model.inverse_dynamics(q, qd, qdd), expected)


def test_the_refinement_runs_on_windows_of_the_runs_at_their_own_step_beyond_its_sample_cap():
    from sim2real.identification.effects import Signals
    from sim2real.identification.fitting.refine import refinement_rows

    lengths = [70_000, 3_000, 50_000]  # three runs at 1 kHz, one shorter than a window
    time = np.concatenate([np.arange(n) * 1e-3 for n in lengths])
    bounds = np.cumsum([0, *lengths])
    runs = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
    zeros = np.zeros((len(time), 1))
    signals = Signals(["j"], time, zeros, zeros, zeros, zeros, runs)
    everything, none = refinement_rows(signals, 10**6, 5.0)
    assert none is None and np.array_equal(everything, np.arange(len(time)))
    every_kth, none = refinement_rows(signals, 12_000)
    assert none is None and np.all(np.diff(every_kth) == 11)
    rows, windows = refinement_rows(signals, 12_000, 5.0)
    assert len(rows) <= 12_000 and len(windows) == 2  # 12 000 // 5 000 windows, the first and the last
    assert windows[0].start == 0 and windows[-1].stop == len(rows)
    for window in windows:
        taken = rows[window]
        assert np.all(np.diff(taken) == 1)  # contiguous: the log's own step
        assert sum(run.start <= taken[0] and taken[-1] < run.stop for run in runs) == 1  # inside one run
    assert rows[0] == 0 and rows[-1] > bounds[2]  # spread from the first run to the last
    many, windows = refinement_rows(signals, 60_000, 5.0)
    assert len(windows) == 12 and len(np.unique(many)) == len(many)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(samples=st.integers(1, 400), joints=st.integers(1, 7), columns=st.integers(1, 12), chunk=st.integers(1, 300),
       weighted=st.booleans(), seed=st.integers(0, 2**16))
def test_a_long_logs_block_is_scaled_chunk_by_chunk_to_the_same_bits(samples, joints, columns, chunk, weighted, seed):
    """A long log's columns are weighted and their norms summed a chunk of samples at a time, never as one
    weighted copy: the same scale, rows and acting columns as the block taken whole (the demo's path)."""
    from sim2real import blas
    from sim2real.identification.fitting import linear

    rng = np.random.default_rng(seed)
    block = rng.normal(size=(samples, joints, columns)) * 10.0 ** rng.normal(size=(samples, 1, 1))
    block[:, rng.integers(0, joints), rng.integers(0, columns)] = 0.0  # a column that does not act on a joint
    weights = rng.uniform(0.1, 10.0, size=joints) if weighted else None
    whole = linear._scaled_block(block, weights)
    original = blas.CHUNK_ROWS
    try:
        blas.CHUNK_ROWS = chunk
        chunked = linear._scaled_block(block, weights)
    finally:
        blas.CHUNK_ROWS = original
    assert np.array_equal(whole.scale, chunked.scale)
    for (cols_a, rows_a), (cols_b, rows_b) in zip(whole.joints, chunked.joints, strict=True):
        assert np.array_equal(cols_a, cols_b) and np.array_equal(rows_a, rows_b)


def test_payload_and_delay_are_recovered(nominal):
    payload = fitting.fit(["payload"], nominal, _data({"payload": (1.2, [0.02, 0.0, 0.12])}, [3]), FAST)
    assert payload.values["payload"]["mass"] == pytest.approx(1.2, rel=0.02)
    assert payload.values["payload"]["com_in_last_link"] == pytest.approx([0.02, 0.0, 0.12], abs=0.005)
    assert payload.values["payload"]["link"] == "panda_link8"  # reported at the flange, as the Xacro wants it
    delayed = _data({"actuation_delay": 0.012}, [4])
    assert delayed.torque_source == "tau_cmd"
    delay = fitting.fit(["actuation_delay"], nominal, delayed, FAST)
    assert delay.values["actuation_delay"]["delay"] == pytest.approx(0.012, abs=0.002)
    # The delay has an interval like the linear parameters (a linearised step per bootstrap replicate). It
    # is statistical: on this 100 Hz grid the linear interpolation of the shift biases the delay ~0.2 ms.
    lo, hi = delay.intervals["actuation_delay"]["delay"]
    assert lo < delay.values["actuation_delay"]["delay"] < hi
    assert 0.0 < hi - lo < 0.002


def test_ladder_falls_rung_by_rung_and_is_deterministic(nominal):
    hidden = {"coulomb_friction": [0.5] * 7, "rotor_inertia": [0.2] * 7}
    fit_data, holdout = _data(hidden, [5]), _data(hidden, [6])
    first, _ = side_ladder(["coulomb_friction", "rotor_inertia"], nominal, fit_data, holdout, FAST)
    again, _ = side_ladder(["coulomb_friction", "rotor_inertia"], nominal, fit_data, holdout, FAST)
    assert json.dumps(first, sort_keys=True) == json.dumps(again, sort_keys=True)
    rmse = [r["metrics"]["torque_rmse"]["overall"] for r in first["ladder"]]
    assert rmse[0] > rmse[1] > rmse[2]
    assert [r["effects"] for r in first["ladder"]] == [[], ["coulomb_friction"], ["coulomb_friction", "rotor_inertia"]]
    assert set(first["ladder"][2]["metrics"]["torque_rmse"]["per_joint"]) == set(PANDA_JOINTS)
    assert first["diagnosis"]["status"] == "at_noise_floor"


def _write_real_log(path, run, with_repeats=True):
    """A real-log style table: only time, q, qd, tau; irregular stamps, repeated samples."""
    rng = np.random.default_rng(0)
    keep = np.sort(rng.choice(len(run.time), size=int(0.8 * len(run.time)), replace=False))
    table = {"time": run.time[keep] + rng.uniform(0, 2e-4, size=len(keep))}
    for j, joint in enumerate(PANDA_JOINTS):
        table[f"q.{joint}"] = run.q[keep, j]
        table[f"qd.{joint}"] = run.qd[keep, j] + rng.normal(scale=0.01, size=len(keep))
        table[f"tau.{joint}"] = run.tau[keep, j]
    frame = pd.DataFrame(table)
    if with_repeats:
        frame = pd.concat([frame, frame.iloc[::7]]).sort_values("time", kind="stable")
        frame["time"] = frame["time"] + np.arange(len(frame)) * 1e-9  # repeated state, fresh stamp
    frame.to_csv(path, index=False)
    path.with_suffix(".yaml").write_text(yaml.safe_dump({"robot": "panda", "source": "real", "control_mode": "torque"}))


def test_real_log_mode_without_commands(tmp_path):
    hidden = {"coulomb_friction": [0.6] * 7}
    for name, seed in (("a", 7), ("b", 8)):
        _write_real_log(tmp_path / f"{name}.csv", make_run(name, hidden, seed, duration=12.0, rate=1000.0))
    (tmp_path / "measurements.yaml").write_text(yaml.safe_dump({"runs": [
        {"name": "a", "path": "a.csv", "role": "fit"}, {"name": "b", "path": "b.csv", "role": "holdout"}]}))
    (tmp_path / "model.yaml").write_text("effects:\n- coulomb_friction\nfit: {bootstrap_replicates: 20, fit_rate_hz: 100}\n")
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump({"armature": {"panda_joint*": 0.1}, "flange": "panda_link8"}))
    out = tmp_path / "out"
    document = sysid.run_sysid("panda", sysid.SysidFiles(
        PANDA_URDF, tmp_path / "robot.yaml", tmp_path / "model.yaml", tmp_path / "measurements.yaml",
        out / "ladder.json", out / "params.yaml", out / "calibration.yaml", root=tmp_path,
    ))
    assert document["state_domain"]["status"] == "skipped"
    assert document["state_domain"]["reason"] == "no_commands"  # nothing to replay
    assert "actuation_delay" in [s["effect"] for s in document["diagnosis"]["skipped"]]
    rmse = [r["metrics"]["torque_rmse"]["overall"] for r in document["ladder"]]
    assert rmse[1] < 0.3 * rmse[0]
    params = yaml.safe_load((out / "params.yaml").read_text())
    assert params["effects"]["coulomb_friction"]["friction"]["panda_joint4"] == pytest.approx(0.6, rel=0.1)
    calibration = yaml.safe_load((out / "calibration.yaml").read_text())
    assert calibration["joints"]["panda_joint4"]["friction"] == pytest.approx(0.6, rel=0.1)
    assert json.loads((out / "ladder.json").read_text()) == document


def test_model_yaml_errors_name_the_key(tmp_path):
    bad = tmp_path / "model.yaml"
    bad.write_text("effects:\n- coulomb_frictoin\n")
    with pytest.raises(InputError, match="effects/0"):
        sysid.load_model_config(bad)
    bad.write_text("effects: [payload, payload]\n")
    with pytest.raises(InputError, match="effects"):
        sysid.load_model_config(bad)


def test_a_drive_line_can_be_kept_on_one_link_and_only_a_drive_line(tmp_path):
    """'- asymmetric_friction: actuator' keeps a drive's effect on one link (behind a link-side sensor it is fitted on
    both); an effect fitted on one link anyway, or a link that is none, is refused with the line's fix."""
    model = tmp_path / "model.yaml"
    model.write_text("effects:\n- link_inertia\n- asymmetric_friction: actuator\n- rotor_inertia\n")
    config = sysid.load_model_config(model)
    assert config.effects == ("link_inertia", "asymmetric_friction", "rotor_inertia")
    assert config.sides == {"asymmetric_friction": "actuator"}
    assert config.as_settings() == {"effects": ["link_inertia", "asymmetric_friction", "rotor_inertia"],
                                    "links": {"asymmetric_friction": "actuator"}, "fit": {}, "diagnosis": {}}
    refused = {"- link_inertia: actuator": r"effects/0.*fitted on one side only.*write '- link_inertia'",
               "- asymmetric_friction: motor": "effects",
               "- asymmetric_friction\n- asymmetric_friction: body": "listed twice"}
    for lines, match in refused.items():
        model.write_text(f"effects:\n{lines}\n")
        with pytest.raises(InputError, match=match):
            sysid.load_model_config(model)


def test_runs_mixing_torque_sources_are_refused(nominal):
    runs = [make_run("a", {}, 1, duration=3.0), make_run("b", {"actuation_delay": 0.01}, 2, duration=3.0)]
    with pytest.raises(InputError, match="torque sources"):
        fitting.stack_runs(runs, PANDA_JOINTS)
