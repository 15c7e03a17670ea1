"""Hypothesis fuzzing of every user input, through the package functions (issue 21).

Property, for each input: it is accepted and what comes out is valid, or an ``InputError`` naming the
file is raised; never another exception, never a partial output file, never a changed source file.
Inputs start from the shipped configs (or a valid measurement run, a small URDF) and Hypothesis breaks
them: a key removed, a value replaced by junk (None, NaN, inf, negatives, strings, lists, maps), an
unknown key added; for tables a column dropped, renamed or retyped, NaN/inf, repeated or missing
samples, backwards stamps, degrees. Fixed seed and a small budget here (about a minute in all);
``benchmarks/fuzz_inputs.py`` runs the same properties longer.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sim2real.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = int(os.environ.get("SIM2REAL_FUZZ_EXAMPLES", "0")) or None
RANDOM = os.environ.get("SIM2REAL_FUZZ_RANDOM") == "1"  # benchmarks/fuzz_inputs.py --seed: explore beyond the fixed seed


def fuzz(examples: int) -> settings:
    """Fixed seed, no example database, ``examples`` cases (``SIM2REAL_FUZZ_EXAMPLES`` overrides)."""
    return settings(derandomize=not RANDOM, max_examples=EXAMPLES or examples, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]

JUNK = st.one_of(
    st.none(), st.booleans(), st.integers(-10**9, 10**9),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0, -1, 0.0, -0.5, 1e308, -1e-300, "", "1.0", "x"]),
    st.text(max_size=6),
    st.lists(st.one_of(st.integers(-5, 5), st.floats(allow_nan=True), st.text(max_size=3)), max_size=4),
    st.dictionaries(st.text(max_size=4), st.integers(-3, 3), max_size=2),
)


# --------------------------------------------------------------------------------------------
# the property


def sources_of(paths: Sequence[Path]) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in paths if p.is_file()}


def holds(call: Callable[[], Any], name: str | Path, sources: Sequence[Path], outputs: Sequence[Path] = (),
          valid: Callable[[Any], None] | None = None) -> Any:
    """Run ``call``: accepted (and ``valid`` passes on its result) or an InputError naming ``name``.

    Any other exception propagates (Hypothesis reports it). Sources are unchanged either way; on an
    InputError no output exists, nor a temporary file beside one.
    """
    before = sources_of(sources)
    try:
        result = call()
    except InputError as exc:
        assert str(name) in str(exc), f"the error does not name {name}: {exc}"
        for out in outputs:
            assert not out.exists(), f"partial output {out} after: {exc}"
            assert not [p for p in out.parent.glob(f".{out.name}.*")] if out.parent.exists() else True
        result = None
    else:
        if valid is not None:
            valid(result)
    assert sources_of(sources) == before, "a source file changed"
    return result


# --------------------------------------------------------------------------------------------
# breaking a YAML document


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a document (maps and lists), the root included."""
    found = [prefix]
    if isinstance(doc, dict):
        for key, value in doc.items():
            found += _paths(value, (*prefix, key))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            found += _paths(value, (*prefix, i))
    return found


@st.composite
def broken(draw: st.DrawFn, base: Any, extra_values: st.SearchStrategy = st.nothing()) -> Any:
    """``base`` with one to three edits: a value replaced (junk or a value from elsewhere in it), a key
    removed, an unknown key added."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(doc)))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "replace", "remove", "add"]))
        if not path:
            if action == "replace":
                doc = copy.deepcopy(draw(JUNK))
            continue
        target = parent[path[-1]]
        if action == "replace":
            parent[path[-1]] = copy.deepcopy(draw(st.one_of(JUNK, extra_values)))  # never a strategy's own object
        elif action == "remove":
            del parent[path[-1]]
        elif isinstance(target, dict):
            target[draw(st.text(min_size=1, max_size=6))] = copy.deepcopy(draw(JUNK))
        elif isinstance(target, list):
            target.append(copy.deepcopy(draw(JUNK)))
    return doc


def dump(path: Path, doc: Any) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def shipped(name: str) -> Any:
    return yaml.safe_load((ROOT / name).read_text())


# --------------------------------------------------------------------------------------------
# configs


@fuzz(300)
@given(doc=broken(shipped("configs/panda/model.yaml"), st.sampled_from(["link_inertia", "payload", "magic"])))
def test_model_yaml(tmp_path_factory: pytest.TempPathFactory, doc: Any) -> None:
    from sim2real.identification.effects import EFFECTS
    from sim2real.identification.model_config import load_model_config

    path = dump(tmp_path_factory.mktemp("model") / "model.yaml", doc)

    def valid(config: Any) -> None:
        assert set(config.effects) <= set(EFFECTS) and len(set(config.effects)) == len(config.effects)
        assert set(config.sides) <= set(config.effects) and set(config.sides.values()) <= {"body", "actuator"}

    holds(lambda: load_model_config(path), path, [path], valid=valid)


@fuzz(150)
@given(doc=broken(shipped("configs/panda/lab.yaml"), st.sampled_from([PANDA_JOINTS[:3], "panda_joint9", -1.0])))
def test_lab_yaml(tmp_path_factory: pytest.TempPathFactory, doc: Any) -> None:
    from sim2real.lab import load_lab_config, scenario_runs

    path = dump(tmp_path_factory.mktemp("lab") / "lab.yaml", doc)

    def valid(config: dict) -> None:
        assert config["scenarios"]
        for scenario in config["scenarios"].values():
            assert {r["role"] for r in scenario["runs"]} <= {"fit", "holdout"}
            assert float(scenario["duration_s"]) > 0 and float(scenario["sample_rate_hz"]) > 0
        holds(lambda: scenario_runs(path, sorted(config["scenarios"])[0]), path, [path])

    holds(lambda: load_lab_config(path), path, [path], valid=valid)


@fuzz(300)
@given(doc=broken(shipped("configs/panda/measurements.yaml"), st.sampled_from(["fit", "holdout", "x.csv"])))
def test_measurements_yaml(tmp_path_factory: pytest.TempPathFactory, doc: Any) -> None:
    from sim2real.measurements import load_measurement_list, measurement_settings

    path = dump(tmp_path_factory.mktemp("measurements") / "measurements.yaml", doc)

    def valid(entries: list) -> None:
        assert entries and len({e.name for e in entries}) == len(entries)
        assert all(e.role in ("fit", "holdout") for e in entries)
        settings_ = measurement_settings(path)
        assert settings_["cutoff_hz"] > 0 and settings_["order"] >= 1 and settings_["horizon_s"] > 0

    holds(lambda: load_measurement_list(path), path, [path], valid=valid)


CAMPAIGN = {
    "runs": [{"name": "fit", "path": "data/panda_2/fit.parquet", "role": "fit"},
             {"name": "holdout", "path": "data/panda_2/holdout.parquet", "role": "holdout"}],
    "campaign": {"arm": "panda_2", "date": "2026-11"},
}
FILE_NAME = st.text(st.characters(codec="utf-8", exclude_characters="/\\\0\n\r"), min_size=1, max_size=12)


@fuzz(300)
@given(doc=broken(CAMPAIGN, st.sampled_from(["2026-13", "2026-11-05", "26-11", "sysid"])),
       name=st.one_of(st.sampled_from(["panda_2-2026-11", "sysid", "lab", "default", "-x", "a b"]), FILE_NAME),
       suffix=st.sampled_from([".yaml", ".yaml", ".yml", ".txt"]))
def test_campaign_files(tmp_path_factory: pytest.TempPathFactory, doc: Any, name: str, suffix: str) -> None:
    from sim2real.measurements.campaigns import DATE_PATTERN, NAME_PATTERN, RESERVED_NAMES, robot_campaigns, wildcard_pattern

    configs = tmp_path_factory.mktemp("configs")
    path = configs / "panda" / "campaigns" / f"{name}{suffix}"
    if name in (".", "..") or len(path.name.encode()) > 255:
        return
    dump(path, doc)

    def valid(campaigns: list) -> None:
        for campaign in campaigns:
            assert NAME_PATTERN.match(campaign.name) and campaign.name not in RESERVED_NAMES
            assert campaign.date is None or DATE_PATTERN.match(campaign.date)
        wildcard_pattern([c.name for c in campaigns])

    holds(lambda: robot_campaigns("panda", configs), path.name, [path], valid=valid)


# --------------------------------------------------------------------------------------------
# dr.yaml against a small MJCF with the Panda's element names


SMALL_PANDA = """<mujoco model="small_panda">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <worldbody>
    <body name="panda_link0">
      <geom name="base" type="box" size="0.1 0.1 0.1" mass="4"/>
{links}
    </body>
  </worldbody>
  <actuator>
{actuators}
  </actuator>
</mujoco>
"""


def small_panda(path: Path) -> Path:
    links, indent = [], "      "
    for i in range(1, 8):
        links.append(f'{indent}<body name="panda_link{i}" pos="0 0 0.1">'
                     f'<joint name="panda_joint{i}" axis="0 0 1" range="-2 2" damping="0.1"/>'
                     f'<geom type="capsule" size="0.04 0.05" mass="1"/>')
        indent += "  "
    fingers = ('<body name="panda_leftfinger"><geom type="box" size="0.01 0.01 0.02" mass="0.1"/></body>'
               '<body name="panda_rightfinger"><geom type="box" size="0.01 0.01 0.02" mass="0.1"/></body>')
    closing = "".join("</body>" for _ in range(7))
    actuators = "\n".join(f'    <position name="panda_joint{i}" joint="panda_joint{i}" kp="100" kv="10" nsample="20"'
                          f' interp="zoh" delay="0.0"/>' for i in range(1, 8))
    path.write_text(SMALL_PANDA.format(links="\n".join(links) + fingers + closing, actuators=actuators))
    return path


@fuzz(400)
@given(doc=broken(shipped("configs/panda/dr.yaml"), st.sampled_from([[1.1, 0.9], [-1.0, 1.0], [0.5, 0.5], "nomatch*"])))
def test_dr_yaml(tmp_path_factory: pytest.TempPathFactory, doc: Any) -> None:
    from sim2real.dr import resolve_files
    from sim2real.files import write_json

    folder = tmp_path_factory.mktemp("dr")
    path, mjcf, out = dump(folder / "dr.yaml", doc), small_panda(folder / "panda.xml"), folder / "out" / "dr.json"

    def run() -> dict:
        resolved = resolve_files(path, mjcf, robot="panda")
        write_json(out, resolved)
        return resolved

    def valid(resolved: dict) -> None:
        assert out.is_file()
        for channel in resolved["physics"]:
            assert channel["targets"]
            for target in channel["targets"]:
                values = [v for k, v in target.items() if k != "name" and isinstance(v, (int, float))]
                assert all(math.isfinite(v) for v in values), target

    holds(run, path, [path, mjcf], [out], valid=valid)


def test_small_panda_resolves_the_shipped_dr_yaml(tmp_path: Path) -> None:
    """The fuzzing's base case is accepted: edits, not the stand-in MJCF, cause its errors."""
    from sim2real.dr import resolve_files

    resolved = resolve_files(ROOT / "configs/panda/dr.yaml", small_panda(tmp_path / "panda.xml"), robot="panda")
    assert {c["term"] for c in resolved["physics"]} >= {"body_mass", "joint_damping", "action_delay"}


# --------------------------------------------------------------------------------------------
# URDF inertials and limits


URDF = """<?xml version="1.0"?>
<robot name="arm">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <link name="arm">
    <inertial>
      <origin xyz="0 0 0.1"/>
      <mass value="{mass}"/>
      <inertia ixx="{ixx}" ixy="{ixy}" ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/>
    </inertial>
  </link>
  <joint name="shoulder" type="{jtype}">
    <parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>
    {limit}
  </joint>
</robot>
"""
NUMBER = st.one_of(st.floats(-10, 10, allow_nan=False), st.sampled_from(["0", "-1", "nan", "inf", "-inf", "1e400", "", "x", "0.1 0.2"]))
URDF_FIELDS = ("mass", "ixx", "iyy", "izz", "ixy", "ixz", "iyz", "lower", "upper", "effort", "velocity")
VALID_URDF = {"mass": 1.5, "ixx": 0.02, "iyy": 0.03, "izz": 0.04, "ixy": 0.001, "ixz": 0.0, "iyz": 0.0,
              "lower": -2.0, "upper": 2.0, "effort": 80.0, "velocity": 2.0}


# Each example expands its Xacro in the sandbox's forked child (a fork of the test process): 200 here, the
# benchmark's 2000 beyond the suite.
@fuzz(200)
@given(broken_fields=st.dictionaries(st.sampled_from(URDF_FIELDS), NUMBER, max_size=3),
       removed=st.lists(st.sampled_from(["lower", "upper", "effort", "velocity", "limit"]), max_size=2),
       jtype=st.sampled_from(["revolute", "revolute", "prismatic", "continuous", "fixed", "hinge"]))
def test_urdf_inertials_and_limits(tmp_path_factory: pytest.TempPathFactory, broken_fields: dict, removed: list,
                                   jtype: str) -> None:
    from sim2real.assets.urdf import build_urdf

    folder = tmp_path_factory.mktemp("urdf")
    fields = {**VALID_URDF, **broken_fields}
    limit = {k: fields[k] for k in ("lower", "upper", "effort", "velocity") if k not in removed}
    limit_xml = "" if "limit" in removed else "<limit " + " ".join(f'{k}="{v}"' for k, v in limit.items()) + "/>"
    source = folder / "arm.urdf.xacro"
    source.write_text(URDF.format(jtype=jtype, limit=limit_xml, **{k: fields[k] for k in URDF_FIELDS[:7]}))
    out = folder / "out" / "arm.urdf"

    def valid(_: None) -> None:
        import xml.etree.ElementTree as ET

        from sim2real.assets.urdf import validate_urdf

        validate_urdf(out)  # what was written passes the checks it was built under
        root = ET.parse(out).getroot()
        for mass in root.iter("mass"):
            assert math.isfinite(float(mass.get("value"))) and float(mass.get("value")) >= 0
        for joint in root.iter("joint"):
            limit = joint.find("limit")
            if joint.get("type") in ("revolute", "prismatic", "continuous"):
                assert 0 < float(limit.get("effort")) < math.inf, "effort must be finite and > 0"
                assert 0 < float(limit.get("velocity", "1")) < math.inf, "velocity must be finite and > 0"
            if joint.get("type") in ("revolute", "prismatic"):
                lower, upper = float(limit.get("lower")), float(limit.get("upper"))
                assert -math.inf < lower < upper < math.inf, "a finite range"

    holds(lambda: build_urdf(source, out), source, [source], [out], valid=valid)


# --------------------------------------------------------------------------------------------
# measurement tables


def good_run(n: int) -> dict[str, np.ndarray]:
    time = np.arange(n) / 200.0
    table: dict[str, np.ndarray] = {"time": time}
    for kind, scale in (("q", 0.4), ("qd", 0.2), ("tau", 3.0), ("tau_cmd", 3.0)):
        for i, joint in enumerate(PANDA_JOINTS[:3]):
            table[f"{kind}.{joint}"] = scale * np.sin(0.7 * time * (i + 1) + i)
    return table


TABLE_EDIT = st.sampled_from([
    "none", "none", "none", "nan", "inf", "string", "drop_column", "rename_column", "unknown_kind", "unknown_joint", "degrees",
    "backwards", "repeat_stamps", "repeat_samples", "drop_samples", "truncate", "milliseconds", "empty",
    "constant_q", "huge", "only_time", "no_torque", "contact",
])
LIMITS = {j: (-2.9, 2.9) for j in PANDA_JOINTS}
RUN_META = {"robot": "panda", "source": "real", "control_mode": "torque", "sample_rate_hz": 200.0, "torque_sensor": "link"}


SIGNED_META = {**RUN_META, "torque_sign": {"panda_joint2": -1, "panda_joint3": 1}}


@fuzz(100)
@given(meta=st.one_of(st.just(SIGNED_META), broken(SIGNED_META, st.sampled_from(
    [-1, 1, -1.0, 2, "panda_joint1", "panda_joint9", {"panda_joint1": -1}, {"elbow": -1}, {"panda_joint1": 0}]))))
def test_run_metadata_torque_sign(tmp_path_factory: pytest.TempPathFactory, meta: Any) -> None:
    """A run's metadata with its ``torque_sign`` broken: read with every named joint's torque multiplied by its sign
    (1 or -1), or refused naming the metadata file."""
    import pandas as pd

    from sim2real.measurements import read_run

    folder = tmp_path_factory.mktemp("signed")
    table = good_run(400)
    pd.DataFrame(table).to_csv(folder / "run.csv", index=False)
    dump(folder / "run.yaml", meta)

    def valid(run: Any) -> None:
        signs = run.meta.torque_sign or {}
        assert set(signs) <= set(run.joint_names) and all(sign in (1, -1) for sign in signs.values())
        for i, joint in enumerate(run.joint_names):
            assert np.allclose(run.tau[:, i], signs.get(joint, 1) * table[f"tau.{joint}"])

    holds(lambda: read_run(folder / "run.csv"), folder / "run.yaml", [folder / "run.csv", folder / "run.yaml"],
          valid=valid)


@fuzz(600)
@given(edits=st.lists(st.tuples(TABLE_EDIT, st.integers(0, 10**6), st.floats(-1e3, 1e3)), min_size=1, max_size=3),
       meta=st.one_of(st.just(RUN_META), st.just(RUN_META), st.just(RUN_META), broken(RUN_META)),
       keep_meta=st.sampled_from([True, True, True, False]), parquet=st.booleans(), n=st.integers(300, 900))
def test_measurement_tables(tmp_path_factory: pytest.TempPathFactory, edits: list, meta: Any, keep_meta: bool,
                            parquet: bool, n: int) -> None:
    import pandas as pd

    from sim2real.measurements import load_run, prepare_run

    table = good_run(n)
    frame = pd.DataFrame(table)
    for edit, pick, value in edits:
        cols = [c for c in frame.columns if c != "time"] or ["time"]
        col = cols[pick % len(cols)]
        row = pick % max(len(frame), 1)
        if edit == "nan" and len(frame):
            frame.loc[row, col] = np.nan
        elif edit == "inf" and len(frame):
            frame.loc[row, col] = np.inf if value > 0 else -np.inf
        elif edit == "string" and len(frame):
            frame[col] = frame[col].astype(object)
            frame.loc[row, col] = "n/a"
        elif edit == "drop_column":
            frame = frame.drop(columns=[col])
        elif edit == "rename_column":
            frame = frame.rename(columns={col: col.replace("panda_joint", "joint")})
        elif edit == "unknown_kind":
            frame = frame.rename(columns={col: "effort." + col.split(".")[-1]})
        elif edit == "unknown_joint":
            joint = col.split(".")[-1]
            frame = frame.rename(columns={c: c.replace(joint, "elbow") for c in frame.columns})
        elif edit == "degrees" and col.startswith("q."):
            frame[col] = np.degrees(frame[col]) + value
        elif edit == "backwards" and len(frame) > 2:
            frame.loc[row:, "time"] -= abs(value) / 100 + 1e-3
        elif edit == "repeat_stamps" and len(frame) > 2:
            frame.loc[row, "time"] = frame.loc[max(row - 1, 0), "time"]
        elif edit == "repeat_samples":
            frame = pd.concat([frame, frame.iloc[row:row + 5]]).sort_values("time", kind="stable").reset_index(drop=True)
        elif edit == "drop_samples":
            frame = frame.drop(index=frame.index[row:row + 1 + pick % 200]).reset_index(drop=True)
        elif edit == "truncate":
            frame = frame.iloc[: pick % 40].reset_index(drop=True)
        elif edit == "milliseconds":
            frame["time"] = frame["time"] * 1000.0
        elif edit == "empty":
            frame = frame.iloc[:0]
        elif edit == "constant_q":
            for c in frame.columns:
                if c.startswith("q."):
                    frame[c] = 0.1
        elif edit == "huge" and len(frame):
            frame.loc[row, col] = 1e300 * (1 if value >= 0 else -1)
        elif edit == "only_time":
            frame = frame[["time"]] if "time" in frame.columns else frame
        elif edit == "no_torque":
            frame = frame[[c for c in frame.columns if not c.startswith("tau")]]
        elif edit == "contact":
            frame["contact"] = (np.arange(len(frame)) % 2).astype(float)

    folder = tmp_path_factory.mktemp("run")
    parquet = parquet and frame.columns.is_unique  # Parquet cannot hold two columns of one name; a CSV can
    path = folder / ("run.parquet" if parquet else "run.csv")
    if parquet:
        try:
            frame.to_parquet(path, index=False)
        except Exception:  # a column of mixed objects pyarrow cannot store: write it as text
            frame.astype(str).to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)
    if keep_meta:
        dump(path.with_suffix(".yaml"), meta)

    def call() -> Any:
        run = load_run(path, known_joints=PANDA_JOINTS, position_limits=LIMITS)
        return prepare_run(run, sample_rate_hz=None)

    def valid(prepared: Any) -> None:
        assert prepared.time.size >= 2 and np.all(np.diff(prepared.time) > 0)
        for signal in (prepared.q, prepared.qd, prepared.qdd, prepared.tau):
            assert np.all(np.isfinite(signal)), "non-finite prepared signal"
        assert prepared.q.shape[1] == len(prepared.joint_names)

    holds(call, folder / "run", [path, path.with_suffix(".yaml")], valid=valid)  # run.csv/.parquet or run.yaml
