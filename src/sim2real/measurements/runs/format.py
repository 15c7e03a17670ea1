"""The measurement format: the signal kinds and the limits a run is held to, and the types of a run as read
(``Run``), as prepared (``PreparedRun``), its line of the measurement list (``MeasurementEntry``) and the runs of
a list (``RunSet``), with where a run's torque is measured.

Format (a contract shared with real robot logs and the virtual lab):

* A table, CSV or Parquet: ``time`` in seconds and, per joint named as in the URDF, ``q.<joint>``
  (rad or m), optionally ``qd.<joint>``, ``tau.<joint>`` (torque measured at the joint),
  ``tau_cmd.<joint>`` (torque the controller commanded at that stamp), ``q_cmd.<joint>``.
  ``q`` and at least one of ``tau`` / ``tau_cmd`` are required; a signal kind is given for all
  joints or for none.
* Beside it ``<stem>.yaml`` validated by ``schemas/measurement.schema.yaml``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Literal, Protocol, TypeVar

import numpy as np

from sim2real.errors import InputError
from sim2real.measurements.records import FilterSettings, IncompleteRows, RunMeta, SensorPlacement

SIGNAL_KINDS = ("q", "qd", "tau", "tau_cmd", "q_cmd")
DEFAULT_TORQUE_SENSOR = SensorPlacement.MOTOR_SIDE
MIN_DURATION_S = 1.0
MIN_SAMPLES = 100
# A uniform grid more than this many times denser than the logged samples means a gap, a stamp in other
# units or a sample_rate_hz that is not the log's: refused before it is allocated.
MAX_GRID_PER_SAMPLE = 20
# More than a turn plus a margin: no revolute joint angle in rad, but common in degrees.
DEGREES_THRESHOLD_RAD = 2 * np.pi + 0.5
# A row with an empty cell (blank, NaN) is a sample the logger lost: dropped, and a stretch of them splits the run
# like any gap (sim2real.measurements.prepare). Beyond this share of a column's or of the table's rows it is no
# loss but a table put together from signals on different clocks, or a column that was not logged: refused.
MAX_INCOMPLETE_FRACTION = 0.2
DEFAULT_CUTOFF_HZ = 10.0
DEFAULT_FILTER_ORDER = 4
Role = Literal["fit", "holdout"]


@dataclass(frozen=True)
class MeasurementEntry:
    """A run of the measurement list: its name there, its file, and its role (``fit`` or ``holdout``)."""

    name: str
    path: Path
    role: str  # "fit" | "holdout"


@dataclass(frozen=True)
class Run:
    """A measurement run as loaded and validated (original, possibly irregular stamps)."""

    name: str
    path: Path
    joint_names: list[str]
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray | None
    tau: np.ndarray | None
    tau_cmd: np.ndarray | None
    q_cmd: np.ndarray | None
    meta: RunMeta
    contact: np.ndarray | None = None  # (N,) bool contact flag when the log has a `contact` column
    # where rows with an empty cell were dropped (:data:`MAX_INCOMPLETE_FRACTION`): the file's data row of each
    # sample, and what was dropped; None when every row was whole
    rows: np.ndarray | None = None
    incomplete: IncompleteRows | None = None
    entry: MeasurementEntry | None = None  # the run's line of the measurement list (None: read on its own)

    @property
    def role(self) -> str | None:
        """``fit`` or ``holdout``, as the measurement list says (None: the run was read on its own)."""
        return None if self.entry is None else self.entry.role


@dataclass(frozen=True)
class PreparedRun:
    """A run cleaned and put on a uniform time grid: what fits and comparisons use."""

    name: str
    joint_names: list[str]
    time: np.ndarray
    dt: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    torque_source: str
    tau_cmd: np.ndarray | None
    q_cmd: np.ndarray | None
    # what the preparation did (None: a run not prepared here, e.g. the residuals read back at the fit's rate)
    filter: FilterSettings | None
    torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR  # where tau is measured (metadata `torque_sensor`)
    qd_measured: np.ndarray | None = None  # logged velocity on the grid (unfiltered), if any
    contact: np.ndarray | None = None
    raw_torque_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))  # per-joint white-noise std
    # per joint, the RMS of tau that no actuator model can explain from tau_cmd (with_command_floor); empty
    # until computed, and unless the run logs both
    command_torque_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # the line of the measurement list the run (or this piece of it, split at a logging gap) was prepared from
    entry: MeasurementEntry | None = None

    @property
    def role(self) -> str | None:
        """``fit`` or ``holdout``, as the measurement list says (None: the run was prepared on its own)."""
        return None if self.entry is None else self.entry.role


class _HasEntry(Protocol):
    @property
    def entry(self) -> MeasurementEntry | None: ...

    @property
    def role(self) -> str | None: ...


R = TypeVar("R", bound=_HasEntry)


@dataclass(frozen=True)
class RunSet(Generic[R]):
    """The runs of a measurement list, in its order, each with its line of the list (its role, its file), and the
    list's preparation settings (:func:`measurement_settings`). A run split at its logging gaps is there as its
    pieces, each with the run's line."""

    runs: tuple[R, ...]
    settings: dict[str, Any]

    def __iter__(self) -> Iterator[R]:
        return iter(self.runs)

    def __len__(self) -> int:
        return len(self.runs)

    def __getitem__(self, index: int) -> R:
        return self.runs[index]

    def of_role(self, role: Role) -> tuple[R, ...]:
        """The runs of ``role``, in the list's order."""
        return tuple(run for run in self.runs if run.role == role)

    @property
    def fit(self) -> tuple[R, ...]:
        """The runs the model is fitted on."""
        return self.of_role("fit")

    @property
    def holdout(self) -> tuple[R, ...]:
        """The runs the model is judged on."""
        return self.of_role("holdout")

    @property
    def entries(self) -> tuple[MeasurementEntry | None, ...]:
        """Each run's line of the measurement list (its name there, its file, its role)."""
        return tuple(run.entry for run in self.runs)


class _HasTorqueSensor(Protocol):
    name: str
    torque_source: str
    torque_sensor: SensorPlacement


def torque_sensor_of(runs: Sequence[_HasTorqueSensor]) -> SensorPlacement:
    """Where the ``tau`` of ``runs`` (prepared runs, or the fit's :class:`~sim2real.identification.fitting.RunSamples`)
    is measured: one place for all of them, checked here once. Runs that mix sensor positions are refused: one arm's
    sensor is fitted together."""
    measured = [run for run in runs if run.torque_source == "tau"]
    places = {run.torque_sensor for run in measured}
    if len(places) > 1:
        listing = ", ".join(f"{run.name} ({run.torque_sensor})" for run in measured)
        raise InputError(None, "torque_sensor", f"the runs mix torque sensor positions: {listing}",
                         "fit runs of one arm's sensor together: every run's metadata `torque_sensor` the same "
                         "(motor or link)")
    return SensorPlacement(places.pop()) if places else DEFAULT_TORQUE_SENSOR


def measured_after_drive(torque_source: str, torque_sensor: SensorPlacement) -> bool:
    """Whether the judged torque is measured after the drive (a link-side sensor's ``tau``): it then does not hold
    the drive's rotor inertia and friction."""
    return torque_source == "tau" and torque_sensor == SensorPlacement.LINK_SIDE
