"""Prepared runs on disk (the rule ``prepare_runs``): :func:`write_prepared_runs` once, for the sysid and gap report
rules, which read them back (:func:`read_prepared_runs`; :func:`runs_for_model` takes either a measurement list or
that file): a change of model.yaml prepares nothing again."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.measurements.prepare import prepare_for_model
from sim2real.measurements.records import FilterSettings, SensorPlacement
from sim2real.measurements.runs import MeasurementEntry, PreparedRun, RunSet

# Prepared runs on disk (the rule ``prepare_runs``): one zip of .npy arrays and a JSON header, written with
# fixed member times so that the same runs give the same bytes.
PREPARED_SUFFIX = ".npz"
_PREPARED_ARRAYS = ("time", "q", "qd", "qdd", "tau", "tau_cmd", "q_cmd", "qd_measured", "contact", "raw_torque_sigma",
                    "command_torque_sigma")
_SIGMAS = ("raw_torque_sigma", "command_torque_sigma")  # always arrays (empty when unknown)
# What the fit reads of the prepared runs (sim2real.identification.sysid.run_sysid): not the commanded positions, the logged
# velocity or the contacts.
FIT_ARRAYS = ("time", "q", "qd", "qdd", "tau", "tau_cmd", *_SIGMAS)


def write_prepared_runs(path: str | Path, runs: RunSet[PreparedRun]) -> None:
    """Prepared runs (:func:`prepare_for_model`, each with its line of the measurement list) in one file that
    :func:`read_prepared_runs` reads back exactly."""
    from sim2real.files import write_array_archive

    header: dict[str, Any] = {"settings": dict(runs.settings), "runs": []}
    members = []
    for i, run in enumerate(runs):
        entry = run.entry
        if entry is None or run.filter is None:
            raise ValueError(f"prepared run {run.name} has no line of a measurement list or no preparation record")
        header["runs"].append({
            "entry": {"name": entry.name, "path": Path(entry.path).as_posix(), "role": entry.role},
            "name": run.name, "joint_names": list(run.joint_names), "dt": float(run.dt),
            "torque_source": run.torque_source, "torque_sensor": run.torque_sensor,
            "filter": run.filter.as_document(),
            "arrays": [a for a in _PREPARED_ARRAYS if getattr(run, a) is not None],
        })
        members += [(f"{i}/{name}", getattr(run, name)) for name in header["runs"][-1]["arrays"]]
    write_array_archive(path, members, header)


def read_prepared_runs(path: str | Path, arrays: Collection[str] | None = None) -> RunSet[PreparedRun]:
    """The file of :func:`write_prepared_runs`: the prepared runs, their lines of the list and the settings, as
    they were written.
    ``arrays``: read only these of the runs' arrays (the others None; default: all): a 10-minute log at 1 kHz
    holds 32 MB per signal and run, and the fit never reads the commanded positions or the logged velocity."""
    import zipfile

    from sim2real.files import read_array_archive

    try:
        header, read = read_array_archive(path, None if arrays is None else lambda member: member.split("/")[-1] in arrays)
        runs = []
        for i, item in enumerate(header["runs"]):
            own = {name: read[f"{i}/{name}"] for name in item["arrays"] if f"{i}/{name}" in read}
            runs.append(PreparedRun(
                name=item["name"], joint_names=list(item["joint_names"]), dt=float(item["dt"]),
                torque_source=item["torque_source"], torque_sensor=SensorPlacement(item["torque_sensor"]),
                filter=FilterSettings.from_document(item["filter"]),
                **{name: own.get(name) for name in _PREPARED_ARRAYS if name not in _SIGMAS},
                **{name: own.get(name, np.zeros(0)) for name in _SIGMAS},
                entry=MeasurementEntry(item["entry"]["name"], Path(item["entry"]["path"]), item["entry"]["role"]),
            ))
    except (OSError, KeyError, TypeError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(path, None, f"not a file of prepared runs ({exc})",
                         "rebuild it: snakemake --forcerun prepare_runs") from exc
    return RunSet(tuple(runs), dict(header["settings"]))


def runs_for_model(
    source: str | Path, urdf_path: str | Path, root: str | Path = ".", arrays: Collection[str] | None = None,
) -> RunSet[PreparedRun]:
    """Prepared runs from ``source``: a file of :func:`write_prepared_runs` (``.npz``), read back (``arrays``:
    only these, :func:`read_prepared_runs`), or a measurement list, read and prepared against the URDF
    (:func:`prepare_for_model`)."""
    if Path(source).suffix == PREPARED_SUFFIX:
        return read_prepared_runs(source, arrays)
    return prepare_for_model(source, urdf_path, root)
