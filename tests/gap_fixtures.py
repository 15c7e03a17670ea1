"""Shared fixtures of the measurement/lab/gap tests: a small Panda (or UR5) model from example-robot-data.

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


def description_dir(name: str) -> Path:
    """example-robot-data's ``robots/<name>`` (``panda_description``, ``ur_description``)."""
    for entry in sys.path:
        candidate = Path(entry or ".") / "cmeel.prefix/share/example-robot-data/robots" / name
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("example-robot-data is not installed (pip install example-robot-data)")


def panda_description_dir() -> Path:
    return description_dir("panda_description")


def build_dev_panda(directory: Path) -> tuple[Path, Path]:
    """Collision-only Panda URDF (absolute mesh paths) and the MJCF MuJoCo makes of it."""
    return _build_dev(directory, "panda_description", "urdf/panda.urdf", "panda")


def build_dev_ur5(directory: Path) -> tuple[Path, Path]:
    """Collision-only UR5 URDF (absolute mesh paths) and the MJCF MuJoCo makes of it."""
    return _build_dev(directory, "ur_description", "urdf/ur5_robot.urdf", "ur5")


def build_dev_iiwa14(directory: Path) -> tuple[Path, Path]:
    """The shipped iiwa 14 (robots/iiwa14, primitives only, bare flange) as URDF and the MJCF MuJoCo makes of it."""
    from sim2real.assets.urdf import build_urdf

    repo = Path(__file__).resolve().parents[1]
    directory.mkdir(parents=True, exist_ok=True)
    urdf = directory / "iiwa14.urdf"
    build_urdf(repo / "robots/iiwa14/iiwa14.urdf.xacro", urdf, {"tool": "none"})
    return urdf, _mjcf_of(urdf, directory / "iiwa14.xml")


def _mjcf_of(urdf: Path, mjcf: Path) -> Path:
    model = mujoco.MjModel.from_xml_path(str(urdf))
    mujoco.mj_saveLastXML(str(mjcf), model)
    return mjcf


def _build_dev(directory: Path, description: str, urdf_file: str, robot: str) -> tuple[Path, Path]:
    base = description_dir(description)
    text = (base / urdf_file).read_text(encoding="utf-8")
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    text = text.replace(f"package://example-robot-data/robots/{description}/", f"{base.resolve()}/")
    directory.mkdir(parents=True, exist_ok=True)
    urdf = directory / f"{robot}.urdf"
    urdf.write_text(text, encoding="utf-8")
    return urdf, _mjcf_of(urdf, directory / f"{robot}.xml")


def short_lab_config(directory: Path, duration_s: float = 6.0, robot: str = "panda") -> Path:
    """configs/<robot>/lab.yaml with shorter runs (same scenarios and effect sizes)."""
    repo = Path(__file__).resolve().parents[1]
    data = yaml.safe_load((repo / "configs" / robot / "lab.yaml").read_text(encoding="utf-8"))
    data["defaults"]["duration_s"] = duration_s
    for scenario in data["scenarios"].values():
        if scenario and "duration_s" in scenario:
            scenario["duration_s"] = duration_s
    path = directory / "lab.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path
