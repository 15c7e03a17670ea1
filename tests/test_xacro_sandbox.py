"""A pull request's Xacro is expanded as untrusted input: it reads only the robot's packages, within a time and a
memory limit, and what breaks that is refused with one line naming the file and the element, writing nothing."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sim2real.assets.urdf import XACRO_LIMITS, build_urdf
from sim2real.errors import InputError
from sim2real.forked import Limits

HEAD = '<?xml version="1.0"?>\n<robot name="evil" xmlns:xacro="http://www.ros.org/wiki/xacro">\n'
LINK = '  <link name="base"/>\n'


def _robot(tmp_path: Path, body: str, link: str = LINK) -> Path:
    """robots/evil/evil.urdf.xacro in a tree of its own (its package root: tmp_path/robots)."""
    xacro = tmp_path / "robots" / "evil" / "evil.urdf.xacro"
    xacro.parent.mkdir(parents=True)
    xacro.write_text(HEAD + body + link + "</robot>\n")
    return xacro


def _refused(xacro: Path, limits: Limits = XACRO_LIMITS) -> str:
    out = xacro.parents[2] / "out" / "evil.urdf"
    with pytest.raises(InputError) as error:
        build_urdf(xacro, out, {}, limits=limits)
    message = str(error.value)
    assert "\n" not in message, message
    assert message.startswith(str(xacro)), message  # the file that holds the element
    assert not out.parent.exists() or not any(out.parent.iterdir()), "no partial output"
    return message


def test_an_include_of_a_system_file_is_refused(tmp_path: Path) -> None:
    message = _refused(_robot(tmp_path, '  <xacro:include filename="/etc/hostname"/>\n'))
    assert '<xacro:include filename="/etc/hostname">' in message
    assert "outside the robot's package roots" in message and "Fix:" in message


def test_a_load_yaml_out_of_the_tree_is_refused(tmp_path: Path) -> None:
    (tmp_path / "secret.yaml").write_text("token: abc\n")
    xacro = _robot(tmp_path, '  <xacro:property name="s" value="${xacro.load_yaml(\'../../secret.yaml\')}"/>\n'
                             '  <link name="${s.token}"/>\n')
    message = _refused(xacro)
    assert "xacro.load_yaml(" in message and "secret.yaml" in message and "outside" in message
    assert "abc" not in message


def test_a_symlink_out_of_the_tree_is_refused_and_a_file_inside_is_read(tmp_path: Path) -> None:
    (tmp_path / "secret.xacro").write_text(HEAD + "</robot>\n")
    xacro = _robot(tmp_path, '  <xacro:include filename="inside.xacro"/>\n', link='  <link name="${base}"/>\n')
    (xacro.parent / "inside.xacro").write_text(HEAD + '  <xacro:property name="base" value="inside"/>\n</robot>\n')
    out = tmp_path / "ok.urdf"
    build_urdf(xacro, out, {})
    assert '<link name="inside"/>' in out.read_text()
    (xacro.parent / "inside.xacro").unlink()
    os.symlink(tmp_path / "secret.xacro", xacro.parent / "inside.xacro")
    message = _refused(xacro)
    assert '<xacro:include filename=' in message and "secret.xacro" in message


def test_a_huge_range_is_stopped_at_the_memory_limit(tmp_path: Path) -> None:
    xacro = _robot(tmp_path, '  <xacro:property name="n" value="${len([i for i in python.range(10**10)])}"/>\n'
                             '  <link name="l${n}"/>\n')
    message = _refused(xacro, Limits(seconds=30, memory_bytes=256 * 2**20))
    assert "memory limit of 256 MB" in message


def test_a_macro_that_doubles_itself_is_stopped_at_the_time_limit(tmp_path: Path) -> None:
    xacro = _robot(tmp_path, '  <xacro:macro name="grow" params="n">\n'
                             '    <xacro:if value="${n > 0}"><xacro:grow n="${n - 1}"/><xacro:grow n="${n - 1}"/>'
                             '</xacro:if>\n  </xacro:macro>\n  <xacro:grow n="60"/>\n')
    message = _refused(xacro, Limits(seconds=1, memory_bytes=XACRO_LIMITS.memory_bytes))
    assert "macro 'grow'" in message and "time limit of 1 s" in message
