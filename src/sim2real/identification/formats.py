"""The sysid rule's files, each read and written here alone: ``ladder.json`` (:func:`write_ladder`,
:func:`read_ladder`), ``params.yaml`` (:func:`write_params`, :func:`read_params`) and ``residuals.npz``, the body
side's last rung on every run (:class:`ModelResiduals`: :func:`write_model_residuals`, :func:`read_model_residuals`).

The prepared runs (``prepared_runs.npz``) are the measurements stage's: :mod:`sim2real.measurements.store`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.identification.records import SensorPlacement, Side

# The arrays of each role in residuals.npz, in the order they are written.
RESIDUAL_ARRAYS = ("time", "q", "qd", "qdd", "tau", "residual")
ROLES = ("fit", "holdout")


def write_ladder(path: str | Path, document: Mapping[str, Any]) -> None:
    """ladder.json: :func:`sim2real.identification.sysid.fit_model`'s document (sorted keys, stable bytes)."""
    from sim2real.files import write_json

    write_json(path, document)


def read_ladder(path: str | Path) -> dict[str, Any]:
    """The document of :func:`write_ladder`."""
    import json

    return json.loads(Path(path).read_text(encoding="utf-8"))


def write_params(path: str | Path, params: Mapping[str, Any]) -> None:
    """params.yaml: :func:`sim2real.identification.documents.params_document`'s document."""
    from sim2real.files import write_yaml

    write_yaml(path, params)


def read_params(path: str | Path) -> dict[str, Any]:
    """The document of :func:`write_params` (an empty file: no parameters)."""
    from sim2real.files import read_yaml

    return read_yaml(path) or {}


@dataclasses.dataclass(frozen=True)
class RoleResiduals:
    """One role's runs stacked at the fit's rate: their motion, judged torque and the current model's residual
    (judged minus predicted torque), each run's rows (``runs``: name, start, stop) and each joint's noise floor."""

    runs: tuple[tuple[str, int, int], ...]
    noise_floor: np.ndarray
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    residual: np.ndarray

    def by_run(self) -> Iterator[tuple[str, dict[str, np.ndarray]]]:
        """Each run's name and its rows of :data:`RESIDUAL_ARRAYS`."""
        for name, start, stop in self.runs:
            yield name, {array: getattr(self, array)[start:stop] for array in RESIDUAL_ARRAYS}


@dataclasses.dataclass(frozen=True)
class ModelResiduals:
    """The current model (the body side's last rung, ``effects``, on ``side``) on every run by role: what the gap
    report judges it by. ``roles`` holds ``fit`` and ``holdout``, or only those read back."""

    side: Side
    effects: tuple[str, ...]
    joints: tuple[str, ...]
    torque_source: str
    torque_sensor: SensorPlacement
    roles: Mapping[str, RoleResiduals]


def write_model_residuals(path: str | Path, residuals: ModelResiduals) -> None:
    """residuals.npz: an array archive (:func:`sim2real.files.write_array_archive`) of each role's arrays
    (``{role}/{array}``) and a header of the rest."""
    from sim2real.files import write_array_archive

    header: dict[str, Any] = {"link": str(residuals.side), "effects": list(residuals.effects),
                              "joints": list(residuals.joints), "torque_source": residuals.torque_source,
                              "torque_sensor": residuals.torque_sensor, "roles": {}}
    members = []
    for role, part in residuals.roles.items():
        header["roles"][role] = {"noise_floor": [float(v) for v in part.noise_floor],
                                 "runs": [{"name": name, "start": start, "stop": stop}
                                          for name, start, stop in part.runs]}
        members += [(f"{role}/{array}", getattr(part, array)) for array in RESIDUAL_ARRAYS]
    write_array_archive(path, members, header)


def read_model_residuals(path: str | Path, roles: Collection[str] = ROLES) -> ModelResiduals:
    """The file of :func:`write_model_residuals`, with the arrays of ``roles`` only. Raises OSError, KeyError,
    ValueError or zipfile.BadZipFile on a file of another kind."""
    from sim2real.files import read_array_archive

    header, arrays = read_array_archive(path, lambda name: name.partition("/")[0] in roles)
    parts = {}
    for role in roles:
        own = header["roles"][role]
        parts[role] = RoleResiduals(
            runs=tuple((run["name"], int(run["start"]), int(run["stop"])) for run in own["runs"]),
            noise_floor=np.asarray(own["noise_floor"], dtype=float),
            **{array: arrays[f"{role}/{array}"] for array in RESIDUAL_ARRAYS})
    return ModelResiduals(side=Side(header["link"]), effects=tuple(header["effects"]), joints=tuple(header["joints"]),
                          torque_source=header["torque_source"], torque_sensor=SensorPlacement(header["torque_sensor"]), roles=parts)
