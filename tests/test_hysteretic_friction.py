"""Hysteretic (Dahl) friction (issue 30 item 6): its state follows the measured positions, the fit finds it, and
the MJCF gets its sliding level with the hysteresis honestly left out."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run
from sysid_lab import side_ladder
from sim2real.identification import fitting
from sim2real.identification.fitting import RunSamples
from sim2real.identification.effects import apply_to_spec, get_effect
from sim2real.identification.effects.hysteretic_friction import dahl_state


def euler_dahl(q: np.ndarray, start: float, presliding: float) -> np.ndarray:
    """Dahl's law stepped sample by sample along q (an independent integration, not the effect's closed form)."""
    z = np.empty_like(q)
    z[0] = start
    for k in range(1, q.size):
        step = q[k] - q[k - 1]
        z[k] = np.clip(z[k - 1] + (1.0 - z[k - 1] * np.sign(step)) * step / presliding, -1.0, 1.0)
    return z


def test_the_state_follows_dahls_law_along_the_measured_positions():
    t = np.linspace(0.0, 12.0, 24001)
    q = (0.4 * np.sin(0.9 * t) + 0.1 * np.sin(2.3 * t))[:, None]
    qd = (0.36 * np.cos(0.9 * t) + 0.23 * np.cos(2.3 * t))[:, None]
    z = dahl_state(q, qd, [slice(0, t.size)], np.array([0.03]))
    assert np.max(np.abs(z[:, 0] - euler_dahl(q[:, 0], 1.0, 0.03))) < 5e-3
    # hysteresis: just after a reversal the friction still has the old sign
    reversal = np.flatnonzero(np.diff(np.sign(qd[:, 0])))[0] + 1
    assert np.sign(z[reversal + 1, 0]) == -np.sign(qd[reversal + 1, 0])
    # and each run starts afresh: a second segment is the same as the first on its own
    twice = dahl_state(np.vstack([q, q]), np.vstack([qd, qd]), [slice(0, t.size), slice(t.size, 2 * t.size)],
                       np.array([0.03]))
    assert np.array_equal(twice[t.size:], z)


def _dahl_run(name: str, seed: int, level: float, presliding: float) -> RunSamples:
    run = make_run(name, {}, seed, duration=12.0, noise=0.01)
    z = np.column_stack([euler_dahl(run.q[:, j], np.sign(run.qd[0, j]) or 1.0, presliding)
                         for j in range(len(PANDA_JOINTS))])
    return dataclasses.replace(run, tau=run.tau + level * z)


def test_the_fit_recovers_the_level_and_the_presliding_length():
    nominal = fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")
    data = [fitting.stack_runs([_dahl_run(n, s, 0.3, 0.04)], PANDA_JOINTS) for n, s in (("fit", 3), ("holdout", 4))]
    settings = {"fit": {"bootstrap_replicates": 20, "refine_max_samples": 1500}}
    document, result = side_ladder(["hysteretic_friction"], nominal, data[0], data[1], settings["fit"],
                                   diagnosed=False)
    values = result.values["hysteretic_friction"]
    for joint in PANDA_JOINTS:
        assert values["level"][joint] == pytest.approx(0.3, rel=0.1), joint
        assert values["presliding_rad"][joint] == pytest.approx(0.04, rel=0.35), joint
    floor = document["noise_floor"]["torque_rmse"]["overall"]
    assert document["ladder"][-1]["metrics"]["torque_rmse"]["overall"] < 1.2 * floor


def test_the_mjcf_gets_the_sliding_level_on_top_of_its_dry_friction():
    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(name="link")
    body.add_geom(size=[0.1, 0, 0])
    joint = body.add_joint(name="j", type=mujoco.mjtJoint.mjJNT_HINGE)
    joint.frictionloss = 0.2
    params = {"effects": {"hysteretic_friction": {"level": {"j": 0.3}, "presliding_rad": {"j": 0.05}}}}
    apply_to_spec(spec, params, include_urdf_effects=True)
    assert spec.joint("j").frictionloss == pytest.approx(0.5)
    assert not get_effect("hysteretic_friction").in_urdf
