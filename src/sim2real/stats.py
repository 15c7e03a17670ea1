"""Error measures in the shape every report uses: {"overall": x, "per_joint": {joint: x}}."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def rmse(error: np.ndarray, joint_names: Sequence[str]) -> dict[str, object]:
    """Root-mean-square of an (N, n_joints) error: over all samples and joints, and per joint."""
    error = np.asarray(error, dtype=float)
    return joint_figures(float(np.sqrt(np.mean(error**2))), joint_names, np.sqrt(np.mean(error**2, axis=0)))


def joint_figures(overall: float, joint_names: Sequence[str], per_joint: Sequence[float]) -> dict[str, object]:
    """A figure over the arm (``overall``) and each joint's, in the shape every report uses."""
    return {"overall": float(overall),
            "per_joint": {name: float(v) for name, v in zip(joint_names, per_joint, strict=True)}}


def floor_multiple(x: float) -> str:
    """A residual in units of its noise floor as verdicts write it: "1.04x", "0.98x" (two decimals below 10x, where
    two significant digits would write both "1x"), "29x" from 10x up."""
    return f"{x:.0f}x" if abs(x) >= 10 else f"{x:.2f}x"
