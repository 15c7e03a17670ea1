"""The nonlinear program of an excitation design, solved by IPOPT through CasADi.

Decision variables: the Fourier coefficients of the excited joints (:mod:`..fourier`). Constraints:
at rest at t = 0 (linear equalities), position, velocity and acceleration limits on a grid of one period
(linear in the coefficients, tightened by what a trigonometric polynomial can gain between the grid's
points), joint torques of the nominal model within the usable effort (nonlinear, on the objective's samples
where the torque comes near its limit), and the distance to collision (nonlinear, on the samples where it
comes near the margin). The nonlinear rows are active sets: IPOPT's cost grows with its rows (a dense torque
row per sample and joint cost more than the objective), so each pass carries the rows near their limits,
and the pass is repeated from where it ended when a check of every row (torques on the objective's samples,
MuJoCo on a grid four times the limits') finds one short. The objective (:mod:`..information`) and the
torques enter the program as CasADi callbacks with exact Jacobians (:mod:`.adapters`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from sim2real.errors import InputError
from sim2real.excitation.clearance import Clearance
from sim2real.excitation.config import Design, Limits, limits, start_pose
from sim2real.excitation.design.adapters import _Numeric, _sparse
from sim2real.excitation.fourier import FourierSeries, random_start
from sim2real.excitation.information import Identification, identification_effects
from sim2real.excitation.separation import Separation
from sim2real.identification.fitting import NominalModel

ACTIVE_SET_ROUNDS = 3
TORQUE_WATCH = 0.5  # torque rows above this fraction of the usable effort enter the program
CLEARANCE_WATCH = 3.0  # clearance minima below this many margins enter the program ...
# ... held this fraction of the margin above it, so that the dense check between the program's samples passes with
# room to spare (the Panda's identification design: closest approach 16.2 mm against its 10 mm margin)
CLEARANCE_SLACK = 0.5
CLEARANCE_SCAN = 4  # the clearance is scanned on a grid this many times the limits' grid
# Distances are exact up to CLEARANCE_WATCH margins (at least CLEARANCE_SEARCH_M); farther, a pose is simply "clear".
# MuJoCo finds every pair within that distance at every pose: a search of 10 cm takes 20x as long as one of 3 cm.
CLEARANCE_SEARCH_M = 0.02
START_FILL = 0.5  # the initial guess uses this fraction of the tightest limit
# The start is well inside thousands of limit rows: with IPOPT's default barrier (0.1) their log terms pull
# the motion towards the start pose for many iterations (the D-optimal design came out worse than its start).
MU_INIT = 1e-4
LBFGS_HISTORY = 20  # pairs IPOPT's quasi-Newton Hessian keeps (default 6): a better condition number per iteration
# The quasi-Newton pairs as extra rows of the one factorised KKT system, instead of IPOPT's default Sherman-Morrison-
# Woodbury update, which backsolves once per column of the low-rank update at every iteration (11 of a pass's 27 s of
# CPU): about half the time per iteration.
LBFGS_AUG_SOLVER = "extended"


class _Grid:
    """Samples of one period: the maps from the coefficients to every joint's q, qd, qdd (K, n, size)."""

    def __init__(self, series: FourierSeries, time: np.ndarray, excited: np.ndarray, n: int, start: np.ndarray):
        self.time, self.start = time, start
        position, velocity, acceleration = series.basis(time)  # (K, 2L)
        width = 2 * series.harmonics
        self.maps = []
        for basis in (position, velocity, acceleration):
            full = np.zeros((len(time), n, series.size))
            for slot, j in enumerate(excited):
                full[:, j, slot * width : (slot + 1) * width] = basis
            self.maps.append(full)

    @classmethod
    def subset(cls, grid: _Grid, samples: np.ndarray) -> _Grid:
        """The grid's samples ``samples`` only."""
        out = cls.__new__(cls)
        out.time, out.start, out.maps = grid.time[samples], grid.start, [m[samples] for m in grid.maps]
        return out

    def state(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, qd, qdd at the grid's samples (read-only; the last x's are kept: the objective, its gradient, the
        torques and their Jacobian are asked for at the same point)."""
        key = x.tobytes()
        if getattr(self, "_last_state", (None, None))[0] != key:
            q, qd, qdd = (m @ x for m in self.maps)
            state = (self.start + q, qd, qdd)
            for array in state:
                array.flags.writeable = False
            self._last_state = (key, state)
        return self._last_state[1]

    def chain(self, dq: np.ndarray, dqd: np.ndarray, dqdd: np.ndarray) -> np.ndarray:
        """Gradient with respect to x of a scalar whose gradients per sample state are (K, n) each."""
        return sum(np.einsum("kj,kjs->s", g, m) for g, m in zip((dq, dqd, dqdd), self.maps, strict=True))


def _torque_jacobian(nominal: NominalModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     grid: _Grid) -> np.ndarray:
    """d tau / d x (K, n, size): the nominal model's analytic inverse-dynamics derivatives per sample, chained through
    the grid's maps."""
    derivatives = nominal.dynamics.inverse_dynamics_derivatives(q, qd, qdd)
    return sum(np.einsum("kjc,kcs->kjs", derivatives[which], grid.maps[which]) for which in range(3))


def _tightening(series: FourierSeries, count: int) -> float:
    """How far a limit on ``count`` samples of one period must sit inside the true one: a trigonometric polynomial of
    degree L w has |p''| <= (L w)^2 |p - c| (Bernstein), and its extreme is within half a step h of a sample, so
    |p - c| <= grid's |p - c| / (1 - (L w h)^2 / 8): imposing the grid's limits that much inside holds them
    everywhere (the dense check then passes)."""
    step = series.period / count
    return min((series.harmonics * series.omega * step) ** 2 / 8.0, 0.5)  # a grid that coarse: half the range


def _scaled_start(series: FourierSeries, grid: _Grid, lim: Limits, excited: np.ndarray, seed: int) -> np.ndarray:
    """A random series at rest at t = 0, each joint scaled to START_FILL of its tightest position, velocity or
    acceleration limit (the lab's excitation is drawn the same way)."""
    x = random_start(series, np.random.default_rng(seed))
    q, qd, qdd = grid.state(x)
    room = np.minimum(grid.start - lim.lower, lim.upper - grid.start)[excited]
    ratios = np.min([room / np.max(np.abs(q - grid.start)[:, excited], axis=0),
                     lim.velocity[excited] / np.max(np.abs(qd[:, excited]), axis=0),
                     lim.acceleration[excited] / np.max(np.abs(qdd[:, excited]), axis=0)], axis=0)
    # Scaling one joint's coefficients keeps it at rest at t = 0 (the rest constraints are per joint).
    return (START_FILL * ratios[:, None] * x.reshape(len(excited), -1)).ravel()


@dataclass(frozen=True)
class DesignRobot:
    """The robot a design is for: the nominal model of the design's joints, the built URDF (its limits) and MJCF (its
    collision parts), and its home pose (robot.yaml's ``home``, which a design's ``start: home`` names)."""

    nominal: NominalModel
    mjcf_path: str | Path
    urdf_path: str | Path
    home: Mapping[str, float]


@dataclass(frozen=True, eq=False)
class _Program:
    """What every pass of one design reads: its start, limits and clearance, the series, its grids and the objective,
    with the objective and the torques as functions of the coefficients (and their Jacobians)."""

    design: Design
    nominal: NominalModel
    excited: np.ndarray
    start: np.ndarray
    lim: Limits
    margin: float
    clearance: Clearance
    effects: list[str]
    ident: Identification
    series: FourierSeries
    objective_grid: _Grid
    limit_grid: _Grid
    objective: str
    judge: Identification | Separation

    @property
    def n(self) -> int:
        return len(self.design.joints)

    def f(self, x: np.ndarray) -> np.ndarray:
        return np.array([self.judge.value(*self.objective_grid.state(x), self.objective)])

    def df(self, x: np.ndarray) -> np.ndarray:
        _, dq, dqd, dqdd = self.judge.state_gradient(*self.objective_grid.state(x), self.objective)
        return self.objective_grid.chain(dq, dqd, dqdd).reshape(1, -1)

    def torque(self, x: np.ndarray) -> np.ndarray:
        return self.nominal.dynamics.inverse_dynamics(*self.objective_grid.state(x)).ravel()

    def torque_jac(self, x: np.ndarray, samples: np.ndarray) -> np.ndarray:
        """The Jacobian's rows of ``samples`` only (the program carries the torques near their limits)."""
        grid = _Grid.subset(self.objective_grid, samples)
        return _torque_jacobian(self.nominal, *grid.state(x), grid).reshape(-1, self.series.size)


@dataclass(frozen=True)
class _Solved:
    """Where the passes of IPOPT ended."""

    x: np.ndarray
    status: str
    iterations: int
    active: list[float]  # the times (one period) where the clearance was constrained



def _program(design: Design, robot: DesignRobot, model_effects: Sequence[str],
             separation: Separation | None) -> _Program:
    """The design's start pose (clear of collision), limits, clearance, series, grids and objective."""
    settings, joints = design.settings, design.joints
    dynamics = robot.nominal.dynamics
    n = len(joints)
    excited = np.array([joints.index(j) for j in design.excite])
    start = start_pose(design, robot.home, dynamics.lower, dynamics.upper)
    lim = limits(design, dynamics.lower, dynamics.upper, dynamics.velocity_limit, dynamics.effort_limit, start,
                 dynamics.gravity(start)[0], robot.urdf_path)
    margin = float(settings["margins"]["collision_m"])
    clearance = Clearance(robot.mjcf_path, joints, settings["obstacles"],
                          max(CLEARANCE_SEARCH_M, CLEARANCE_WATCH * margin), design.path, design.key("obstacles"))
    _check_start(design, clearance, start, margin)

    noise_floor = design.per_joint("noise_floor")
    effects = identification_effects(model_effects)
    solver = settings["solver"]
    ident = Identification(robot.nominal, effects, noise_floor, lim.lower, lim.upper, lim.velocity, lim.acceleration,
                           seed=int(solver["seed"]))
    series = FourierSeries(2.0 * np.pi * float(settings["base_frequency_hz"]), int(settings["harmonics"]),
                           len(excited))
    period = series.period
    objective_grid = _Grid(series, np.linspace(0.0, period, int(solver["objective_samples"]), endpoint=False),
                           excited, n, start)
    limit_grid = _Grid(series, np.linspace(0.0, period, int(solver["limit_samples"]), endpoint=False),
                       excited, n, start)
    objective = str(settings["objective"]) if separation is None else "separate"
    judge: Identification | Separation = ident if separation is None else separation
    return _Program(design, robot.nominal, excited, start, lim, margin, clearance, effects, ident, series,
                    objective_grid, limit_grid, objective, judge)


def _check_start(design: Design, clearance: Clearance, start: np.ndarray, margin: float) -> None:
    """The start pose must be clear of every obstacle and of self-collision by the margin."""
    distance, pair = clearance.closest(start)
    if distance < margin:
        obstacle = next((o for o in (pair or "").split(" / ") if o.startswith("obstacle_")), None)
        what = (f"obstacle '{obstacle.removeprefix('obstacle_')}' contains the start pose or comes within "
                f"{margin:g} m of it" if obstacle else f"the start pose is in self-collision ({pair})")
        raise InputError(design.path, design.key("obstacles" if obstacle else "start"),
                         f"{what}: distance {distance:.3g} m at the start pose",
                         "move the obstacle away from the robot, choose another start pose, or lower "
                         "margins/collision_m")


def _optimise(program: _Program, x0: np.ndarray, log: Callable[[str], None]) -> _Solved:
    """Passes of IPOPT from ``x0``, each with the torque and clearance rows near their limits (the active sets), until
    a check of every row finds none short (at most ACTIVE_SET_ROUNDS + 1 passes)."""
    series, margin, clearance = program.series, program.margin, program.clearance
    scan_grid = _Grid(series, np.linspace(0.0, series.period, CLEARANCE_SCAN * len(program.limit_grid.time),
                                          endpoint=False), program.excited, program.n, program.start)
    usable = np.tile(program.lim.torque, len(program.objective_grid.time))
    active: list[float] = []  # times (one period) where the clearance is constrained
    rows = np.zeros(0, dtype=int)  # torque rows (sample * n + joint) in the program
    x = x0
    status, iterations = "not run", 0
    for _ in range(ACTIVE_SET_ROUNDS + 1):
        rows = np.union1d(rows, np.flatnonzero(np.abs(program.torque(x)) >= TORQUE_WATCH * usable))
        distances = clearance.distances(scan_grid.state(x)[0])
        # The closest sample of each stretch near the margin, and of each stretch inside it: a stretch near the margin
        # can dip inside it away from its closest sample (another link, another obstacle).
        active = sorted(set(active) | set(_short_samples(distances, scan_grid, CLEARANCE_WATCH * margin))
                        | set(_short_samples(distances, scan_grid, margin)))
        x, status, iterations = _solve(program, rows, usable, active, margin * (1.0 + CLEARANCE_SLACK), x)
        # Every row, those in the program too: a pass stopped at its iteration limit can end where a row it carries
        # is still violated (a clearance row 0.25 m into the table), which the every-sample check would then fix by
        # scaling the whole motion down (to 0.6x); another pass from there restores it.
        over = np.flatnonzero(np.abs(program.torque(x)) > usable)
        distances = clearance.distances(scan_grid.state(x)[0])
        short = _short_samples(distances, scan_grid, margin)
        log(f"IPOPT: {status} after {iterations} iterations with {len(rows)} torque rows and {len(active)} clearance "
            f"rows; {len(over)} torques over their limit and {len(short)} samples short of clearance")
        if not short and not len(over):
            break
    return _Solved(x, status, iterations, active)


def _short_samples(distances: np.ndarray, grid: _Grid, margin: float) -> list[float]:
    """Times of the grid where the clearance is below the margin: one per run of consecutive samples (its worst)."""
    return [float(grid.time[k]) for k in _closest_of_each_stretch(distances, margin)]


def _closest_of_each_stretch(distances: np.ndarray, margin: float) -> list[int]:
    """Indices of the smallest distance in each run of consecutive samples below ``margin``."""
    short = distances < margin
    out = []
    k = 0
    while k < len(short):
        if short[k]:
            end = k
            while end + 1 < len(short) and short[end + 1]:
                end += 1
            out.append(k + int(np.argmin(distances[k : end + 1])))
            k = end + 1
        else:
            k += 1
    return out


def _solve(program: _Program, rows: np.ndarray, usable: np.ndarray, active: Sequence[float], least: float,
           x0: np.ndarray) -> tuple[np.ndarray, str, int]:
    """One IPOPT pass from ``x0``: the torque rows ``rows`` (of the objective's samples) within ``usable``, the
    clearance at the times ``active`` at least ``least``."""
    series, grid, lim, excited = program.series, program.limit_grid, program.lim, program.excited
    clearance = program.clearance
    x = ca.MX.sym("x", series.size)
    constraints, lower, upper = [], [], []

    def add(expr: Any, lo: np.ndarray, hi: np.ndarray) -> None:
        constraints.append(expr)
        lower.append(np.asarray(lo, dtype=float).ravel())
        upper.append(np.asarray(hi, dtype=float).ravel())

    rest = series.rest_constraints()
    add(ca.mtimes(_sparse(rest), x), np.zeros(len(rest)), np.zeros(len(rest)))
    count = len(grid.time)
    inside = _tightening(series, count)
    for state_map, lo, hi in ((grid.maps[0], lim.lower - grid.start, lim.upper - grid.start),
                              (grid.maps[1], -lim.velocity, lim.velocity),
                              (grid.maps[2], -lim.acceleration, lim.acceleration)):
        margin = inside * 0.5 * (hi - lo)[excited]
        state_rows = state_map[:, excited].reshape(-1, series.size)
        add(ca.mtimes(_sparse(state_rows), x), np.tile(lo[excited] + margin, count),
            np.tile(hi[excited] - margin, count))
    callbacks = [_Numeric("objective", series.size, 1, program.f, program.df)]
    if len(rows):
        samples, where = np.unique(rows // grid.maps[0].shape[1], return_inverse=True)
        flat = where * grid.maps[0].shape[1] + rows % grid.maps[0].shape[1]  # the rows among those samples' rows
        callbacks.append(_Numeric("torque", series.size, len(rows), lambda xv: program.torque(xv)[rows],
                                  lambda xv: program.torque_jac(xv, samples)[flat]))
        add(callbacks[-1](x), -usable[rows], usable[rows])
    if active:
        active_grid = _Grid(series, np.asarray(active), excited, grid.maps[0].shape[1], grid.start)

        def distance(xv: np.ndarray) -> np.ndarray:
            return clearance.distances(active_grid.state(xv)[0])

        def distance_jac(xv: np.ndarray) -> np.ndarray:
            q = active_grid.state(xv)[0]
            return np.stack([clearance.gradient(q[k]) @ active_grid.maps[0][k] for k in range(len(q))])

        callbacks.append(_Numeric("clearance", series.size, len(active), distance, distance_jac))
        add(callbacks[-1](x), np.full(len(active), least), np.full(len(active), np.inf))
    nlp = {"x": x, "f": callbacks[0](x), "g": ca.densify(ca.vertcat(*constraints))}
    max_iterations = int(program.design.settings["solver"]["max_iterations"])
    options = {"ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": max_iterations,
               "ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False, "ipopt.tol": 1e-6,
               "ipopt.acceptable_tol": 1e-3, "ipopt.mu_init": MU_INIT, "ipopt.mu_strategy": "monotone",
               "ipopt.limited_memory_max_history": LBFGS_HISTORY, "ipopt.limited_memory_aug_solver": LBFGS_AUG_SOLVER}
    solver = ca.nlpsol("excitation", "ipopt", nlp, options)
    result = solver(x0=x0, lbg=np.concatenate(lower), ubg=np.concatenate(upper))
    stats = solver.stats()
    return np.asarray(result["x"]).ravel(), str(stats["return_status"]), int(stats["iter_count"])
