"""The runtime sampler: :class:`DomainRandomizer` turns dr.json and a base ``MjModel`` into a
randomized model in memory per episode (no file written), reproducible under a seed; action delay
through MuJoCo's actuator ``delay`` (history buffer, sized by :func:`load_model`); observation noise
per step from its own random stream.

Sampling happens in the *declared* space and the operation maps it onto the element's nominal value
(:func:`sim2real.dr.parameters.apply_operation`). A curriculum level with scale ``s`` shrinks each
range toward the nominal model, ``nominal + s * (declared range - nominal)``, and multiplies a noise
std by ``s``.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from scipy.special import ndtr, ndtri

from sim2real.dr.parameters import (
    CONST_CHANNELS,
    PARAMETER_BY_CHANNEL,
    Parameter,
    apply_operation,
    declared_nominal,
    fmt,
    geom_id,
    get_values,
    set_values,
)
from sim2real.dr.resolve import load_resolved
from sim2real.errors import InputError


def load_model(mjcf_path: str | Path, resolved: Mapping[str, Any]) -> mujoco.MjModel:
    """Compile the MJCF with actuator history buffers long enough for the randomized delay.

    MuJoCo sizes the buffer at compile time (``nsample``) and silently caps a longer runtime
    ``actuator_delay`` at it, so the buffer is widened here via MjSpec; nothing is written to disk.
    """
    spec = mujoco.MjSpec.from_file(str(mjcf_path))
    samples = int(resolved.get("actuator_history_samples", 0))
    delayed = {t["name"] for c in resolved["physics"] if c["channel"] == "delay" for t in c["targets"]}
    if samples:
        for actuator in spec.actuators:
            if actuator.name in delayed and actuator.nsample < samples:
                actuator.nsample = samples
    return spec.compile()


@dataclass
class _Channel:
    name: str
    parameter: Parameter
    mode: str
    distribution: str
    operation: str
    shared: bool
    ids: np.ndarray
    nominal: np.ndarray  # (n, width), absolute, from the base model
    anchor: np.ndarray  # nominal in declared space
    declared_lo: float
    declared_hi: float
    mean: float | None
    std: float | None
    # per-level arrays, filled by set_level
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    level_mean: np.ndarray | None = None
    level_std: float | None = None


@dataclass
class _Noise:
    term: str
    distribution: str
    mean: float
    std: float
    lo: float
    hi: float
    read: Callable[[mujoco.MjData], np.ndarray]
    names: list[str]
    level_scale: float = 1.0


class DomainRandomizer:
    """Randomized copies of a base model, per episode, in memory.

    ``reset()`` redraws every ``reset``-mode parameter into ``self.model`` (one working model,
    updated in place: cheap enough for every episode) and returns it; ``startup`` parameters are
    drawn once at construction. ``sample()`` returns an independent deep copy instead.
    The same ``seed`` gives the same sequence of models; observation noise uses its own stream,
    so the number of observations taken does not change the models drawn.
    """

    def __init__(
        self,
        resolved: Mapping[str, Any],
        base_model: mujoco.MjModel,
        *,
        seed: int | None = 0,
        level: str | None = None,
    ) -> None:
        self.resolved = resolved
        self.base_model = base_model
        self.model = copy.deepcopy(base_model)
        self._scratch = mujoco.MjData(self.model)
        model_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        self.rng = np.random.default_rng(model_seed)
        self.noise_rng = np.random.default_rng(noise_seed)
        self.levels = {lvl["name"]: float(lvl["scale"]) for lvl in resolved["curriculum"]["levels"]}
        self.channels = [self._compile_channel(c) for c in resolved["physics"]]
        self.noise = [self._compile_noise(n) for n in resolved["observation_noise"]]
        self.last_draw: dict[str, np.ndarray] = {}
        self._check_delay_capacity()
        self.set_level(level or resolved["curriculum"]["default_level"])
        self._draw(("startup",))

    @classmethod
    def from_files(
        cls, dr_json: str | Path, mjcf_path: str | Path, *, seed: int | None = 0, level: str | None = None
    ) -> DomainRandomizer:
        resolved = load_resolved(dr_json)
        return cls(resolved, load_model(mjcf_path, resolved), seed=seed, level=level)

    # -- construction ------------------------------------------------------------------------

    def _ids(self, obj: mujoco.mjtObj, names: Sequence[str], where: str) -> np.ndarray:
        ids = []
        for name in names:
            if obj == mujoco.mjtObj.mjOBJ_GEOM:
                element_id = geom_id(self.base_model, name)
            else:
                element_id = mujoco.mj_name2id(self.base_model, obj, name)
            if element_id < 0:
                raise InputError(
                    None,
                    where,
                    f"element '{name}' of dr.json is not in the base model",
                    "rebuild dr.json from the same MJCF (snakemake all) or pass the matching model",
                )
            ids.append(element_id)
        return np.array(ids, dtype=int)

    def _compile_channel(self, c: Mapping[str, Any]) -> _Channel:
        parameter = PARAMETER_BY_CHANNEL[c["channel"]]
        obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "geom": mujoco.mjtObj.mjOBJ_GEOM, "joint": mujoco.mjtObj.mjOBJ_JOINT,
               "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR}.get(parameter.element)
        names = [t["name"] for t in c["targets"]]
        where = f"dr.json physics '{c['term']}/{c['channel']}'"
        if parameter.channel == "base_tilt":  # a model channel whose element is the root body, by name
            obj = mujoco.mjtObj.mjOBJ_BODY
        ids = np.zeros(1, dtype=int) if obj is None else self._ids(obj, names, where)
        nominal = get_values(self.base_model, parameter.channel, ids)
        return _Channel(
            name=f"{c['term']}/{c['channel']}",
            parameter=parameter,
            mode=c["mode"],
            distribution=c["distribution"],
            operation=c["operation"],
            shared=bool(c.get("shared", False)),
            ids=ids,
            nominal=nominal,
            anchor=declared_nominal(c["operation"], nominal),
            declared_lo=float(c["range"][0]),
            declared_hi=float(c["range"][1]),
            mean=c.get("mean"),
            std=c.get("std"),
        )

    def _compile_noise(self, n: Mapping[str, Any]) -> _Noise:
        names = [t["name"] for t in n["targets"]]
        if n["element"] == "joint":
            ids = self._ids(mujoco.mjtObj.mjOBJ_JOINT, names, f"dr.json observation_noise '{n['term']}'")
            index = self.base_model.jnt_qposadr[ids] if n["term"] == "joint_position" else self.base_model.jnt_dofadr[ids]
            field = "qpos" if n["term"] == "joint_position" else "qvel"

            def read(data: mujoco.MjData, index: np.ndarray = index, field: str = field) -> np.ndarray:
                return getattr(data, field)[index]
        else:
            ids = self._ids(mujoco.mjtObj.mjOBJ_SENSOR, names, f"dr.json observation_noise '{n['term']}'")
            index = np.concatenate(
                [np.arange(a, a + d) for a, d in zip(self.base_model.sensor_adr[ids], self.base_model.sensor_dim[ids])]
            )

            def read(data: mujoco.MjData, index: np.ndarray = index) -> np.ndarray:
                return data.sensordata[index]

        lo, hi = n.get("range", [0.0, 0.0])
        return _Noise(n["term"], n["distribution"], float(n.get("mean", 0.0)), float(n.get("std", 0.0)), float(lo), float(hi), read, names)

    def _check_delay_capacity(self) -> None:
        timestep = float(self.base_model.opt.timestep)
        for channel in self.channels:
            if channel.parameter.channel != "delay":
                continue
            needed = int(math.ceil(max(channel.declared_hi, float(channel.nominal.max())) / timestep - 1e-9))
            for element_id in channel.ids:
                held = int(self.base_model.actuator_history[element_id, 0])
                if held < needed:
                    name = mujoco.mj_id2name(self.base_model, mujoco.mjtObj.mjOBJ_ACTUATOR, int(element_id))
                    raise InputError(
                        None,
                        f"actuator '{name}'",
                        f"its history buffer holds {held} samples ({fmt(held * timestep)} s) but action_delay reaches "
                        f"{fmt(channel.declared_hi)} s; MuJoCo would silently cap the delay",
                        "load the model with sim2real.dr.load_model(mjcf, resolved) (or DomainRandomizer.from_files), "
                        f"or set nsample=\"{needed + 1}\" on the actuator in the MJCF",
                    )

    # -- curriculum --------------------------------------------------------------------------

    def set_level(self, level: str) -> None:
        """Shrink every range toward the nominal model by the level's scale (see module doc)."""
        if level not in self.levels:
            raise InputError(None, f"curriculum level '{level}'", "is not defined in dr.json", f"use one of: {', '.join(self.levels)}")
        self.level = level
        s = self.levels[level]
        for c in self.channels:
            c.lo = c.anchor + s * (c.declared_lo - c.anchor)
            c.hi = c.anchor + s * (c.declared_hi - c.anchor)
            if c.distribution == "gaussian":
                c.level_mean = c.anchor + s * (float(c.mean or 0.0) - c.anchor)
                c.level_std = float(c.std or 0.0) * s
        for n in self.noise:
            n.level_scale = s

    # -- sampling ----------------------------------------------------------------------------

    def _declared_draw(self, c: _Channel) -> np.ndarray:
        assert c.lo is not None and c.hi is not None
        shape = (1, c.parameter.width) if c.shared else c.nominal.shape
        u = self.rng.random(shape)
        if c.distribution == "uniform":
            return c.lo + (c.hi - c.lo) * u
        if c.distribution == "log_uniform":
            log_lo, log_hi = np.log(c.lo), np.log(c.hi)
            return np.exp(log_lo + (log_hi - log_lo) * u)
        # Truncated gaussian by inverse CDF: exact, and one uniform per value keeps streams aligned.
        assert c.level_mean is not None and c.level_std is not None
        a = ndtr((c.lo - c.level_mean) / c.level_std)
        b = ndtr((c.hi - c.level_mean) / c.level_std)
        return np.clip(c.level_mean + c.level_std * ndtri(a + (b - a) * u), c.lo, c.hi)

    def _draw(self, modes: Sequence[str]) -> None:
        touched_const = False
        for c in self.channels:
            if c.mode not in modes:
                continue
            declared = self._declared_draw(c)
            values = apply_operation(c.operation, c.nominal, declared)
            set_values(self.model, self.base_model, c.parameter.channel, c.ids, values)
            self.last_draw[c.name] = values
            touched_const |= c.parameter.channel in CONST_CHANNELS
        if touched_const:
            # Keep the qpos0-derived constants (subtree mass, inverse weights) as a compile would.
            mujoco.mj_setConst(self.model, self._scratch)

    def reset(self) -> mujoco.MjModel:
        """Redraw every reset-mode parameter into ``self.model`` and return it (in place)."""
        self._draw(("reset",))
        return self.model

    def sample(self) -> mujoco.MjModel:
        """An independent randomized model (deep copy): for keeping several models alive."""
        return copy.deepcopy(self.reset())

    def reset_data(self, data: mujoco.MjData, ctrl: np.ndarray | None = None, keyframe: int | None = None) -> None:
        """Reset ``data`` for the current model (to ``keyframe`` when given, which also sets its
        ctrl), optionally override ``ctrl``, and hold that command in every actuator history, so a
        delayed actuator starts from it instead of replaying zeros for the length of the delay."""
        if keyframe is None:
            mujoco.mj_resetData(self.model, data)
        else:
            mujoco.mj_resetDataKeyframe(self.model, data, keyframe)
        if ctrl is not None:
            data.ctrl[:] = ctrl
        for actuator_id in range(self.model.nu):
            samples = int(self.model.actuator_history[actuator_id, 0])
            if samples > 0:
                value = np.full((samples, 1), float(data.ctrl[actuator_id]))
                mujoco.mj_initCtrlHistory(self.model, data, actuator_id, None, value)
        mujoco.mj_forward(self.model, data)

    # -- observation noise -------------------------------------------------------------------

    def add_noise(self, term: str, values: np.ndarray) -> np.ndarray:
        """``values`` (ordered as the term's targets in dr.json) plus one step of noise."""
        noise = next((n for n in self.noise if n.term == term), None)
        if noise is None:
            raise InputError(None, f"observation noise '{term}'", "is not declared in dr.json",
                             f"declare it under observation_noise in dr.yaml, or use one of: {', '.join(n.term for n in self.noise)}")
        values = np.asarray(values, dtype=float)
        s = noise.level_scale
        if noise.distribution == "gaussian":
            return values + s * noise.mean + s * noise.std * self.noise_rng.standard_normal(values.shape)
        return values + s * self.noise_rng.uniform(noise.lo, noise.hi, values.shape)

    def observe(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Noisy observations of every declared noise term, read from ``data``."""
        return {n.term: self.add_noise(n.term, n.read(data)) for n in self.noise}
