"""Mesh conversion: visual meshes -> one OBJ per material + parts.json; collision meshes -> binary STL.

A mesh may be Collada (read with pycollada: its materials, units and up axis), or any format trimesh reads (OBJ with
its MTL, STL, PLY, glTF/GLB, ...: :data:`TRIMESH_FORMATS`). MuJoCo reads neither DAE nor materials from meshes, so
each visual mesh becomes one OBJ per material and a ``parts.json`` that carries each part's color::

    {"source": "<package uri>", "parts": [{"file": "<name>_<i>.obj", "material": "<name>", "rgba": [r, g, b, a]}]}

A color is kept where the format carries one: a Collada or MTL material's diffuse color, a glTF material's base
color, a PLY's (or OBJ's) face or vertex colors (one part per color); a mesh without one gets :data:`DEFAULT_RGBA`.
Outputs are deterministic (fixed number format, sorted vertex table) and written atomically.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim2real.assets.urdf import mesh_name
from sim2real.errors import InputError
from sim2real.files import atomic_dir, atomic_path, write_json

if TYPE_CHECKING:
    import trimesh

log = logging.getLogger(__name__)

DEFAULT_RGBA = (0.7, 0.7, 0.7, 1.0)  # for untextured-but-mapped or material-less primitives
PARTS_FILE = "parts.json"


@dataclass
class _Part:
    material: str
    rgba: tuple[float, float, float, float]
    triangles: list[np.ndarray] = field(default_factory=list)  # (T, 3, 3) positions
    normals: list[np.ndarray] = field(default_factory=list)  # (T, 3, 3) or empty


def _material_color(material: object) -> tuple[float, float, float, float]:
    effect = getattr(material, "effect", None)
    diffuse = getattr(effect, "diffuse", None)
    if isinstance(diffuse, tuple) and len(diffuse) >= 3:
        rgba = [float(c) for c in diffuse[:4]] + [1.0] * (4 - len(diffuse[:4]))
        return (round(rgba[0], 6), round(rgba[1], 6), round(rgba[2], 6), round(rgba[3], 6))
    return DEFAULT_RGBA  # a texture map: MuJoCo would need UVs and the image; keep a neutral color


def _up_axis_rotation(up_axis: str | None) -> np.ndarray:
    """Rotation that brings a Collada document's up axis onto +Z (URDF convention)."""
    if up_axis == "Y_UP":
        return np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    if up_axis == "X_UP":
        return np.array([[0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0]])
    return np.eye(3)


def read_collada_parts(dae_path: str | Path, source_label: str | None = None, where: str | None = None) -> list[_Part]:
    """Triangles of a Collada file grouped by material, in order of first appearance; ``where``: the links that use it,
    for an error's message.

    LineSet (and other non-surface) primitives are skipped with a warning.
    """
    import collada

    dae_path = Path(dae_path)
    label = source_label or str(dae_path)
    try:
        document = collada.Collada(
            str(dae_path), ignore=[collada.common.DaeUnsupportedError, collada.common.DaeBrokenRefError]
        )
    except Exception as exc:
        raise InputError(label, where, f"cannot read the Collada file ({exc})", "re-export the mesh as valid Collada 1.4") from exc
    scale = float(document.assetInfo.unitmeter or 1.0)
    rotation = _up_axis_rotation(getattr(document.assetInfo, "upaxis", None))
    parts: dict[str, _Part] = {}
    if document.scene is None:
        raise InputError(label, where or "<scene>", "the Collada file has no scene", "export the mesh with a visual scene")
    skipped: dict[str, int] = {}
    for geometry in document.scene.objects("geometry"):
        for primitive in geometry.primitives():
            kind = type(primitive).__name__
            if "Polylist" in kind or "Polygons" in kind:
                primitive = primitive.triangleset()
                kind = type(primitive).__name__
            if "TriangleSet" not in kind:
                skipped[kind] = skipped.get(kind, 0) + 1
                continue
            if len(primitive) == 0:
                continue
            material = primitive.material
            key = getattr(material, "name", None) or getattr(material, "id", None) or "default"
            part = parts.setdefault(key, _Part(key, _material_color(material)))
            vertices = np.asarray(primitive.vertex, dtype=float)[np.asarray(primitive.vertex_index)]
            part.triangles.append(vertices @ rotation.T * scale)
            if primitive.normal is not None and primitive.normal_index is not None:
                normals = np.asarray(primitive.normal, dtype=float)[np.asarray(primitive.normal_index)]
                part.normals.append(normals @ rotation.T)
            else:
                part.normals.append(np.empty((0, 3, 3)))
    for kind, count in sorted(skipped.items()):
        log.warning("%s: skipped %d %s primitive(s) (not a surface; MuJoCo and USD need triangles)", label, count, kind)
    if not parts:
        raise InputError(label, where or "<library_geometries>", "no triangle geometry found (an empty mesh)",
                         "export the mesh with triangles")
    return list(parts.values())


# The formats read through trimesh (every other one is Collada's, read with pycollada above).
TRIMESH_FORMATS = frozenset(f".{kind}" for kind in ("obj", "stl", "ply", "off", "glb", "gltf", "3mf"))
# glTF is Y-up by its specification: turned onto the link frame's Z, as a Collada file's Y_UP is. OBJ, STL and PLY
# say nothing of an up axis: their coordinates are the link frame's, as URDF tools read them.
GLTF_SUFFIXES = frozenset({".glb", ".gltf"})


def mesh_format(path: str | Path, label: str, where: str | None = None) -> str:
    """``collada`` or ``trimesh``: how the mesh file ``path`` is read; a file that does not exist or of another format
    is an InputError naming ``label`` and ``where``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(label, where, f"the mesh file does not exist ({path})", "correct the URI or add the file")
    suffix = path.suffix.lower()
    if suffix == ".dae":
        return "collada"
    if suffix in TRIMESH_FORMATS:
        return "trimesh"
    raise InputError(label, where, f"'{suffix}' is not a mesh format read here",
                     "export the mesh as OBJ, STL, DAE, glTF/GLB or PLY")


def read_trimesh_parts(path: str | Path, label: str, where: str | None = None) -> list[_Part]:
    """Triangles of a mesh file trimesh reads (its scene's nodes placed), grouped by color (:func:`_face_groups`), in
    order of first appearance; an unreadable or empty file is an InputError naming ``label`` and ``where``."""
    import trimesh

    path = Path(path)
    try:
        scene = trimesh.load_scene(path, process=False)
    except Exception as exc:  # trimesh raises assorted errors on bad files
        raise InputError(label, where, f"cannot be read as a mesh ({type(exc).__name__}: {exc})",
                         "re-export the mesh as OBJ, STL, DAE or glTF/GLB") from exc
    rotation = _up_axis_rotation("Y_UP") if path.suffix.lower() in GLTF_SUFFIXES else np.eye(3)
    parts: dict[tuple[str, tuple[float, ...]], _Part] = {}
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        mesh = scene.geometry[geometry_name]
        faces = np.asarray(getattr(mesh, "faces", np.empty((0, 3))), dtype=np.int64)
        if faces.size == 0:
            continue  # a point cloud or a path: no surface
        placement = np.asarray(transform, dtype=float)
        vertices = np.asarray(mesh.vertices, dtype=float) @ placement[:3, :3].T + placement[:3, 3]
        for material, rgba, rows in _face_groups(mesh, str(geometry_name)):
            part = parts.setdefault((material, rgba), _Part(material, rgba))
            part.triangles.append(vertices[faces[rows]] @ rotation.T)
            part.normals.append(np.empty((0, 3, 3)))
    if not parts:
        raise InputError(label, where, "holds no triangles (an empty mesh)", "export the mesh with its surfaces")
    return list(parts.values())


def _rgba(color: object) -> tuple[float, float, float, float]:
    """An 8-bit RGBA (trimesh's colors) as four fractions, rounded as Collada's are."""
    values = np.asarray(color, dtype=float).ravel()[:4] / 255.0
    values = np.concatenate([values, np.ones(4 - values.size)])
    red, green, blue, alpha = (round(float(v), 6) for v in values)
    return (red, green, blue, alpha)


def _face_groups(mesh: object, name: str) -> list[tuple[str, tuple[float, float, float, float], np.ndarray]]:
    """The faces of a trimesh mesh by color: (material name, rgba, face indices). A material's main color (an MTL's
    diffuse, a glTF's base color factor; a texture's image is not sampled: MuJoCo would need its UVs), else one group
    per face (or vertex) color, else :data:`DEFAULT_RGBA`."""
    visual = getattr(mesh, "visual", None)
    count = len(mesh.faces)  # type: ignore[attr-defined]
    every = np.arange(count)
    material = getattr(visual, "material", None)
    if material is not None:
        return [(getattr(material, "name", None) or name, _rgba(material.main_color), every)]
    if getattr(visual, "kind", None) in ("face", "vertex"):
        colors = np.asarray(visual.face_colors)  # type: ignore[union-attr]
        unique, first, inverse = np.unique(colors, axis=0, return_index=True, return_inverse=True)
        order = np.argsort(first)  # in order of first appearance
        return [(f"{name}_{k}", _rgba(unique[u]), np.flatnonzero(inverse.ravel() == u)) for k, u in enumerate(order)]
    return [(name, DEFAULT_RGBA, every)]


def read_visual_parts(path: str | Path, label: str, where: str | None = None) -> list[_Part]:
    """A visual mesh's triangles grouped by material and color, whichever format it is (:func:`mesh_format`)."""
    if mesh_format(path, label, where) == "collada":
        return read_collada_parts(path, label, where)
    return read_trimesh_parts(path, label, where)


def urdf_mesh(path: str | Path) -> trimesh.Trimesh:
    """One triangle mesh of a URDF's mesh file in its link's frame, read as trimesh reads it (a glTF file turned onto
    the link frame's Z-up, as :func:`read_trimesh_parts` turns it): the geometry the fit's inertia bands bound."""
    import trimesh

    loaded = trimesh.load(path, force="mesh")
    if Path(path).suffix.lower() in GLTF_SUFFIXES:
        turn = np.eye(4)
        turn[:3, :3] = _up_axis_rotation("Y_UP")
        loaded.apply_transform(turn)
    return loaded


def links_of(links: Sequence[str] | None) -> str | None:
    """Where a mesh is used, for an error's message: ``link 'a'`` or ``links 'a', 'b'`` (None: not known)."""
    if not links:
        return None
    return ("link " if len(links) == 1 else "links ") + ", ".join(f"'{link}'" for link in links)


def mesh_links(urdf_path: str | Path) -> dict[str, dict[str, list[str]]]:
    """``{kind: {mesh name: the links that use it}}`` of a URDF (``kind``: visual, collision)."""
    import xml.etree.ElementTree as ET

    from sim2real.assets.urdf import MESH_KINDS, mesh_refs

    out: dict[str, dict[str, list[str]]] = {kind: {} for kind in MESH_KINDS}
    for ref in mesh_refs(ET.parse(urdf_path).getroot()):
        links = out[ref.kind].setdefault(mesh_name(ref.uri), [])
        if ref.link not in links:
            links.append(ref.link)
    return out


def _format_obj(triangles: np.ndarray, normals: np.ndarray | None) -> str:
    """OBJ text with a deduplicated, sorted vertex table (deterministic)."""
    corners = triangles.reshape(-1, 3)
    if normals is not None:
        lengths = np.linalg.norm(normals.reshape(-1, 3), axis=1, keepdims=True)
        unit = np.divide(normals.reshape(-1, 3), lengths, out=np.zeros_like(corners), where=lengths > 0)
        table = np.round(np.hstack([corners, unit]), 9)
    else:
        table = np.round(corners, 9)
    unique, inverse = np.unique(table, axis=0, return_inverse=True)
    faces = inverse.reshape(-1, 3) + 1
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in unique[:, :3]]
    if normals is not None:
        lines += [f"vn {x:.6g} {y:.6g} {z:.6g}" for x, y, z in unique[:, 3:]]
        lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in faces]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def convert_visual_mesh(mesh_path: str | Path, out_dir: str | Path, source_uri: str,
                        links: Sequence[str] | None = None) -> dict:
    """Write ``out_dir/{name}_{i}.obj`` per material and ``out_dir/parts.json``; return the parts record.

    ``name`` is the stem of ``out_dir``; ``links``: the links that use the mesh, named by an error. The directory is
    replaced atomically.
    """
    out_dir = Path(out_dir)
    name = out_dir.name
    parts = read_visual_parts(mesh_path, source_uri, links_of(links))
    record: dict = {"source": source_uri, "parts": []}
    with atomic_dir(out_dir) as tmp:
        for index, part in enumerate(parts):
            triangles = np.concatenate(part.triangles)
            have_normals = all(n.shape[0] == t.shape[0] for n, t in zip(part.normals, part.triangles))
            normals = np.concatenate(part.normals) if have_normals else None
            filename = f"{name}_{index}.obj"
            (tmp / filename).write_text(_format_obj(triangles, normals), encoding="utf-8")
            record["parts"].append({"file": filename, "material": part.material, "rgba": list(part.rgba)})
        write_json(tmp / PARTS_FILE, record)
    return record


def read_parts(visual_dir: str | Path) -> dict:
    """The parts record of a converted visual mesh directory."""
    import json

    path = Path(visual_dir) / PARTS_FILE
    if not path.is_file():
        raise InputError(path, None, "parts.json is missing", "rebuild the visual mesh (snakemake)")
    return json.loads(path.read_text(encoding="utf-8"))


def _ascii_stl_triangles(data: bytes) -> np.ndarray:
    """Triangles (T, 3, 3) of an ASCII STL."""
    words = data.decode("ascii", errors="replace").split()
    values = [
        (float(words[i + 1]), float(words[i + 2]), float(words[i + 3]))
        for i in range(len(words) - 3)
        if words[i] == "vertex"
    ]
    return np.asarray(values, dtype=np.float32).reshape(-1, 3, 3)


def _binary_stl(triangles: np.ndarray) -> bytes:
    """Binary STL with a fixed header, normals from the winding (deterministic)."""
    triangles = triangles.astype(np.float32)
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0).astype(np.float32)
    record = np.zeros(len(triangles), dtype=[("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
    record["normal"] = normals
    record["vertices"] = triangles
    header = b"binary STL written by sim2real".ljust(80, b" ")
    return header + np.uint32(len(triangles)).tobytes() + record.tobytes()


def convert_collision_mesh(mesh_path: str | Path, out_path: str | Path, source_uri: str | None = None,
                           links: Sequence[str] | None = None) -> None:
    """A collision mesh as binary STL: a binary STL byte for byte; an ASCII STL, or another format trimesh reads
    (:func:`read_trimesh_parts`), rewritten as binary. ``links``: the links that use it, named by an error."""
    stl_path = Path(mesh_path)
    label = source_uri or str(stl_path)
    where = links_of(links)
    if not stl_path.is_file():
        raise InputError(label, where, f"collision mesh does not exist ({stl_path})", "correct the URI or add the file")
    if stl_path.suffix.lower() != ".stl":
        mesh_format(stl_path, label, where)
        triangles = np.concatenate([t for part in read_trimesh_parts(stl_path, label, where) for t in part.triangles])
        with atomic_path(out_path) as tmp:
            tmp.write_bytes(_binary_stl(triangles))
        return
    data = stl_path.read_bytes()
    count = int(np.frombuffer(data[80:84], dtype="<u4")[0]) if len(data) >= 84 else -1
    if count > 0 and len(data) == 84 + 50 * count:
        payload = data  # binary STL, consistent size
    elif data.lstrip().startswith(b"solid") and b"vertex" in data:
        triangles = _ascii_stl_triangles(data)
        if len(triangles) == 0:
            raise InputError(label, where, "the ASCII STL has no triangles (an empty mesh)", "re-export the mesh")
        payload = _binary_stl(triangles)
    else:
        raise InputError(label, where, "is neither a binary nor an ASCII STL (or has no triangles)", "re-export the mesh as STL")
    with atomic_path(out_path) as tmp:
        tmp.write_bytes(payload)


@dataclass(frozen=True)
class BuiltMeshes:
    """The built meshes the asset writers (MJCF, USD) place: each visual mesh's directory of parts (``parts.json``
    inside) by mesh name, and each URDF collision mesh URI's files (one STL, or CoACD's convex parts)."""

    visual: dict[str, Path]
    collision: Mapping[str, Sequence[str | Path]]

    @classmethod
    def of(cls, visual_dirs: Mapping[str, str | Path] | Sequence[str | Path],
           collision: Mapping[str, Sequence[str | Path]]) -> BuiltMeshes:
        """``visual_dirs``: a list of directories (a directory's name is its mesh name, the URI's file stem) or a
        mapping URI -> directory."""
        if isinstance(visual_dirs, Mapping):
            return cls({mesh_name(uri): Path(d) for uri, d in visual_dirs.items()}, collision)
        return cls({Path(d).name: Path(d) for d in visual_dirs}, collision)
