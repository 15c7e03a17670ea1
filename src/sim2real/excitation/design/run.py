"""One excitation designed: the program solved from its start (:mod:`.program`), the motion checked at every
sample (:mod:`.checks`), and the design's report."""

from __future__ import annotations

import time as clock
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim2real.excitation.config import Design, Limits
from sim2real.excitation.design.checks import Trajectory, _check_every_sample, _Checked, _head, _trajectory
from sim2real.excitation.design.program import DesignRobot, _optimise, _program, _Program, _scaled_start, _Solved
from sim2real.excitation.information import condition_number
from sim2real.excitation.separation import Separation


@dataclass
class DesignResult:
    design: Design
    joints: list[str]
    coefficients: np.ndarray  # (excited joints, 2 * harmonics)
    start: np.ndarray
    limits: Limits
    trajectory: Trajectory
    torque: np.ndarray  # nominal joint torque at every sample (N, n)
    clearance: np.ndarray  # smallest distance to collision at every sample of one period
    closest_pair: str | None
    summary: dict[str, Any] = field(default_factory=dict)


def design_trajectory(design: Design, robot: DesignRobot, model_effects: Sequence[str],
                      log: Callable[[str], None] = lambda message: None,
                      separation: Separation | None = None,
                      start_coefficients: np.ndarray | None = None) -> DesignResult:
    """Design one excitation: the optimised coefficients and the checked trajectory at the controller rate.

    ``separation``: design the run that tells two confounded candidates apart (:mod:`.separation`) instead of
    one that conditions the identification; ``start_coefficients``: the coefficients IPOPT starts from (excited
    joints x 2 harmonics; :func:`design_start`), instead of a random series at a fraction of the limits.

    Parameters
    ----------
    design : Design
        One design of excitation.yaml (:func:`~sim2real.excitation.config.load_design`).
    robot : DesignRobot
        The nominal model of the design's joints, the built URDF and MJCF (collision parts), the home pose.
    model_effects : sequence of str
        model.yaml's effects the motion should identify, beside the links' inertial parameters.
    log : callable, optional
        Called with each progress line.
    separation, start_coefficients : optional
        See above.

    Returns
    -------
    DesignResult
        The coefficients, the trajectory checked at every sample, its nominal torque and clearance, the summary.

    Raises
    ------
    InputError
        The design leaves no motion within its limits, or its start pose collides (naming the key and the fix).

    Examples
    --------
    A design and its robot; the design itself needs the built MJCF and takes a minute, so it is not run here:

    >>> from sim2real.excitation.config import load_design
    >>> from sim2real.identification.fitting import load_nominal
    >>> _ = (example_dir / "excitation.yaml").write_text(
    ...     "{joints: [panda_joint1, panda_joint2], designs: {short: {duration_s: 10, base_frequency_hz: 0.1}}}")
    >>> design = load_design(example_dir / "excitation.yaml", "short")
    >>> design.excite, design.periods, design.settings["objective"], design.settings["harmonics"]
    (['panda_joint1', 'panda_joint2'], 1, 'd_optimal', 5)
    >>> robot = DesignRobot(load_nominal(urdf, design.joints), "results/panda/mjcf/panda.xml", urdf, home={})
    >>> result = design_trajectory(design, robot, ["viscous_friction"])  # doctest: +SKIP
    >>> result.coefficients.shape, result.trajectory.q.shape[1]  # doctest: +SKIP
    ((2, 10), 2)
    """
    started = clock.perf_counter()
    program = _program(design, robot, model_effects, separation)
    series = program.series
    if start_coefficients is None:
        x0 = _scaled_start(series, program.limit_grid, program.lim, program.excited, int(design.settings["solver"]["seed"]))
    else:
        x0 = np.asarray(start_coefficients, dtype=float).ravel().copy()
        assert x0.size == series.size, f"a start of {x0.size} coefficients for a series of {series.size}"
    initial = x0.copy()
    solved = _optimise(program, x0, log)
    checked = _check_every_sample(program, solved.x, log)
    log(f"designed in {clock.perf_counter() - started:.1f} s")  # the log, not the outputs: those stay byte-identical
    summary = _summary(program, initial, solved, checked, separation)
    return DesignResult(design=design, joints=list(design.joints), coefficients=checked.x.reshape(len(program.excited), -1),
                        start=program.start, limits=program.lim, trajectory=checked.trajectory, torque=checked.torque,
                        clearance=checked.distances, closest_pair=summary["closest_pair"], summary=summary)


def _summary(program: _Program, initial: np.ndarray, solved: _Solved, checked: _Checked,
             separation: Separation | None) -> dict[str, Any]:
    """The design's report: the objective and condition number before and after, the solver, the closest approach
    and the peaks against the limits."""
    ident, trajectory = program.ident, checked.trajectory
    head = _head(trajectory, checked.one_period)
    before = _trajectory(program.series, initial, checked.time, program.start, program.excited, program.n)
    before_head = _head(before, checked.one_period)
    _, closest = program.clearance.closest(head.q[int(np.argmin(checked.distances))])
    summary: dict[str, Any] = {
        "objective": program.objective,
        "identified": {"inertial": "base parameters of the moving bodies", "effects": program.effects,
                       "base_parameters": ident.size},
        "objective_value": {"initial": round(program.f(initial)[0], 6), "designed": round(program.f(checked.x)[0], 6)},
        "condition_number": {"initial": round(condition_number(ident.matrix(before_head.q, before_head.qd,
                                                                             before_head.qdd)), 4),
                             "designed": round(condition_number(ident.matrix(head.q, head.qd, head.qdd)), 4)},
        "solver": {"status": solved.status, "iterations": solved.iterations,
                   "active_clearance_samples": len(solved.active), "scaled_by": round(checked.scale, 6)},
        "min_clearance_m": round(float(checked.distances.min()), 6),
        "closest_pair": closest,
        "peak": _peaks(program.design.joints, program.lim, trajectory, checked.torque),
    }
    if separation is not None:
        summary["separation"] = {
            "candidates": separation.names,
            "difference_x_floor": {"initial": round(separation.rms_x_floor(before_head.q, before_head.qd,
                                                                           before_head.qdd), 4),
                                   "designed": round(separation.rms_x_floor(head.q, head.qd, head.qdd), 4)},
        }
    return summary


def _peaks(joints: Sequence[str], lim: Limits, trajectory: Trajectory, tau: np.ndarray) -> dict[str, dict[str, float]]:
    """Each joint's peak torque, velocity and acceleration and its range of motion, beside its usable limits."""
    return {
        "torque_Nm": _per_joint(joints, np.abs(tau).max(axis=0)),
        "torque_limit_Nm": _per_joint(joints, lim.torque),
        "velocity_rad_s": _per_joint(joints, np.abs(trajectory.qd).max(axis=0)),
        "velocity_limit_rad_s": _per_joint(joints, lim.velocity),
        "acceleration_rad_s2": _per_joint(joints, np.abs(trajectory.qdd).max(axis=0)),
        "acceleration_limit_rad_s2": _per_joint(joints, lim.acceleration),
        "position_min_rad": _per_joint(joints, trajectory.q.min(axis=0)),
        "position_max_rad": _per_joint(joints, trajectory.q.max(axis=0)),
        "position_lower_rad": _per_joint(joints, lim.lower),
        "position_upper_rad": _per_joint(joints, lim.upper),
    }


def design_start(design: Design, robot: DesignRobot, log: Callable[[str], None] = lambda message: None) -> np.ndarray:
    """Where a design for any model starts: the same design for the nominal model and friction alone (what
    ``effects: []`` identifies), from a random series. It reads nothing of model.yaml, so a change of the model's
    effects designs from here (a few seconds) rather than from a random series, and the result is the same bytes
    whatever was designed before. Coefficients: excited joints x 2 harmonics."""
    return design_trajectory(design, robot, [], log=log).coefficients


def _per_joint(joints: Sequence[str], values: np.ndarray) -> dict[str, float]:
    return {j: round(float(v), 6) for j, v in zip(joints, values, strict=True)}
