"""Shared fixtures of the measurement/lab/gap tests: a small Panda model from example-robot-data.

The tests use the upstream Panda description directly (not the pipeline's build) so they run in
seconds and do not depend on the URDF/MJCF stages.
"""

from __future__ import annotations

import re
from pathlib import Path

import sys

import mujoco
import yaml

PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


def panda_description_dir() -> Path:
    for entry in sys.path:
        candidate = Path(entry or ".") / "cmeel.prefix/share/example-robot-data/robots/panda_description"
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("example-robot-data is not installed (pip install example-robot-data)")


def build_dev_panda(directory: Path) -> tuple[Path, Path]:
    """Collision-only Panda URDF (absolute mesh paths) and the MJCF MuJoCo makes of it."""
    base = panda_description_dir()
    text = (base / "urdf" / "panda.urdf").read_text(encoding="utf-8")
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    text = text.replace("package://example-robot-data/robots/panda_description/", f"{base.resolve()}/")
    directory.mkdir(parents=True, exist_ok=True)
    urdf = directory / "panda.urdf"
    urdf.write_text(text, encoding="utf-8")
    model = mujoco.MjModel.from_xml_path(str(urdf))
    mjcf = directory / "panda.xml"
    mujoco.mj_saveLastXML(str(mjcf), model)
    return urdf, mjcf


def short_lab_config(directory: Path, duration_s: float = 6.0) -> Path:
    """configs/panda/lab.yaml with shorter runs (same scenarios and effect sizes)."""
    repo = Path(__file__).resolve().parents[1]
    data = yaml.safe_load((repo / "configs" / "panda" / "lab.yaml").read_text(encoding="utf-8"))
    data["defaults"]["duration_s"] = duration_s
    for scenario in data["scenarios"].values():
        if scenario and "duration_s" in scenario:
            scenario["duration_s"] = duration_s
    path = directory / "lab.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path
