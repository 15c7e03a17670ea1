"""The current model's holdout residual as every decision of the diagnosis reads it (:class:`CurrentResidual`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.identification import fitting


@dataclass(frozen=True)
class CurrentResidual:
    """The current model's holdout residual (judged minus predicted torque, N*m) and its measures, each joint in units
    of its own noise floor (:func:`sim2real.identification.fitting.joint_weights`, the weights of the fit too): a wrist
    residual 8x its floor weighs what a shoulder residual 8x its floor weighs, whatever their N*m.

    ``unit``: each joint's unit (N*m); ``scaled``: the residual in those units; ``sse``: its squared sum per joint;
    ``excess``: that sum above white noise at the floor; ``x_floor``: its RMS per joint; ``noise``: the floors' RMS,
    arm-wide (N*m)."""

    residual: np.ndarray
    unit: np.ndarray
    scaled: np.ndarray
    sse: np.ndarray
    excess: np.ndarray
    x_floor: np.ndarray
    noise: float

    @classmethod
    def of(cls, residual: np.ndarray, noise_floor: np.ndarray) -> CurrentResidual:
        floor = np.asarray(noise_floor, dtype=float)
        noise = float(np.sqrt(np.mean(floor**2)))
        unit = noise / fitting.joint_weights(floor) if noise > 0 else np.ones(residual.shape[1])
        scaled = residual / unit
        sse = np.sum(scaled**2, axis=0)
        rows = residual.shape[0]
        return cls(residual=residual, unit=unit, scaled=scaled, sse=sse,
                   excess=np.clip(sse - rows, 0.0, None), x_floor=np.sqrt(sse / max(rows, 1)), noise=noise)

    @property
    def rows(self) -> int:
        return int(self.residual.shape[0])

    @property
    def total(self) -> float:
        """The squared residual summed over joints, in floor units."""
        return float(self.sse.sum())

    @property
    def rmse(self) -> float:
        """The residual's RMS over every joint and sample, N*m."""
        return float(np.sqrt(np.mean(self.residual**2)))

    @property
    def ratio(self) -> float:
        """The residual's RMS x the floors, arm-wide."""
        return float(np.sqrt(np.mean(self.x_floor**2)))
