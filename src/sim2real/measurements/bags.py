"""ROS 2 bags (MCAP) converted to measurement runs, for real arms that log with ``ros2 bag record``.

:func:`mcap_to_run` reads the joint states (and optionally the commands) of a bag and writes a run in
the measurement format of :mod:`sim2real.measurements` (table + metadata), which the rules then read
like any other log. The bag's topics come from measurements.yaml (:func:`ros2_topics`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.files import read_validated_yaml
from sim2real.measurements.records import RunMeta
from sim2real.measurements.runs import DEFAULT_TORQUE_SENSOR, SensorPlacement, write_run

DEFAULT_JOINT_TOPIC = "/joint_states"


def ros2_topics(path: str | Path) -> dict[str, str | None]:
    """ROS 2 bag topics of measurements.yaml (`ros2: {joint_topic, command_topic}`), with defaults."""
    ros2 = read_validated_yaml(path, "measurements.schema.yaml").get("ros2", {})
    return {
        "joint_topic": ros2.get("joint_topic", DEFAULT_JOINT_TOPIC),
        "command_topic": ros2.get("command_topic"),
        "torque_sensor": ros2.get("torque_sensor", DEFAULT_TORQUE_SENSOR),
    }


def mcap_to_run(
    bag_path: str | Path, output: str | Path, robot: str, joint_topic: str = DEFAULT_JOINT_TOPIC,
    command_topic: str | None = None, joints: Sequence[str] | None = None,
    torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR,
) -> Path:
    """Convert a ROS 2 bag (MCAP) to a measurement run (table + metadata) at ``output``.

    ``joint_topic`` carries ``sensor_msgs/msg/JointState``: position -> q, velocity -> qd, effort -> tau
    (fields that are empty in every message are left out). ``command_topic`` (optional) carries either
    ``sensor_msgs/msg/JointState`` (effort -> tau_cmd, position -> q_cmd) or
    ``std_msgs/msg/Float64MultiArray`` (data -> tau_cmd in joint order); the last command at or before
    each state stamp is used (zero-order hold), states before the first command are dropped.
    Stamps are the message header stamps (the log time when a header is zero). ``torque_sensor``: where
    the effort is measured, written to the run's metadata (``link`` for a Panda's franka_ros2 joint
    states, whose effort is the link-side tau_J).
    """
    bag_path = Path(bag_path)
    if not bag_path.exists():
        raise InputError(bag_path, None, "bag does not exist", "record it or correct the path")
    states, commands = _read_bag(bag_path, joint_topic, command_topic)
    if not states:
        raise InputError(bag_path, f"topic {joint_topic}", "no JointState messages", "check the joint_topic setting")
    names, time, signals = _joint_signals(bag_path, joint_topic, states, joints)
    if commands:
        time, signals = _held_commands(bag_path, command_topic, commands, names, time, signals)
    meta = RunMeta(robot=robot, source="real", control_mode="torque" if "tau_cmd" in signals else "position",
                   torque_sensor=torque_sensor if "tau" in signals else None,
                   notes=f"converted from ROS 2 bag {bag_path.name} (joint topic {joint_topic}, "
                         f"command topic {command_topic or 'none'})")
    write_run(output, time - time[0], names, signals, meta)
    return Path(output)


_State = tuple[float, dict[str, tuple[float, float | None, float | None]]]


def _read_bag(bag_path: Path, joint_topic: str, command_topic: str | None,
              ) -> tuple[list[_State], list[tuple[float, str, Any]]]:
    """The bag's joint states ((stamp, {joint: (position, velocity, effort)})) and commands ((stamp, message type,
    message)), in the bag's order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    states: list[_State] = []
    commands: list[tuple[float, str, Any]] = []
    topics = [joint_topic] + ([command_topic] if command_topic else [])
    with bag_path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=topics):
            header = getattr(decoded, "header", None)
            stamp = header.stamp.sec + 1e-9 * header.stamp.nanosec if header is not None else 0.0
            if stamp == 0.0:
                stamp = message.log_time * 1e-9
            if channel.topic == joint_topic:
                if schema.name != "sensor_msgs/msg/JointState":
                    raise InputError(bag_path, f"topic {joint_topic}", f"has type {schema.name}",
                                     "record sensor_msgs/msg/JointState on the joint topic")
                row = {}
                for i, name in enumerate(decoded.name):
                    vel = decoded.velocity[i] if len(decoded.velocity) > i else None
                    eff = decoded.effort[i] if len(decoded.effort) > i else None
                    row[name] = (decoded.position[i], vel, eff)
                states.append((stamp, row))
            else:
                commands.append((stamp, schema.name, decoded))
    return states, commands


def _joint_signals(bag_path: Path, joint_topic: str, states: list[_State], joints: Sequence[str] | None,
                   ) -> tuple[list[str], np.ndarray, dict[str, np.ndarray]]:
    """The joints (``joints``, else the first message's), the states' stamps in time order, and q, qd and tau where
    every message has them."""
    states.sort(key=lambda s: s[0])
    names = list(joints) if joints is not None else list(states[0][1].keys())
    for k, (_, row) in enumerate(states):
        missing = [j for j in names if j not in row]
        if missing:
            raise InputError(bag_path, f"topic {joint_topic}, message {k}", f"no joint(s) {', '.join(missing)}",
                             "publish every joint in every JointState message")
    time = np.array([s[0] for s in states])
    q = np.array([[row[j][0] for j in names] for _, row in states])
    qd_raw = [[row[j][1] for j in names] for _, row in states]
    tau_raw = [[row[j][2] for j in names] for _, row in states]
    qd = None if any(v is None for r in qd_raw for v in r) else np.array(qd_raw, dtype=float)
    tau = None if any(v is None for r in tau_raw for v in r) else np.array(tau_raw, dtype=float)
    signals: dict[str, np.ndarray] = {"q": q}
    if qd is not None:
        signals["qd"] = qd
    if tau is not None:
        signals["tau"] = tau
    return names, time, signals


def _held_commands(
    bag_path: Path, command_topic: str | None, commands: list[tuple[float, str, Any]], names: Sequence[str],
    time: np.ndarray, signals: dict[str, np.ndarray],
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The states from the first command on, with the last command at or before each (zero-order hold): tau_cmd
    and q_cmd where every command has them."""
    commands.sort(key=lambda c: c[0])
    c_time = np.array([c[0] for c in commands])
    tau_cmd_rows, q_cmd_rows = [], []
    for _, kind, msg in commands:
        if kind == "sensor_msgs/msg/JointState":
            index = {n: i for i, n in enumerate(msg.name)}
            tau_cmd_rows.append([msg.effort[index[j]] if len(msg.effort) else np.nan for j in names])
            q_cmd_rows.append([msg.position[index[j]] if len(msg.position) else np.nan for j in names])
        elif kind == "std_msgs/msg/Float64MultiArray":
            if len(msg.data) != len(names):
                raise InputError(bag_path, f"topic {command_topic}", f"{len(msg.data)} values for {len(names)} joints",
                                 "publish one command per joint, in JointState order")
            tau_cmd_rows.append(list(msg.data))
            q_cmd_rows.append([np.nan] * len(names))
        else:
            raise InputError(bag_path, f"topic {command_topic}", f"unsupported type {kind}",
                             "use sensor_msgs/msg/JointState or std_msgs/msg/Float64MultiArray")
    idx = np.searchsorted(c_time, time, side="right") - 1
    valid = idx >= 0
    time, idx = time[valid], idx[valid]
    signals = {k: v[valid] for k, v in signals.items()}
    tau_cmd = np.asarray(tau_cmd_rows, dtype=float)[idx]
    q_cmd = np.asarray(q_cmd_rows, dtype=float)[idx]
    if np.all(np.isfinite(tau_cmd)):
        signals["tau_cmd"] = tau_cmd
    if np.all(np.isfinite(q_cmd)):
        signals["q_cmd"] = q_cmd
    return time, signals
