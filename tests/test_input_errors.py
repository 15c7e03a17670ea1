"""Bad input through Snakemake: the one-line message is the last thing the user sees (issue 21).

Each case breaks one input of a copy of the project and reads what Snakemake prints. Many cases share
one invocation (``--keep-going``: every broken job fails on its own); a stub MJCF stands in for the
built one where only dr.yaml is under test (``--allowed-rules`` keeps Snakemake from rebuilding it).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from buildtree import SNAKEMAKE, copy_repo, edit_yaml

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow

PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
STUB_MJCF = '<mujoco model="stub"><worldbody><body name="b"><joint name="j"/><geom size="0.1"/></body></worldbody></mujoco>\n'


def snakemake_fails(tree: Path, *args: str) -> list[str]:
    """Run Snakemake, expect it to fail, return the non-empty lines of what it printed."""
    done = subprocess.run(
        [*SNAKEMAKE, "--cores", "2", *args],
        cwd=tree, capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONHASHSEED": "0"},
    )
    assert done.returncode != 0, done.stderr[-3000:]
    return [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]


def assert_last_lines(lines: list[str], messages: list[tuple[str, ...]]) -> None:
    """The last len(messages) lines are the messages (each line holds every fragment of one), no traceback."""
    tail = lines[-len(messages):]
    for fragments in messages:
        assert any(all(f in line for f in fragments) for line in tail), (fragments, lines[-30:])
    text = "\n".join(lines)
    assert "raise InputError(" not in text and "Traceback (most recent call last)" not in text, text[-3000:]
    assert not any("CalledProcessError" in line or "WorkflowError" in line for line in tail), tail


def write_run(tree: Path, name: str, table: dict[str, np.ndarray]) -> str:
    """A measurement run (CSV + metadata YAML) under data/panda/; returns its path."""
    path = tree / "data" / "panda" / f"{name}.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(table)
    rows = np.column_stack([table[c] for c in columns])
    path.write_text(",".join(columns) + "\n" + "\n".join(",".join(f"{v:.6g}" for v in row) for row in rows) + "\n")
    path.with_suffix(".yaml").write_text(yaml.safe_dump({"robot": "panda", "source": "real", "control_mode": "torque"}))
    return path.relative_to(tree).as_posix()


def good_table(n: int = 400) -> dict[str, np.ndarray]:
    time = np.arange(n) / 100.0
    table = {"time": time}
    for i, joint in enumerate(PANDA_JOINTS):
        table[f"q.{joint}"] = 0.3 * np.sin(0.5 * time + i)
    for i, joint in enumerate(PANDA_JOINTS):
        table[f"tau.{joint}"] = np.cos(0.5 * time + i)
    return table


def campaign(path: str, date: str | None = None) -> str:
    data = {"runs": [{"name": "fit", "path": path, "role": "fit"}, {"name": "holdout", "path": path, "role": "holdout"}]}
    if date:
        data["campaign"] = {"arm": "panda", "date": date}
    return yaml.safe_dump(data, sort_keys=False)


def test_rule_entry_logs_the_traceback_and_prints_the_message(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The entry of every script, without Snakemake: what the log and stderr get, and what onerror finds."""
    from types import SimpleNamespace

    from sim2real.cli import INPUT_ERROR_MARK, input_error_lines, rule_entry
    from sim2real.errors import InputError

    log = tmp_path / "logs" / "rule.log"
    log.parent.mkdir()
    job = SimpleNamespace(log=[str(log)])
    with pytest.raises(SystemExit) as exit_:
        with rule_entry(job):
            raise InputError("configs/x.yaml", "key 'a'", "is wrong\nacross lines", "fix it")
    assert exit_.value.code == 1
    assert capsys.readouterr().err == "configs/x.yaml: key 'a': is wrong across lines. Fix: fix it\n"
    text = log.read_text()
    assert "Traceback (most recent call last)" in text and "raise InputError(" in text
    assert text.splitlines()[-1] == INPUT_ERROR_MARK + "configs/x.yaml: key 'a': is wrong across lines. Fix: fix it"
    main_log = tmp_path / "snakemake.log"
    main_log.write_text(f"Error in rule x:\n    jobid: 3\n    log: {log} (check log file(s) for error details)\n")
    assert input_error_lines(main_log) == ["configs/x.yaml: key 'a': is wrong across lines. Fix: fix it"]
    with pytest.raises(KeyError):  # a bug propagates, traceback and all
        with rule_entry(job):
            raise KeyError("bug")
    assert "KeyError: 'bug'" in log.read_text()
    root = logging.getLogger()
    for handler in [h for h in root.handlers if isinstance(h, logging.FileHandler)]:
        root.removeHandler(handler)
        handler.close()


def test_a_config_that_is_not_yaml_names_the_line_column_and_character(tmp_path: Path) -> None:
    """Configs are parsed by libyaml (sim2real.files.read_yaml); a file it rejects is named with PyYAML's own message,
    which says which character is wrong, at the same line and column."""
    from sim2real.errors import InputError
    from sim2real.files import read_yaml

    good = tmp_path / "lab.yaml"
    good.write_text((ROOT / "configs/panda/lab.yaml").read_text())
    assert read_yaml(good) == yaml.safe_load(good.read_text())
    for text, where, what in (("joints: [a, b]\nruns:\n\t- fit\n", "line 3, column 1", "found character '\\t'"),
                              ("robot: panda\nnotes: @draft\n", "line 2, column 8", "found character '@'"),
                              ("joints: [a, b\n", "line 2, column 1", "expected ',' or ']'")):
        bad = tmp_path / "bad.yaml"
        bad.write_text(text)
        with pytest.raises(InputError) as error:
            read_yaml(bad)
        message = str(error.value)
        assert str(bad) in message and where in message and what in message and "Fix: fix the YAML syntax" in message


def test_robot_without_folder_one_line_at_parse_time(tmp_path: Path) -> None:
    tree = copy_repo(ROOT, tmp_path / "repo")
    edit_yaml(tree / "configs/config.yaml", lambda c: c.update(robots=["panda", "ghost"]))
    lines = snakemake_fails(tree, "--dry-run", "all")
    assert_last_lines(lines, [("configs/ghost/robot.yaml", "does not exist", "Fix:")])


def test_each_bad_input_ends_in_its_one_line_message(tmp_path: Path) -> None:
    tree = copy_repo(ROOT, tmp_path / "repo")
    # ur5: a revolute joint without limits in the Xacro (the urdf job)
    xacro = tree / "robots/ur5/ur5.urdf.xacro"
    xacro.write_text(xacro.read_text().replace(
        '<limit lower="${-limit}" upper="${limit}" effort="${effort}" velocity="${velocity}"/>', ""))
    # panda: a reversed randomization range (the dr_resolve job, on a stub MJCF)
    (tree / "results/panda/mjcf").mkdir(parents=True)
    (tree / "results/panda/mjcf/panda.xml").write_text(STUB_MJCF)
    edit_yaml(tree / "configs/panda/dr.yaml",
              lambda d: d["physics_randomization"]["body_mass"].update(range=[1.1, 0.9]))
    # panda: measurement CSVs with an infinite value, an unknown joint, degrees, backwards time (one prepare_runs job each)
    overflow = good_table()
    overflow[f"q.{PANDA_JOINTS[2]}"][57] = np.inf
    unknown = good_table()
    unknown["q.elbow"] = unknown.pop(f"q.{PANDA_JOINTS[6]}")
    unknown["tau.elbow"] = unknown.pop(f"tau.{PANDA_JOINTS[6]}")
    degrees = good_table()
    degrees[f"q.{PANDA_JOINTS[3]}"] = np.degrees(degrees[f"q.{PANDA_JOINTS[3]}"]) - 90.0
    backwards = good_table()
    backwards["time"][200:] -= 1.0
    (tree / "configs/panda/measurements.yaml").write_text(campaign(write_run(tree, "overflow", overflow)))
    campaigns = tree / "configs/panda/campaigns"
    for shipped in campaigns.glob("*.yaml"):  # the shipped fleet demo's campaign
        shipped.unlink()
    for name, table, date in (("unknown", unknown, "2026-01"), ("degrees", degrees, "2026-02"),
                              ("backwards", backwards, "2026-03")):
        (campaigns / f"{name}.yaml").write_text(campaign(write_run(tree, name, table), date))
    targets = ["results/ur5/ur5.urdf", "results/panda/dr.json", "results/panda/sysid/ladder.json"] + [
        f"results/panda/{name}/sysid/ladder.json" for name in ("unknown", "degrees", "backwards")]
    lines = snakemake_fails(tree, "--keep-going", "--allowed-rules", "urdf", "prepare_runs", "sysid", "dr_resolve", "--",
                            *targets)
    assert_last_lines(lines, [
        ("robots/ur5/ur5.urdf.xacro", "limit"),
        ("configs/panda/dr.yaml", "physics_randomization/body_mass/range", "reversed", "Fix: write it as [0.9, 1.1]"),
        ("data/panda/overflow.csv", "q.panda_joint3", "infinite"),
        ("data/panda/unknown.csv", "column q.elbow", "is not in", "Fix: name the columns after the URDF"),
        ("data/panda/degrees.csv", "q.panda_joint4", "degrees", "Fix:"),
        ("data/panda/backwards.csv", "column 'time', row 200", "1.99 s then 1 s", "Fix:"),
    ])
    log = (tree / "results/panda/logs/prepare_runs.log").read_text()  # the runs are prepared before the sysid job
    assert "Traceback (most recent call last)" in log and "raise InputError(" in log  # the traceback went here

    # the same copy, two more inputs broken: an unknown effect in model.yaml, a negative friction range
    (tree / "configs/panda/measurements.yaml").write_text(campaign(write_run(tree, "good", good_table())))
    for name in ("unknown", "degrees", "backwards"):
        (campaigns / f"{name}.yaml").unlink()
    edit_yaml(tree / "configs/panda/model.yaml", lambda m: m.update(effects=["link_inertia", "magic_friction"]))
    edit_yaml(tree / "configs/panda/dr.yaml",
              lambda d: d["physics_randomization"]["body_mass"].update(range=[-0.5, 1.1]))
    lines = snakemake_fails(tree, "--keep-going", "--allowed-rules", "urdf", "prepare_runs", "sysid", "dr_resolve",
                            "--", "results/panda/dr.json", "results/panda/sysid/ladder.json")
    assert_last_lines(lines, [
        ("configs/panda/model.yaml", "magic_friction"),
        ("configs/panda/dr.yaml", "physics_randomization/body_mass/range", "scale of -0.5 is not physical", "Fix:"),
    ])


def test_a_bug_keeps_its_traceback(tmp_path: Path) -> None:
    """Not an InputError: Snakemake shows the script's traceback, and no line is repeated at the end."""
    tree = copy_repo(ROOT, tmp_path / "repo")
    (tree / "scripts/build_urdf.py").write_text(
        "from sim2real.cli import rule_entry\n\nwith rule_entry(snakemake):\n    {}['missing key']\n")
    lines = snakemake_fails(tree, "results/ur5/ur5.urdf")
    assert "Traceback (most recent call last)" in "\n".join(lines)
    assert any("KeyError" in line for line in lines)
    assert "KeyError" in (tree / "results/ur5/logs/urdf.log").read_text()
