"""The lab's logger: what it writes of a played run (:mod:`.loop`), the torque sensor's reading through the chain
to the log, the stamps, the rows it loses, the lone glitches, at its own rate."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.filters import first_order_lag
from sim2real.lab.loop import _Hidden
from sim2real.lab.sensor_chain import chained_torque, held_positions, sensor_chain


def _logged(scenario: Mapping[str, Any], joints: Sequence[str],
            desired: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], played: Mapping[str, np.ndarray | None],
            hidden: _Hidden, dt: float, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """What the logger writes: the torque sensor's reading (lagged, scaled, offset, noisy, drifting) through the
    chain to the log (:mod:`sim2real.lab.sensor_chain`), the stamps (jittered), less the rows dropped, with lone
    glitches, at the logger's rate; the scenario's columns only."""
    sensors = scenario["sensors"]
    time, q_des = desired[0], desired[1]
    steps, n = played["q"].shape  # type: ignore[union-attr]
    seen = first_order_lag(played["link"] if played["link"] is not None else played["applied"], dt,
                          float(sensors.get("torque_time_constant_s", 0.0)))
    gain, bias = hidden.scales["torque_gain"], hidden.scales["torque_bias"]
    tau_sensor = gain * seen + bias + float(sensors["torque_noise_std"]) * rng.standard_normal((steps, n))
    if hidden.drift is not None:
        tau_sensor = tau_sensor + hidden.drift
    chain = sensor_chain(scenario)
    tau_sensor = chained_torque(tau_sensor, chain, joints, dt, rng, None)
    signals = {"q": held_positions(played["q"], chain, dt), "qd": played["qd"], "tau": tau_sensor,  # type: ignore[arg-type]
               "tau_cmd": played["cmd"], "q_cmd": q_des}
    columns = set(scenario["columns"])
    jitter = float(sensors.get("stamp_jitter_s", 0.0))
    if jitter > 0:
        # Stamps wander around the sample instants; a real logger never writes them out of order.
        stamps = time + jitter * rng.standard_normal(steps)
        time = np.maximum.accumulate(np.clip(stamps, time - 0.45 * dt, time + 0.45 * dt))
    logged = _logged_rows(time, sensors.get("dropouts") or {}, rng)
    # Lone samples off by a fixed size (a bus error, a flipped bit), drawn after the rest.
    _glitch(signals["tau"], (sensors.get("glitches") or {}).get("count", 0),
            (sensors.get("glitches") or {}).get("size_nm", 0.0), rng)
    _glitch(signals["q"], (sensors.get("encoder_glitches") or {}).get("count", 0),
            (sensors.get("encoder_glitches") or {}).get("size_rad", 0.0), rng)
    logged[np.arange(steps) % log_every(scenario) != 0] = False  # a logger slower than the controller
    return time[logged], {k: v[logged] for k, v in signals.items() if k in columns}  # type: ignore[index]


def _glitch(signal: np.ndarray, count: int, size: float, rng: np.random.Generator) -> None:
    """``count`` samples of ``signal`` (random rows and joints) moved by ``size`` either way, in place; no draw
    when there are none."""
    if int(count) > 0:
        rows, which = rng.choice(signal.shape[0], size=int(count), replace=False), rng.integers(signal.shape[1], size=int(count))
        signal[rows, which] += rng.choice([-1.0, 1.0], size=int(count)) * float(size)


def log_every(scenario: Mapping[str, Any]) -> int:
    """The logger writes every this many control steps: ``sensors.log_rate_hz`` (default: the control rate,
    ``sample_rate_hz``), rounded to a whole number of steps."""
    rate = float(scenario["sample_rate_hz"])
    return max(1, int(round(rate / float(scenario["sensors"].get("log_rate_hz") or rate))))


def _logged_rows(time: np.ndarray, dropouts: Mapping[str, Any], rng: np.random.Generator) -> np.ndarray:
    """The rows the logger keeps: all but ``dropouts.count`` stretches of ``dropouts.length_s`` each (a real
    logger loses samples: a full buffer, a dropped connection), one at a random place within each of ``count``
    equal slots of the run's middle 80 % (drawn last: the rest of the run is the same with or without them)."""
    count, length = int(dropouts.get("count", 0)), float(dropouts.get("length_s", 0.0))
    keep = np.ones(time.size, dtype=bool)
    if count <= 0 or length <= 0:
        return keep
    first, span = time[0] + 0.1 * (time[-1] - time[0]), 0.8 * (time[-1] - time[0])
    slot = span / count
    for k, u in enumerate(rng.uniform(size=count)):
        start = first + k * slot + u * max(slot - length, 0.0)
        keep &= ~((time >= start) & (time < start + length))
    return keep
