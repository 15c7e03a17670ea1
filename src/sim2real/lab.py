"""Virtual lab: a simulated robot with hidden physical effects that writes measurement runs.

The lab stands in for the real arm. Its "reality" is the built MJCF plus hidden effects that the
lab implements ITSELF (it never imports the fit-side effect code), so a diagnosis that finds them
has learnt them from the data alone.

Hidden effect vocabulary (``configs/{robot}/lab.yaml``, per-joint values as a scalar, a list in
joint order or a ``{joint: value}`` map):

* ``viscous_friction`` ``{coefficient}`` N*m*s/rad: added to the joint damping (implicit in MuJoCo).
* ``coulomb_friction`` ``{coefficient}`` N*m: MuJoCo ``frictionloss`` (sticks at reversals like real
  dry friction); or ``{model: gaz_sigmoid, phi1, phi2, phi3}`` (Gaz et al. 2019):
  tau_f = phi1/(1+exp(-phi2*(qd+phi3))) - phi1/(1+exp(-phi2*phi3)), applied as a passive torque.
  Options of either model: ``stribeck: {peak, velocity}`` adds a Stribeck hump
  peak*exp(-(qd/velocity)^2)*tanh(qd/0.005) opposing the motion (a passive torque; not the fit library's
  tanh/viscous forms); ``after_sensor`` (0..1 per joint) is the share of the joint's friction acting
  between a link-side torque sensor and the link (output bearings, seals): the motion is unchanged, but
  that sensor then sees the share (see ``tau`` below).
* ``rotor_inertia`` ``{armature}`` kg*m^2: added to the joint armature.
* ``actuation_delay`` ``{delay_s}``: the applied torque is the command delayed by delay_s.
* ``actuator_gain`` ``{gain}`` and ``command_bias`` ``{bias}`` N*m: the motor applies
  gain * (delayed command) + bias, as a motor constant off by some percent or a drive's current offset
  would; a motor-side torque sensor measures that applied torque (a link-side one what reaches the link).
* ``payload`` ``{mass, com?, body?}``: a point-ish mass at the flange (last body), added with MjSpec.
* ``link_inertia`` ``{scale?, mass_scale?, com_offset?}``: the body moved by each joint made heavier or
  lighter (``scale``/``mass_scale``: mass and inertia about the COM multiplied, as a denser or larger
  part would be) and its centre of mass moved (``com_offset``: ``{joint: [x, y, z]}`` m in the body
  frame), as a real arm's links differ from their CAD values.
* ``torque_bias`` ``{bias}`` N*m and ``torque_gain`` ``{gain}``: sensor side, see below.
* ``hysteretic_friction`` ``{level, presliding_rad}``: Dahl friction in the drive, level * z with
  z' = (1 - z sign(dq)) dq / presliding_rad, a passive torque whose state is integrated along the simulated
  motion (:func:`dahl_step`): hysteresis around every reversal, which no static friction law follows.
* ``cogging`` ``{amplitude, period_rad?}``: a detent torque amplitude * sin(2 pi q / period_rad), a function of
  the joint's position that the fit library has no effect for.
* ``torque_drift`` ``{amplitude, time_constant_s?}``: the torque sensor warms up, its offset drifting as
  level * (1 - exp(-t / time_constant_s)) with a level drawn anew in every run (0.5 to 1.5 x amplitude, either
  sign): nothing of the motion explains it.

Column semantics of the written runs:

* ``q.<j>``: joint position from the encoder, quantized to ``sensors.encoder_resolution_rad``.
* ``qd.<j>``: the velocity the controller uses: true velocity plus ``sensors.velocity_noise_std``.
* ``tau_cmd.<j>``: the controller's command at that stamp (PD + gravity or computed torque, both on
  the NOMINAL model, fed by the noisy sensors).
* ``tau.<j>``: the joint torque sensor: the torque it sees times ``torque_gain`` plus ``torque_bias``
  plus white noise ``sensors.torque_noise_std``. Where it sits is ``sensors.torque_sensor``:

  - ``motor`` (the default, every scenario but the ``link_side_*`` ones): at the motor output, it sees the
    applied torque (the command after any delay, through the motor's gain and offset), before the
    joint's rotor inertia, damping and friction (a motor-current estimate).
  - ``link`` (``link_side_sensor``, ``link_side_tau_only``; the Panda's ``tau_J``, a KUKA iiwa's sensors):
    after the gearbox, it sees the torque transmitted to the link, the rigid-body inverse dynamics of the
    real arm (its hidden link inertias and payload included) at the true state and acceleration of the
    sample, without the drive terms: the applied torque minus armature * qdd, damping * qd and the joint's
    friction (frictionloss, Gaz, Stribeck). Rotor inertia and joint friction then lie between ``tau_cmd``
    and ``tau``, but for ``coulomb_friction``'s ``after_sensor`` share: tau = inverse dynamics +
    after_sensor * the joint's friction torque (passive ones at the sample's true velocity, frictionloss
    as the solver's force), as a real Panda's tau_J shows friction.

  The run's metadata says which (``torque_sensor: motor|link``) whenever it logs ``tau``.
* ``time``: the logger's stamps: the sample instants plus Gaussian ``sensors.stamp_jitter_s`` (kept
  increasing), like a real log whose stamps wander around the control period.
* ``q_cmd.<j>``: the desired trajectory.

A scenario lists the columns it writes (e.g. a delay scenario writes only ``tau_cmd``, like an arm
without torque sensors). Contacts are disabled: lab runs are free-space identification motions.
The excitation is a finite Fourier series (Swevers et al.): 5 harmonics of base 0.15*pi rad/s by
default, scaled to stay inside the position and velocity limits.

One piece (~620 lines): the hidden effects, the controller and the sensors act inside one simulation
loop (:func:`simulate_run`) on the same models and state, and the config's validation names their keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import InputError
from sim2real.files import merge_settings, read_validated_yaml, write_yaml

EFFECTS = (
    "viscous_friction",
    "coulomb_friction",
    "hysteretic_friction",
    "cogging",
    "torque_drift",
    "rotor_inertia",
    "actuation_delay",
    "payload",
    "link_inertia",
    "torque_bias",
    "torque_gain",
    "actuator_gain",
    "command_bias",
)

DEFAULTS: dict[str, Any] = {
    "duration_s": 20.0,
    "sample_rate_hz": 1000.0,
    "substeps": 1,
    "columns": ["q", "qd", "tau", "tau_cmd", "q_cmd"],
    "controller": {"type": "computed_torque", "kp": 400.0, "kd": 40.0},
    "excitation": {
        "harmonics": 5,
        "base_frequency_rad_s": 0.15 * np.pi,
        "position_fraction": 0.6,
        "velocity_fraction": 0.6,
    },
    "sensors": {"torque_noise_std": 0.05, "encoder_resolution_rad": 1.0e-6, "velocity_noise_std": 0.002,
                "torque_sensor": "motor"},
    "effects": {},
}


# ---------------------------------------------------------------------------------------------
# configuration


def load_lab_config(path: str | Path) -> dict[str, Any]:
    """Validated lab.yaml with defaults merged into every scenario: {joints, scenarios: {name: settings}}."""
    path = Path(path)
    data = read_validated_yaml(path, "lab.schema.yaml")
    base = merge_settings(DEFAULTS, data.get("defaults", {}), replace=("effects",))
    scenarios = {name: merge_settings(base, spec or {}, replace=("effects",))
                 for name, spec in data["scenarios"].items()}
    for name, scenario in scenarios.items():
        if not scenario.get("runs"):
            raise InputError(path, f"scenarios/{name}/runs", "no runs: neither the scenario nor defaults lists any",
                             "list runs under defaults: (or the scenario), e.g. runs: [{name: fit, seed: 1, role: fit}, "
                             "{name: holdout, seed: 2, role: holdout}]")
        names = [run["name"] for run in scenario["runs"]]
        if len(set(names)) != len(names):
            raise InputError(path, f"scenarios/{name}/runs", "duplicate run names", "give each run a unique name")
        if "q" not in scenario["columns"] or not {"tau", "tau_cmd"} & set(scenario["columns"]):
            raise InputError(path, f"scenarios/{name}/columns", "must contain q and tau or tau_cmd",
                             "add q and at least one torque column")
    return {"joints": list(data["joints"]), "scenarios": scenarios, "path": path}


def scenario_runs(config_path: str | Path, scenario: str) -> list[dict[str, Any]]:
    """Runs ({name, seed, role}) that a scenario writes."""
    config = load_lab_config(config_path)
    if scenario not in config["scenarios"]:
        raise InputError(config_path, f"scenarios/{scenario}", "no such scenario",
                         f"use one of {', '.join(sorted(config['scenarios']))}")
    return list(config["scenarios"][scenario]["runs"])


def _per_joint(value: Any, joints: Sequence[str], where: str, path: Path | None) -> np.ndarray:
    if isinstance(value, Mapping):
        unknown = [k for k in value if k not in joints]
        if unknown:
            raise InputError(path, where, f"unknown joint(s) {', '.join(unknown)}", f"use {', '.join(joints)}")
        return np.array([float(value.get(j, 0.0)) for j in joints])
    if isinstance(value, (list, tuple)):
        if len(value) != len(joints):
            raise InputError(path, where, f"has {len(value)} values for {len(joints)} joints",
                             "give one value per joint, a scalar, or a {joint: value} map")
        return np.asarray(value, dtype=float)
    return np.full(len(joints), float(value))


def _per_joint_vectors(value: Mapping[str, Any], joints: Sequence[str], where: str, path: Path | None) -> np.ndarray:
    """``{joint: [x, y, z]}`` -> (n, 3), zero for joints not listed."""
    unknown = [k for k in value if k not in joints]
    if unknown:
        raise InputError(path, where, f"unknown joint(s) {', '.join(unknown)}", f"use {', '.join(joints)}")
    return np.array([np.asarray(value.get(j, [0.0, 0.0, 0.0]), dtype=float) for j in joints])


# ---------------------------------------------------------------------------------------------
# model


def arm_spec(mjcf_path: str | Path, joints: Sequence[str]) -> mujoco.MjSpec:
    """The MJCF as a torque-driven arm: unmeasured joints welded, one motor per measured joint.

    Existing actuators, equalities and tendons are removed (they involve the welded gripper or
    implement position control); contacts are disabled (free-space motion). Used by the lab and by
    the gap report's replay so both drive the robot the same way: ``ctrl`` = joint torque.
    """
    mjcf_path = Path(mjcf_path)
    try:
        spec = mujoco.MjSpec.from_file(str(mjcf_path))
    except Exception as exc:
        raise InputError(mjcf_path, None, f"MuJoCo cannot load it ({exc})", "rebuild the MJCF") from exc
    names = [j.name for j in spec.joints]
    unknown = [j for j in joints if j not in names]
    if unknown:
        raise InputError(mjcf_path, f"joint(s) {', '.join(unknown)}", "not in the MJCF", f"use {', '.join(names)}")
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for equality in list(spec.equalities):
        spec.delete(equality)
    for tendon in list(spec.tendons):
        spec.delete(tendon)
    for sensor in list(spec.sensors):
        spec.delete(sensor)
    for joint in list(spec.joints):
        if joint.name not in joints:
            spec.delete(joint)
    for key in list(spec.keys):
        spec.delete(key)
    for body in spec.bodies:
        body.gravcomp = 0.0
    for name in joints:
        actuator = spec.add_actuator()
        actuator.name = f"motor_{name}"
        actuator.target = name
        actuator.trntype = mujoco.mjtTrn.mjTRN_JOINT
        actuator.ctrllimited = 0
        actuator.forcelimited = 0
        actuator.set_to_motor()
        spec.joint(name).actfrclimited = 0
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return spec


def compile_arm(spec: mujoco.MjSpec, joints: Sequence[str]) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """Compile; return the model and the qpos/dof indices of the joints in the caller's order."""
    model = spec.compile()
    qadr = np.array([model.jnt_qposadr[model.joint(j).id] for j in joints])
    dadr = np.array([model.jnt_dofadr[model.joint(j).id] for j in joints])
    if model.nq != len(joints) or model.nv != len(joints):
        raise InputError(None, "MJCF", f"arm has nq={model.nq}, nv={model.nv} for {len(joints)} measured joints",
                         "measure every 1-DoF joint of the arm (others are welded)")
    return model, qadr, dadr


def _apply_spec_effects(spec: mujoco.MjSpec, joints: Sequence[str], effects: Mapping[str, Any],
                        path: Path | None) -> dict[str, Any]:
    """Effects that live in the model itself; returns the resolved hidden values for truth.yaml."""
    truth: dict[str, Any] = {}
    if "viscous_friction" in effects:
        values = _per_joint(effects["viscous_friction"]["coefficient"], joints, "viscous_friction", path)
        for j, v in zip(joints, values):
            # MuJoCo 4 joint damping is a polynomial in velocity: only the linear term is viscous.
            damping = np.array(spec.joint(j).damping, dtype=float).reshape(-1)
            damping[0] += v
            spec.joint(j).damping = damping
        truth["viscous_friction"] = {"coefficient": dict(zip(joints, values.tolist()))}
    coulomb = effects.get("coulomb_friction")
    if coulomb and coulomb.get("model", "sign") == "sign":
        values = _per_joint(coulomb["coefficient"], joints, "coulomb_friction", path)
        for j, v in zip(joints, values):
            spec.joint(j).frictionloss = spec.joint(j).frictionloss + v
        truth["coulomb_friction"] = {"model": "sign", "coefficient": dict(zip(joints, values.tolist()))}
    if "rotor_inertia" in effects:
        values = _per_joint(effects["rotor_inertia"]["armature"], joints, "rotor_inertia", path)
        for j, v in zip(joints, values):
            spec.joint(j).armature = spec.joint(j).armature + v
        truth["rotor_inertia"] = {"armature": dict(zip(joints, values.tolist()))}
    if "link_inertia" in effects:
        link = effects["link_inertia"]
        moving = [spec.joint(j).parent for j in joints]
        scales = _per_joint(link.get("scale", 1.0), joints, "link_inertia/scale", path)
        scales = scales * _per_joint(link.get("mass_scale", 1.0), joints, "link_inertia/mass_scale", path)
        if np.any(scales <= 0):
            raise InputError(path, "link_inertia/mass_scale", "a mass scale is not positive", "give factors > 0")
        offsets = _per_joint_vectors(link.get("com_offset", {}), joints, "link_inertia/com_offset", path)
        for body, scale, offset in zip(moving, scales, offsets):
            body.mass = body.mass * scale
            body.inertia = np.asarray(body.inertia) * scale
            if np.all(np.isfinite(body.fullinertia)):
                body.fullinertia = np.asarray(body.fullinertia) * scale
            body.ipos = np.asarray(body.ipos) + offset
        truth["link_inertia"] = {
            "mass_scale": {b.name: float(s) for b, s in zip(moving, scales)},
            "com_offset": {b.name: o.tolist() for b, o in zip(moving, offsets) if np.any(o)},
        }
    if "payload" in effects:
        payload = effects["payload"]
        body_name = payload.get("body") or spec.joint(joints[-1]).parent.name
        parent = spec.body(body_name)
        if parent is None:
            raise InputError(path, "payload/body", f"no body '{body_name}'", "name a body of the MJCF")
        com = np.asarray(payload.get("com", [0.0, 0.0, 0.0]), dtype=float)
        mass = float(payload["mass"])
        radius = float(payload.get("radius", 0.03))
        child = parent.add_body()
        child.name = "lab_payload"
        child.pos = com
        child.mass = mass
        child.inertia = np.full(3, 0.4 * mass * radius**2)  # solid sphere
        child.explicitinertial = True
        truth["payload"] = {"mass": mass, "com": com.tolist(), "body": body_name, "radius": radius}
    return truth


# Per-joint gains and offsets: (effect, its key, the value when absent). The motor's act on the command
# before the joint, the sensor's on the measured torque after it.
GAINS_AND_BIASES = (("actuator_gain", "gain", 1.0), ("command_bias", "bias", 0.0),
                    ("torque_gain", "gain", 1.0), ("torque_bias", "bias", 0.0))


def _gains_and_biases(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                      truth: dict[str, Any]) -> dict[str, np.ndarray]:
    """Each of :data:`GAINS_AND_BIASES` per joint; the hidden ones are recorded in ``truth``."""
    out = {}
    for name, key, absent in GAINS_AND_BIASES:
        out[name] = np.full(len(joints), absent)
        if name in effects:
            out[name] = _per_joint(effects[name][key], joints, name, path)
            truth[name] = {key: dict(zip(joints, out[name].tolist()))}
    return out


def gaz_friction(qd: np.ndarray, phi1: np.ndarray, phi2: np.ndarray, phi3: np.ndarray) -> np.ndarray:
    """Friction torque of Gaz et al. 2019 (zero at rest), per joint."""
    return phi1 / (1.0 + np.exp(-phi2 * (qd + phi3))) - phi1 / (1.0 + np.exp(-phi2 * phi3))


# The hump's sign is tanh(qd / this): near a true sign, yet smooth enough for the explicit passive torque at 1 kHz
# with peaks of a few tenths of N*m (slope peak/0.005 N*m*s/rad at rest).
STRIBECK_SMOOTHING_RAD_S = 0.005


def stribeck_friction(qd: np.ndarray, peak: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Stribeck hump, along the velocity: peak * exp(-(qd/velocity)^2) * tanh(qd/0.005), per joint."""
    return peak * np.exp(-((qd / velocity) ** 2)) * np.tanh(qd / STRIBECK_SMOOTHING_RAD_S)


def _joint_friction(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                    truth: dict[str, Any]) -> dict[str, Any]:
    """``coulomb_friction``'s passive torques (Gaz sigmoid, Stribeck hump) and its ``after_sensor`` fraction.

    Returns ``{gaz, stribeck, after}`` (None, None, zeros when absent) and records the hidden values in
    ``truth["coulomb_friction"]`` (the ``sign`` model's coefficient is already there, from the spec).
    """
    n = len(joints)
    friction: dict[str, Any] = {"gaz": None, "stribeck": None, "after": np.zeros(n)}
    coulomb = effects.get("coulomb_friction")
    if not coulomb:
        return friction
    where = "coulomb_friction"
    if coulomb.get("model") == "gaz_sigmoid":
        friction["gaz"] = tuple(_per_joint(coulomb[k], joints, f"{where}/{k}", path) for k in ("phi1", "phi2", "phi3"))
        truth[where] = {"model": "gaz_sigmoid",
                        **{k: dict(zip(joints, v.tolist())) for k, v in zip(("phi1", "phi2", "phi3"), friction["gaz"])}}
    record = truth.setdefault(where, {})
    if "stribeck" in coulomb:
        hump = coulomb["stribeck"]
        if not isinstance(hump, Mapping) or not {"peak", "velocity"} <= set(hump):
            raise InputError(path, f"{where}/stribeck", "needs peak and velocity", "give {peak: N*m, velocity: rad/s}")
        peak = _per_joint(hump["peak"], joints, f"{where}/stribeck/peak", path)
        velocity = _per_joint(hump["velocity"], joints, f"{where}/stribeck/velocity", path)
        if not np.all(np.isfinite(peak)) or np.any(peak < 0):
            raise InputError(path, f"{where}/stribeck/peak", "a peak is negative or not finite", "give peaks >= 0 N*m")
        if np.any((peak > 0) & ~(velocity > 0)) or not np.all(np.isfinite(velocity)):
            raise InputError(path, f"{where}/stribeck/velocity", "a joint with a peak has no positive velocity",
                             "give a Stribeck velocity > 0 rad/s for every joint whose peak is not zero")
        # Joints without a hump keep a harmless velocity (a {joint: value} map leaves the others at 0).
        friction["stribeck"] = (peak, np.where(peak > 0, velocity, 1.0))
        record["stribeck"] = {"peak": dict(zip(joints, peak.tolist())),
                              "velocity": dict(zip(joints, velocity.tolist()))}
    if "after_sensor" in coulomb:
        after = _per_joint(coulomb["after_sensor"], joints, f"{where}/after_sensor", path)
        if not np.all((after >= 0) & (after <= 1)):
            raise InputError(path, f"{where}/after_sensor", "a fraction is outside 0..1",
                             "give the share of each joint's friction acting after the sensor, 0 to 1")
        friction["after"] = after
        record["after_sensor"] = dict(zip(joints, after.tolist()))
    return friction


def passive_friction(qd: np.ndarray, friction: Mapping[str, Any]) -> np.ndarray | None:
    """The lab's friction applied as a passive torque (Gaz + Stribeck + the hysteretic friction's present state),
    along qd; None when there is none."""
    out = None
    if friction["gaz"] is not None:
        out = gaz_friction(qd, *friction["gaz"])
    if friction["stribeck"] is not None:
        hump = stribeck_friction(qd, *friction["stribeck"])
        out = hump if out is None else out + hump
    if friction.get("dahl") is not None:
        level, _ = friction["dahl"]
        memory = level * friction["dahl_state"]
        out = memory if out is None else out + memory
    return out


def dahl_step(state: np.ndarray, displacement: np.ndarray, presliding: np.ndarray) -> np.ndarray:
    """Dahl's friction state after a displacement (z' = (1 - z sign(dq)) dq / presliding, |z| <= 1): the friction
    torque level * z rises along the motion from its value at the last reversal towards the sliding level, over a
    few presliding lengths, and keeps its sign until the motion has reversed far enough (hysteresis)."""
    return np.clip(state + (1.0 - state * np.sign(displacement)) * displacement / presliding, -1.0, 1.0)


def _hysteretic_friction(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                         truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``hysteretic_friction``'s (level N*m, presliding length rad) per joint, or None; recorded in ``truth``."""
    hidden = effects.get("hysteretic_friction")
    if not hidden:
        return None
    where = "hysteretic_friction"
    level = _per_joint(hidden["level"], joints, f"{where}/level", path)
    presliding = _per_joint(hidden["presliding_rad"], joints, f"{where}/presliding_rad", path)
    if np.any(level < 0) or np.any(~(presliding > 0)):
        raise InputError(path, where, "a level is negative or a presliding length is not positive",
                         "give levels >= 0 N*m and presliding lengths > 0 rad")
    truth[where] = {"level": dict(zip(joints, level.tolist())), "presliding_rad": dict(zip(joints, presliding.tolist()))}
    return level, presliding


def _cogging(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
             truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``cogging``'s (amplitude N*m, period rad) per joint, or None: a detent torque amplitude*sin(2 pi q / period)
    that the joint's own position decides (a motor's cogging, a harmonic drive's ripple); recorded in ``truth``."""
    hidden = effects.get("cogging")
    if not hidden:
        return None
    amplitude = _per_joint(hidden["amplitude"], joints, "cogging/amplitude", path)
    period = _per_joint(hidden.get("period_rad", 1.0), joints, "cogging/period_rad", path)
    if np.any((amplitude != 0) & ~(period > 0)) or not np.all(np.isfinite(period)):
        raise InputError(path, "cogging/period_rad", "a joint with an amplitude has no positive period",
                         "give a period > 0 rad for every joint whose amplitude is not zero")
    period = np.where(amplitude != 0, period, 1.0)  # joints without a ripple keep a harmless period
    truth["cogging"] = {"amplitude": dict(zip(joints, amplitude.tolist())), "period_rad": dict(zip(joints, period.tolist()))}
    return amplitude, period


def cogging_torque(q: np.ndarray, cogging: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    amplitude, period = cogging
    return amplitude * np.sin(2.0 * np.pi * q / period)


def _torque_drift(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None, seed: int,
                  truth: dict[str, Any], time: np.ndarray) -> np.ndarray | None:
    """``torque_drift``: each joint's torque sensor warms up, its offset drifting as level * (1 - exp(-t/tau)),
    the level a different draw in every run (between 0.5 and 1.5 times ``amplitude``, either sign), like a
    sensor whose offset settles anew each time the arm starts. (N, n) or None."""
    hidden = effects.get("torque_drift")
    if not hidden:
        return None
    amplitude = _per_joint(hidden["amplitude"], joints, "torque_drift/amplitude", path)
    tau = float(hidden.get("time_constant_s", 5.0))
    if not tau > 0:
        raise InputError(path, "torque_drift/time_constant_s", "is not positive", "give a warm-up time constant > 0 s")
    draw = np.random.default_rng(seed + 104729)
    level = amplitude * draw.uniform(0.5, 1.5, size=len(joints)) * draw.choice([-1.0, 1.0], size=len(joints))
    truth["torque_drift"] = {"amplitude": dict(zip(joints, amplitude.tolist())), "time_constant_s": tau}
    return level[None, :] * (1.0 - np.exp(-(time - time[0])[:, None] / tau))


# ---------------------------------------------------------------------------------------------
# excitation


def fourier_excitation(
    time: np.ndarray, lower: np.ndarray, upper: np.ndarray, velocity_limit: np.ndarray, settings: Mapping[str, Any],
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finite Fourier series q(t) = q0 + sum_l a_l/(w l) sin(w l t) - b_l/(w l) cos(w l t), per joint.

    Random coefficients (seeded) scaled so that |q - q0| stays within position_fraction of the half range
    and |qd| within velocity_fraction of the velocity limit. Returns q, qd, qdd, each (N, n).
    """
    rng = np.random.default_rng(seed)
    n = lower.size
    harmonics = int(settings["harmonics"])
    w = float(settings["base_frequency_rad_s"])
    ell = np.arange(1, harmonics + 1)
    a = rng.normal(size=(n, harmonics))
    b = rng.normal(size=(n, harmonics))
    wt = np.outer(time, w * ell)  # (N, L)
    sin, cos = np.sin(wt), np.cos(wt)
    # offsets chosen so the series is zero-mean; scale applied after
    dq = (sin @ (a / (w * ell)).T) - (cos @ (b / (w * ell)).T)
    dqd = cos @ a.T + sin @ b.T
    dqdd = -(sin @ (a * w * ell).T) + cos @ (b * w * ell).T
    q0 = 0.5 * (lower + upper)
    half_range = 0.5 * (upper - lower)
    scale_pos = settings["position_fraction"] * half_range / np.max(np.abs(dq), axis=0)
    scale_vel = settings["velocity_fraction"] * velocity_limit / np.max(np.abs(dqd), axis=0)
    scale = np.minimum(scale_pos, scale_vel)
    return q0 + dq * scale, dqd * scale, dqdd * scale


# ---------------------------------------------------------------------------------------------
# simulation


TORQUE_SENSORS = ("motor", "link")


def _torque_sensor(scenario: Mapping[str, Any], path: Path | None) -> str:
    """``sensors.torque_sensor`` of a scenario: ``motor`` (the default) or ``link``."""
    where = str(scenario.get("sensors", {}).get("torque_sensor", "motor"))
    if where not in TORQUE_SENSORS:
        raise InputError(path, "sensors/torque_sensor", f"unknown torque sensor '{where}'",
                         f"use one of {', '.join(TORQUE_SENSORS)}")
    return where


def _link_side_model(mjcf_path: str | Path, joints: Sequence[str], effects: Mapping[str, Any],
                     path: Path | None) -> mujoco.MjModel:
    """The real arm (hidden effects included) without its drive terms: no armature, damping or
    frictionloss on the measured joints. Its inverse dynamics is the torque transmitted to the links."""
    spec = arm_spec(mjcf_path, joints)
    _apply_spec_effects(spec, joints, effects, path)
    for name in joints:
        joint = spec.joint(name)
        joint.armature = 0.0
        joint.damping = np.zeros_like(np.array(joint.damping, dtype=float).reshape(-1))
        joint.frictionloss = 0.0
    return compile_arm(spec, joints)[0]


def _nominal_torque(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray, qd: np.ndarray,
                    qdd: np.ndarray, qadr: np.ndarray, dadr: np.ndarray) -> np.ndarray:
    data.qpos[qadr] = q
    data.qvel[dadr] = qd
    data.qacc[dadr] = qdd
    mujoco.mj_inverse(model, data)
    return data.qfrc_inverse[dadr].copy()


def _friction_now(data: mujoco.MjData, qd: np.ndarray, friction: Mapping[str, Any],
                  dof_of: Mapping[int, int]) -> np.ndarray:
    """Each joint's friction torque at the forward-computed sample, along the velocity: the passive torques
    at the true velocity plus MuJoCo's dry friction (frictionloss rows of the constraint solver)."""
    out = passive_friction(qd, friction)
    out = np.zeros(len(qd)) if out is None else out.copy()
    for row in np.flatnonzero(data.efc_type[:data.nefc] == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF):
        joint = dof_of.get(int(data.efc_id[row]))
        if joint is not None:
            out[joint] -= data.efc_force[row]  # the constraint force opposes the motion
    return out


def simulate_run(
    mjcf_path: str | Path, joints: Sequence[str], scenario: Mapping[str, Any], seed: int,
    config_path: str | Path | None = None,
    trajectory: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """Simulate one run of a scenario: (time, {column kind: (N, n)}, resolved hidden values).

    ``trajectory`` (time, q, qd, qdd at the scenario's rate): the desired motion to play instead of the
    scenario's random Fourier series (a designed excitation, :func:`read_excitation`).
    """
    path = Path(config_path) if config_path else None
    effects = dict(scenario.get("effects") or {})
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise InputError(path, f"effects/{unknown[0]}", "unknown effect", f"use one of {', '.join(EFFECTS)}")

    nominal_spec = arm_spec(mjcf_path, joints)
    real_spec = arm_spec(mjcf_path, joints)
    truth = _apply_spec_effects(real_spec, joints, effects, path)
    rate = float(scenario["sample_rate_hz"])
    substeps = int(scenario["substeps"])
    dt = 1.0 / rate
    nominal, qadr, dadr = compile_arm(nominal_spec, joints)
    real, qadr_r, dadr_r = compile_arm(real_spec, joints)
    for model in (nominal, real):
        model.opt.timestep = dt / substeps
    nominal_data, real_data = mujoco.MjData(nominal), mujoco.MjData(real)
    n = len(joints)

    lower = nominal.jnt_range[[nominal.joint(j).id for j in joints], 0]
    upper = nominal.jnt_range[[nominal.joint(j).id for j in joints], 1]
    vel_limit = _per_joint(scenario.get("velocity_limit", 2.0), joints, "velocity_limit", path)
    if trajectory is None:
        steps = int(round(float(scenario["duration_s"]) * rate))
        time = np.arange(steps) * dt
        q_des, qd_des, qdd_des = fourier_excitation(time, lower, upper, vel_limit, scenario["excitation"], seed)
    else:
        time, q_des, qd_des, qdd_des = trajectory
        steps = len(time)

    friction = _joint_friction(effects, joints, path, truth)
    dahl = _hysteretic_friction(effects, joints, path, truth)
    if dahl is not None:
        friction["dahl"], friction["dahl_state"] = dahl, np.zeros(len(joints))
    cogging = _cogging(effects, joints, path, truth)
    drift = _torque_drift(effects, joints, path, seed, truth, time)
    passive = friction["gaz"] is not None or friction["stribeck"] is not None or dahl is not None
    after = friction["after"]
    delay_steps = 0
    if "actuation_delay" in effects:
        delay_steps = int(round(float(effects["actuation_delay"]["delay_s"]) * rate))
        truth["actuation_delay"] = {"delay_s": delay_steps * dt}
    scales = _gains_and_biases(effects, joints, path, truth)
    motor_gain, motor_bias = scales["actuator_gain"], scales["command_bias"]
    gain, bias = scales["torque_gain"], scales["torque_bias"]

    sensors = scenario["sensors"]
    # A link-side torque sensor: the rigid-body inverse dynamics of the real arm without its drive terms,
    # at each sample's true state and acceleration (two MuJoCo calls per sample, only when tau is logged).
    link_side = _torque_sensor(scenario, path) == "link" and "tau" in scenario["columns"]
    if link_side:
        real_link = _link_side_model(mjcf_path, joints, effects, path)
        link_data = mujoco.MjData(real_link)
        dadr_l = np.array([real_link.jnt_dofadr[real_link.joint(j).id] for j in joints])
        out_link = np.empty((steps, n))
        dof_of = {int(d): i for i, d in enumerate(dadr_r)}
    controller = scenario["controller"]
    kp = _per_joint(controller["kp"], joints, "controller/kp", path)
    kd = _per_joint(controller["kd"], joints, "controller/kd", path)
    rng = np.random.default_rng(seed + 7919)  # sensor noise stream, independent of the excitation draw
    resolution = float(sensors["encoder_resolution_rad"])
    vel_noise = float(sensors["velocity_noise_std"])

    real_data.qpos[qadr_r] = q_des[0]
    real_data.qvel[dadr_r] = qd_des[0]
    out_q = np.empty((steps, n))
    out_qd = np.empty((steps, n))
    out_cmd = np.empty((steps, n))
    out_applied = np.empty((steps, n))
    ctrl_index = np.array([real.actuator(f"motor_{j}").id for j in joints])
    for k in range(steps):
        q_true = real_data.qpos[qadr_r]
        qd_true = real_data.qvel[dadr_r]
        q_meas = np.round(q_true / resolution) * resolution if resolution > 0 else q_true.copy()
        qd_meas = qd_true + vel_noise * rng.standard_normal(n)
        if controller["type"] == "computed_torque":
            acc = qdd_des[k] + kp * (q_des[k] - q_meas) + kd * (qd_des[k] - qd_meas)
            cmd = _nominal_torque(nominal, nominal_data, q_meas, qd_meas, acc, qadr, dadr)
        else:  # PD plus gravity compensation on the nominal model
            gravity = _nominal_torque(nominal, nominal_data, q_meas, np.zeros(n), np.zeros(n), qadr, dadr)
            cmd = kp * (q_des[k] - q_meas) + kd * (qd_des[k] - qd_meas) + gravity
        out_cmd[k] = cmd
        # Actuation delay: the motor applies an older command, through its own gain and offset.
        applied = motor_gain * out_cmd[max(k - delay_steps, 0)] + motor_bias
        out_q[k], out_qd[k], out_applied[k] = q_meas, qd_meas, applied
        real_data.ctrl[ctrl_index] = applied
        if link_side:
            if passive or cogging is not None:
                torque = np.zeros(n) if not passive else -passive_friction(real_data.qvel[dadr_r], friction)
                if cogging is not None:
                    torque = torque + cogging_torque(real_data.qpos[qadr_r], cogging)
                real_data.qfrc_applied[dadr_r] = torque
            mujoco.mj_forward(real, real_data)  # the acceleration the step below integrates
            link_data.qpos[:] = real_data.qpos
            link_data.qvel[:] = real_data.qvel
            link_data.qacc[:] = real_data.qacc
            mujoco.mj_inverse(real_link, link_data)
            out_link[k] = link_data.qfrc_inverse[dadr_l]
            if np.any(after > 0):
                # Output bearings and seals sit between the sensor and the link: the sensor transmits the
                # link's inverse dynamics plus their share of the friction (the arm's motion is unchanged).
                out_link[k] += after * _friction_now(real_data, qd_true, friction, dof_of)
        for _ in range(substeps):
            before = real_data.qpos[qadr_r].copy()
            if passive or cogging is not None:
                torque = np.zeros(n) if not passive else -passive_friction(real_data.qvel[dadr_r], friction)
                if cogging is not None:
                    torque = torque + cogging_torque(real_data.qpos[qadr_r], cogging)
                real_data.qfrc_applied[dadr_r] = torque
            mujoco.mj_step(real, real_data)
            if dahl is not None:  # the friction's memory follows the motion the step made
                friction["dahl_state"] = dahl_step(friction["dahl_state"], real_data.qpos[qadr_r] - before, dahl[1])

    seen = out_link if link_side else out_applied
    tau_sensor = gain * seen + bias + float(sensors["torque_noise_std"]) * rng.standard_normal((steps, n))
    if drift is not None:
        tau_sensor = tau_sensor + drift
    signals = {"q": out_q, "qd": out_qd, "tau": tau_sensor, "tau_cmd": out_cmd, "q_cmd": q_des}
    columns = set(scenario["columns"])
    jitter = float(sensors.get("stamp_jitter_s", 0.0))
    if jitter > 0:
        # Stamps wander around the sample instants; a real logger never writes them out of order.
        stamps = time + jitter * rng.standard_normal(steps)
        time = np.maximum.accumulate(np.clip(stamps, time - 0.45 * dt, time + 0.45 * dt))
    return time, {k: v for k, v in signals.items() if k in columns}, truth


def excitation_design(lab_config: str | Path, scenario: str, run: str) -> str | None:
    """The designed excitation a run plays (its ``excitation`` key), or None for the scenario's random series."""
    runs = {r["name"]: r for r in scenario_runs(lab_config, scenario)}
    return runs[run].get("excitation") if run in runs else None


def read_excitation(path: str | Path, joints: Sequence[str], rate_hz: float, where: str,
                    config_path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A designed excitation CSV (time, q.<j>, qd.<j>, qdd.<j>) as the desired motion of a lab run."""
    import pandas as pd

    table = pd.read_csv(path)
    missing = [f"{kind}.{j}" for kind in ("q", "qd", "qdd") for j in joints if f"{kind}.{j}" not in table]
    if missing:
        raise InputError(path, f"column {missing[0]}", "missing: the design does not move the lab's joints",
                         f"list the lab's joints ({', '.join(joints)}) in the excitation.yaml `joints`")
    time = table["time"].to_numpy()
    if len(time) > 1 and abs(float(np.median(np.diff(time))) * rate_hz - 1.0) > 1e-6:
        raise InputError(config_path, where, f"the design is sampled at {1.0 / float(np.median(np.diff(time))):.6g} Hz, "
                         f"the scenario at {rate_hz:g} Hz", "give both the same sample rate")
    return (time, *(table[[f"{kind}.{j}" for j in joints]].to_numpy() for kind in ("q", "qd", "qdd")))


def run_lab_scenario_run(
    mjcf_path: str | Path, lab_config: str | Path, robot: str, scenario: str, run: str, output: str | Path,
    excitation: str | Path | None = None,
) -> None:
    """Simulate one run of ``scenario`` and write it (table + metadata) to ``output``.

    ``excitation``: the designed trajectory's CSV when the run names one (:func:`excitation_design`).
    """
    from sim2real.measurements import write_run

    config = load_lab_config(lab_config)
    runs = {r["name"]: r for r in scenario_runs(lab_config, scenario)}
    if run not in runs:
        raise InputError(lab_config, f"scenarios/{scenario}/runs", f"no run '{run}'", f"use {', '.join(runs)}")
    settings = config["scenarios"][scenario]
    trajectory = None
    if excitation is not None:
        trajectory = read_excitation(excitation, config["joints"], float(settings["sample_rate_hz"]),
                                     f"scenarios/{scenario}/runs/{run}/excitation", lab_config)
    time, signals, _ = simulate_run(mjcf_path, config["joints"], settings, int(runs[run]["seed"]), lab_config,
                                    trajectory)
    meta = {
        "robot": robot,
        "source": "synthetic",
        "control_mode": "torque",
        "sample_rate_hz": float(settings["sample_rate_hz"]),
        **({"torque_sensor": _torque_sensor(settings, Path(lab_config))} if "tau" in signals else {}),
        "notes": f"virtual lab scenario '{scenario}', run '{run}' (seed {runs[run]['seed']}"
                 + (f", designed excitation '{runs[run]['excitation']}'" if excitation is not None else "") + "); "
                 "hidden effects are in truth.yaml, which no comparison reads",
    }
    write_run(output, time, config["joints"], signals, meta)


def write_truth(lab_config: str | Path, mjcf_path: str | Path, scenario: str, output: str | Path) -> None:
    """truth.yaml: the hidden effects with their resolved values, and the scenario's settings."""
    config = load_lab_config(lab_config)
    settings = config["scenarios"][scenario]
    joints = config["joints"]
    spec = arm_spec(mjcf_path, joints)
    truth = _apply_spec_effects(spec, joints, settings.get("effects") or {}, Path(lab_config))
    effects = settings.get("effects") or {}
    _joint_friction(effects, joints, Path(lab_config), truth)
    dt = 1.0 / float(settings["sample_rate_hz"])
    if "actuation_delay" in effects:
        truth["actuation_delay"] = {"delay_s": round(float(effects["actuation_delay"]["delay_s"]) / dt) * dt}
    _gains_and_biases(effects, joints, Path(lab_config), truth)
    _hysteretic_friction(effects, joints, Path(lab_config), truth)
    _cogging(effects, joints, Path(lab_config), truth)
    if "torque_drift" in effects:
        _torque_drift(effects, joints, Path(lab_config), 0, truth, np.zeros(1))
    write_yaml(output, {
        "scenario": scenario,
        "joints": joints,
        "effects": truth,
        "sensors": settings["sensors"],
        "controller": settings["controller"],
        "columns": list(settings["columns"]),
    })
