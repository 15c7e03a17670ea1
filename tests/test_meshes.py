"""Mesh conversion: DAE -> per-material OBJ + parts.json, STL copies, mesh naming."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from sim2real.errors import InputError
from sim2real.assets.meshes import convert_collision_mesh, convert_visual_mesh, read_parts
from sim2real.assets.urdf import mesh_names, resolve_package_uri

PANDA_MESHES = "package://example-robot-data/robots/panda_description/meshes"


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces = [], []
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(v) for v in line.split()[1:]])
        elif line.startswith("f "):
            faces.append([int(v.split("/")[0]) for v in line.split()[1:]])
    return np.array(vertices), np.array(faces)


def test_visual_mesh_one_obj_per_material_with_colors(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    uri = f"{PANDA_MESHES}/visual/link5.dae"
    with caplog.at_level(logging.WARNING):
        record = convert_visual_mesh(resolve_package_uri(uri), tmp_path / "link5", uri)
    assert any("LineSet" in r.getMessage() for r in caplog.records)  # link5.dae has one line set
    assert record == read_parts(tmp_path / "link5")
    assert record["source"] == uri
    files = sorted(p.name for p in (tmp_path / "link5").iterdir())
    assert files == sorted(["parts.json", *(p["file"] for p in record["parts"])])
    assert [p["file"] for p in record["parts"]] == [f"link5_{i}.obj" for i in range(len(record["parts"]))]
    colors = {tuple(p["rgba"]) for p in record["parts"]}
    assert len(colors) >= 2 and all(len(c) == 4 and all(0 <= v <= 1 for v in c) for c in colors)
    for part in record["parts"]:
        vertices, faces = read_obj(tmp_path / "link5" / part["file"])
        assert len(faces) > 0 and faces.min() >= 1 and faces.max() <= len(vertices)
        assert np.abs(vertices).max() < 0.5  # metres, the size of a Panda link


def test_visual_mesh_is_deterministic(tmp_path: Path) -> None:
    uri = f"{PANDA_MESHES}/visual/finger.dae"
    convert_visual_mesh(resolve_package_uri(uri), tmp_path / "a" / "finger", uri)
    convert_visual_mesh(resolve_package_uri(uri), tmp_path / "b" / "finger", uri)
    for path in sorted((tmp_path / "a" / "finger").iterdir()):
        assert path.read_bytes() == (tmp_path / "b" / "finger" / path.name).read_bytes()
    assert json.loads((tmp_path / "a" / "finger" / "parts.json").read_text())["parts"]


def test_broken_collada_is_an_input_error_and_leaves_nothing(tmp_path: Path) -> None:
    bad = tmp_path / "bad.dae"
    bad.write_text("<COLLADA><not-closed></COLLADA>")
    with pytest.raises(InputError, match="package://x/bad.dae: cannot read the Collada file"):
        convert_visual_mesh(bad, tmp_path / "out" / "bad", "package://x/bad.dae")
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []


def test_collision_binary_stl_copied_byte_for_byte(tmp_path: Path) -> None:
    source = resolve_package_uri(f"{PANDA_MESHES}/collision/link1.stl")
    convert_collision_mesh(source, tmp_path / "link1.stl")
    assert (tmp_path / "link1.stl").read_bytes() == source.read_bytes()


def test_collision_ascii_stl_rewritten_as_binary(tmp_path: Path) -> None:
    ascii_stl = tmp_path / "tri.stl"
    ascii_stl.write_text(
        "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n"
        "  endloop\n endfacet\nendsolid t\n"
    )
    convert_collision_mesh(ascii_stl, tmp_path / "out.stl")
    data = (tmp_path / "out.stl").read_bytes()
    assert len(data) == 84 + 50 and int.from_bytes(data[80:84], "little") == 1
    normal = np.frombuffer(data[84:96], dtype="<f4")
    assert normal.tolist() == [0.0, 0.0, 1.0]
    (tmp_path / "junk.stl").write_bytes(b"\x00" * 10)
    with pytest.raises(InputError, match="neither a binary nor an ASCII STL"):
        convert_collision_mesh(tmp_path / "junk.stl", tmp_path / "junk_out.stl")
    assert not (tmp_path / "junk_out.stl").exists()


def test_two_meshes_with_one_stem_are_rejected(tmp_path: Path) -> None:
    urdf = tmp_path / "r.urdf"
    urdf.write_text(
        '<robot name="r">'
        f'<link name="a"><visual><geometry><mesh filename="{PANDA_MESHES}/visual/link0.dae"/></geometry></visual></link>'
        '<link name="b"><visual><geometry><mesh filename="package://other/visual/link0.dae"/></geometry></visual></link>'
        "</robot>"
    )
    with pytest.raises(InputError, match="two visual meshes share the file name 'link0'"):
        mesh_names(urdf)
