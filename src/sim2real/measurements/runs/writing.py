"""Writing a run in the measurement format (:mod:`.format`): the table and its metadata beside it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.measurements.records import RunMeta
from sim2real.measurements.runs.format import SIGNAL_KINDS


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
