"""What a run says of itself and what its preparation did, typed: a run's metadata (:class:`RunMeta`, the ``.yaml``
beside its table) and a prepared run's record of its preparation (:class:`FilterSettings`, with the rows dropped for
an empty cell, the lone spikes replaced and the logging gaps split at).

Each gives the document it is written as (``as_document``: the run's ``.yaml``, ``gap.json``'s ``runs[].filter``,
the prepared runs' file) and is read back from it (``from_document``), the same to the byte.
"""

from __future__ import annotations

from collections.abc import Mapping
import enum
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal


class SensorPlacement(enum.StrEnum):
    """Where a run's measured torque ``tau`` is taken, its one definition (values: the run metadata's and the lab
    scenario's ``torque_sensor``, and ladder.json's ``links.torque_sensor``): at the motor's output, before the joint's
    rotor inertia and friction (a motor-current estimate, the default), or after the gearbox (link-side: the Panda's
    tau_J, a KUKA iiwa's sensors)."""

    MOTOR_SIDE = "motor"
    LINK_SIDE = "link"


@dataclass(frozen=True)
class RunMeta:
    """A run's metadata (``schemas/measurement.schema.yaml``). None: not given (the schema's default, or the median
    time step, applies); ``extra``: the keys the schema does not name, kept as they were given."""

    robot: str
    source: Literal["real", "synthetic"]
    control_mode: Literal["torque", "position"]
    sample_rate_hz: float | None = None
    torque_sensor: SensorPlacement | None = None
    # per joint, +1 or -1: what the logged ``tau.<joint>`` is multiplied by to follow the URDF's joint axis (a sensor
    # or driver that reports the reaction torque); a joint not named keeps its sign
    torque_sign: Mapping[str, int] | None = None
    notes: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    _NAMED: ClassVar[tuple[str, ...]] = ("robot", "source", "control_mode", "sample_rate_hz", "torque_sensor",
                                         "torque_sign", "notes")

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> RunMeta:
        """The metadata of a validated ``.yaml`` (every value as it was given)."""
        return cls(**{key: document[key] for key in cls._NAMED if key in document},
                   extra={key: value for key, value in document.items() if key not in cls._NAMED})

    def as_document(self) -> dict[str, Any]:
        """The ``.yaml`` beside the run: the keys given, nothing added."""
        named = {key: getattr(self, key) for key in self._NAMED if getattr(self, key) is not None}
        return {**named, **self.extra}


@dataclass(frozen=True)
class StepRange:
    """The steps between a run's logged stamps, in ms."""

    min: float
    median: float
    max: float


@dataclass(frozen=True)
class SpikeRecord:
    """The lone samples replaced (:func:`sim2real.measurements.cleaning.lone_spikes`): ``replaced[kind][joint]``, how
    many, for the signal kinds and joints that had any; ``scales``: the threshold."""

    scales: float
    replaced: Mapping[str, Mapping[str, int]]


@dataclass(frozen=True)
class HeldRecord:
    """The columns whose samples a logger held (:func:`sim2real.measurements.cleaning.held_samples`): a value repeated
    from the row before while the rest of the row changed, a signal updated slower than the log. ``held[kind][joint]``,
    how many of ``of`` rows, for the columns held often enough to matter; each such column was rebuilt from its update
    instants (the samples where its value changed) before anything was filtered or differentiated."""

    held: Mapping[str, Mapping[str, int]]
    of: int

    def as_document(self) -> dict[str, Any]:
        return {"held": {kind: dict(joints) for kind, joints in self.held.items()}, "of": self.of,
                "rebuilt_from": "update instants"}

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> HeldRecord:
        return cls({kind: dict(joints) for kind, joints in document["held"].items()}, document["of"])


@dataclass(frozen=True)
class IncompleteRows:
    """The rows dropped for an empty cell (:func:`sim2real.measurements.runs.read_run`): how many, of how many, the
    first as a location in the file; ``run``: the run of the measurement list (None until it is named)."""

    dropped: int
    of: int
    first_row: str
    run: str | None = None


@dataclass(frozen=True)
class LoggingGap:
    """A stretch the logger lost: after which stamp, and how long."""

    after_s: float
    lost_s: float


@dataclass(frozen=True)
class GapPiece:
    """A piece of a run between its logging gaps, and whether it was long enough to prepare."""

    name: str
    from_s: float
    to_s: float
    kept: bool


@dataclass(frozen=True)
class GapRecord:
    """Where a run was split at its logging gaps (:func:`sim2real.measurements.prepare.prepare_pieces`)."""

    max_step_s: float
    gaps: tuple[LoggingGap, ...]
    pieces: tuple[GapPiece, ...]
    run: str


# Differences of these orders estimate the same white noise (each normalised by its own gain, C(2k, k)); on a torque
# smoothed, held or upsampled before it was logged they do not: its noise is no longer white.
DIFFERENCE_ORDERS = (2, 3, 4, 5)


@dataclass(frozen=True)
class NoiseFloorRecord:
    """How each joint's noise floor was measured when the run was prepared (:func:`measured_noise_floor`), with the
    figures that chose the method: ``method[j]`` is ``differences`` (the white part, orders agree), ``rounding`` (the
    logger's quantum), ``updates`` (a held column's white part, from its own updates), ``spectrum``
    (:func:`spectrum_noise_sigma`: differences do not measure this log's noise) or ``stated`` (the run's metadata, ``noise_floor.reason``); ``differences[k][j]``: the estimate of order
    :data:`DIFFERENCE_ORDERS` ``[k]``; ``equal_steps[j]``: the share of consecutive samples that are equal;
    ``spectrum[j]``: the spectral estimate (None where the log is too slow for it); ``motion_band_hz``: where the
    motion's band ends (the position filter's cutoff)."""

    method: tuple[str, ...]
    differences: tuple[tuple[float, ...], ...]
    equal_steps: tuple[float, ...]
    spectrum: tuple[float, ...] | None
    motion_band_hz: float
    stated_reason: str | None = None

    def as_document(self) -> dict[str, Any]:
        """The record as the prepared runs' file and gap.json's ``runs[].filter.noise_floor`` hold it."""
        return {"method": list(self.method), "difference_orders": list(DIFFERENCE_ORDERS),
                "differences": [list(row) for row in self.differences], "equal_steps": list(self.equal_steps),
                "spectrum": None if self.spectrum is None else list(self.spectrum),
                "motion_band_hz": self.motion_band_hz, "stated_reason": self.stated_reason}

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> NoiseFloorRecord:
        spectrum = document["spectrum"]
        return cls(tuple(document["method"]), tuple(tuple(row) for row in document["differences"]),
                   tuple(document["equal_steps"]), None if spectrum is None else tuple(spectrum),
                   float(document["motion_band_hz"]), document.get("stated_reason"))


@dataclass(frozen=True)
class FilterSettings:
    """What :func:`sim2real.measurements.prepare.prepare_run` did to a run: the grid, the filter, the derivatives,
    and the records of what it found (spikes, incomplete rows, logging gaps, held samples; None where there was none)."""

    order: int
    cutoff_hz: float
    velocity: str
    resampled_to_hz: float
    raw_step_ms: StepRange
    repeated_samples_dropped: int
    trimmed_s_each_end: float
    spikes: SpikeRecord | None = None
    incomplete_rows: IncompleteRows | None = None
    gaps: GapRecord | None = None
    held: HeldRecord | None = None
    # how the torque's noise floor was measured, where any joint's is not the white part from differences
    noise_floor: NoiseFloorRecord | None = None
    type: str = "butterworth low-pass, zero-phase (scipy.signal.sosfiltfilt)"
    applied_to: str = "q (torque is not filtered)"
    acceleration: str = "central differences of the velocity"
    resampling: str = "linear interpolation onto a uniform grid"

    def as_document(self) -> dict[str, Any]:
        """The preparation as the documents hold it (gap.json's ``runs[].filter``, the prepared runs' file)."""
        document: dict[str, Any] = {
            "type": self.type, "order": self.order, "cutoff_hz": self.cutoff_hz, "applied_to": self.applied_to,
            "velocity": self.velocity, "acceleration": self.acceleration, "resampled_to_hz": self.resampled_to_hz,
            "resampling": self.resampling,
            "raw_step_ms": {"min": self.raw_step_ms.min, "median": self.raw_step_ms.median,
                            "max": self.raw_step_ms.max},
            "repeated_samples_dropped": self.repeated_samples_dropped, "trimmed_s_each_end": self.trimmed_s_each_end,
        }
        if self.spikes is not None:
            document["spikes"] = {"scales": self.spikes.scales,
                                  "replaced": {kind: dict(joints) for kind, joints in self.spikes.replaced.items()}}
        if self.incomplete_rows is not None:
            rows = self.incomplete_rows
            document["incomplete_rows"] = {**({"run": rows.run} if rows.run is not None else {}),
                                           "dropped": rows.dropped, "of": rows.of, "first_row": rows.first_row}
        if self.gaps is not None:
            record = self.gaps
            document["gaps"] = {
                "max_step_s": record.max_step_s,
                "gaps": [{"after_s": g.after_s, "lost_s": g.lost_s} for g in record.gaps],
                "pieces": [{"name": p.name, "from_s": p.from_s, "to_s": p.to_s, "kept": p.kept} for p in record.pieces],
                "run": record.run,
            }
        if self.held is not None:
            document["held"] = self.held.as_document()
        if self.noise_floor is not None:
            document["noise_floor"] = self.noise_floor.as_document()
        return document

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> FilterSettings:
        """The preparation of :meth:`as_document`, read back."""
        spikes, rows, record = document.get("spikes"), document.get("incomplete_rows"), document.get("gaps")
        return cls(
            order=document["order"], cutoff_hz=document["cutoff_hz"], velocity=document["velocity"],
            resampled_to_hz=document["resampled_to_hz"], raw_step_ms=StepRange(**document["raw_step_ms"]),
            repeated_samples_dropped=document["repeated_samples_dropped"],
            trimmed_s_each_end=document["trimmed_s_each_end"],
            spikes=None if spikes is None else SpikeRecord(
                spikes["scales"], {kind: dict(joints) for kind, joints in spikes["replaced"].items()}),
            incomplete_rows=None if rows is None else IncompleteRows(**rows),
            gaps=None if record is None else GapRecord(
                record["max_step_s"], tuple(LoggingGap(**g) for g in record["gaps"]),
                tuple(GapPiece(**p) for p in record["pieces"]), record["run"]),
            held=None if "held" not in document else HeldRecord.from_document(document["held"]),
            noise_floor=None if "noise_floor" not in document else NoiseFloorRecord.from_document(document["noise_floor"]),
            type=document["type"], applied_to=document["applied_to"], acceleration=document["acceleration"],
            resampling=document["resampling"],
        )
