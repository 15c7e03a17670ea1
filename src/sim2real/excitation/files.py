"""The design's outputs: the CSV at the controller rate, a ROS 2 JointTrajectory, the report and its figure.

Every number is written with a fixed format, so the same inputs give the same bytes.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sim2real.excitation.config import Design, design_from_spec, load_design  # noqa: E402
from sim2real.excitation.design import DesignResult, DesignRobot, design_start, design_trajectory  # noqa: E402
from sim2real.identification.fitting import load_nominal  # noqa: E402
from sim2real.identification.formats import read_ladder  # noqa: E402
from sim2real.errors import InputError  # noqa: E402
from sim2real.excitation.names import confounded_pair  # noqa: E402
from sim2real.excitation.separation import Separation, fitted_candidates  # noqa: E402
from sim2real.files import (  # noqa: E402
    atomic_path, dump_yaml, read_array_archive, write_array_archive, write_json, write_text,
)
from sim2real.assets.robot_config import read_robot_config  # noqa: E402

PNG_METADATA = {"Software": None}


def write_csv(result: DesignResult, target: str | Path) -> None:
    """time, q.<joint>, qd.<joint>, qdd.<joint> at the controller rate (the measurement runs' column names)."""
    traj = result.trajectory
    header = ["time"] + [f"{kind}.{j}" for kind in ("q", "qd", "qdd") for j in result.joints]
    table = np.column_stack([traj.time, traj.q, traj.qd, traj.qdd])
    with atomic_path(target) as tmp:
        with open(tmp, "w", encoding="utf-8") as out:
            out.write(",".join(header) + "\n")
            for row in table:
                out.write(",".join(f"{v:.9g}" for v in row) + "\n")


def joint_trajectory(result: DesignResult, rate_hz: float) -> dict[str, Any]:
    """A ``trajectory_msgs/msg/JointTrajectory`` (as YAML) at ``rate_hz``: positions, velocities and
    accelerations, so a ``joint_trajectory_controller`` interpolates the series with quintic splines."""
    traj = result.trajectory
    step = max(1, int(round(float(result.design.settings["sample_rate_hz"]) / rate_hz)))
    def clean(values: np.ndarray) -> list[float]:
        # 9 significant digits; round-off around zero (the rest at t = 0) written as 0.
        return [0.0 if abs(v) < 1e-12 else float(f"{v:.9g}") for v in values]

    points = []
    last = len(traj.time) - 1
    for k in list(range(0, len(traj.time), step)) + ([last] if last % step else []):
        nanoseconds = int(round(traj.time[k] * 1e9))
        points.append({
            "positions": clean(traj.q[k]),
            "velocities": clean(traj.qd[k]),
            "accelerations": clean(traj.qdd[k]),
            "time_from_start": {"sec": nanoseconds // 1_000_000_000, "nanosec": nanoseconds % 1_000_000_000},
        })
    # The end pose: the series is periodic, so the last period ends where it began, at rest.
    duration_ns = int(round(float(result.design.settings["duration_s"]) * 1e9))
    points.append({"positions": clean(result.start), "velocities": [0.0] * len(result.joints),
                   "accelerations": [0.0] * len(result.joints),
                   "time_from_start": {"sec": duration_ns // 1_000_000_000, "nanosec": duration_ns % 1_000_000_000}})
    return {"header": {"frame_id": ""}, "joint_names": list(result.joints), "points": points}


def figure(result: DesignResult, target: str | Path) -> None:
    traj = result.trajectory
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    step = max(1, len(traj.time) // 2000)  # decimated: the figure shows the shape, the CSV holds the samples
    t = traj.time[::step]
    for j, name in enumerate(result.joints):
        axes[0].plot(t, traj.q[::step, j], lw=1, label=name)
        axes[1].plot(t, traj.qd[::step, j], lw=1)
        axes[2].plot(t, result.torque[::step, j] / result.limits.torque[j], lw=1)
    axes[0].set_ylabel("q [rad]")
    axes[1].set_ylabel("qd [rad/s]")
    axes[2].set_ylabel("torque / usable limit")
    axes[2].axhline(1.0, color="k", lw=0.5, ls="--")
    axes[2].axhline(-1.0, color="k", lw=0.5, ls="--")
    axes[2].set_xlabel("time [s]")
    axes[0].legend(fontsize=7, ncol=4, loc="upper right")
    s = result.summary
    fig.suptitle(f"Excitation '{result.design.name}': condition number {s['condition_number']['initial']:.3g} -> "
                 f"{s['condition_number']['designed']:.3g}; closest approach {s['min_clearance_m'] * 1000:.1f} mm")
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=90, metadata=PNG_METADATA)
    plt.close(fig)


def markdown(result: DesignResult, robot: str, outputs: Mapping[str, str]) -> str:
    s = result.summary
    settings = result.design.settings
    margins = settings["margins"]
    peak = s["peak"]
    lines = [
        f"# Excitation trajectory `{result.design.name}` of {robot}", "",
        f"A periodic Fourier series ({settings['harmonics']} harmonics of {settings['base_frequency_hz']:g} Hz, "
        f"{settings['duration_s']:g} s = {result.design.periods} period(s)) on {', '.join(result.design.excite)}, "
        f"starting and ending at rest at the start pose. Designed for the identification of "
        f"{s['identified']['base_parameters']} base parameters: the inertial parameters of the moving bodies and "
        f"{', '.join(s['identified']['effects'])} (configs/{robot}/model.yaml).", "",
        f"- Objective: **{s['objective']}**, {s['objective_value']['initial']:.6g} -> "
        f"{s['objective_value']['designed']:.6g} (minimised)." + (
            f" The run that tells {' from '.join(s['separation']['candidates'])} apart: their fitted predictions "
            f"differ by {s['separation']['difference_x_floor']['designed']:.3g}x the noise floor (RMS over joints "
            f"and samples; {s['separation']['difference_x_floor']['initial']:.3g}x on a random run of the same "
            f"limits). Add it to configs/{robot}/measurements.yaml with `role: fit` once recorded."
            if "separation" in s else ""),
        f"- Condition number of the identification regressor (unit-norm columns, each joint scaled by its noise "
        f"floor): **{s['condition_number']['initial']:.4g} -> {s['condition_number']['designed']:.4g}** "
        "(the initial guess is a random series scaled into the limits, as the lab's excitation is drawn).",
        (f"- Closest approach to collision: **{s['min_clearance_m'] * 1000:.1f} mm** ({s['closest_pair']}), "
         if s["closest_pair"] else f"- Closest approach to collision: more than **{s['min_clearance_m'] * 1000:.1f} "
         "mm** (no two collision parts come that close), ")
        + f"margin {margins['collision_m'] * 1000:g} mm, checked by MuJoCo at every sample of a period on the built "
        "MJCF's collision parts with the obstacles " + (", ".join(o["name"] for o in settings["obstacles"]) or "none")
        + ".",
        f"- Solver: IPOPT (CasADi), {s['solver']['status']} after {s['solver']['iterations']} iterations, "
        f"{s['solver']['active_clearance_samples']} samples with an active clearance constraint (its time: the "
        f"rule's log and results/{robot}/benchmarks/excitation/{result.design.name}.tsv)." + (f" Scaled by {s['solver']['scaled_by']:.3g} towards the start pose to "
                                               "pass the check at every sample." if s["solver"]["scaled_by"] < 1 else ""),
        "",
        "| joint | position [rad] (usable) | peak velocity [rad/s] (usable) | peak acceleration [rad/s^2] (usable) | "
        "peak torque [N*m] (usable) |",
        "|---|---|---|---|---|",
    ]
    for j in result.joints:
        lines.append(
            f"| {j} | {peak['position_min_rad'][j]:.3f} .. {peak['position_max_rad'][j]:.3f} "
            f"({peak['position_lower_rad'][j]:.3f} .. {peak['position_upper_rad'][j]:.3f}) | "
            f"{peak['velocity_rad_s'][j]:.3g} ({peak['velocity_limit_rad_s'][j]:.3g}) | "
            f"{peak['acceleration_rad_s2'][j]:.3g} ({peak['acceleration_limit_rad_s2'][j]:.3g}) | "
            f"{peak['torque_Nm'][j]:.3g} ({peak['torque_limit_Nm'][j]:.3g}) |")
    lines += [
        "", f"Usable limits are the URDF's minus the margins: position {margins['position_rad']:g} rad, velocity "
        f"{margins['velocity_fraction']:.0%}, acceleration {margins['acceleration_fraction']:.0%} (of "
        f"`acceleration_limit`), torque {margins['torque_fraction']:.0%}. Torques are the nominal model's.", "",
        f"Files: `{Path(outputs['csv']).name}` (time, q, qd, qdd at {settings['sample_rate_hz']:g} Hz), "
        f"`{Path(outputs['trajectory']).name}` (a `trajectory_msgs/JointTrajectory` at "
        f"{settings['trajectory_rate_hz']:g} Hz for a ros2_control joint_trajectory_controller), "
        f"`{Path(outputs['figure']).name}`.", "",
        f"![excitation]({Path(outputs['figure']).name})", "",
    ]
    return "\n".join(lines)


@dataclass(frozen=True)
class ExcitationInputs:
    """One design of an excitation.yaml and the built robot it is designed on: what both rules of a design read."""

    robot: str
    config: str | Path  # the excitation.yaml
    name: str  # the design's name in it
    urdf: str | Path
    mjcf: str | Path
    robot_config: str | Path
    robot_settings: Mapping[str, Any] | None = None  # robot_config's content, when already read (read_robot_config)
    # the design as already read (:meth:`sim2real.excitation.config.Design.spec`, the DAG's param)
    design_spec: Mapping[str, Any] | None = None

    def design(self) -> Design:
        """The design: from its spec when the DAG passed it, else read (a separating name takes the file's
        defaults)."""
        if self.design_spec is not None:
            return design_from_spec(self.config, self.name, self.design_spec)
        return load_design(self.config, self.name, allow_default=confounded_pair(self.name) is not None)

    def design_robot(self, design: Design, robot_settings: Mapping[str, Any]) -> DesignRobot:
        """The robot ``design`` is for: the nominal model of its joints (robot.yaml's armature and flange)."""
        nominal = load_nominal(self.urdf, design.joints, robot_settings.get("armature"), robot_settings.get("flange"))
        return DesignRobot(nominal, self.mjcf, self.urdf, robot_settings.get("home") or {})


def build_excitation_start(inputs: ExcitationInputs, output: str | Path) -> np.ndarray:
    """Where design ``inputs.name`` starts for any model (:func:`sim2real.excitation.design.design_start`),
    written to ``output`` (an array archive: ``coefficients``, excited joints x 2 harmonics)."""
    design = inputs.design()
    robot_settings = read_robot_config(inputs.robot_config, inputs.robot_settings)
    coefficients = design_start(design, inputs.design_robot(design, robot_settings), log=logging.info)
    write_array_archive(output, {"coefficients": coefficients},
                        {"design": inputs.name, "robot": inputs.robot, "excited": list(design.excite)})
    return coefficients


def read_start(path: str | Path, name: str, excited: Sequence[str], harmonics: int) -> np.ndarray:
    """The coefficients of :func:`build_excitation_start` for design ``name``, checked against its joints and
    harmonics."""
    import zipfile

    try:
        header, arrays = read_array_archive(path)
        coefficients = np.asarray(arrays["coefficients"], dtype=float)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as error:
        raise InputError(path, "coefficients", f"is not a design start ({error})",
                         f"rebuild it: snakemake {Path(path).as_posix()}") from None
    if header.get("design") != name or coefficients.shape != (len(excited), 2 * harmonics):
        raise InputError(path, "coefficients", f"are of design {header.get('design')!r} with shape "
                         f"{coefficients.shape}, not of {name!r} ({len(excited)} joints x {2 * harmonics})",
                         f"rebuild it: snakemake {Path(path).as_posix()}")
    return coefficients


def build_excitation(inputs: ExcitationInputs, model_config: str | Path | None, outputs: Mapping[str, str], *,
                     ladder: str | Path | None = None, model_effects: Sequence[str] | None = None,
                     start: str | Path | None = None) -> DesignResult:
    """Design ``inputs.name`` and write its outputs (keys csv, trajectory, json, md, figure).

    A name ``separate-<a>-vs-<b>`` designs the run that tells the confounded candidates a and b of
    ``ladder`` (results/{robot}/sysid/ladder.json) apart, with the file's default settings (or its own entry).
    ``model_effects``: ``model_config``'s effects, when already read (the DAG passes them as params), checked as the
    file's would be; ``start``: the file of :func:`build_excitation_start` the design starts from (None: from a
    random series).
    """
    from sim2real.identification.model_config import effect_lines, load_model_config

    name = inputs.name
    pair = confounded_pair(name)
    design = inputs.design()
    robot_settings = read_robot_config(inputs.robot_config, inputs.robot_settings)
    if model_effects is not None:
        effects = [line.name for line in effect_lines(model_effects, model_config or "model.yaml")]
    else:
        effects = list(load_model_config(model_config).effects) if model_config and Path(model_config).exists() else []
    robot = inputs.design_robot(design, robot_settings)
    separation = None if pair is None else _separation(inputs, design, robot, pair, ladder)
    coefficients = (None if start is None else
                    read_start(start, name, design.excite, int(design.settings["harmonics"])))
    result = design_trajectory(design, robot, effects, log=logging.info, separation=separation,
                               start_coefficients=coefficients)
    write_csv(result, outputs["csv"])
    rate = float(design.settings["trajectory_rate_hz"])
    write_text(outputs["trajectory"], dump_yaml(joint_trajectory(result, rate), sort_keys=False, width=200,
                                                default_flow_style=None))
    figure(result, outputs["figure"])
    write_json(outputs["json"], result.summary)
    write_text(outputs["md"], markdown(result, inputs.robot, outputs))
    return result


def _separation(inputs: ExcitationInputs, design: Design, robot: DesignRobot, pair: tuple[str, str],
                ladder: str | Path | None) -> Separation:
    """What a separating design tells apart: the fits of the confounded ``pair`` in the diagnosis ``ladder``."""
    if ladder is None:
        raise InputError(inputs.config, f"designs/{inputs.name}", "a separating design needs the diagnosis",
                         f"build it with snakemake results/{inputs.robot}/excitation/{inputs.name}.csv")
    document = read_ladder(ladder)
    if document.get("joints") != design.joints:
        raise InputError(inputs.config, "joints", f"are not the joints of {ladder} ({document.get('joints')})",
                         "list the identified joints in the excitation.yaml `joints`")
    floor = design.per_joint("noise_floor")
    if floor is None:
        floor = np.array([document["noise_floor"]["torque_rmse"]["per_joint"][j] for j in design.joints])
    return Separation(robot.nominal, fitted_candidates(document, pair, str(ladder)), floor, str(ladder))
