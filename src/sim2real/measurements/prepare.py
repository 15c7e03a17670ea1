"""Preparation of runs for the comparison with a model (:func:`prepare_run`, per run):

0. A run is split at its logging gaps (:func:`split_at_gaps`: stretches the logger lost, longer than the filter
   can bridge) and each piece prepared on its own: interpolated across a lost stretch, the positions would be a
   straight line whose second derivative is no acceleration the arm made, and the torque one it never measured.
   A lone sample of a position or a torque far from both its neighbours
   (:func:`~sim2real.measurements.cleaning.lone_spikes`: an encoder's or a bus's error, a flipped bit) is replaced by
   the median of the three; the run's ``filter.spikes`` counts them.
1. Consecutive samples with identical positions (a logger faster than the state) are dropped:
   they carry a stale state, and keeping them would put steps into the differentiated signals. A position column
   that repeats while the rest of the row changes (:func:`held_columns`: one joint's, or every joint's while the
   torque changes, a position updated slower than the log) is taken at its own update instants, its held samples
   treated as missing: differentiated as logged, a hold would read as a stop and a jump. The run's
   ``filter.held`` counts them.
2. Everything is linearly interpolated onto a uniform grid (median time step, or ``sample_rate_hz``).
3. Positions are low-pass filtered with a zero-phase Butterworth filter (``scipy.signal.sosfiltfilt``),
   velocities and accelerations are obtained by central differences of the filtered positions
   (a logged ``qd`` is noisy or missing on real arms, so it is not trusted unless asked for).
4. Both ends are trimmed by the filter's settling time.
5. Torques are NOT filtered. The model is judged on the raw torque: what remains for a perfect model
   is the torque's own high-frequency noise, which is exactly what the noise floor measures
   (:mod:`sim2real.measurements.noise`), so RMSE and noise floor are directly comparable.

:func:`prepare_runs` checks the runs of :func:`sim2real.measurements.runs.read_runs` against the model's joints
and limits and prepares them (:func:`load_prepared_runs` does both when the joints are known;
:func:`prepare_for_model` takes the joints and limits from a URDF). What the logger got wrong (steps 0 and 1: gaps,
spikes, held columns) is found in :mod:`sim2real.measurements.cleaning`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.measurements.cleaning import (
    SPIKE_SCALES, _held_record, _replace_spikes, gap_threshold_s, held_columns, split_at_gaps,
)
from sim2real.measurements.noise import (
    MeasuredFloor, command_floor_where_measured, command_white_noise, measured_noise_floor, stated_noise_floor,
)
from sim2real.measurements.signs import check_torque_signs
from sim2real.measurements.records import (
    FilterSettings, GapPiece, GapRecord, LoggingGap, SensorPlacement, SpikeRecord, StepRange,
)
from sim2real.measurements.runs import (
    DEFAULT_CUTOFF_HZ, DEFAULT_FILTER_ORDER, DEFAULT_TORQUE_SENSOR, MAX_GRID_PER_SAMPLE, MIN_SAMPLES, PreparedRun, Run,
    RunSet, check_run, file_row, read_runs,
)

def prepare_run(
    run: Run,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    sample_rate_hz: float | None = None,
    use_measured_qd: bool = False,
) -> PreparedRun:
    """Dedup, resample to a uniform grid, zero-phase filter q, differentiate: see the module docstring.

    Parameters
    ----------
    run : Run
        A run as read (:func:`~sim2real.measurements.runs.read_run`, :func:`~sim2real.measurements.runs.read_runs`).
    cutoff_hz, order : float, int
        The Butterworth filter of the positions (measurements.yaml's ``filter``).
    sample_rate_hz : float, optional
        The grid's rate; default: the metadata's ``sample_rate_hz``, else the log's median step.
    use_measured_qd : bool, default False
        Take the logged ``qd`` (filtered) instead of differentiating the filtered positions.

    Returns
    -------
    PreparedRun
        Positions, velocities, accelerations and the raw torques on the trimmed grid, the filter's record and the
        torque's measured noise floor (``raw_torque_sigma``, per joint).

    Raises
    ------
    InputError
        The run is too short once the filter's edges are trimmed, or its grid would be far denser than its samples.

    Examples
    --------
    >>> from sim2real.measurements.runs import read_runs
    >>> run = read_runs(example_dir / "measurements.yaml", root=example_dir)[0]
    >>> prepared = prepare_run(run, cutoff_hz=10.0)
    >>> prepared.q.shape == prepared.qdd.shape == prepared.tau.shape, prepared.torque_source
    (True, 'tau')
    >>> round(1.0 / prepared.dt), prepared.filter.trimmed_s_each_end > 0, prepared.raw_torque_sigma.shape
    (250, True, (7,))
    """
    run, spikes = _replace_spikes(run)
    # 1. drop stale repeats: a row whose positions equal the previous row's; a column held while others change is
    # taken at its own update instants
    keep = np.concatenate([[True], ~np.all(run.q[1:] == run.q[:-1], axis=1)])
    updates = held_columns(run)
    raw_steps = np.diff(run.time)
    # 2. uniform grid
    rate = sample_rate_hz or run.meta.sample_rate_hz or 1.0 / float(np.median(raw_steps))
    dt = 1.0 / float(rate)
    grid = _uniform_grid(run, rate, dt, raw_steps)
    # 3. filtered positions, their derivatives
    q_f, qd_f, qdd_f, velocity_source = _filtered_motion(run, grid, (keep, updates), rate, cutoff_hz, order,
                                                         use_measured_qd)
    # 4. trim the filter's transient at both ends (a few time constants of the cutoff)
    trim = _trim_samples(cutoff_hz, dt)
    n = grid.size
    if n - 2 * trim < MIN_SAMPLES:
        raise InputError(run.path, "column 'time'", "run too short once the filter's edges are trimmed",
                         f"log a longer run (at least {2 * trim * dt + MIN_SAMPLES * dt:.2f} s)")
    sl = slice(trim, n - trim)
    # 5. the torques, the commands and the contacts on the grid, unfiltered
    torques = _unfiltered_signals(run, grid, sl)
    record = FilterSettings(
        order=int(order), cutoff_hz=float(cutoff_hz), velocity=velocity_source, resampled_to_hz=float(rate),
        raw_step_ms=StepRange(min=float(raw_steps.min() * 1e3), median=float(np.median(raw_steps) * 1e3),
                              max=float(raw_steps.max() * 1e3)),
        repeated_samples_dropped=int(np.count_nonzero(~keep)), trimmed_s_each_end=float(trim * dt),
        spikes=SpikeRecord(SPIKE_SCALES, spikes) if spikes else None, incomplete_rows=run.incomplete,
        held=_held_record(run, updates),
    )
    floor = _measured_floor(run, cutoff_hz)
    return PreparedRun(
        name=run.name, joint_names=list(run.joint_names), time=grid[sl], dt=dt, q=q_f[sl], qd=qd_f[sl],
        qdd=qdd_f[sl], torque_source="tau" if run.tau is not None else "tau_cmd",
        filter=dataclasses.replace(record, noise_floor=floor.record), raw_torque_sigma=floor.sigma,
        torque_sensor=SensorPlacement(run.meta.torque_sensor or DEFAULT_TORQUE_SENSOR) if run.tau is not None
        else DEFAULT_TORQUE_SENSOR,
        entry=run.entry, **torques,
    )


def _measured_floor(run: Run, motion_band_hz: float) -> MeasuredFloor:
    """The noise floor of the run's raw torque (:func:`~sim2real.measurements.noise.measured_noise_floor`), at the
    log's own rate, the motion's band ending at the position filter's cutoff, or as its metadata states it."""
    raw_torque = run.tau if run.tau is not None else run.tau_cmd
    assert raw_torque is not None
    distinct = np.concatenate([[True], np.any(raw_torque[1:] != raw_torque[:-1], axis=1)])
    stated, reason = stated_noise_floor(run.meta.extra.get("noise_floor"), run.joint_names, run.path.with_suffix(".yaml"))
    rate = 1.0 / float(np.median(np.diff(run.time)))
    return measured_noise_floor(raw_torque, distinct, rate, motion_band_hz, stated, reason)


def _uniform_grid(run: Run, rate: float, dt: float, raw_steps: np.ndarray) -> np.ndarray:
    """The stamps of the uniform grid at ``rate`` (step ``dt``) over ``run``; a grid far denser than the log's
    samples (:data:`MAX_GRID_PER_SAMPLE`: a gap, a stamp in other units, a wrong sample rate) is refused."""
    n_float = np.floor((run.time[-1] - run.time[0]) / dt) + 1
    if not n_float <= MAX_GRID_PER_SAMPLE * run.time.size:  # NaN too: a rate or span no grid can hold
        gap = int(np.argmax(raw_steps)) + 1
        raise InputError(
            run.path, f"column 'time', {file_row(run, gap)}",
            f"{run.time.size} samples span {float(run.time[-1] - run.time[0]):.6g} s, {n_float:.3g} grid points at "
            f"{float(rate):.6g} Hz (largest gap {float(raw_steps[gap - 1]):.6g} s here)",
            "log time in seconds, without gaps, and give sample_rate_hz in Hz (or leave it out)",
        )
    return run.time[0] + dt * np.arange(int(n_float))


def _resample(grid: np.ndarray, x: np.ndarray | None, t_src: np.ndarray, rows: np.ndarray | None = None,
              ) -> np.ndarray | None:
    """``x`` (sampled at ``t_src``, or at its ``rows`` only) linearly interpolated onto ``grid``."""
    if x is None:
        return None
    x = x if rows is None else x[rows]
    return np.column_stack([np.interp(grid, t_src, x[:, j]) for j in range(x.shape[1])])


def _filtered_motion(
    run: Run, grid: np.ndarray, samples: tuple[np.ndarray, Mapping[int, np.ndarray]], rate: float, cutoff_hz: float,
    order: int, use_measured_qd: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The positions on the grid (step ``1 / rate``, from the rows ``samples[0]`` keeps, a held column from its own
    update instants ``samples[1][column]``), low-pass filtered, their velocity and acceleration, and where the velocity
    came from."""
    from scipy import signal

    dt = 1.0 / float(rate)
    keep, updates = samples
    q_grid = _resample(grid, run.q, run.time[keep], keep)
    for j, changed in updates.items():
        # between two updates the column's true value moved on: interpolated, never a stop and a jump
        q_grid[:, j] = np.interp(grid, run.time[changed], run.q[changed, j])
    nyquist = 0.5 * rate
    if cutoff_hz >= nyquist:
        raise InputError(run.path, "filter cutoff", f"{cutoff_hz} Hz is not below the Nyquist frequency {nyquist} Hz",
                         "lower filter.cutoff_hz in measurements.yaml")
    sos = signal.butter(order, cutoff_hz, btype="low", fs=rate, output="sos")
    q_f = signal.sosfiltfilt(sos, q_grid, axis=0)
    if use_measured_qd and run.qd is not None:
        qd_f = signal.sosfiltfilt(sos, _resample(grid, run.qd, run.time), axis=0)
        velocity_source = "logged qd, filtered"
    else:
        qd_f = np.gradient(q_f, dt, axis=0)
        velocity_source = "central differences of filtered q"
    return q_f, qd_f, np.gradient(qd_f, dt, axis=0), velocity_source


def _unfiltered_signals(run: Run, grid: np.ndarray, sl: slice) -> dict[str, np.ndarray | None]:
    """The judged torque (``tau``, else ``tau_cmd``), the commands, the logged velocity and the contacts on the
    grid, unfiltered, within ``sl``."""
    raw_torque = run.tau if run.tau is not None else run.tau_cmd
    tau = _resample(grid, raw_torque, run.time)
    assert tau is not None
    # judged on the command: resampled once
    tau_cmd = tau.copy() if run.tau is None else _resample(grid, run.tau_cmd, run.time)
    q_cmd = _resample(grid, run.q_cmd, run.time)
    qd_measured = _resample(grid, run.qd, run.time)
    contact = None
    if run.contact is not None:
        idx = np.clip(np.searchsorted(run.time, grid, side="right") - 1, 0, run.time.size - 1)
        contact = run.contact[idx][sl]
    return {"tau": tau[sl], "tau_cmd": None if tau_cmd is None else tau_cmd[sl],
            "q_cmd": None if q_cmd is None else q_cmd[sl],
            "qd_measured": None if qd_measured is None else qd_measured[sl], "contact": contact}


def _trim_samples(cutoff_hz: float, dt: float) -> int:
    """Samples trimmed at each end of a prepared run: a few time constants of the filter's cutoff."""
    return int(np.ceil(max(0.05, 3.0 / cutoff_hz) / dt))


def with_command_floor(run: PreparedRun) -> PreparedRun:
    """``run`` with its actuator-link noise floor (:func:`command_white_noise`, ``command_torque_sigma``) where it
    logs both the measured and the commanded torque: computed once, by the rule that prepares the runs."""
    if run.tau_cmd is None or run.torque_source != "tau" or run.command_torque_sigma.size:
        return run
    return dataclasses.replace(run, command_torque_sigma=command_floor_where_measured(
        command_white_noise(run.tau, run.tau_cmd, run.dt), run))


def prepare_runs(
    runs: RunSet[Run], known_joints: Sequence[str] | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
) -> RunSet[PreparedRun]:
    """Runs of :func:`read_runs` checked against the model (:func:`check_run`), then prepared with the
    list's filter settings: each run's pieces (:func:`prepare_pieces`; one, the run, when it has no gap), each with
    the run's line of the list: a run split at its gaps counts as several runs of its role."""
    for run in runs:
        check_run(run, known_joints, limits)
    return RunSet(tuple(piece for run in runs for piece in prepare_pieces(run, runs.settings)), runs.settings)


def prepare_pieces(run: Run, settings: Mapping[str, Any]) -> list[PreparedRun]:
    """``run`` split at its logging gaps (:func:`split_at_gaps`, :func:`gap_threshold_s`) and each piece prepared
    (:func:`prepare_run`) on the run's own grid rate. A piece too short to prepare once the filter's edges are
    trimmed is left out; every piece kept records the gaps and what was left out (its ``filter.gaps``). A run
    with no piece long enough is refused, naming its largest piece and its gaps."""
    cutoff = float(settings["cutoff_hz"])
    threshold = gap_threshold_s(run.time, cutoff, settings.get("max_step_s"))
    pieces = split_at_gaps(run, threshold)
    if len(pieces) == 1:
        return [_named_incomplete(prepare_run(run, cutoff_hz=cutoff, order=settings["order"]), run.name)]
    rate = float(run.meta.sample_rate_hz or 1.0 / float(np.median(np.diff(run.time))))
    trim = _trim_samples(cutoff, 1.0 / rate)
    # A piece's grid holds floor(span * rate) + 1 points; MIN_SAMPLES must remain once both edges are trimmed.
    long_enough = [np.floor((p.time[-1] - p.time[0]) * rate) + 1 - 2 * trim >= MIN_SAMPLES for p in pieces]
    steps = np.diff(run.time)
    record = GapRecord(
        max_step_s=threshold,
        gaps=tuple(LoggingGap(after_s=float(run.time[k - 1]), lost_s=float(steps[k - 1]))
                   for k in np.flatnonzero(steps > threshold) + 1),
        pieces=tuple(GapPiece(name=p.name, from_s=float(p.time[0]), to_s=float(p.time[-1]), kept=bool(keep))
                     for p, keep in zip(pieces, long_enough, strict=True)),
        run=run.name,
    )
    if not any(long_enough):
        longest = max(pieces, key=lambda p: float(p.time[-1] - p.time[0]))
        raise InputError(
            run.path, "column 'time'",
            f"the log has {len(record.gaps)} gap(s) longer than {threshold:.3g} s (the first after "
            f"{record.gaps[0].after_s:.6g} s, {record.gaps[0].lost_s:.3g} s lost), and no stretch between them is long "
            f"enough to prepare (the longest, {float(longest.time[-1] - longest.time[0]):.3g} s, needs "
            f"{(2 * trim + MIN_SAMPLES) / rate:.3g} s)",
            "log without dropouts, or set gaps.max_step_s in the measurement list above the longest lost stretch "
            "(it is then interpolated across)")
    prepared = []
    for piece, keep in zip(pieces, long_enough, strict=True):
        if keep:
            done = prepare_run(piece, cutoff_hz=cutoff, order=settings["order"], sample_rate_hz=rate)
            prepared.append(_named_incomplete(
                dataclasses.replace(done, filter=dataclasses.replace(done.filter, gaps=record)), run.name))
    return prepared


def _named_incomplete(prepared: PreparedRun, name: str) -> PreparedRun:
    """The record of the rows dropped for an empty cell (sim2real.measurements.runs.read_run) named after the run of
    the measurement list, as its gaps are, whichever piece of it this is."""
    rows = prepared.filter.incomplete_rows if prepared.filter is not None else None
    if rows is None:
        return prepared
    return dataclasses.replace(prepared, filter=dataclasses.replace(
        prepared.filter, incomplete_rows=dataclasses.replace(rows, run=name)))


def load_prepared_runs(
    measurement_list: str | Path, known_joints: Sequence[str] | None = None, root: str | Path = ".",
    limits: Mapping[str, tuple[float, float]] | None = None,
) -> RunSet[PreparedRun]:
    """:func:`read_runs` then :func:`prepare_runs`, when the model's joints are known beforehand.

    Returns the prepared runs with the settings of :func:`measurement_settings`, each with its line of the list,
    a run split at its logging gaps (:func:`prepare_pieces`) as several pieces of the same line.
    """
    return prepare_runs(read_runs(measurement_list, root), known_joints, limits)


def prepare_for_model(
    measurement_list: str | Path, urdf_path: str | Path, root: str | Path = ".",
) -> RunSet[PreparedRun]:
    """Every run of a measurement list read, checked against the URDF's joints and limits, and prepared.

    A run column naming a joint the URDF lacks is refused in the run's own terms (the file to edit is the
    run), and so is a run whose measured torque is the negative of the URDF's on some joint
    (:func:`~sim2real.measurements.signs.check_torque_signs`). Returns the prepared runs, as :func:`load_prepared_runs`.
    """
    from sim2real.assets.dynamics import RigidBodyModel

    runs = read_runs(measurement_list, root)
    probe = RigidBodyModel(urdf_path)
    for run in runs:
        unknown = [j for j in run.joint_names if j not in probe.joint_names]
        if unknown:
            raise InputError(run.path, f"column q.{unknown[0]}", f"joint '{unknown[0]}' is not in {urdf_path}",
                             f"name the columns after the URDF's joints ({', '.join(probe.joint_names)})")
    probe = RigidBodyModel(urdf_path, runs[0].joint_names)
    limits = {j: (float(lo), float(hi)) for j, lo, hi in zip(probe.joint_names, probe.lower, probe.upper, strict=True)}
    prepared = prepare_runs(runs, probe.joint_names, limits)
    check_torque_signs(prepared, probe, root)
    return dataclasses.replace(prepared, runs=tuple(with_command_floor(piece) for piece in prepared))
