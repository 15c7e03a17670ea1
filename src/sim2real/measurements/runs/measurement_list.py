"""The measurement list (``configs/{robot}/measurements.yaml``): its runs, each with its role, and its settings.

A rule reads each run file once: :func:`read_runs` reads every run of a measurement list; the caller
builds its model from the runs' joints and prepares them (:mod:`sim2real.measurements.prepare`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sim2real.errors import InputError
from sim2real.files import read_validated_yaml
from sim2real.measurements.runs.format import (
    DEFAULT_CUTOFF_HZ, DEFAULT_FILTER_ORDER, MeasurementEntry, Run, RunSet,
)
from sim2real.measurements.runs.reading import read_run


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

    Parameters
    ----------
    measurement_list : str or Path
        ``measurements.yaml``: the runs (``name``, ``path``, ``role``: fit or holdout) and the settings.
    root : str or Path, default "."
        The directory the list's paths are relative to.

    Returns
    -------
    RunSet[Run]
        The runs, each named as in the list with its line (``entry``), and ``settings`` (filter, replay, gaps).

    Raises
    ------
    InputError
        The list or a run breaks its schema or format, two runs share a name, or the runs log different joints.

    Examples
    --------
    >>> runs = read_runs(example_dir / "measurements.yaml", root=example_dir)
    >>> [(run.name, run.entry.role) for run in runs]
    [('fit', 'fit'), ('holdout', 'holdout')]
    >>> runs[0].joint_names[:2], runs[0].q.shape, runs.settings["cutoff_hz"]
    (['panda_joint1', 'panda_joint2'], (750, 7), 10.0)
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
