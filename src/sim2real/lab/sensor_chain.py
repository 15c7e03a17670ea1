"""The torque sensor's chain between the sensor and the log (``sensors.chain`` of a scenario, any arm): what a real
arm's logger receives rather than the sensor's reading.

* ``low_pass_hz``: the reading, noise included, passes a first-order low-pass inside the chain (a drive's filtered
  torque estimate, a fieldbus's smoothing) before it is logged: the logged noise is no longer white.
* ``hold_s``: each joint's reading is updated every ``hold_s`` and held in between, on a log that is faster; the
  joints are polled in turn (each on its own phase, as a bus reads its drives one after another), so no row of the
  log repeats the previous one whole, yet most consecutive samples of a joint are equal.
* ``position_hold_s``: the logged positions are updated every ``position_hold_s`` (the encoders read more slowly
  than the torque) and held in between.
* ``run_offset_nm``: each run's torque sensor starts with an offset of its own, drawn per run and joint uniformly
  within +-this (a sensor zeroed anew at each start).

:func:`chained_torque` and :func:`held_positions` apply them to a run's signals at the control rate;
:func:`logged_noise_rms` is the noise the log then holds, for the lab's truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.filters import first_order_lag
from sim2real.lab.config import _per_joint


def sensor_chain(scenario: Mapping[str, Any]) -> Mapping[str, Any]:
    """The scenario's ``sensors.chain`` (empty: the reading is logged as it is)."""
    return scenario["sensors"].get("chain") or {}


def low_pass_time_constant(chain: Mapping[str, Any]) -> float:
    """The chain's first-order time constant, s (0: no low-pass)."""
    cutoff = chain.get("low_pass_hz")
    return 0.0 if not cutoff else 1.0 / (2.0 * np.pi * float(cutoff))


def chained_torque(reading: np.ndarray, chain: Mapping[str, Any], joints: Sequence[str], dt: float,
                   rng: np.random.Generator, path: Path | None) -> np.ndarray:
    """The torque ``reading`` (N, n), noise included, at the control step ``dt`` as the chain passes it on: offset
    by the run's draw, low-passed, held per joint; unchanged without a chain (and no draw from ``rng``)."""
    out = reading
    if chain.get("run_offset_nm") is not None:
        bound = _per_joint(chain["run_offset_nm"], joints, "sensors/chain/run_offset_nm", path)
        out = out + rng.uniform(-1.0, 1.0, size=len(joints)) * bound
    out = first_order_lag(out, dt, low_pass_time_constant(chain))
    if chain.get("hold_s"):
        out = held_per_joint(out, _steps(float(chain["hold_s"]), dt), staggered=True)
    return out


def held_positions(q: np.ndarray, chain: Mapping[str, Any], dt: float) -> np.ndarray:
    """The logged positions (N, n), updated every ``position_hold_s`` (all joints at once) and held in between."""
    if not chain.get("position_hold_s"):
        return q
    return held_per_joint(q, _steps(float(chain["position_hold_s"]), dt), staggered=False)


def held_per_joint(signal: np.ndarray, every: int, staggered: bool) -> np.ndarray:
    """``signal`` (N, n) updated every ``every`` samples and held in between; ``staggered``: joint j is updated
    ``j * every // n`` samples after joint 0 (polled in turn)."""
    if every <= 1:
        return signal
    steps, n = signal.shape
    rows = np.arange(steps)
    out = np.empty_like(signal)
    for j in range(n):
        phase = (j * every) // n if staggered else 0
        updated = np.maximum(((rows - phase) // every) * every + phase, 0)
        out[:, j] = signal[updated, j]
    return out


def _steps(seconds: float, dt: float) -> int:
    return max(1, int(round(seconds / dt)))


def logged_noise_rms(chain: Mapping[str, Any], noise_std: float, dt: float) -> float:
    """The RMS of the sensor's white noise (``noise_std`` at the control step ``dt``) as the log holds it: a first-order
    low-pass y_k = a y_(k-1) + (1 - a) x_k leaves (1 - a) / (1 + a) of its variance; a hold, an offset and a slower
    logger leave it as it is."""
    constant = low_pass_time_constant(chain)
    if constant <= 0:
        return float(noise_std)
    a = float(np.exp(-dt / constant))
    return float(noise_std * np.sqrt((1.0 - a) / (1.0 + a)))
