"""A base mounted off level, written into an MJCF: the world (and a scene's floor) stays level, the base turns."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.assets.mjcf_geometry import rpy_to_quat


def turn_base_body(spec: Any, tilt_x: float, tilt_y: float) -> None:
    """Turn the robot's base body (the first child of the world) about the world's origin by ``tilt_x`` about the
    world's x, then ``tilt_y`` about the world's y (a URDF origin's ``rpy = (tilt_x, tilt_y, 0)``), in place, after
    whatever placement it has."""
    import mujoco

    base = spec.worldbody.first_body()
    if base is None:
        return
    turn = np.array(rpy_to_quat([float(tilt_x), float(tilt_y), 0.0]))
    out, pos = np.zeros(4), np.zeros(3)
    mujoco.mju_mulQuat(out, turn, np.asarray(base.quat, dtype=float))
    mujoco.mju_rotVecQuat(pos, np.asarray(base.pos, dtype=float), turn)
    base.quat, base.pos = out, pos
