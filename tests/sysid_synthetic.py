"""Synthetic torque data with a known hidden effect, written independently of the fit code.

q, qd, qdd come from a finite Fourier series; the torque is Pinocchio's inverse dynamics of the
nominal URDF plus the hidden effect plus white noise. Used until (and besides) the virtual lab.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim2real.assets.dynamics import RigidBodyModel
from sim2real.identification.fitting import RunSamples

PANDA_URDF = (
    Path(__file__).resolve().parents[1]
    / ".venv/lib/python3.11/site-packages/cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/panda.urdf"
)
PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
GAZ_PHI1 = np.array([0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489])
GAZ_PHI2 = np.array([5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336])
GAZ_PHI3 = np.array([0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526])


def fourier_trajectory(model: RigidBodyModel, duration: float, rate: float, seed: int, harmonics: int = 5):
    """Finite Fourier series excitation inside the joint limits (analytic derivatives)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    w = 0.15 * np.pi
    n = model.n
    center = 0.5 * (model.lower + model.upper)
    half = 0.5 * (model.upper - model.lower)
    q = np.tile(center, (len(t), 1))
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    for j in range(n):
        a = rng.normal(size=harmonics)
        b = rng.normal(size=harmonics)
        k = np.arange(1, harmonics + 1)
        # Scale so the position stays within 60% of the range and velocity below ~1.2 rad/s.
        pos = (a[:, None] / (w * k[:, None])) * np.sin(w * k[:, None] * t) - (b[:, None] / (w * k[:, None])) * np.cos(w * k[:, None] * t)
        vel = a[:, None] * np.cos(w * k[:, None] * t) + b[:, None] * np.sin(w * k[:, None] * t)
        acc = -a[:, None] * w * k[:, None] * np.sin(w * k[:, None] * t) + b[:, None] * w * k[:, None] * np.cos(w * k[:, None] * t)
        s = min(0.6 * half[j] / max(np.abs(pos.sum(0)).max(), 1e-9), 1.2 / np.abs(vel.sum(0)).max())
        q[:, j] += s * pos.sum(0)
        qd[:, j] = s * vel.sum(0)
        qdd[:, j] = s * acc.sum(0)
    return t, q, qd, qdd


def make_run(
    name: str,
    hidden: dict,
    seed: int,
    duration: float = 20.0,
    rate: float = 200.0,
    noise: float = 0.05,
    urdf: Path = PANDA_URDF,
    joints: list[str] | None = None,
    armature: float = 0.1,
) -> RunSamples:
    """One run as sim2real.identification.fitting.stack_runs takes it; ``hidden`` maps effect -> value."""
    joints = joints or PANDA_JOINTS
    model = RigidBodyModel(urdf, joints, armature={j: armature for j in joints})
    t, q, qd, qdd = fourier_trajectory(model, duration, rate, seed)
    tau = model.inverse_dynamics(q, qd, qdd)
    if "payload" in hidden:
        mass, com = hidden["payload"]
        # A point mass on the last link: extra inertial parameters of the last body.
        heavy = RigidBodyModel(urdf, joints, armature={j: armature for j in joints})
        import pinocchio as pin

        last = heavy.model.njoints - 1
        heavy.model.inertias[last] = heavy.model.inertias[last] + pin.Inertia(mass, np.asarray(com), np.zeros((3, 3)))
        tau = heavy.inverse_dynamics(q, qd, qdd)
    if "viscous_friction" in hidden:
        tau = tau + np.asarray(hidden["viscous_friction"]) * qd
    if "coulomb_friction" in hidden:
        tau = tau + np.asarray(hidden["coulomb_friction"]) * np.sign(qd)
    if "gaz_friction" in hidden:
        tau = tau + GAZ_PHI1 / (1 + np.exp(-GAZ_PHI2 * (qd + GAZ_PHI3))) - GAZ_PHI1 / (1 + np.exp(-GAZ_PHI2 * GAZ_PHI3))
    if "rotor_inertia" in hidden:
        tau = tau + np.asarray(hidden["rotor_inertia"]) * qdd
    if "torque_gain" in hidden:
        tau = tau * np.asarray(hidden["torque_gain"])
    if "torque_bias" in hidden:
        tau = tau + np.asarray(hidden["torque_bias"])
    if "actuation_delay" in hidden:
        # Command = applied torque d seconds later.
        d = float(hidden["actuation_delay"])
        tau = np.column_stack([np.interp(t + d, t, tau[:, j]) for j in range(tau.shape[1])])
    rng = np.random.default_rng(seed + 1000)
    tau = tau + rng.normal(scale=noise, size=tau.shape)
    return RunSamples(name, t, q, qd, qdd, tau, torque_source="tau_cmd" if "actuation_delay" in hidden else "tau",
                      has_commands="actuation_delay" in hidden, noise_floor=np.full(len(joints), noise))
