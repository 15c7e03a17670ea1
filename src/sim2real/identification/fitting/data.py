"""Torque data: runs (:class:`RunSamples`, a prepared run with its noise floor) stacked along time on a uniform grid
per run (:class:`TorqueData`), and where the judged torque is measured (:func:`link_side`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sim2real.errors import InputError
from sim2real.measurements.runs import (
    DEFAULT_TORQUE_SENSOR, SensorPlacement, measured_after_drive, torque_sensor_of,
)

if TYPE_CHECKING:
    from sim2real.measurements.runs import PreparedRun


def kept_segments(segments: Sequence[slice], rows: np.ndarray) -> list[slice]:
    """Run segments (slices of stacked rows) after keeping the sorted ``rows``: empty runs drop out."""
    kept = []
    start = 0
    for seg in segments:
        count = int(np.count_nonzero((rows >= seg.start) & (rows < seg.stop)))
        if count:
            kept.append(slice(start, start + count))
        start += count
    return kept


@dataclass
class TorqueData:
    """Runs stacked along time, on a uniform grid per run; ``segments`` are the run boundaries."""

    joint_names: list[str]
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # judged torque
    segments: list[slice]
    run_names: list[str]
    torque_source: str  # "tau" (sensor) or "tau_cmd" (command)
    has_commands: bool
    noise_floor: np.ndarray  # per joint, RMS of torque no model can explain
    torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR  # where tau is measured (sim2real.measurements.runs)

    @property
    def n_samples(self) -> int:
        return len(self.time)

    def subset(self, rows: np.ndarray) -> TorqueData:
        """Rows of the stacked arrays (sorted); segments are rebuilt from the kept rows."""
        rows = np.sort(rows)
        segments = kept_segments(self.segments, rows)
        return TorqueData(
            self.joint_names, self.time[rows], self.q[rows], self.qd[rows], self.qdd[rows], self.tau[rows],
            segments, self.run_names, self.torque_source, self.has_commands, self.noise_floor, self.torque_sensor,
        )


@dataclass(frozen=True)
class RunSamples:
    """One run's samples as the fit stacks them: the judged torque, where it is measured and its noise floor."""

    name: str
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # judged torque
    torque_source: str  # "tau" (sensor) or "tau_cmd" (command)
    has_commands: bool
    noise_floor: np.ndarray  # per joint
    torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR

    @classmethod
    def of(cls, prepared: PreparedRun, noise_floor: np.ndarray, tau: np.ndarray | None = None) -> RunSamples:
        """A prepared run with the floor its side is judged against; ``tau``: another judged torque (the
        drive side's command), the measured one by default."""
        return cls(prepared.name, prepared.time, prepared.q, prepared.qd, prepared.qdd,
                   prepared.tau if tau is None else tau, prepared.torque_source, prepared.tau_cmd is not None,
                   noise_floor, prepared.torque_sensor)


def stack_runs(runs: Sequence[RunSamples], joint_names: Sequence[str], fit_rate_hz: float | None = None) -> TorqueData:
    """Stack runs along time, each on its own uniform grid.

    Each run is decimated to at most ``fit_rate_hz`` (every k-th sample: the signals are already
    zero-phase filtered, the torque noise stays white). Noise floors combine as an RMS over samples.
    """
    if not runs:
        raise InputError(None, "runs", "no runs to fit or judge", "list runs with role fit and holdout in measurements.yaml")
    sources = {r.torque_source for r in runs}
    if len(sources) > 1:
        raise InputError(
            None, "runs", f"runs mix judged torque sources {sorted(sources)}",
            "give every run the same torque columns (all tau, or all tau_cmd only)",
        )
    sensor = torque_sensor_of(runs)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("time", "q", "qd", "qdd", "tau")}
    segments, floors, counts, names = [], [], [], []
    start = 0
    for run in runs:
        time = np.asarray(run.time, dtype=float)
        step = 1
        if fit_rate_hz and len(time) > 1:
            rate = 1.0 / float(np.median(np.diff(time)))
            step = max(1, int(round(rate / fit_rate_hz)))
        for key in parts:
            parts[key].append(np.asarray(getattr(run, key), dtype=float)[::step])
        count = len(parts["time"][-1])
        segments.append(slice(start, start + count))
        start += count
        floors.append(np.asarray(run.noise_floor, dtype=float))
        counts.append(count)
        names.append(str(run.name))
    weights = np.asarray(counts, dtype=float)
    noise = np.sqrt(np.average(np.vstack(floors) ** 2, axis=0, weights=weights))
    return TorqueData(
        list(joint_names), *(_stacked(parts[k]) for k in ("time", "q", "qd", "qdd", "tau")),
        segments=segments, run_names=names, torque_source=sources.pop(),
        has_commands=all(r.has_commands for r in runs), noise_floor=noise, torque_sensor=sensor,
    )


def _stacked(parts: list[np.ndarray]) -> np.ndarray:
    """The runs' arrays one after the other; one run's own array when it is already contiguous (the actuator
    side takes a 10-minute run at 1 kHz as it is, not a copy of it: the same values and layout)."""
    return np.ascontiguousarray(parts[0]) if len(parts) == 1 else np.concatenate(parts)


def link_side(data: TorqueData) -> bool:
    """The judged torque is measured after the drive (a link-side sensor): it does not hold the drive's terms."""
    return measured_after_drive(data.torque_source, data.torque_sensor)

