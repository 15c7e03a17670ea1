"""What a logger got wrong, found and repaired before a run is prepared (:mod:`sim2real.measurements.prepare`):
its logging gaps (:func:`split_at_gaps`: the run is cut there), its lone spikes (:func:`lone_spikes`: replaced by the
median of three) and its held position columns (:func:`held_columns`: taken at their own update instants).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from sim2real.measurements.noise import white_noise_sigma
from sim2real.measurements.records import HeldRecord
from sim2real.measurements.runs import Run

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


def _held_record(run: Run, updates: Mapping[int, np.ndarray]) -> HeldRecord | None:
    """What :func:`held_columns` found, by joint: each held column's rows that were no update."""
    if not updates:
        return None
    held = {run.joint_names[j]: int(np.count_nonzero(~changed[1:])) for j, changed in updates.items()}
    return HeldRecord({"q": held}, of=int(run.q.shape[0]))


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
