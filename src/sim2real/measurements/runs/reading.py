"""Reading a run and checking it: the table and its metadata beside it against the format (:mod:`.format`),
then the joints and their positions against a model."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim2real.errors import InputError
from sim2real.files import read_validated_yaml
from sim2real.measurements.records import IncompleteRows, RunMeta
from sim2real.measurements.runs.format import (
    DEGREES_THRESHOLD_RAD, MAX_INCOMPLETE_FRACTION, MIN_DURATION_S, MIN_SAMPLES, SIGNAL_KINDS, Run,
)

if TYPE_CHECKING:
    import pandas as pd


def file_row(run: Run, index: int) -> str:
    """Sample ``index`` of ``run`` as a location in its file (:func:`_row_label`), across rows that were dropped."""
    return _row_label(run.path, int(run.rows[index]) if run.rows is not None else index)


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
