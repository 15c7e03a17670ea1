"""Meshes in the formats users have: OBJ (with its MTL) and glTF/GLB visual and collision meshes build into the MJCF,
the USD and CoACD's convex parts, colors kept; an empty or unreadable mesh is refused in one line naming the file
and the link."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh
import yaml
from pxr import Usd, UsdGeom, UsdShade

from sim2real.assets.collision import CoacdSettings, MeshSettings, decompose, load_source_mesh
from sim2real.assets.meshes import (
    DEFAULT_RGBA, BuiltMeshes, convert_collision_mesh, convert_visual_mesh, mesh_links, read_parts,
)
from sim2real.assets.mjcf import build_mjcf
from sim2real.assets.urdf import mesh_names, resolve_package_uri
from sim2real.assets.usd import build_usd
from sim2real.errors import InputError

FAST = MeshSettings(source="collision", coacd=CoacdSettings(threshold=0.3, max_convex_hull=4, preprocess_mode="off",
                                                            mcts_iterations=10), voxels_per_extent=30)
ORANGE = (1.0, round(128 / 255, 6), 0.0, 1.0)
BLUE = (0.0, 0.0, 1.0, 1.0)


def colored(mesh: trimesh.Trimesh, name: str, rgba: tuple[float, ...]) -> trimesh.Trimesh:
    color = [int(round(c * 255)) for c in rgba]
    mesh.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name=name, baseColorFactor=color))
    return mesh


def write_meshes(folder: Path) -> None:
    """base.glb (an orange box; glTF is Y-up: the box's long side along glTF's Y is the link's Z), arm.obj + its MTL (a
    blue cylinder and an orange cap: two materials), arm_collision.glb and base_collision.obj."""
    folder.mkdir(parents=True, exist_ok=True)
    tall = trimesh.creation.box((0.1, 0.3, 0.1))  # 0.3 along glTF's up, Y
    trimesh.Scene({"body": colored(tall, "orange", ORANGE)}).export(folder / "base.glb")
    arm = colored(trimesh.creation.cylinder(0.04, 0.3, sections=16), "blue", BLUE)
    cap = colored(trimesh.creation.box((0.1, 0.1, 0.05)), "orange", ORANGE)
    cap.apply_translation((0, 0, 0.17))
    trimesh.Scene({"arm": arm, "cap": cap}).export(folder / "arm.obj")
    trimesh.creation.cylinder(0.05, 0.3, sections=12).apply_transform(
        trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0))).export(folder / "arm_collision.glb")
    trimesh.creation.box((0.12, 0.12, 0.3)).export(folder / "base_collision.obj")


URDF = """<robot name="tiny">
  <link name="base">
    <inertial><mass value="2"/><inertia ixx="0.02" iyy="0.02" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="{d}/base.glb"/></geometry></visual>
    <collision><geometry><mesh filename="{d}/base_collision.obj"/></geometry></collision>
  </link>
  <link name="arm">
    <inertial><origin xyz="0 0 0.15"/><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><origin xyz="0 0 0.15"/><geometry><mesh filename="{d}/arm.obj"/></geometry></visual>
    <collision><origin xyz="0 0 0.15"/><geometry><mesh filename="{d}/arm_collision.glb"/></geometry></collision>
  </link>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="arm"/><origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="50" velocity="2"/>
  </joint>
</robot>
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("tiny")
    write_meshes(root / "meshes")
    (root / "tiny.urdf").write_text(URDF.format(d=root / "meshes"), encoding="utf-8")
    (root / "robot.yaml").write_text(yaml.safe_dump({
        "xacro": "tiny.urdf.xacro", "flange": "arm", "armature": {"*": 0.05},
        "actuators": [{"joints": "shoulder", "type": "motor"}]}), encoding="utf-8")
    return root


def build(root: Path) -> tuple[Path, dict[str, Path], dict[str, list[Path]]]:
    """Every mesh of the tiny arm converted (visual parts; collision STL, then CoACD parts), the MJCF and the USD
    built from them."""
    urdf = root / "tiny.urdf"
    names, links = mesh_names(urdf), mesh_links(urdf)
    visual = {}
    for name, uri in names["visual"].items():
        visual[uri] = root / "visual" / name
        convert_visual_mesh(resolve_package_uri(uri), visual[uri], uri, links["visual"][name])
    collision = {}
    for name, uri in names["collision"].items():
        stl = root / "collision" / f"{name}.stl"
        convert_collision_mesh(resolve_package_uri(uri), stl, uri, links["collision"][name])
        collision[uri] = decompose(stl, FAST, root / "coacd" / name).part_files
    meshes = BuiltMeshes.of(visual, collision)
    build_mjcf(urdf, root / "robot.yaml", meshes, root / "mjcf" / "tiny.xml", root / "mjcf" / "scene.xml")
    build_usd(urdf, root / "robot.yaml", meshes, root / "usd" / "tiny.usda", root / "usd" / "tiny_geometry.usda")
    return urdf, visual, collision


def test_obj_and_glb_meshes_build_mjcf_usd_and_collision_with_their_colors(tiny):
    _, visual, collision = build(tiny)
    base, arm = (read_parts(visual[str(tiny / "meshes" / f"{n}.{s}")]) for n, s in (("base", "glb"), ("arm", "obj")))
    assert [tuple(p["rgba"]) for p in base["parts"]] == [ORANGE]
    assert sorted(tuple(p["rgba"]) for p in arm["parts"]) == sorted([BLUE, ORANGE])  # one part per MTL material
    model = mujoco.MjModel.from_xml_path(str(tiny / "mjcf" / "scene.xml"))
    visual_rgba = {tuple(round(float(c), 3) for c in model.mat_rgba[model.geom_matid[g]]) for g in range(model.ngeom)
                   if model.geom_group[g] == 2}
    assert visual_rgba == {tuple(round(c, 3) for c in BLUE), tuple(round(c, 3) for c in ORANGE)}
    arm_body = model.body("arm").id
    assert sum(1 for g in range(model.ngeom) if model.geom_group[g] == 3 and model.geom_bodyid[g] == arm_body) == len(
        collision[str(tiny / "meshes" / "arm_collision.glb")])
    # glTF is Y-up: the base's 0.3 m side stands along the link's Z, in the visual parts and in the convex parts
    part = trimesh.load(visual[str(tiny / "meshes" / "base.glb")] / base["parts"][0]["file"], force="mesh")
    assert np.allclose(part.extents, [0.1, 0.1, 0.3], atol=1e-6)
    arm_hull = load_source_mesh(tiny / "collision" / "arm_collision.stl")
    assert np.allclose(arm_hull.extents, [0.1, 0.1, 0.3], atol=2e-3)
    stage = Usd.Stage.Open(str(tiny / "usd" / "tiny.usda"))
    colors = set()
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh) and UsdGeom.Imageable(prim).GetPurposeAttr().Get() != UsdGeom.Tokens.guide:
            material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
            shader = UsdShade.Shader(material.GetSurfaceOutput().GetConnectedSource()[0].GetPrim())
            colors.add(tuple(round(float(c), 3) for c in shader.GetInput("diffuseColor").Get()))
    assert colors == {tuple(round(c, 3) for c in BLUE[:3]), tuple(round(c, 3) for c in ORANGE[:3])}


def test_the_converted_meshes_are_byte_identical_on_rebuild(tiny, tmp_path):
    uri = str(tiny / "meshes" / "arm.obj")
    convert_visual_mesh(uri, tmp_path / "a" / "arm", uri)
    convert_visual_mesh(uri, tmp_path / "b" / "arm", uri)
    for path in sorted((tmp_path / "a" / "arm").iterdir()):
        assert path.read_bytes() == (tmp_path / "b" / "arm" / path.name).read_bytes()


def test_face_colors_become_one_part_each_and_an_uncolored_stl_the_default(tmp_path):
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    box.visual.face_colors = np.tile([255, 0, 0, 255], (len(box.faces), 1))
    box.visual.face_colors[:4] = [0, 255, 0, 255]
    box.export(tmp_path / "painted.ply")
    record = convert_visual_mesh(tmp_path / "painted.ply", tmp_path / "out" / "painted", "painted.ply")
    assert [tuple(p["rgba"]) for p in record["parts"]] == [(0.0, 1.0, 0.0, 1.0), (1.0, 0.0, 0.0, 1.0)]
    assert [len(trimesh.load(tmp_path / "out" / "painted" / p["file"], force="mesh").faces) for p in record["parts"]] == [4, 8]
    box.export(tmp_path / "plain.stl")
    record = convert_visual_mesh(tmp_path / "plain.stl", tmp_path / "out" / "plain", "plain.stl")
    assert [tuple(p["rgba"]) for p in record["parts"]] == [DEFAULT_RGBA]


@pytest.mark.parametrize(("file", "content", "problem"), [
    ("empty.obj", b"", "holds no triangles (an empty mesh)"),
    ("empty.glb", b"", "cannot be read as a mesh"),
    ("broken.glb", b"glTF not really", "cannot be read as a mesh"),
    ("empty.stl", b"", "is neither a binary nor an ASCII STL"),
    ("lines.obj", b"v 0 0 0\nv 1 0 0\nl 1 2\n", "holds no triangles (an empty mesh)"),
])
def test_an_empty_or_unreadable_mesh_is_refused_in_one_line_naming_the_file_and_the_link(tmp_path, file, content,
                                                                                        problem):
    path = tmp_path / file
    path.write_bytes(content)
    uri = f"package://tiny/meshes/{file}"
    convert = convert_collision_mesh if file.endswith(".stl") else convert_visual_mesh
    with pytest.raises(InputError) as error:
        convert(path, tmp_path / "out" / Path(file).stem, uri, ["forearm"])
    message = str(error.value)
    assert len(message.splitlines()) == 1
    assert message.startswith(f"{uri}: link 'forearm': ") and problem in message
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())  # nothing written


def test_a_mesh_of_a_format_not_read_is_refused(tmp_path):
    (tmp_path / "arm.fbx").write_bytes(b"Kaydara FBX Binary")
    with pytest.raises(InputError, match=r"arm\.fbx: links 'a', 'b': '\.fbx' is not a mesh format read here"):
        convert_visual_mesh(tmp_path / "arm.fbx", tmp_path / "out" / "arm", str(tmp_path / "arm.fbx"), ["a", "b"])
