"""Measurement runs: loading, validation and preparation for comparison with a model.

Format (a contract shared with real robot logs and the virtual lab):

* A table, CSV or Parquet: ``time`` in seconds and, per joint named as in the URDF, ``q.<joint>``
  (rad or m), optionally ``qd.<joint>``, ``tau.<joint>`` (torque measured at the joint),
  ``tau_cmd.<joint>`` (torque the controller commanded at that stamp), ``q_cmd.<joint>``.
  ``q`` and at least one of ``tau`` / ``tau_cmd`` are required; a signal kind is given for all
  joints or for none.
* Beside it ``<stem>.yaml`` validated by ``schemas/measurement.schema.yaml``.

A rule reads each run file once: ``read_runs`` reads every run of a measurement list, the caller
builds its model from the runs' joints, and ``prepare_runs`` checks the runs against the model's
joints and limits and prepares them (``load_prepared_runs`` does both when the joints are known;
``prepare_for_model`` takes the joints and limits from a URDF). The rule ``prepare_runs`` writes them once
(``write_prepared_runs``) for the sysid and gap report rules, which read them back (``read_prepared_runs``;
``runs_for_model`` takes either a list or that file): a change of model.yaml prepares nothing again.

Preparation (``prepare_run``, per run) for the comparisons:

1. Consecutive samples with identical positions (a logger faster than the state) are dropped:
   they carry a stale state, and keeping them would put steps into the differentiated signals.
2. Everything is linearly interpolated onto a uniform grid (median time step, or ``sample_rate_hz``).
3. Positions are low-pass filtered with a zero-phase Butterworth filter (``scipy.signal.sosfiltfilt``),
   velocities and accelerations are obtained by central differences of the filtered positions
   (a logged ``qd`` is noisy or missing on real arms, so it is not trusted unless asked for).
4. Both ends are trimmed by the filter's settling time.
5. Torques are NOT filtered. The model is judged on the raw torque: what remains for a perfect model
   is the torque's own high-frequency noise, which is exactly what ``estimate_noise_floor`` measures,
   so RMSE and noise floor are directly comparable (a perfect model lands at about the noise floor).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.blas import one_blas_thread
from sim2real.errors import InputError
from sim2real.io import read_validated_yaml

if TYPE_CHECKING:
    import pandas as pd

SIGNAL_KINDS = ("q", "qd", "tau", "tau_cmd", "q_cmd")
MIN_DURATION_S = 1.0
MIN_SAMPLES = 100
# A uniform grid more than this many times denser than the logged samples means a gap, a stamp in other
# units or a sample_rate_hz that is not the log's: refused before it is allocated.
MAX_GRID_PER_SAMPLE = 20
# More than a turn plus a margin: no revolute joint angle in rad, but common in degrees.
DEGREES_THRESHOLD_RAD = 2 * np.pi + 0.5
DEFAULT_CUTOFF_HZ = 10.0
DEFAULT_FILTER_ORDER = 4


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
    meta: dict
    contact: np.ndarray | None = None  # (N,) bool contact flag when the log has a `contact` column


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
    filter: dict
    torque_sensor: str = "motor"  # where tau is measured (metadata `torque_sensor`): "motor" or "link"
    qd_measured: np.ndarray | None = None  # logged velocity on the grid (unfiltered), if any
    contact: np.ndarray | None = None
    raw_torque_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))  # per-joint white-noise std
    # per joint, the RMS of tau that no actuator model can explain from tau_cmd (with_command_floor); empty
    # until computed, and unless the run logs both
    command_torque_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class MeasurementEntry:
    name: str
    path: Path
    role: str  # "fit" | "holdout"


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
    import pandas as pd
    path = Path(path)
    meta_path = path.with_suffix(".yaml")
    if not meta_path.exists():
        raise InputError(
            meta_path, None, "metadata file beside the run does not exist",
            "write <stem>.yaml with robot, source (real|synthetic) and control_mode (torque|position)",
        )
    meta = read_validated_yaml(meta_path, "measurement.schema.yaml")
    table = _read_table(path)
    columns = [str(c) for c in table.columns]
    if "time" not in columns:
        raise InputError(path, "column 'time'", "is missing", "add a column 'time' in seconds")

    by_kind: dict[str, list[str]] = {kind: [] for kind in SIGNAL_KINDS}
    has_contact = False
    for col in columns:
        if col == "time":
            continue
        if col == "contact":
            has_contact = True
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

    numeric_cols = [c for c in columns if c != "contact"]
    values = table[numeric_cols]
    for col in numeric_cols:
        try:
            column = pd.to_numeric(values[col], errors="raise").to_numpy(dtype=float)
        except (ValueError, TypeError) as exc:
            bad = pd.to_numeric(values[col], errors="coerce").isna() & values[col].notna()
            row = int(np.flatnonzero(bad.to_numpy())[0]) if bad.any() else 0
            raise InputError(path, f"column '{col}', {_row_label(path, row)}", f"not a number ({exc})",
                             "write plain decimal numbers") from exc
        bad_rows = np.flatnonzero(~np.isfinite(column))
        if bad_rows.size:
            raise InputError(
                path, f"column '{col}', {_row_label(path, int(bad_rows[0]))}",
                f"NaN or infinite value ({bad_rows.size} such row(s))",
                "remove or fill these rows (e.g. drop incomplete samples) before loading",
            )

    time = table["time"].to_numpy(dtype=float, copy=True)  # not a view that keeps the whole table alive
    steps = np.diff(time)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            path, f"column 'time', {_row_label(path, k)}",
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

    def block(kind: str) -> np.ndarray | None:
        if not by_kind[kind]:
            return None
        return table[[f"{kind}.{j}" for j in joints]].to_numpy(dtype=float)

    q = block("q")
    assert q is not None
    for i, joint in enumerate(joints):
        worst = int(np.argmax(np.abs(q[:, i])))
        if abs(q[worst, i]) > DEGREES_THRESHOLD_RAD:
            _raise_degrees(path, joint, q[:, i], worst)

    contact = None
    if has_contact:
        contact = table["contact"].astype(bool).to_numpy()
    return Run(
        name=path.stem, path=path, joint_names=list(joints), time=time, q=q, qd=block("qd"),
        tau=block("tau"), tau_cmd=block("tau_cmd"), q_cmd=block("q_cmd"), meta=dict(meta), contact=contact,
    )


def _raise_degrees(path: Path, joint: str, col: np.ndarray, row: int) -> None:
    raise InputError(
        path, f"column 'q.{joint}', {_row_label(path, row)}",
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
            _raise_degrees(run.path, joint, col, int(np.flatnonzero(outside)[0]))


def load_run(
    path: str | Path,
    known_joints: Sequence[str] | None = None,
    position_limits: Mapping[str, tuple[float, float]] | None = None,
) -> Run:
    """:func:`read_run` then :func:`check_run`: one run read and checked against the model's joints."""
    run = read_run(path)
    check_run(run, known_joints, position_limits)
    return run


def white_noise_sigma(x: np.ndarray) -> np.ndarray:
    """Per-column std of the white part of x from second differences (MAD-based, robust to the signal)."""
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(6.0)


def prepare_run(
    run: Run,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    sample_rate_hz: float | None = None,
    use_measured_qd: bool = False,
) -> PreparedRun:
    """Dedup, resample to a uniform grid, zero-phase filter q, differentiate: see the module docstring."""
    from scipy import signal
    # 1. drop stale repeats: a row whose positions equal the previous row's
    same = np.all(run.q[1:] == run.q[:-1], axis=1)
    keep = np.concatenate([[True], ~same])
    n_repeats = int(np.count_nonzero(~keep))
    t_raw = run.time[keep]
    raw_steps = np.diff(run.time)

    # 2. uniform grid
    rate = sample_rate_hz or run.meta.get("sample_rate_hz") or 1.0 / float(np.median(raw_steps))
    dt = 1.0 / float(rate)
    n_float = np.floor((run.time[-1] - run.time[0]) / dt) + 1
    if not n_float <= MAX_GRID_PER_SAMPLE * run.time.size:  # NaN too: a rate or span no grid can hold
        gap = int(np.argmax(raw_steps)) + 1
        raise InputError(
            run.path, f"column 'time', {_row_label(run.path, gap)}",
            f"{run.time.size} samples span {float(run.time[-1] - run.time[0]):.6g} s, {n_float:.3g} grid points at "
            f"{float(rate):.6g} Hz (largest gap {float(raw_steps[gap - 1]):.6g} s here)",
            "log time in seconds, without gaps, and give sample_rate_hz in Hz (or leave it out)",
        )
    n = int(n_float)
    grid = run.time[0] + dt * np.arange(n)

    def resample(x: np.ndarray | None, t_src: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray | None:
        if x is None:
            return None
        x = x if rows is None else x[rows]
        return np.column_stack([np.interp(grid, t_src, x[:, j]) for j in range(x.shape[1])])

    q_grid = resample(run.q, t_raw, keep)
    nyquist = 0.5 * rate
    if cutoff_hz >= nyquist:
        raise InputError(run.path, "filter cutoff", f"{cutoff_hz} Hz is not below the Nyquist frequency {nyquist} Hz",
                         "lower filter.cutoff_hz in measurements.yaml")
    sos = signal.butter(order, cutoff_hz, btype="low", fs=rate, output="sos")
    q_f = signal.sosfiltfilt(sos, q_grid, axis=0)
    if use_measured_qd and run.qd is not None:
        qd_f = signal.sosfiltfilt(sos, resample(run.qd, run.time), axis=0)
        velocity_source = "logged qd, filtered"
    else:
        qd_f = np.gradient(q_f, dt, axis=0)
        velocity_source = "central differences of filtered q"
    qdd_f = np.gradient(qd_f, dt, axis=0)

    # 4. trim the filter's transient at both ends (a few time constants of the cutoff)
    trim = int(np.ceil(max(0.05, 3.0 / cutoff_hz) / dt))
    if n - 2 * trim < MIN_SAMPLES:
        raise InputError(run.path, "column 'time'", "run too short once the filter's edges are trimmed",
                         f"log a longer run (at least {2 * trim * dt + MIN_SAMPLES * dt:.2f} s)")
    sl = slice(trim, n - trim)

    torque_source = "tau" if run.tau is not None else "tau_cmd"
    raw_torque = run.tau if run.tau is not None else run.tau_cmd
    assert raw_torque is not None
    tau = resample(raw_torque, run.time)
    tau_cmd = tau.copy() if run.tau is None else resample(run.tau_cmd, run.time)  # judged on the command: resampled once
    q_cmd = resample(run.q_cmd, run.time)
    qd_measured = resample(run.qd, run.time)
    contact = None
    if run.contact is not None:
        idx = np.clip(np.searchsorted(run.time, grid, side="right") - 1, 0, run.time.size - 1)
        contact = run.contact[idx][sl]

    filter_info: dict[str, Any] = {
        "type": "butterworth low-pass, zero-phase (scipy.signal.sosfiltfilt)",
        "order": int(order),
        "cutoff_hz": float(cutoff_hz),
        "applied_to": "q (torque is not filtered)",
        "velocity": velocity_source,
        "acceleration": "central differences of the velocity",
        "resampled_to_hz": float(rate),
        "resampling": "linear interpolation onto a uniform grid",
        "raw_step_ms": {"min": float(raw_steps.min() * 1e3), "median": float(np.median(raw_steps) * 1e3),
                        "max": float(raw_steps.max() * 1e3)},
        "repeated_samples_dropped": n_repeats,
        "trimmed_s_each_end": float(trim * dt),
    }
    keep_raw = np.concatenate([[True], np.any(raw_torque[1:] != raw_torque[:-1], axis=1)])
    return PreparedRun(
        name=run.name, joint_names=list(run.joint_names), time=grid[sl], dt=dt, q=q_f[sl], qd=qd_f[sl],
        qdd=qdd_f[sl], tau=tau[sl], torque_source=torque_source,
        tau_cmd=None if tau_cmd is None else tau_cmd[sl], q_cmd=None if q_cmd is None else q_cmd[sl],
        filter=filter_info, qd_measured=None if qd_measured is None else qd_measured[sl], contact=contact,
        raw_torque_sigma=white_noise_sigma(raw_torque[keep_raw]),
        torque_sensor=str(run.meta.get("torque_sensor", "motor")) if run.tau is not None else "motor",
    )


def with_command_floor(run: PreparedRun) -> PreparedRun:
    """``run`` with its actuator-link noise floor (:func:`command_white_noise`, ``command_torque_sigma``) where it
    logs both the measured and the commanded torque: computed once, by the rule that prepares the runs."""
    if run.tau_cmd is None or run.torque_source != "tau" or run.command_torque_sigma.size:
        return run
    return dataclasses.replace(run, command_torque_sigma=command_white_noise(run.tau, run.tau_cmd, run.dt))


@one_blas_thread  # its products' last digits: the same from the rule and from any caller
def command_white_noise(tau: np.ndarray, tau_cmd: np.ndarray, dt: float) -> np.ndarray:
    """Per joint, the RMS of the measured torque ``tau`` that no actuator model can explain from ``tau_cmd``.

    The second differences of ``tau`` are regressed on the second differences of ``tau_cmd`` at every
    lag up to the longest delay the fit allows (a short FIR filter, per joint); what is left is the
    sensor's white noise, measured robustly as :func:`white_noise_sigma` does. The differences remove
    biases and slow motion; the lags hold any delay and gain, so the floor is the same with or without the
    effects it is meant to expose (:mod:`sim2real.actuator`'s noise floor).
    """
    from sim2real.effects.actuation_delay import MAX_DELAY
    from sim2real.inertial import CHUNK_ROWS

    lags = int(round(MAX_DELAY / dt)) + 1
    d2_tau = np.diff(tau, n=2, axis=0)
    d2_cmd = np.diff(tau_cmd, n=2, axis=0)
    rows = len(d2_tau) - lags
    floor = np.empty(tau.shape[1])
    for j in range(tau.shape[1]):
        # Row i holds the command's differences at lags 0..lags-1 before sample lags + i (a view, no copy).
        design = np.lib.stride_tricks.sliding_window_view(d2_cmd[:, j], lags)[1 : rows + 1, ::-1]
        target = d2_tau[lags:, j]
        if rows <= CHUNK_ROWS:
            gram, rhs = design.T @ design, design.T @ target
        else:  # a long log: its products summed a chunk of rows at a time (whole, numpy copies the view twice)
            gram, rhs = np.zeros((lags, lags)), np.zeros(lags)
            for start in range(0, rows, CHUNK_ROWS):
                part = np.ascontiguousarray(design[start : start + CHUNK_ROWS])
                gram += part.T @ part
                rhs += part.T @ target[start : start + CHUNK_ROWS]
        coef = np.linalg.lstsq(gram, rhs, rcond=None)[0]
        left = target - design @ coef
        floor[j] = 1.4826 * np.median(np.abs(left - np.median(left))) / np.sqrt(6.0)
    return floor


def estimate_noise_floor(prepared: PreparedRun) -> np.ndarray:
    """Per-joint torque RMS that no model can explain: the white part of the raw torque.

    Estimated from second differences of the raw (unfiltered, de-duplicated) torque, robustly (MAD),
    so smooth motion does not count as noise. Because the comparison uses the unfiltered torque, a
    model that explains everything else has a residual RMS of about this value.
    """
    return np.asarray(prepared.raw_torque_sigma, dtype=float).copy()


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
    }


def read_runs(
    measurement_list: str | Path, root: str | Path = ".",
) -> tuple[list[MeasurementEntry], list[Run], dict[str, Any]]:
    """Every run of a measurement list read once (:func:`read_run`), named as in the list.

    Returns (entries, runs in the same order, settings of :func:`measurement_settings`). Every run must
    log the same joints; the caller builds its model from ``runs[0].joint_names`` and hands it to
    :func:`prepare_runs`.
    """
    path = Path(measurement_list)
    data = read_validated_yaml(path, "measurements.schema.yaml")
    entries = _entries(path, data)
    runs = [dataclasses.replace(read_run(Path(root) / e.path), name=e.name) for e in entries]
    joints = runs[0].joint_names
    for run in runs:
        if run.joint_names != joints:
            raise InputError(run.path, "columns q.<joint>", "joints differ from the first run's",
                             f"log the same joints in every run: {', '.join(joints)}")
    return entries, runs, _settings(data)


def prepare_runs(
    runs: Sequence[Run], settings: Mapping[str, Any], known_joints: Sequence[str] | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
) -> list[PreparedRun]:
    """Runs of :func:`read_runs` checked against the model (:func:`check_run`), then prepared with the
    list's filter settings (:func:`prepare_run`)."""
    for run in runs:
        check_run(run, known_joints, limits)
    return [prepare_run(run, cutoff_hz=settings["cutoff_hz"], order=settings["order"]) for run in runs]


def load_prepared_runs(
    measurement_list: str | Path, known_joints: Sequence[str] | None = None, root: str | Path = ".",
    limits: Mapping[str, tuple[float, float]] | None = None,
) -> tuple[list[MeasurementEntry], list[PreparedRun], dict[str, Any]]:
    """:func:`read_runs` then :func:`prepare_runs`, when the model's joints are known beforehand.

    Returns (entries, prepared runs in the same order, settings of :func:`measurement_settings`).
    """
    entries, runs, settings = read_runs(measurement_list, root)
    return entries, prepare_runs(runs, settings, known_joints, limits), settings


def prepare_for_model(
    measurement_list: str | Path, urdf_path: str | Path, root: str | Path = ".",
) -> tuple[list[MeasurementEntry], list[PreparedRun], dict[str, Any]]:
    """Every run of a measurement list read, checked against the URDF's joints and limits, and prepared.

    A run column naming a joint the URDF lacks is refused in the run's own terms (the file to edit is the
    run). Returns (entries, prepared runs in the same order, settings of :func:`measurement_settings`).
    """
    from sim2real.dynamics import RigidBodyModel

    entries, runs, settings = read_runs(measurement_list, root)
    probe = RigidBodyModel(urdf_path)
    for run in runs:
        unknown = [j for j in run.joint_names if j not in probe.joint_names]
        if unknown:
            raise InputError(run.path, f"column q.{unknown[0]}", f"joint '{unknown[0]}' is not in {urdf_path}",
                             f"name the columns after the URDF's joints ({', '.join(probe.joint_names)})")
    probe = RigidBodyModel(urdf_path, runs[0].joint_names)
    limits = {j: (float(lo), float(hi)) for j, lo, hi in zip(probe.joint_names, probe.lower, probe.upper, strict=True)}
    prepared = [with_command_floor(run) for run in prepare_runs(runs, settings, probe.joint_names, limits)]
    return entries, prepared, settings


# Prepared runs on disk (the rule ``prepare_runs``): one zip of .npy arrays and a JSON header, written with
# fixed member times so that the same runs give the same bytes.
PREPARED_SUFFIX = ".npz"
_PREPARED_ARRAYS = ("time", "q", "qd", "qdd", "tau", "tau_cmd", "q_cmd", "qd_measured", "contact", "raw_torque_sigma",
                    "command_torque_sigma")
_SIGMAS = ("raw_torque_sigma", "command_torque_sigma")  # always arrays (empty when unknown)
# What the fit reads of the prepared runs (sim2real.sysid.run_sysid): not the commanded positions, the logged
# velocity or the contacts.
FIT_ARRAYS = ("time", "q", "qd", "qdd", "tau", "tau_cmd", *_SIGMAS)


def write_prepared_runs(
    path: str | Path, entries: Sequence[MeasurementEntry], prepared: Sequence[PreparedRun], settings: Mapping[str, Any],
) -> None:
    """Prepared runs (:func:`prepare_for_model`) in one file that :func:`read_prepared_runs` reads back exactly."""
    from sim2real.io import write_array_archive

    header: dict[str, Any] = {"settings": dict(settings), "runs": []}
    members = []
    for i, (entry, run) in enumerate(zip(entries, prepared, strict=True)):
        header["runs"].append({
            "entry": {"name": entry.name, "path": Path(entry.path).as_posix(), "role": entry.role},
            "name": run.name, "joint_names": list(run.joint_names), "dt": float(run.dt),
            "torque_source": run.torque_source, "torque_sensor": run.torque_sensor, "filter": run.filter,
            "arrays": [a for a in _PREPARED_ARRAYS if getattr(run, a) is not None],
        })
        members += [(f"{i}/{name}", getattr(run, name)) for name in header["runs"][-1]["arrays"]]
    write_array_archive(path, members, header)


def read_prepared_runs(path: str | Path, arrays: Collection[str] | None = None,
                       ) -> tuple[list[MeasurementEntry], list[PreparedRun], dict[str, Any]]:
    """The file of :func:`write_prepared_runs`: (entries, prepared runs, settings), as they were written.
    ``arrays``: read only these of the runs' arrays (the others None; default: all): a 10-minute log at 1 kHz
    holds 32 MB per signal and run, and the fit never reads the commanded positions or the logged velocity."""
    import zipfile

    from sim2real.io import read_array_archive

    try:
        header, read = read_array_archive(path, None if arrays is None else lambda member: member.split("/")[-1] in arrays)
        entries, runs = [], []
        for i, item in enumerate(header["runs"]):
            own = {name: read[f"{i}/{name}"] for name in item["arrays"] if f"{i}/{name}" in read}
            entries.append(MeasurementEntry(item["entry"]["name"], Path(item["entry"]["path"]), item["entry"]["role"]))
            runs.append(PreparedRun(
                name=item["name"], joint_names=list(item["joint_names"]), dt=float(item["dt"]),
                torque_source=item["torque_source"], torque_sensor=item["torque_sensor"], filter=item["filter"],
                **{name: own.get(name) for name in _PREPARED_ARRAYS if name not in _SIGMAS},
                **{name: own.get(name, np.zeros(0)) for name in _SIGMAS},
            ))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(path, None, f"not a file of prepared runs ({exc})",
                         "rebuild it: snakemake --forcerun prepare_runs") from exc
    return entries, runs, dict(header["settings"])


def runs_for_model(
    source: str | Path, urdf_path: str | Path, root: str | Path = ".", arrays: Collection[str] | None = None,
) -> tuple[list[MeasurementEntry], list[PreparedRun], dict[str, Any]]:
    """Prepared runs from ``source``: a file of :func:`write_prepared_runs` (``.npz``), read back (``arrays``:
    only these, :func:`read_prepared_runs`), or a measurement list, read and prepared against the URDF
    (:func:`prepare_for_model`)."""
    if Path(source).suffix == PREPARED_SUFFIX:
        return read_prepared_runs(source, arrays)
    return prepare_for_model(source, urdf_path, root)


def write_run(
    path: str | Path, time: np.ndarray, joint_names: Sequence[str], signals: Mapping[str, np.ndarray],
    meta: Mapping[str, Any],
) -> None:
    """Write a run (CSV or Parquet by extension) plus its metadata YAML, atomically and deterministically."""
    import pandas as pd
    from sim2real.io import atomic_path, validate, write_yaml

    path = Path(path)
    columns: dict[str, np.ndarray] = {"time": np.asarray(time, dtype=float)}
    for kind in SIGNAL_KINDS:
        if kind in signals and signals[kind] is not None:
            for i, joint in enumerate(joint_names):
                columns[f"{kind}.{joint}"] = np.asarray(signals[kind], dtype=float)[:, i]
    frame = pd.DataFrame(columns)
    validate(dict(meta), "measurement.schema.yaml", path.with_suffix(".yaml"))
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".parquet":
            frame.to_parquet(tmp, index=False)
        else:
            frame.to_csv(tmp, index=False, float_format="%.9g")
    write_yaml(path.with_suffix(".yaml"), dict(meta))
