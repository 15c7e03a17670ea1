"""Measurement runs: the table format, reading and checking a run, the measurement list, writing a run.

Format (a contract shared with real robot logs and the virtual lab):

* A table, CSV or Parquet: ``time`` in seconds and, per joint named as in the URDF, ``q.<joint>``
  (rad or m), optionally ``qd.<joint>``, ``tau.<joint>`` (torque measured at the joint),
  ``tau_cmd.<joint>`` (torque the controller commanded at that stamp), ``q_cmd.<joint>``.
  ``q`` and at least one of ``tau`` / ``tau_cmd`` are required; a signal kind is given for all
  joints or for none.
* Beside it ``<stem>.yaml`` validated by ``schemas/measurement.schema.yaml``.

A rule reads each run file once: :func:`read_runs` reads every run of a measurement list; the caller
builds its model from the runs' joints and prepares them (:mod:`sim2real.measurements.prepare`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, Literal, Protocol, TypeVar

import numpy as np

from sim2real.errors import InputError
from sim2real.files import read_validated_yaml
from sim2real.measurements.records import FilterSettings, IncompleteRows, RunMeta, TorqueSensor

if TYPE_CHECKING:
    import pandas as pd

SIGNAL_KINDS = ("q", "qd", "tau", "tau_cmd", "q_cmd")
TORQUE_SENSORS: tuple[TorqueSensor, ...] = ("motor", "link")
DEFAULT_TORQUE_SENSOR: TorqueSensor = "motor"
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


def file_row(run: Run, index: int) -> str:
    """Sample ``index`` of ``run`` as a location in its file (:func:`_row_label`), across rows that were dropped."""
    return _row_label(run.path, int(run.rows[index]) if run.rows is not None else index)


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
    torque_sensor: TorqueSensor = DEFAULT_TORQUE_SENSOR  # where tau is measured (metadata `torque_sensor`)
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
    torque_sensor: TorqueSensor


def torque_sensor_of(runs: Sequence[_HasTorqueSensor]) -> TorqueSensor:
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
    return places.pop() if places else DEFAULT_TORQUE_SENSOR


def measured_after_drive(torque_source: str, torque_sensor: str) -> bool:
    """Whether the judged torque is measured after the drive (a link-side sensor's ``tau``): it then does not hold
    the drive's rotor inertia and friction."""
    return torque_source == "tau" and torque_sensor == "link"


def _read_table(path: Path) -> pd.DataFrame:
    import pandas as pd
    if not path.exists():
        raise InputError(path, None, "file does not exist", "create it or correct the path in measurements.yaml")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            return pd.read_csv(path)
        if suffix == ".parquet":
            table = pd.read_parquet(path)
            # Arrow keeps the memory it read the file into for later reads: give it back now (a 10-minute log at
            # 1 kHz leaves ~0.4 GB behind per run, beside every other run of the list).
            import pyarrow

            pyarrow.default_memory_pool().release_unused()
            return table
    except Exception as exc:  # pandas/pyarrow raise many types
        raise InputError(path, None, f"cannot be read as a table ({exc})", "write a valid CSV or Parquet file") from exc
    raise InputError(path, None, f"unsupported extension '{suffix}'", "use .csv or .parquet")


def _row_label(path: Path, index: int) -> str:
    """Data row index -> a location a user finds in the file (CSV line numbers count the header)."""
    if path.suffix.lower() == ".csv":
        return f"row {index} (line {index + 2})"
    return f"row {index}"


def read_run(path: str | Path) -> Run:
    """Read a CSV/Parquet run and its metadata, checked against the format (not yet against a model).

    ``InputError`` (file, column, row) on bad input. :func:`check_run` checks the joints and their
    limits once the model is known; :func:`load_run` does both.
    """
    path = Path(path)
    meta = _read_meta(path)
    table = _read_table(path)
    columns = [str(c) for c in table.columns]
    by_kind, has_contact = _columns_by_kind(path, columns)
    joints = by_kind["q"]
    numbers, incomplete = _numeric_columns(path, table, [c for c in columns if c != "contact"])
    kept = np.flatnonzero(~incomplete)
    if incomplete.any():
        _check_incomplete(path, incomplete)
        table = table.iloc[kept]
        numbers = {col: column[kept] for col, column in numbers.items()}
    _check_torques_move(path, numbers)
    time = _checked_time(path, numbers["time"].copy(), kept)  # a copy: not a view that keeps the whole table alive

    def block(kind: str) -> np.ndarray | None:
        if not by_kind[kind]:
            return None
        return np.column_stack([numbers[f"{kind}.{j}"] for j in joints])

    q = block("q")
    assert q is not None
    for i, joint in enumerate(joints):
        worst = int(np.argmax(np.abs(q[:, i])))
        if abs(q[worst, i]) > DEGREES_THRESHOLD_RAD:
            _raise_degrees(path, joint, q[:, i], worst, int(kept[worst]))
    contact = table["contact"].astype(bool).to_numpy() if has_contact else None
    return Run(
        name=path.stem, path=path, joint_names=list(joints), time=time, q=q, qd=block("qd"),
        tau=_signed_torque(path, meta, joints, block("tau")),
        tau_cmd=block("tau_cmd"), q_cmd=block("q_cmd"), meta=meta, contact=contact,
        **({"rows": kept, "incomplete": IncompleteRows(
            dropped=int(incomplete.sum()), of=int(incomplete.size),
            first_row=_row_label(path, int(np.flatnonzero(incomplete)[0])))} if incomplete.any() else {}),
    )


def _read_meta(path: Path) -> RunMeta:
    """The metadata beside the run ``path`` (``<stem>.yaml``), validated."""
    meta_path = path.with_suffix(".yaml")
    if not meta_path.exists():
        raise InputError(
            meta_path, None, "metadata file beside the run does not exist",
            "write <stem>.yaml with robot, source (real|synthetic) and control_mode (torque|position)",
        )
    return RunMeta.from_document(read_validated_yaml(meta_path, "measurement.schema.yaml"))


def _signed_torque(path: Path, meta: RunMeta, joints: Sequence[str], tau: np.ndarray | None) -> np.ndarray | None:
    """The measured torque ``tau`` with each joint's metadata ``torque_sign`` applied (a joint not named keeps its
    sign); a sign for a joint the run does not log, or for a run without ``tau``, is refused."""
    if not meta.torque_sign:
        return tau
    meta_path = path.with_suffix(".yaml")
    unknown = [j for j in meta.torque_sign if j not in joints]
    if unknown:
        raise InputError(meta_path, f"torque_sign.{unknown[0]}", f"'{unknown[0]}' is not a joint of the run "
                         f"({path.name} logs {', '.join(joints)})", "name the joints as the run's q.<joint> columns do")
    if tau is None:
        raise InputError(meta_path, "torque_sign", f"{path.name} logs no measured torque (tau.<joint>) to sign",
                         "leave torque_sign out: the commanded torque tau_cmd is taken as logged")
    signs = np.array([float(meta.torque_sign.get(j, 1)) for j in joints])
    return tau * signs


def _columns_by_kind(path: Path, columns: Sequence[str]) -> tuple[dict[str, list[str]], bool]:
    """The table's columns by signal kind ({kind: joints}, in the table's order) and whether it has ``contact``:
    every column one of the format's, ``q`` for some joints, every other kind for all of them or none, a torque."""
    if "time" not in columns:
        raise InputError(path, "column 'time'", "is missing", "add a column 'time' in seconds")
    by_kind: dict[str, list[str]] = {kind: [] for kind in SIGNAL_KINDS}
    for col in columns:
        if col in ("time", "contact"):
            continue
        kind, _, joint = col.rpartition(".")
        if kind not in by_kind or not joint:
            raise InputError(
                path, f"column '{col}'", "is not part of the measurement format",
                "name columns time, q.<joint>, qd.<joint>, tau.<joint>, tau_cmd.<joint>, q_cmd.<joint> (or contact)",
            )
        by_kind[kind].append(joint)
    joints = by_kind["q"]
    if not joints:
        raise InputError(path, "columns q.<joint>", "no joint positions", "add one column q.<joint> per joint")
    for kind in SIGNAL_KINDS[1:]:
        present = by_kind[kind]
        if present and sorted(present) != sorted(joints):
            missing = sorted(set(joints) - set(present))
            extra = sorted(set(present) - set(joints))
            detail = "; ".join([f"missing for {', '.join(missing)}"] * bool(missing)
                               + [f"without q for {', '.join(extra)}"] * bool(extra))
            raise InputError(
                path, f"columns {kind}.<joint>", f"given for some joints only ({detail})",
                f"give {kind}.<joint> for every joint of q.<joint>, with the same joint names, or for none",
            )
    if not by_kind["tau"] and not by_kind["tau_cmd"]:
        raise InputError(
            path, "columns tau.<joint> / tau_cmd.<joint>", "no torque at all",
            "log the measured joint torque (tau.<joint>) or the commanded torque (tau_cmd.<joint>)",
        )
    return by_kind, "contact" in columns


def _numeric_columns(path: Path, table: pd.DataFrame, names: Sequence[str]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The columns ``names`` as float arrays (empty cells NaN), and the rows with an empty cell; a cell that is no
    number, an infinite value or a column mostly empty is refused."""
    import pandas as pd

    values = table[list(names)]
    numbers = {}
    incomplete = np.zeros(len(table), dtype=bool)
    for col in names:
        try:
            column = pd.to_numeric(values[col], errors="raise").to_numpy(dtype=float)
        except (ValueError, TypeError) as exc:
            bad = pd.to_numeric(values[col], errors="coerce").isna() & values[col].notna()
            row = int(np.flatnonzero(bad.to_numpy())[0]) if bad.any() else 0
            raise InputError(path, f"column '{col}', {_row_label(path, row)}", f"not a number ({exc})",
                             "write plain decimal numbers") from exc
        infinite = np.flatnonzero(np.isinf(column))
        if infinite.size:
            raise InputError(
                path, f"column '{col}', {_row_label(path, int(infinite[0]))}",
                f"infinite value ({infinite.size} such row(s)): an overflow, not a measurement",
                "log finite numbers; leave the cell empty where a sample was lost",
            )
        empty = np.isnan(column)
        if empty.sum() > MAX_INCOMPLETE_FRACTION * column.size:
            raise InputError(
                path, f"column '{col}'", f"empty in {int(empty.sum())} of {column.size} rows (first: "
                f"{_row_label(path, int(np.flatnonzero(empty)[0]))}): more than a logger loses",
                f"leave the column out if it was not logged; signals logged on different clocks are put on one before "
                f"loading (e.g. pandas.merge_asof on time)",
            )
        numbers[col] = column
        incomplete |= empty
    return numbers, incomplete


def _check_incomplete(path: Path, incomplete: np.ndarray) -> None:
    """Rows with an empty cell are samples the logger lost, up to :data:`MAX_INCOMPLETE_FRACTION` of the table."""
    first = int(np.flatnonzero(incomplete)[0])
    if incomplete.sum() > MAX_INCOMPLETE_FRACTION * incomplete.size:
        raise InputError(
            path, f"{_row_label(path, first)} and {int(incomplete.sum()) - 1} more",
            f"{int(incomplete.sum())} of {incomplete.size} rows have an empty cell in some column: more than a "
            "logger loses",
            "signals logged on different clocks are put on one before loading (e.g. pandas.merge_asof on time)",
        )


def _check_torques_move(path: Path, numbers: Mapping[str, np.ndarray]) -> None:
    for col, column in numbers.items():
        if col.split(".", 1)[0] in ("tau", "tau_cmd") and column.size > 1 and np.all(column == column[0]):
            # A torque that never moves while the arm does measured nothing: judged, it would be a residual
            # no effect explains, and it has no noise to be judged in units of.
            raise InputError(
                path, f"column '{col}'", f"the same value ({float(column[0]):g}) in every row: a torque channel "
                "that measured nothing (a dead sensor, a driver that did not publish)",
                "log the joint's torque; to judge the commanded torque instead, leave out every tau.<joint> column",
            )


def _checked_time(path: Path, time: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """``time``, increasing and long enough to judge; ``kept``: the file's data row of each sample."""
    steps = np.diff(time)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            path, f"column 'time', {_row_label(path, int(kept[k]))}",
            f"time does not increase ({float(time[k - 1]):.9g} s then {float(time[k]):.9g} s; {bad.size} such step(s))",
            "sort the samples by time and drop duplicated stamps",
        )
    span = float(time[-1] - time[0]) if time.size else 0.0
    if time.size < MIN_SAMPLES or span < MIN_DURATION_S:
        raise InputError(
            path, "column 'time'",
            f"run too short to judge ({time.size} samples over {span:.3f} s)",
            f"log at least {MIN_DURATION_S:g} s and {MIN_SAMPLES} samples of motion",
        )
    return time


def _raise_degrees(path: Path, joint: str, col: np.ndarray, row: int, file_row_index: int | None = None) -> None:
    """``row``: the sample; ``file_row_index``: its data row in the file, where rows were dropped."""
    raise InputError(
        path, f"column 'q.{joint}', {_row_label(path, row if file_row_index is None else file_row_index)}",
        f"value {col[row]:.4g} looks like degrees (outside the joint's range in radians)",
        "log angles in radians (multiply degrees by pi/180)",
    )


def check_run(
    run: Run,
    known_joints: Sequence[str] | None = None,
    position_limits: Mapping[str, tuple[float, float]] | None = None,
) -> None:
    """Check a run read by :func:`read_run` against the model: joints it knows, positions in radians.

    A position outside the joint's limits (with a margin) that would be inside them read as degrees
    is refused as degrees. ``InputError`` naming the file, the column and the fix.
    """
    if known_joints is not None:
        unknown = [j for j in run.joint_names if j not in known_joints]
        if unknown:
            raise InputError(
                run.path, f"column(s) {', '.join(f'q.{j}' for j in unknown)}", f"unknown joint(s) {', '.join(unknown)}",
                f"use joint names of the robot description: {', '.join(known_joints)}",
            )
    for i, joint in enumerate(run.joint_names):
        if not position_limits or joint not in position_limits:
            continue
        col = run.q[:, i]
        lo, hi = position_limits[joint]
        margin = 0.1 * (hi - lo) + 0.05
        outside = (col < lo - margin) | (col > hi + margin)
        in_limits_as_deg = np.all((np.deg2rad(col) >= lo - margin) & (np.deg2rad(col) <= hi + margin))
        if outside.any() and in_limits_as_deg:
            first = int(np.flatnonzero(outside)[0])
            _raise_degrees(run.path, joint, col, first, None if run.rows is None else int(run.rows[first]))


def load_run(
    path: str | Path,
    known_joints: Sequence[str] | None = None,
    position_limits: Mapping[str, tuple[float, float]] | None = None,
) -> Run:
    """:func:`read_run` then :func:`check_run`: one run read and checked against the model's joints."""
    run = read_run(path)
    check_run(run, known_joints, position_limits)
    return run


def load_measurement_list(path: str | Path) -> list[MeasurementEntry]:
    """``configs/{robot}/measurements.yaml`` -> entries (name, path, role), names unique."""
    return _entries(Path(path), read_validated_yaml(path, "measurements.schema.yaml"))


def _entries(path: Path, data: Mapping[str, Any]) -> list[MeasurementEntry]:
    entries: list[MeasurementEntry] = []
    seen: set[str] = set()
    for i, item in enumerate(data["runs"]):
        if item["name"] in seen:
            raise InputError(path, f"runs/{i}/name", f"duplicate run name '{item['name']}'", "give each run a unique name")
        seen.add(item["name"])
        entries.append(MeasurementEntry(name=item["name"], path=Path(item["path"]), role=item["role"]))
    return entries


def measurement_settings(path: str | Path) -> dict[str, Any]:
    """Filter and replay settings of measurements.yaml, with defaults filled in."""
    return _settings(read_validated_yaml(path, "measurements.schema.yaml"))


def _settings(data: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "cutoff_hz": float(data.get("filter", {}).get("cutoff_hz", DEFAULT_CUTOFF_HZ)),
        "order": int(data.get("filter", {}).get("order", DEFAULT_FILTER_ORDER)),
        "horizon_s": float(data.get("replay", {}).get("horizon_s", 0.5)),
        # None: the default of sim2real.measurements.cleaning.gap_threshold_s, from each run's own steps
        "max_step_s": data.get("gaps", {}).get("max_step_s"),
    }


def read_runs(measurement_list: str | Path, root: str | Path = ".") -> RunSet[Run]:
    """Every run of a measurement list read once (:func:`read_run`), named as in the list, each with its line of it.

    Returns the runs in the list's order with the settings of :func:`measurement_settings`. Every run must
    log the same joints; the caller builds its model from ``runs[0].joint_names`` and hands it to
    :func:`prepare_runs`.
    """
    path = Path(measurement_list)
    data = read_validated_yaml(path, "measurements.schema.yaml")
    entries = _entries(path, data)
    runs = [dataclasses.replace(read_run(Path(root) / e.path), name=e.name, entry=e) for e in entries]
    joints = runs[0].joint_names
    for run in runs:
        if run.joint_names != joints:
            raise InputError(run.path, "columns q.<joint>", "joints differ from the first run's",
                             f"log the same joints in every run: {', '.join(joints)}")
    return RunSet(tuple(runs), _settings(data))


def write_run(
    path: str | Path, time: np.ndarray, joint_names: Sequence[str], signals: Mapping[str, np.ndarray],
    meta: RunMeta | Mapping[str, Any],
) -> None:
    """Write a run (CSV or Parquet by extension) plus its metadata YAML, atomically and deterministically.
    ``meta``: the run's metadata, or its document (the ``.yaml``'s content, written as given)."""
    import pandas as pd
    from sim2real.files import atomic_path, validate, write_yaml

    path = Path(path)
    columns: dict[str, np.ndarray] = {"time": np.asarray(time, dtype=float)}
    for kind in SIGNAL_KINDS:
        if kind in signals and signals[kind] is not None:
            for i, joint in enumerate(joint_names):
                columns[f"{kind}.{joint}"] = np.asarray(signals[kind], dtype=float)[:, i]
    frame = pd.DataFrame(columns)
    document = meta.as_document() if isinstance(meta, RunMeta) else dict(meta)
    validate(document, "measurement.schema.yaml", path.with_suffix(".yaml"))
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".parquet":
            frame.to_parquet(tmp, index=False)
        else:
            frame.to_csv(tmp, index=False, float_format="%.9g")
    write_yaml(path.with_suffix(".yaml"), document)
