"""The checks a user's log needs: a torque logged with the opposite sign (refused, ``torque_sign`` turns it) and
position columns held by a logger slower than the log (stated, taken at their update instants)."""

from __future__ import annotations

import collections

import numpy as np
import pytest
import yaml

from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run
from sim2real.errors import InputError
from sim2real.measurements import load_run, prepare_for_model, prepare_run, write_run
from sim2real.measurements.records import FilterSettings
from sim2real.report.runs_section import runs_lines

META = {"robot": "panda", "source": "real", "control_mode": "torque", "sample_rate_hz": 200.0}


def _listing(tmp_path, signs: dict | None = None, flip: tuple[str, ...] = ()) -> tuple:
    """Two runs of the Panda (fit, holdout), their torque the URDF's with the joints ``flip`` logged negated, their
    metadata with ``signs`` as ``torque_sign``."""
    runs = {}
    for name, seed in (("fit", 1), ("holdout", 2)):
        run = make_run(name, {}, seed, duration=4.0)
        logged = run.tau * np.array([-1.0 if j in flip else 1.0 for j in PANDA_JOINTS])
        write_run(tmp_path / f"{name}.csv", run.time, PANDA_JOINTS, {"q": run.q, "tau": logged},
                  {**META, **({"torque_sign": signs} if signs else {})})
        runs[name] = run
    listing = tmp_path / "measurements.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "fit", "path": "fit.csv", "role": "fit"},
                                                {"name": "holdout", "path": "holdout.csv", "role": "holdout"}]}))
    return listing, runs


def test_a_flipped_torque_sign_is_refused_naming_the_run_and_every_flipped_joint(tmp_path):
    listing, _ = _listing(tmp_path, flip=("panda_joint2", "panda_joint4"))
    with pytest.raises(InputError) as error:
        prepare_for_model(listing, PANDA_URDF, root=tmp_path)
    message = str(error.value)
    assert len(message.splitlines()) == 1
    assert str(tmp_path / "fit.csv") in message and "column tau.panda_joint2, column tau.panda_joint4" in message
    assert "anti-correlated with the URDF's inverse-dynamics torque on 2 joint(s)" in message
    assert "so are runs holdout" in message
    assert "torque_sign: {panda_joint2: -1, panda_joint4: -1}" in message and str(tmp_path / "fit.yaml") in message
    for joint in ("panda_joint1", "panda_joint3", "panda_joint5", "panda_joint6", "panda_joint7"):
        assert f"tau.{joint}" not in message


def test_torque_sign_in_the_metadata_is_honoured(tmp_path):
    signs = {"panda_joint2": -1, "panda_joint4": -1}
    listing, truth = _listing(tmp_path, signs=signs, flip=tuple(signs))
    prepared = prepare_for_model(listing, PANDA_URDF, root=tmp_path)  # accepted: the signs turn the torque round
    run = load_run(tmp_path / "fit.csv")
    assert run.meta.torque_sign == signs and run.meta.as_document()["torque_sign"] == signs
    assert np.allclose(run.tau, truth["fit"].tau, atol=1e-6)  # every joint as the URDF predicts, the flipped ones too
    fit = prepared.fit[0]
    assert np.corrcoef(fit.tau[:, 1], np.interp(fit.time, truth["fit"].time, truth["fit"].tau[:, 1]))[0, 1] > 0.99


@pytest.mark.parametrize(("signs", "where"), [
    ({"panda_joint9": -1}, "torque_sign.panda_joint9: 'panda_joint9' is not a joint of the run"),
    ({"panda_joint2": 2}, "torque_sign"),
    ({"panda_joint2": "minus"}, "torque_sign"),
])
def test_a_torque_sign_that_is_no_sign_of_a_logged_joint_is_refused(tmp_path, signs, where):
    run = make_run("r", {}, 1, duration=2.0)
    write_run(tmp_path / "r.csv", run.time, PANDA_JOINTS, {"q": run.q, "tau": run.tau}, META)
    (tmp_path / "r.yaml").write_text(yaml.safe_dump({**META, "torque_sign": signs}))
    with pytest.raises(InputError, match=r"r\.yaml") as error:
        load_run(tmp_path / "r.csv")
    assert where in str(error.value)


def _held_run(tmp_path, held: slice, every: int = 4):
    """A 1 kHz run of two joints whose positions in columns ``held`` update every ``every`` rows only (held between),
    while the torque changes every row; and the true velocity at each stamp."""
    t = np.arange(6000) * 1e-3
    q = np.column_stack([0.5 * np.sin(1.3 * t), -0.3 + 0.4 * np.cos(0.9 * t)])
    qd = np.column_stack([0.65 * np.cos(1.3 * t), -0.36 * np.sin(0.9 * t)])
    logged = q.copy()
    stale = np.arange(t.size) - np.arange(t.size) % every
    logged[:, held] = q[stale][:, held]
    tau = 2.0 * qd + 0.01 * np.random.default_rng(0).standard_normal(qd.shape)
    write_run(tmp_path / "held.csv", t, PANDA_JOINTS[:2], {"q": logged, "tau": tau},
              {"robot": "panda", "source": "real", "control_mode": "torque"})
    return load_run(tmp_path / "held.csv"), lambda at: np.column_stack(
        [np.interp(at, t, qd[:, j]) for j in range(2)])


@pytest.mark.parametrize(("held", "joints"), [(slice(0, 2), ["panda_joint1", "panda_joint2"]),
                                              (slice(1, 2), ["panda_joint2"])])
def test_held_positions_are_stated_and_never_differentiated_as_a_stop(tmp_path, held, joints):
    run, true_velocity = _held_run(tmp_path, held)
    prepared = prepare_run(run)
    record = prepared.filter.held
    assert record is not None and record.of == 6000 and set(record.held["q"]) == set(joints)
    assert all(count == 4500 for count in record.held["q"].values())  # three rows of four repeat the update
    assert FilterSettings.from_document(prepared.filter.as_document()) == prepared.filter
    # taken at its update instants, the velocity follows the motion (1.4e-4 rad/s off at most, the filter's own);
    # differentiated as logged, the held column's lags by half an update period (4.9e-4 rad/s off)
    assert np.max(np.abs(prepared.qd - true_velocity(prepared.time))) < 2.5e-4
    document = {"name": "held", "role": "fit", "torque_source": "tau", "samples": prepared.time.size,
                "duration_s": 5.0, "has_commands": False, "filter": prepared.filter.as_document()}
    text = "\n".join(runs_lines([document]))
    assert "Held samples (a column repeating the row before while the rest of the row changes" in text
    assert "- held: `q` " + ", ".join(f"{j} 4500 of 6000 rows (75%)" for j in joints) + "." in text
    assert "taken at its own update instants" in text


def test_a_log_without_holds_says_nothing_of_them(tmp_path):
    run, _ = _held_run(tmp_path, slice(0, 0))
    prepared = prepare_run(run)
    assert prepared.filter.held is None and "held" not in prepared.filter.as_document()
    document = {"name": "clean", "role": "fit", "torque_source": "tau", "samples": 1, "duration_s": 5.0,
                "has_commands": False, "filter": prepared.filter.as_document()}
    assert "Held samples" not in "\n".join(runs_lines([document]))


def _still_wrist_runs(tmp_path):
    """Two runs of the Panda whose wrist (panda_joint7) barely moves (0.02 rad) while the other joints sweep, the
    torque the URDF's plus Coulomb friction on every joint and noise; their list, model.yaml (the friction in the
    model) and robot.yaml."""
    from sim2real.assets.dynamics import RigidBodyModel
    from sysid_synthetic import fourier_trajectory

    model = RigidBodyModel(PANDA_URDF, PANDA_JOINTS, armature={j: 0.1 for j in PANDA_JOINTS})
    runs = []
    for name, seed in (("fit", 1), ("holdout", 2)):
        t, q, qd, qdd = fourier_trajectory(model, 4.0, 200.0, seed)
        centre = q[:, 6].mean()
        scale = 0.02 / np.ptp(q[:, 6])
        q[:, 6], qd[:, 6], qdd[:, 6] = centre + scale * (q[:, 6] - centre), scale * qd[:, 6], scale * qdd[:, 6]
        tau = model.inverse_dynamics(q, qd, qdd) + 0.4 * np.tanh(qd / 0.02)
        tau += np.random.default_rng(seed).normal(scale=0.05, size=tau.shape)
        write_run(tmp_path / f"{name}.csv", t, PANDA_JOINTS, {"q": q, "tau": tau}, META)
        runs.append({"name": name, "path": f"{name}.csv", "role": name})
    listing = tmp_path / "measurements.yaml"
    listing.write_text(yaml.safe_dump({"runs": runs}))
    (tmp_path / "model.yaml").write_text("effects: [coulomb_friction]\n"
                                         "fit: {bootstrap_replicates: 5, fit_rate_hz: 100, refine_max_samples: 500}\n")
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump({"armature": {"panda_joint*": 0.1}, "flange": "panda_link8"}))
    return listing


def test_a_joint_that_barely_moves_is_named_not_judged_and_its_drive_is_not_fitted(tmp_path):
    from sim2real.identification.sysid import SysidFiles, run_sysid
    from sim2real.measurements.motion import MIN_RANGE_RAD, still_joints
    from sim2real.report.gap import GapInputs, compute_gap
    from sim2real.report.markdown import render_gap_markdown

    listing = _still_wrist_runs(tmp_path)
    prepared = prepare_for_model(listing, PANDA_URDF, root=tmp_path)
    still = still_joints(prepared.fit)
    assert list(still) == ["panda_joint7"] and 0.015 < still["panda_joint7"] < MIN_RANGE_RAD
    out = tmp_path / "out"
    ladder = run_sysid("panda", SysidFiles(PANDA_URDF, tmp_path / "robot.yaml", tmp_path / "model.yaml", listing,
                                           out / "ladder.json", out / "params.yaml", out / "calibration.yaml",
                                           root=tmp_path, residuals=out / "residuals.npz"))
    fitted = ladder["ladder"][-1]["params"]["coulomb_friction"]["friction"]
    assert fitted["panda_joint7"] == 0.0  # held at the URDF's (none): never fitted on the wrist's noise
    assert all(0.3 < fitted[j] < 0.5 for j in PANDA_JOINTS[:6])  # the joints that move: 0.4 N*m found
    assert ladder["settings"]["fit"]["still_joints"] == ["panda_joint7"]
    rows = ladder["diagnosis"]["per_joint"]
    assert rows["panda_joint7"]["judged"] is False and all("judged" not in rows[j] for j in PANDA_JOINTS[:6])
    gap, _ = compute_gap(GapInputs("panda", PANDA_URDF, None, listing, root=tmp_path, ladder=out / "ladder.json",
                                   residuals=out / "residuals.npz"))
    assert gap["not_judged"]["joints"]["panda_joint7"]["range_rad"] == pytest.approx(still["panda_joint7"])
    assert gap["not_judged"]["needs_rad"] == MIN_RANGE_RAD  # the other joints sweep a radian
    text = render_gap_markdown(gap, collections.defaultdict(lambda: "figure.svg"))
    assert (f"Not judged: panda_joint7 barely moves in the fit runs ({still['panda_joint7']:.2g} rad at most within "
            "one run): its drive friction and rotor inertia are held at the URDF's rather than fitted on noise") in text
    assert "record a fit run that sweeps it over at least 0.1 rad." in text
