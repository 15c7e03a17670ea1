"""Excitation design (sim2real.excitation): the built trajectory respects every limit at every sample, is
collision-free on the built MJCF, is deterministic, and bad configs get errors naming file, key and fix."""

from __future__ import annotations

import copy
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from buildtree import run_snakemake
from readme import copy_built
from sim2real.report.verdicts import worded
from sim2real.assets.dynamics import RigidBodyModel
from sim2real.errors import InputError
from sim2real.excitation.config import load_designs
from sim2real.excitation.files import ExcitationInputs, build_excitation, build_excitation_start

TARGET = "results/panda/excitation/identification.csv"


@pytest.fixture(scope="module")
def designed(built_tree: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the shared built tree (its `snakemake all` designed the excitation): this module reruns the design."""
    tree = copy_built(built_tree, tmp_path_factory.mktemp("excitation") / "project")
    assert "Nothing to be done" in run_snakemake(tree, "-n", TARGET)
    return tree


def _config(tree: Path) -> dict:
    return yaml.safe_load((tree / "configs/panda/excitation.yaml").read_text())


def test_every_sample_within_the_limits_and_margins(designed: Path) -> None:
    table = pd.read_csv(designed / TARGET)
    config = _config(designed)
    settings = {**config["defaults"], **(config["designs"]["identification"] or {})}
    joints = config["joints"]
    margins = settings["margins"]
    q = table[[f"q.{j}" for j in joints]].to_numpy()
    qd = table[[f"qd.{j}" for j in joints]].to_numpy()
    qdd = table[[f"qdd.{j}" for j in joints]].to_numpy()
    assert len(table) == settings["duration_s"] * settings["sample_rate_hz"]
    assert np.allclose(np.diff(table["time"]), 1.0 / settings["sample_rate_hz"])
    robot = yaml.safe_load((designed / "configs/panda/robot.yaml").read_text())
    model = RigidBodyModel(designed / "results/panda/panda.urdf", joints, armature={j: 0.1 for j in joints})
    tol = 1e-7
    assert np.all(q >= model.lower + margins["position_rad"] - tol)
    assert np.all(q <= model.upper - margins["position_rad"] + tol)
    assert np.all(np.abs(qd) <= (1 - margins["velocity_fraction"]) * model.velocity_limit + tol)
    assert np.all(np.abs(qdd) <= (1 - margins["acceleration_fraction"]) * np.asarray(settings["acceleration_limit"]) + tol)
    torque = model.inverse_dynamics(q, qd, qdd)
    assert np.all(np.abs(torque) <= (1 - margins["torque_fraction"]) * model.effort_limit + tol)
    # Starts and ends at rest at the start pose, and the series is consistent (qd is the derivative of q).
    home = np.array([robot["home"][j] for j in joints])
    assert np.allclose(q[0], home) and np.allclose(qd[0], 0, atol=1e-9) and np.allclose(qdd[0], 0, atol=1e-9)
    dt = 1.0 / settings["sample_rate_hz"]
    assert np.allclose(np.gradient(q, dt, axis=0)[1:-1], qd[1:-1], atol=1e-4)
    # It moves: every excited joint uses a good part of its usable velocity.
    assert np.all(np.abs(qd).max(axis=0) > 0.3 * (1 - margins["velocity_fraction"]) * model.velocity_limit)
    trajectory = yaml.safe_load((designed / "results/panda/excitation/identification.trajectory.yaml").read_text())
    assert trajectory["joint_names"] == joints
    end = trajectory["points"][-1]
    assert end["time_from_start"] == {"sec": int(settings["duration_s"]), "nanosec": 0}
    assert np.allclose(end["positions"], home) and not any(end["velocities"])


def _min_distance(tree: Path, joints: list[str], q: np.ndarray, obstacles: list[dict]) -> float:
    """Smallest distance between collision geoms that may touch, by mj_geomDistance (independent of the design's
    own contact-based check): pairs on different weld groups, not parent and child, the base and its first link
    excluded; the obstacles against every moving link."""
    spec = mujoco.MjSpec.from_file(str(tree / "results/panda/mjcf/panda.xml"))
    for obstacle in obstacles:
        assert obstacle["type"] == "plane"
        spec.worldbody.add_geom(name=obstacle["name"], type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
                                pos=obstacle["point"], group=4)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)  # the joints not designed (the fingers) stay at home
    geoms = [g for g in range(model.ngeom) if model.geom_group[g] in (3, 4)]
    weld = model.body_weldid

    def may_touch(a: int, b: int) -> bool:
        wa, wb = weld[model.geom_bodyid[a]], weld[model.geom_bodyid[b]]
        if wa == wb:
            return False
        pa, pb = weld[model.body_parentid[wa]], weld[model.body_parentid[wb]]
        return pa != wb and pb != wa

    pairs = [(a, b) for i, a in enumerate(geoms) for b in geoms[i + 1:] if may_touch(a, b)]
    qadr = [model.jnt_qposadr[model.joint(j).id] for j in joints]
    fromto = np.zeros(6)
    best = np.inf
    for row in q:
        data.qpos[qadr] = row
        mujoco.mj_kinematics(model, data)
        best = min(best, min(mujoco.mj_geomDistance(model, data, a, b, 0.05, fromto) for a, b in pairs))
    return best


def test_collision_free_on_the_built_mjcf(designed: Path) -> None:
    config = _config(designed)
    joints = config["joints"]
    table = pd.read_csv(designed / TARGET)
    q = table[[f"q.{j}" for j in joints]].to_numpy()[::25]
    margin = config["defaults"]["margins"]["collision_m"]
    distance = _min_distance(designed, joints, q, config["defaults"]["obstacles"])
    assert distance >= margin - 1e-3, distance  # a 25 ms grid can miss the closest sample by a hair
    summary = yaml.safe_load((designed / "results/panda/excitation/identification.json").read_text())
    assert summary["min_clearance_m"] >= margin
    # The design improves on its random start by its own objective (minimised), even in a few iterations.
    assert summary["objective_value"]["designed"] < summary["objective_value"]["initial"], summary["objective_value"]
    report = (designed / "results/panda/excitation/identification.md").read_text()
    assert "Closest approach to collision" in report and "condition number" in report.lower()


def test_same_inputs_same_bytes(designed: Path) -> None:
    files = ["identification.csv", "identification.trajectory.yaml", "identification.md", "identification.png"]
    before = {f: (designed / "results/panda/excitation" / f).read_bytes() for f in files}
    run_snakemake(designed, TARGET, "--forcerun", "excitation")
    for f in files:
        assert (designed / "results/panda/excitation" / f).read_bytes() == before[f], f


def _broken(tree: Path, tmp_path: Path, edit) -> Path:
    config = _config(tree)
    edit(config)
    path = tmp_path / "excitation.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def _build(tree: Path, config: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    build_excitation(ExcitationInputs("panda", config, "identification", tree / "results/panda/panda.urdf",
                                      tree / "results/panda/mjcf/panda.xml", tree / "configs/panda/robot.yaml"),
                     tree / "configs/panda/model.yaml",
                     {k: str(out / f"x.{k}") for k in ("csv", "trajectory", "json", "md", "figure")})


def test_duration_shorter_than_a_period(designed: Path, tmp_path: Path) -> None:
    path = _broken(designed, tmp_path, lambda c: c["defaults"].update(duration_s=5.0))
    with pytest.raises(InputError, match=r"designs/identification/duration_s: 5 s is shorter than one period") as err:
        load_designs(path)
    assert str(path) in str(err.value) and "Fix:" in str(err.value)
    path = _broken(designed, tmp_path, lambda c: c["defaults"].update(duration_s=30.0))
    with pytest.raises(InputError, match=r"1.5 periods.*Fix: use duration_s 40 \(2 periods\)"):
        load_designs(path)


def test_limits_that_leave_no_motion(designed: Path, tmp_path: Path) -> None:
    path = _broken(designed, tmp_path, lambda c: c["defaults"]["margins"].update(position_rad=2.0))
    with pytest.raises(InputError, match=r"margins/position_rad: a margin of 2 rad leaves panda_joint2 no feasible"):
        _build(designed, path, tmp_path)
    path = _broken(designed, tmp_path, lambda c: c["defaults"]["margins"].update(torque_fraction=0.9))
    with pytest.raises(InputError, match=r"margins/torque_fraction: holding the start pose already takes"):
        _build(designed, path, tmp_path)
    assert not (tmp_path / "out").exists()  # nothing written


def test_obstacle_that_contains_the_start_pose(designed: Path, tmp_path: Path) -> None:
    box = {"name": "shelf", "type": "box", "center": [0.3, 0.0, 0.6], "half_size": [0.2, 0.2, 0.2]}

    def add_box(config: dict) -> None:
        config["defaults"]["obstacles"] = copy.deepcopy(config["defaults"]["obstacles"]) + [box]

    path = _broken(designed, tmp_path, add_box)
    with pytest.raises(InputError, match=r"designs/identification/obstacles: obstacle 'shelf' contains the start pose"):
        _build(designed, path, tmp_path)
    assert not (tmp_path / "out").exists()


def test_schema_names_the_key(designed: Path, tmp_path: Path) -> None:
    path = _broken(designed, tmp_path, lambda c: c["defaults"].update(objective="a_optimal"))
    with pytest.raises(InputError, match=r"key 'defaults/objective'"):
        load_designs(path)


def test_the_run_that_separates_confounded_candidates(designed: Path, tmp_path: Path) -> None:
    """Too slow a run cannot tell viscous from Coulomb friction; gap.md names the separating design's target;
    once the lab has played that run and it is added to the fit runs, the diagnosis tells them apart."""
    from sim2real.lab import run_lab_scenario_run
    from sim2real.identification.sysid import SysidFiles, run_sysid

    lab = yaml.safe_load((designed / "configs/panda/lab.yaml").read_text())
    scenario = lab["scenarios"]["slow_viscous"]
    scenario["duration_s"] = 8.0
    separating = "separate-viscous_friction-vs-coulomb_friction"
    scenario["runs"] = [{"name": "fit", "seed": 11, "role": "fit"}, {"name": "holdout", "seed": 12, "role": "holdout"},
                        {"name": "separating", "seed": 13, "role": "fit", "excitation": separating}]
    lab_config = tmp_path / "lab.yaml"
    lab_config.write_text(yaml.safe_dump(lab))
    model = tmp_path / "model.yaml"
    model.write_text(yaml.safe_dump({"effects": [], "fit": {"fit_rate_hz": 100.0, "bootstrap_replicates": 20,
                                                            "refine_max_samples": 1500}}))
    mjcf, urdf, robot = (designed / "results/panda/mjcf/panda.xml", designed / "results/panda/panda.urdf",
                         designed / "configs/panda/robot.yaml")

    def runs(*names: str) -> Path:
        listing = tmp_path / f"{'_'.join(names)}.yaml"
        listing.write_text(yaml.safe_dump({"runs": [
            {"name": r, "path": str(tmp_path / f"{r}.parquet"), "role": "holdout" if r == "holdout" else "fit"}
            for r in names]}))
        return listing

    for run in ("fit", "holdout"):
        run_lab_scenario_run(mjcf, lab_config, "panda", "slow_viscous", run, tmp_path / f"{run}.parquet")
    ladder = tmp_path / "ladder.json"
    before = worded(run_sysid("panda", SysidFiles(urdf, robot, model, runs("fit", "holdout"), ladder,
                                                  tmp_path / "p.yaml", tmp_path / "c.yaml")), "panda")["diagnosis"]
    assert ["viscous_friction", "coulomb_friction"] in before["confounded"]
    assert f"`snakemake results/panda/excitation/{separating}.csv`" in before["verdict"]

    outputs = {k: str(tmp_path / f"separating.{k}") for k in ("csv", "trajectory", "json", "md", "figure")}
    # As the DAG designs it: from its start (rule excitation_start, the design for friction alone, on the defaults).
    start = tmp_path / f"{separating}.start.npz"
    inputs = ExcitationInputs("panda", designed / "configs/panda/excitation.yaml", separating, urdf, mjcf, robot)
    build_excitation_start(inputs, start)
    result = build_excitation(inputs, model, outputs, ladder=ladder, start=start)
    difference = result.summary["separation"]["difference_x_floor"]
    # The design sought the difference out: 3.46x on OpenBLAS's SkylakeX, Haswell, SandyBridge and Prescott kernels
    # (1.15x to 2.64x when a pass could end inside the table and the motion was scaled down to pass the dense check).
    assert difference["designed"] > 2 * difference["initial"]
    assert "tells viscous_friction from coulomb_friction apart" in Path(outputs["md"]).read_text()

    run_lab_scenario_run(mjcf, lab_config, "panda", "slow_viscous", "separating", tmp_path / "separating.parquet",
                         excitation=outputs["csv"])
    after = run_sysid("panda", SysidFiles(urdf, robot, model, runs("fit", "separating", "holdout"),
                                          tmp_path / "ladder2.json", tmp_path / "p.yaml", tmp_path / "c.yaml"))["diagnosis"]
    assert after["confounded"] == []
    assert after["status"] == "add_effect" and after["candidates"][0]["effect"] == "viscous_friction"
    coulomb = next(c for c in after["candidates"] if c["effect"] == "coulomb_friction")
    assert coulomb["evidence"]["x_floor_after"] > after["candidates"][0]["evidence"]["x_floor_after"] + 0.3


def test_gap_md_names_the_design_when_the_inertias_are_poorly_pinned() -> None:
    from sim2real.identification.ladder_rows import Rung, RungMetrics
    from sim2real.report.markdown import ILL_CONDITIONED, _identified_markdown

    def rung(condition: float) -> Rung:
        body = {"moved": False, "mass_change_kg": 0.0, "com_shift_mm": 0.0, "divergence": 0.0, "implausible": [],
                "binding": []}
        return Rung(("link_inertia",), RungMetrics({"overall": 0.0, "per_joint": {}}), {"link_inertia": {
            "base_parameters": 43, "condition_number": condition, "bodies": {"panda_link1": body}}})

    poorly = "\n".join(_identified_markdown(rung(3 * ILL_CONDITIONED), "panda"))
    assert "`snakemake results/panda/excitation/identification.csv`" in poorly
    assert "excitation/" not in "\n".join(_identified_markdown(rung(0.5 * ILL_CONDITIONED), "panda"))


@settings(deadline=None)  # the suite's two processes share two cores
@given(st.lists(st.floats(min_value=-0.05, max_value=0.05), max_size=60))
def test_each_stretch_short_of_clearance_is_named_by_its_closest_sample(distances: list[float]) -> None:
    """The active set's clearance rows and the dense check's first look when it scales a design
    (program._closest_of_each_stretch): one sample per run of consecutive samples below the margin, its smallest."""
    from sim2real.excitation.design.program import _closest_of_each_stretch

    margin = 0.01
    values = np.asarray(distances, dtype=float)
    closest = _closest_of_each_stretch(values, margin)
    short = values < margin
    starts = [k for k in range(len(values)) if short[k] and (k == 0 or not short[k - 1])]
    assert len(closest) == len(starts) and closest == sorted(closest)
    for begin, k in zip(starts, closest, strict=True):
        end = begin
        while end + 1 < len(values) and short[end + 1]:
            end += 1
        assert begin <= k <= end and values[k] == values[begin : end + 1].min()


@pytest.mark.parametrize("objective", ["condition", "d_optimal"])
def test_the_objective_gradient_is_the_derivative_of_the_objective(objective: str) -> None:
    """The design's analytic gradient (Gram eigenpairs, not an SVD) against central differences of its value."""
    from sim2real.excitation.information import objective_and_gradient, objective_value

    rng = np.random.default_rng(3)
    w = rng.normal(size=(300, 12)) * rng.uniform(0.1, 10.0, 12)
    value, gradient = objective_and_gradient(w, objective)
    assert value == pytest.approx(objective_value(w, objective), rel=1e-12)
    for _ in range(3):
        direction = rng.normal(size=w.shape)
        step = 1e-6
        numeric = (objective_value(w + step * direction, objective) - objective_value(w - step * direction, objective)) / (2 * step)
        assert float(np.sum(gradient * direction)) == pytest.approx(numeric, rel=1e-5, abs=1e-8)


def test_the_clearance_gradient_follows_the_distance(designed: Path) -> None:
    """n'(J2 - J1) at the nearest contact against central differences of the distance, where a pair of geoms comes
    within the search distance without touching (the distance is smooth there)."""
    from sim2real.excitation.clearance import Clearance

    joints = [f"panda_joint{i}" for i in range(1, 8)]
    clearance = Clearance(designed / "results/panda/mjcf/panda.xml", joints,
                          [{"name": "table", "type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}], 0.1)
    rng = np.random.default_rng(0)
    home = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
    checked = 0
    for _ in range(200):
        q = home + rng.normal(scale=0.8, size=7)
        distance, pair = clearance.closest(q)
        if pair is None or distance < 0.005:
            continue
        step = 1e-6
        numeric = np.array([(clearance.closest(q + step * e)[0] - clearance.closest(q - step * e)[0]) / (2 * step)
                            for e in np.eye(7)])
        if np.abs(numeric).max() < 0.02:  # a pair whose distance barely moves: nothing to compare
            continue
        # mesh-mesh witness points are found to about a millimetre: a few 1e-3 of slack on top of 10 %
        assert np.allclose(clearance.gradient(q), numeric, atol=0.005 + 0.1 * np.abs(numeric).max()), pair
        checked += 1
    assert checked >= 3


def _panda_nominal(tree: Path):
    from sim2real.identification.fitting import load_nominal

    joints = [f"panda_joint{i}" for i in range(1, 8)]
    return load_nominal(tree / "results/panda/panda.urdf", joints, {"panda_joint*": 0.1}, "panda_link8")


def _random_states(dynamics, count: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return (rng.uniform(dynamics.lower, dynamics.upper, (count, dynamics.n)), rng.normal(size=(count, dynamics.n)),
            rng.normal(size=(count, dynamics.n)))


def test_the_symbolic_regressor_and_its_gradient(designed: Path) -> None:
    """The CasADi regressor is Pinocchio's, and its reverse-mode product against central differences of Pinocchio's."""
    from sim2real.excitation.regressor import SymbolicRegressor

    dynamics = _panda_nominal(designed).dynamics
    q, qd, qdd = _random_states(dynamics, 30, 1)
    symbolic = SymbolicRegressor(dynamics)
    assert np.allclose(symbolic(q, qd, qdd), dynamics.regressor(q, qd, qdd), rtol=0, atol=1e-10)
    weights = np.random.default_rng(2).normal(size=(len(q), dynamics.n, symbolic.width))
    gradient = symbolic.contracted_gradient(q, qd, qdd, weights)
    step = 1e-6
    for which in range(3):
        for j in range(dynamics.n):
            plus, minus = [q.copy(), qd.copy(), qdd.copy()], [q.copy(), qd.copy(), qdd.copy()]
            plus[which][:, j] += step
            minus[which][:, j] -= step
            moved = dynamics.regressor(*plus) - dynamics.regressor(*minus)
            numeric = np.einsum("kjc,kjc->k", moved, weights) / (2 * step)
            assert np.allclose(gradient[which][:, j], numeric, rtol=1e-6, atol=1e-6 * np.abs(numeric).max() + 1e-9)


def test_the_torque_jacobian_is_the_derivative_of_the_torque(designed: Path) -> None:
    """d tau / d x from Pinocchio's RNEA derivatives, chained through the Fourier basis, against central differences."""
    from sim2real.excitation.design.program import _Grid, _torque_jacobian
    from sim2real.excitation.fourier import FourierSeries, random_start

    nominal = _panda_nominal(designed)
    dynamics = nominal.dynamics
    series = FourierSeries(2 * np.pi * 0.05, 10, dynamics.n)
    start = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
    grid = _Grid(series, np.linspace(0.0, series.period, 48, endpoint=False), np.arange(dynamics.n), dynamics.n, start)
    rng = np.random.default_rng(4)
    x = 0.3 * random_start(series, rng)
    jacobian = _torque_jacobian(nominal, *grid.state(x), grid).reshape(-1, series.size)
    step = 1e-6
    for _ in range(3):
        direction = rng.normal(size=series.size)
        numeric = (dynamics.inverse_dynamics(*grid.state(x + step * direction))
                   - dynamics.inverse_dynamics(*grid.state(x - step * direction))).ravel() / (2 * step)
        assert np.allclose(jacobian @ direction, numeric, rtol=1e-6, atol=1e-6 * np.abs(numeric).max())


def test_the_state_gradient_is_the_derivative_of_the_objective(designed: Path) -> None:
    """The identification objective's gradient (exact inertial part, differenced effects) against central differences
    of its value along random state directions."""
    from sim2real.excitation.information import Identification, identification_effects

    nominal = _panda_nominal(designed)
    dynamics = nominal.dynamics
    effects = identification_effects(["link_inertia", "asymmetric_friction", "stribeck_friction", "rotor_inertia"])
    ident = Identification(nominal, effects, np.full(7, 0.03), dynamics.lower, dynamics.upper, np.full(7, 1.0),
                           np.full(7, 3.0))
    q, qd, qdd = _random_states(dynamics, 120, 5)
    rng = np.random.default_rng(6)
    for objective in ("condition", "d_optimal"):
        _, dq, dqd, dqdd = ident.state_gradient(q, qd, qdd, objective)
        for _ in range(2):
            directions = [rng.normal(size=q.shape) for _ in range(3)]
            step = 1e-6
            plus = [a + step * d for a, d in zip((q, qd, qdd), directions, strict=True)]
            minus = [a - step * d for a, d in zip((q, qd, qdd), directions, strict=True)]
            numeric = (ident.value(*plus, objective) - ident.value(*minus, objective)) / (2 * step)
            analytic = sum(float(np.sum(g * d)) for g, d in zip((dq, dqd, dqdd), directions, strict=True))
            assert analytic == pytest.approx(numeric, rel=1e-4, abs=1e-6)


def test_a_design_starts_from_its_design_for_friction_alone_and_a_wrong_start_is_refused(designed: Path,
                                                                                          tmp_path: Path) -> None:
    """Every design starts from its design for the nominal model and friction alone (rule excitation_start, which
    reads nothing of model.yaml): that start is the design `effects: []` gives, to the bit; a start of another shape
    or not a start at all is refused, naming the file and how to rebuild it."""
    from sim2real.excitation.files import read_start
    from sim2real.files import write_array_archive

    config = designed / "configs/panda/excitation.yaml"
    settings = _config(designed)["defaults"]
    built = designed / "results/panda/excitation/identification.start.npz"  # the DAG's
    assert read_start(built, "identification", _config(designed)["joints"], settings["harmonics"]).shape == (7, 20)
    # In one process (IPOPT's path follows the BLAS kernels' last bits): the start, and the design of `effects: []`.
    inputs = ExcitationInputs("panda", config, "identification", designed / "results/panda/panda.urdf",
                              designed / "results/panda/mjcf/panda.xml", designed / "configs/panda/robot.yaml")
    start = build_excitation_start(inputs, tmp_path / "identification.start.npz")
    assert np.array_equal(read_start(tmp_path / "identification.start.npz", "identification",
                                     _config(designed)["joints"], settings["harmonics"]), start)
    out = tmp_path / "out"
    friction_alone = build_excitation(
        inputs, None, {k: str(out / f"x.{k}") for k in ("csv", "trajectory", "json", "md", "figure")})
    assert np.array_equal(friction_alone.coefficients, start)
    assert friction_alone.summary["identified"]["effects"] == ["viscous_friction", "coulomb_friction"]

    wrong = tmp_path / "wrong.start.npz"
    write_array_archive(wrong, {"coefficients": np.zeros((3, 4))}, {"design": "identification"})
    not_a_start = tmp_path / "garbage.start.npz"
    not_a_start.write_bytes(b"not an archive")
    for bad, what in ((wrong, r"shape \(3, 4\), not of 'identification' \(7 joints x 20\)"),
                      (not_a_start, "is not a design start")):
        with pytest.raises(InputError, match=what) as err:
            build_excitation(inputs, designed / "configs/panda/model.yaml",
                             {k: str(out / f"y.{k}") for k in ("csv", "trajectory", "json", "md", "figure")},
                             start=bad)
        assert str(bad) in str(err.value) and f"rebuild it: snakemake {bad.as_posix()}" in str(err.value)
        assert not (out / "y.csv").exists()
