"""Preparation of runs for the comparison with a model (:func:`prepare_run`, per run):

0. A run is split at its logging gaps (:func:`split_at_gaps`: stretches the logger lost, longer than the filter
   can bridge) and each piece prepared on its own: interpolated across a lost stretch, the positions would be a
   straight line whose second derivative is no acceleration the arm made, and the torque one it never measured.
   A lone sample of a position or a torque far from both its neighbours (:func:`lone_spikes`: an encoder's or a
   bus's error, a flipped bit) is replaced by the median of the three; the run's ``filter.spikes`` counts them.
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
:func:`prepare_for_model` takes the joints and limits from a URDF).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.measurements.noise import (
    MeasuredFloor, command_floor_where_measured, command_white_noise, measured_noise_floor, stated_noise_floor,
    white_noise_sigma,
)
from sim2real.measurements.signs import check_torque_signs
from sim2real.measurements.records import (
    FilterSettings, GapPiece, GapRecord, HeldRecord, LoggingGap, SpikeRecord, StepRange,
)
from sim2real.measurements.runs import (
    DEFAULT_CUTOFF_HZ, DEFAULT_FILTER_ORDER, DEFAULT_TORQUE_SENSOR, MAX_GRID_PER_SAMPLE, MIN_SAMPLES, PreparedRun, Run,
    RunSet, check_run, file_row, read_runs,
)

# A step between two stamps is a logging gap above the longer of these: GAP_MEDIAN_STEPS median steps (a
# jittered or slow logger's own rhythm is no gap) and GAP_FILTER_PERIODS periods of the filter's cutoff (a
# stretch the low-pass bridges without inventing motion: 20 ms at 10 Hz).
GAP_MEDIAN_STEPS = 3.0
GAP_FILTER_PERIODS = 0.2


def gap_threshold_s(time: np.ndarray, cutoff_hz: float, max_step_s: float | None = None) -> float:
    """The longest step between two stamps of ``time`` that is not a logging gap: ``max_step_s`` when the
    measurement list sets it (``gaps.max_step_s``), else the longer of :data:`GAP_MEDIAN_STEPS` median steps and
    :data:`GAP_FILTER_PERIODS` periods of the filter's cutoff."""
    if max_step_s is not None:
        return float(max_step_s)
    return max(GAP_MEDIAN_STEPS * float(np.median(np.diff(time))), GAP_FILTER_PERIODS / float(cutoff_hz))


# A sample further than SPIKE_SCALES of its column's scale (the white noise's, or the median step between samples
# where that is larger) from the median of itself and its two neighbours is a glitch of the encoder, the bus or the
# sensor, not a motion or a torque: the median of three keeps every step and every smooth turn of a real signal, at
# 1 kHz and at 30 Hz alike, and moves only a lone sample. No run of the lab's scenarios comes within half of it (at
# most 11 scales, a controller's command chattering at a velocity reversal).
SPIKE_SCALES = 20.0
# The logged signals searched for spikes: positions (before they are filtered and differentiated) and torques.
SPIKE_SIGNALS = ("q", "tau", "tau_cmd")


def lone_spikes(signal: np.ndarray) -> np.ndarray:
    """(N, n) bool: the samples of ``signal`` (raw, (N, n)) that are lone spikes (:data:`SPIKE_SCALES`); the first
    and last sample are never flagged."""
    flags = np.zeros(signal.shape, dtype=bool)
    if signal.shape[0] < 3:
        return flags
    scale = np.maximum(white_noise_sigma(signal), np.median(np.abs(np.diff(signal, axis=0)), axis=0))
    flags[1:-1] = np.abs(signal[1:-1] - _median_of_three(signal)) > SPIKE_SCALES * scale
    return flags


def without_spikes(signal: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """``signal`` with each flagged sample (:func:`lone_spikes`) replaced by the median of it and its neighbours."""
    cleaned = signal.copy()
    inner = cleaned[1:-1]
    inner[flags[1:-1]] = _median_of_three(signal)[flags[1:-1]]
    return cleaned


def _median_of_three(x: np.ndarray) -> np.ndarray:
    """Rows 1..N-2 of ``x``: the median of each row and its two neighbours (elementwise, without stacking copies: a
    10-minute log at 1 kHz is 4 million samples per signal)."""
    before, here, after = x[:-2], x[1:-1], x[2:]
    return np.maximum(np.minimum(before, here), np.minimum(np.maximum(before, here), after))


# A position column is held when, in more than this share of the rows, it repeats the row before while the rest of the
# row changes (another position, a torque): a signal updated slower than the log (a quarter of a real KUKA log's rows;
# half of them when the position comes at half the logger's rate). An encoder stepping through a slow turn or a
# reversal repeats rows too: at most 4 % of the lab's runs (1e-6 rad steps at 1 kHz).
HELD_FRACTION = 0.15


def held_samples(q: np.ndarray, torque: np.ndarray | None) -> np.ndarray:
    """(N, n) bool: the rows of each position column of ``q`` (raw, (N, n)) that repeat the row before while something
    else of the row changes (another position or a torque); the first row never."""
    moved = np.zeros(q.shape, dtype=bool)
    moved[1:] = q[1:] != q[:-1]
    torque_moved = np.zeros(q.shape[0], dtype=bool)
    if torque is not None:
        torque_moved[1:] = np.any(torque[1:] != torque[:-1], axis=1)
    # the rest of the row changed: a torque, or a position of another column (small integers: a 10-minute log at
    # 1 kHz is millions of rows)
    others_moved = (moved.sum(axis=1, dtype=np.int16)[:, None] - moved) > 0
    held = ~moved & (torque_moved[:, None] | others_moved)
    held[0] = False
    return held


def held_columns(run: Run) -> dict[int, np.ndarray]:
    """The position columns of ``run`` held in more than :data:`HELD_FRACTION` of its rows (:func:`held_samples`): by
    column, the rows where its value changed (its update instants, the first row included)."""
    torque = run.tau if run.tau is not None else run.tau_cmd
    held = held_samples(run.q, torque)
    columns = np.flatnonzero(held.sum(axis=0) > HELD_FRACTION * run.q.shape[0])
    updates = {}
    for j in columns.tolist():
        changed = np.ones(run.q.shape[0], dtype=bool)
        changed[1:] = run.q[1:, j] != run.q[:-1, j]
        updates[j] = changed
    return updates


def split_at_gaps(run: Run, max_step_s: float) -> list[Run]:
    """``run`` cut at every step between stamps longer than ``max_step_s``: its pieces in time order, named
    ``<run>#1``, ``<run>#2``, ... (the run itself, unchanged, when it has no gap)."""
    cuts = np.flatnonzero(np.diff(run.time) > max_step_s) + 1
    if not cuts.size:
        return [run]
    bounds = [0, *cuts.tolist(), run.time.size]
    pieces = []
    for k, (start, stop) in enumerate(zip(bounds[:-1], bounds[1:], strict=True), start=1):
        rows = slice(start, stop)
        pieces.append(dataclasses.replace(
            run, name=f"{run.name}#{k}", time=run.time[rows], q=run.q[rows],
            **{name: None if getattr(run, name) is None else getattr(run, name)[rows]
               for name in ("qd", "tau", "tau_cmd", "q_cmd", "contact")},
            rows=(np.arange(run.time.size) if run.rows is None else run.rows)[rows]))
    return pieces


def prepare_run(
    run: Run,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    sample_rate_hz: float | None = None,
    use_measured_qd: bool = False,
) -> PreparedRun:
    """Dedup, resample to a uniform grid, zero-phase filter q, differentiate: see the module docstring."""
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
        torque_sensor=(run.meta.torque_sensor or DEFAULT_TORQUE_SENSOR) if run.tau is not None
        else DEFAULT_TORQUE_SENSOR,
        entry=run.entry, **torques,
    )


def _held_record(run: Run, updates: Mapping[int, np.ndarray]) -> HeldRecord | None:
    """What :func:`held_columns` found, by joint: each held column's rows that were no update."""
    if not updates:
        return None
    held = {run.joint_names[j]: int(np.count_nonzero(~changed[1:])) for j, changed in updates.items()}
    return HeldRecord({"q": held}, of=int(run.q.shape[0]))


def _measured_floor(run: Run, motion_band_hz: float) -> MeasuredFloor:
    """The noise floor of the run's raw torque (:func:`~sim2real.measurements.noise.measured_noise_floor`), at the
    log's own rate, the motion's band ending at the position filter's cutoff, or as its metadata states it."""
    raw_torque = run.tau if run.tau is not None else run.tau_cmd
    assert raw_torque is not None
    distinct = np.concatenate([[True], np.any(raw_torque[1:] != raw_torque[:-1], axis=1)])
    stated, reason = stated_noise_floor(run.meta.extra.get("noise_floor"), run.joint_names, run.path.with_suffix(".yaml"))
    rate = 1.0 / float(np.median(np.diff(run.time)))
    return measured_noise_floor(raw_torque, distinct, rate, motion_band_hz, stated, reason)


def _replace_spikes(run: Run) -> tuple[Run, dict[str, dict[str, int]]]:
    """``run`` with its lone spikes (:func:`lone_spikes`) replaced, and how many per signal kind and joint."""
    spikes = {}
    for kind in SPIKE_SIGNALS:
        raw = getattr(run, kind)
        if raw is not None:
            flags = lone_spikes(raw)
            if flags.any():
                run = dataclasses.replace(run, **{kind: without_spikes(raw, flags)})
                spikes[kind] = {j: int(c) for j, c in zip(run.joint_names, flags.sum(axis=0), strict=True) if c}
    return run, spikes


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
