"""mujoco.sysid configured at its best, the method ``bench_sysid.py`` compares ours with.

The joint positions are the measurement; the fit run is cut into 0.25 s chunks, each started from the
measured state (positions, velocities and, for a delay, the logged command history); the residual is the
plain measured - predicted instead of the default per-column division by |measured|; the lab's own MJCF
arm (collision meshes dropped: contacts are off and the inertials explicit); all chunks and all
finite-difference columns in one threaded rollout (``model_residual`` on the chunk list); 95 % intervals
from its residuals and Jacobian at the optimum with the chunks as clusters
(:func:`chunk_clustered_half_widths`). The case (``bench_sysid.Case``) gives the model's own settings, the
parameters and the optimizer backend.

Workarounds for MuJoCo 4.0.0's mujoco.sysid (each is detected at run time and printed at the end):

1. ``SystemTrajectory.split`` (sysid/_src/trajectory.py:243-247) gives chunk i the initial state
   ``state.data[start_idx - 1]``: one sample before the chunk's first measurement, which the residual
   treats as the initial condition. It also builds the chunks' control and sensor ``TimeSeries``
   without their signal mappings (trajectory.py:255-260), which the default residual asserts on.
   We still let ``split`` cut the chunks, then replace each initial state by the measured state at the
   chunk's first sample and restore the mappings (:func:`toolbox_problem`).
2. ``resample_true=True`` resamples each chunk's control onto ``ceil((t_end - t_0) / dt) + 1`` points
   (sysid/_src/timeseries.py:719-724). On a 1 kHz log, (t_end - t_0) / dt is 249.0000000000001 for some
   chunks, which get 251 points instead of 250: stacking them for the batched rollout fails
   (trajectory.py:509, "all input arrays must have the same shape"), and rolled out one by one they
   would be replayed one step too long with their controls stretched. We pass ``resample_true=False``
   with the log already on the model's time step (checked), which needs no resampling.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from scipy import stats

from sim2real.assets.arm import arm_spec
from sim2real.measurements import Run

try:
    from mujoco import sysid as ms

    HAVE_TOOLBOX = hasattr(ms, "optimize")  # the package swallows a missing extra and stays empty
except ImportError:  # pragma: no cover - depends on the installation
    ms = None
    HAVE_TOOLBOX = False

CHUNK_S = 0.25


@dataclass
class ToolboxProblem:
    spec: mujoco.MjSpec
    model: mujoco.MjModel
    joints: list[str]
    chunks: list[Any]  # ms.SystemTrajectory, equal lengths
    quirks: dict[str, Any] = field(default_factory=dict)


def log_step(run: Run) -> float:
    """The log's nominal sample period (its metadata), else its median step."""
    rate = run.meta.sample_rate_hz
    return 1.0 / float(rate) if rate else float(np.median(np.diff(run.time)))


def toolbox_spec(mjcf: Path, joints: Sequence[str], dt: float, configure: Callable[[mujoco.MjSpec], None]
                 ) -> mujoco.MjSpec:
    """The lab's torque-driven arm (same MJCF, same motors, contacts disabled) at the log's time step, with the
    case's own settings (``configure``, before compiling).

    The collision meshes are dropped: contacts are disabled and the inertials are explicit, so they only
    cost compile time, which the toolbox pays once per residual evaluation and finite-difference column.
    """
    spec = arm_spec(mjcf, list(joints))
    spec.option.timestep = dt
    before = spec.compile()
    for geom in list(spec.geoms):
        spec.delete(geom)
    for mesh in list(spec.meshes):
        spec.delete(mesh)
    after = spec.compile()
    assert np.allclose(before.body_mass, after.body_mass) and np.allclose(before.body_inertia, after.body_inertia)
    configure(spec)
    return spec


def measured_state(model: mujoco.MjModel, data: mujoco.MjData, run: Run, sample: int, joints: Sequence[str]
                   ) -> np.ndarray:
    """Full physics state at a logged sample: time, q, qd and, for delayed actuators, the logged commands.

    The history holds the commands of the samples before ``sample`` (the step at ``sample`` pushes its
    own); before the log starts the lab holds its first command, and so does this.
    """
    mujoco.mj_resetData(model, data)
    dt = model.opt.timestep
    data.time = run.time[sample]
    for index, joint in enumerate(joints):
        jid = model.joint(joint).id
        data.qpos[model.jnt_qposadr[jid]] = run.q[sample, index]
        data.qvel[model.jnt_dofadr[jid]] = run.qd[sample, index]
        actuator = model.actuator(f"motor_{joint}").id
        nsample = int(model.actuator_history[actuator, 0])
        if nsample > 0:
            rows = sample - nsample + np.arange(nsample)
            times = run.time[0] + dt * rows
            mujoco.mj_initCtrlHistory(model, data, actuator, times, run.tau_cmd[np.clip(rows, 0, None), index])
    state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return state


def toolbox_problem(spec: mujoco.MjSpec, run: Run, joints: Sequence[str], chunk_s: float = CHUNK_S) -> ToolboxProblem:
    """The run as equal chunks, each started from the measured state; positions are the measurement."""
    model = spec.compile()
    dt = model.opt.timestep
    if not np.allclose(np.diff(run.time), dt, rtol=0.0, atol=1e-9):
        raise ValueError("the log is not on the model's time step: resample it first (resample_true is avoided)")
    if run.tau_cmd is None or run.qd is None:
        raise ValueError("the replay needs the commanded torque (tau_cmd) and the logged velocity (qd)")
    controls = ms.TimeSeries.from_control_names(run.time, run.tau_cmd, model, [f"motor_{j}" for j in joints])
    positions = ms.TimeSeries.from_names(run.time, run.q, model, [f"{j}_qpos" for j in joints])  # MjStateQPos
    qpos, qvel, act, _ = ms.TimeSeries.compute_all_state_mappings(model)
    # split() needs a state series; only the chunk starts matter and those are replaced below.
    rough = np.tile(ms.create_initial_state(model, run.q[0], run.qd[0]), (len(run.time), 1))
    rough[:, 0] = run.time
    rough[:, 1 + model.jnt_qposadr[[model.joint(j).id for j in joints]]] = run.q
    rough[:, 1 + model.nq + model.jnt_dofadr[[model.joint(j).id for j in joints]]] = run.qd
    whole = ms.SystemTrajectory(model, controls, positions, rough[0], ms.TimeSeries(run.time, rough, qpos | qvel | act))
    size = int(round(chunk_s / dt))
    raw = whole.split(size)
    quirks = {
        "chunks": len(raw),
        "chunk_samples": size,
        # Workaround 1 (trajectory.py:243-247, 255-260): the toolbox's own split, checked and repaired.
        "split_initial_state_early": bool(raw[1].initial_state[0] < raw[1].sensordata.times[0] - 0.5 * dt),
        "split_drops_mappings": raw[1].control.signal_mapping is None or raw[1].sensordata.signal_mapping is None,
        # Workaround 2 (timeseries.py:719-724): how many chunks resample_true=True would lengthen.
        "resample_lengthens": sum(len(c.control.resample(target_dt=dt)) != size for c in raw),
    }
    data = mujoco.MjData(model)
    chunks = [
        chunk.replace(
            initial_state=measured_state(model, data, run, k * size, joints),
            control=ms.TimeSeries(chunk.control.times, chunk.control.data, controls.signal_mapping),
            sensordata=ms.TimeSeries(chunk.sensordata.times, chunk.sensordata.data, positions.signal_mapping),
        )
        for k, chunk in enumerate(raw)
    ]
    return ToolboxProblem(spec, model, list(joints), chunks, quirks)


def plain_position_residual(model: mujoco.MjModel, joints: Sequence[str]) -> Callable[..., tuple[np.ndarray, Any, Any]]:
    """``modify_residual``: measured - predicted joint positions, no per-column normalisation.

    Without it the toolbox divides every column by |measured| / sqrt(2) (residual.py:339,
    signal_modifier.py:325), which weights a joint by how close to zero its angle happens to stay.
    The rollout's state row k is the state after k + 1 steps; the first measured sample of a chunk is
    its initial condition and is left out, as the toolbox does with ``resample_true=False``.
    """
    qadr = np.array([model.jnt_qposadr[model.joint(j).id] for j in joints])

    def modify_residual(params, predicted, measured, model_, return_pred_all, state=None, **_):
        q_predicted = state[:, 1 + qadr]  # mjSTATE_FULLPHYSICS: time, qpos, qvel, ...
        q_measured = measured.data[1:]
        times, mapping = measured.times[1:], measured.signal_mapping
        return (
            (q_measured - q_predicted).ravel(),
            ms.TimeSeries(times, q_predicted, mapping),
            ms.TimeSeries(times, q_measured, mapping),
        )

    return modify_residual


def toolbox_residual_fn(problem: ToolboxProblem) -> Callable[..., tuple[list[np.ndarray], list, list]]:
    """All chunks (and all finite-difference columns) in one threaded rollout per call.

    ``build_residual_fn(models_sequences=...)`` calls ``model_residual`` once per measured sequence
    (residual.py:428), i.e. once per chunk, compiling the model for every chunk and column.
    ``model_residual`` on the chunk list rolls them out together; for a batch of k points it returns
    (m, k * chunks) columns ordered (point, chunk) (residual.py:357-359), reordered here to the
    (chunks * m, k) the optimizer expects.
    """
    modify_residual = plain_position_residual(problem.model, problem.joints)
    n_chunks = len(problem.chunks)

    def build(params) -> mujoco.MjModel:
        return ms.apply_param_modifiers(params, problem.spec)

    def residual_fn(x, params, **_):
        x = np.asarray(x)
        r, _, _ = ms.model_residual(x, params, build, problem.chunks, modify_residual=modify_residual,
                                    resample_true=False)  # workaround 2
        if x.ndim == 1:
            return [r], [], []
        m, k = r.shape[0], x.shape[1]
        return [r.reshape(m, k, n_chunks).transpose(2, 0, 1).reshape(n_chunks * m, k)], [], []

    return residual_fn


@dataclass
class ToolboxFit:
    """The parameters, the half-widths of their chunk-clustered intervals, and what they were computed from."""

    values: np.ndarray
    half_widths: np.ndarray
    residuals: list[np.ndarray]
    jac: np.ndarray
    quirks: dict[str, Any]


def fit(mjcf: Path, run: Run, joints: Sequence[str], configure: Callable[[mujoco.MjSpec], None],
        parameters: Callable[[mujoco.MjSpec], Any], optimizer: str, confidence: float) -> ToolboxFit:
    """The model from the MJCF, the chunks from the log, the fit and its intervals (what the benchmark times).

    ``parameters``: the spec -> its ``ms.ParameterDict`` (started off its bounds here, as the toolbox
    recommends); ``optimizer``: the backend of ``ms.optimize``."""
    spec = toolbox_spec(mjcf, joints, log_step(run), configure)
    problem = toolbox_problem(spec, run, joints)
    params = parameters(spec).move_off_bounds()
    residual_fn = toolbox_residual_fn(problem)
    # optimize() keeps its own `verbose` to itself and the backends print every iteration: swallow it.
    with contextlib.redirect_stdout(io.StringIO()):
        fitted, result = ms.optimize(params, residual_fn, optimizer=optimizer, verbose=False)
    residuals, _, _ = residual_fn(result.x, fitted)
    jac = np.asarray(result.jac)
    half = chunk_clustered_half_widths(np.concatenate(residuals), jac, len(problem.chunks), confidence)
    return ToolboxFit(np.asarray(fitted.as_vector(), dtype=float), half, residuals, jac, problem.quirks)


def own_half_widths(fitted: ToolboxFit) -> np.ndarray:
    """The half-widths ``calculate_intervals`` gives (every residual sample independent), to print beside."""
    with np.errstate(invalid="ignore", divide="ignore"):
        _, own_half = ms.calculate_intervals(fitted.residuals, fitted.jac)
    return np.asarray(own_half, dtype=float)


def position_rmse(mjcf: Path, run: Run, joints: Sequence[str], configure: Callable[[mujoco.MjSpec], None],
                  parameters: Callable[[mujoco.MjSpec], Any], values: np.ndarray) -> float:
    """Position RMSE [rad] of the 0.25 s replays of ``run`` (from the measured state) with the parameters."""
    spec = toolbox_spec(mjcf, joints, log_step(run), configure)
    problem = toolbox_problem(spec, run, joints)
    residuals, _, _ = toolbox_residual_fn(problem)(np.asarray(values, dtype=float), parameters(spec))
    return float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)))


def chunk_clustered_half_widths(residual: np.ndarray, jac: np.ndarray, n_chunks: int,
                                confidence: float) -> np.ndarray:
    """Half-widths of the toolbox's intervals with the chunks as independent clusters (sandwich covariance).

    ``calculate_intervals`` takes every residual sample as independent: along a 0.25 s chunk the position
    residuals are one integrated error (an initial-velocity error grows with time), so its intervals are
    far narrower than the estimate's actual error. The chunks themselves are nearly independent (each
    starts from the measured state), so the cluster-robust covariance
    (J'J)^-1 (sum_c J_c' r_c r_c' J_c) (J'J)^-1 * C / (C - 1), from the same residuals and Jacobian at the
    optimum, is the interval the toolbox's own numbers support; ``print_metrics`` shows both.
    """
    rows = residual.size // n_chunks
    bread = np.linalg.pinv(jac.T @ jac)
    scores = np.stack([jac[c * rows:(c + 1) * rows].T @ residual[c * rows:(c + 1) * rows] for c in range(n_chunks)])
    covariance = bread @ (scores.T @ scores) @ bread * n_chunks / (n_chunks - 1)
    quantile = stats.t.ppf(0.5 + 0.5 * confidence, n_chunks - 1)
    return np.sqrt(np.diag(covariance)) * quantile


def print_toolbox_notes(quirks: dict[str, Any]) -> None:
    if not quirks:
        return
    version = getattr(mujoco, "__version__", "?")
    print(f"\n=== mujoco.sysid (MuJoCo {version}): setup and the workarounds applied")
    print(f"  setup: joint positions as the measurement; {quirks['chunks']} chunks of {CHUNK_S} s "
          f"({quirks['chunk_samples']} samples) each started from the measured state; plain residual measured - "
          "predicted (modify_residual); all chunks in one threaded rollout (model_residual).")
    early = "present" if quirks["split_initial_state_early"] else "not seen in this version"
    dropped = "present" if quirks["split_drops_mappings"] else "not seen in this version"
    print(f"  1. SystemTrajectory.split labels a chunk's initial state one sample early ({early}) and drops the "
          f"signal mappings ({dropped}): each chunk's initial state is replaced by the measured state at its "
          "first sample, and the mappings are restored.")
    print(f"  2. resample_true=True would resample {quirks['resample_lengthens']} of {quirks['chunks']} chunk "
          f"controls to {quirks['chunk_samples'] + 1} points instead of {quirks['chunk_samples']} (float rounding "
          "in ceil); the batched rollout then fails on unequal lengths: resample_true=False, the log being on "
          "the model's time step already.")
    print("  3. calculate_intervals treats every residual sample as independent; along a chunk the position "
          "residuals are one integrated error (an initial-velocity error grows with time), so its intervals are "
          "far narrower than its actual error: the intervals compared are the chunk-clustered sandwich intervals "
          "from the same residuals and Jacobian (chunk_clustered_half_widths).")
