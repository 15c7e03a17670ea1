"""Mesh conversion: Collada visual meshes -> one OBJ per material + parts.json; STL collision copies.

MuJoCo reads neither DAE nor materials from meshes, so each visual mesh becomes one OBJ per material
and a ``parts.json`` that carries each part's color::

    {"source": "<package uri>", "parts": [{"file": "<name>_<i>.obj", "material": "<name>", "rgba": [r, g, b, a]}]}

Outputs are deterministic (fixed number format, sorted vertex table) and written atomically.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim2real.assets.urdf import mesh_name
from sim2real.errors import InputError
from sim2real.files import atomic_dir, atomic_path, write_json

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


def read_collada_parts(dae_path: str | Path, source_label: str | None = None) -> list[_Part]:
    """Triangles of a Collada file grouped by material, in order of first appearance.

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
        raise InputError(label, None, f"cannot read the Collada file ({exc})", "re-export the mesh as valid Collada 1.4") from exc
    scale = float(document.assetInfo.unitmeter or 1.0)
    rotation = _up_axis_rotation(getattr(document.assetInfo, "upaxis", None))
    parts: dict[str, _Part] = {}
    if document.scene is None:
        raise InputError(label, "<scene>", "the Collada file has no scene", "export the mesh with a visual scene")
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
        raise InputError(label, "<library_geometries>", "no triangle geometry found", "export the mesh with triangles")
    return list(parts.values())


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


def convert_visual_mesh(dae_path: str | Path, out_dir: str | Path, source_uri: str) -> dict:
    """Write ``out_dir/{name}_{i}.obj`` per material and ``out_dir/parts.json``; return the parts record.

    ``name`` is the stem of ``out_dir``. The directory is replaced atomically.
    """
    out_dir = Path(out_dir)
    name = out_dir.name
    parts = read_collada_parts(dae_path, source_label=source_uri)
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


def convert_collision_mesh(stl_path: str | Path, out_path: str | Path, source_uri: str | None = None) -> None:
    """Copy a collision STL: binary STL byte for byte; ASCII STL rewritten as binary."""
    stl_path = Path(stl_path)
    label = source_uri or str(stl_path)
    if not stl_path.is_file():
        raise InputError(label, None, f"collision mesh does not exist ({stl_path})", "correct the URI or add the file")
    data = stl_path.read_bytes()
    count = int(np.frombuffer(data[80:84], dtype="<u4")[0]) if len(data) >= 84 else -1
    if count > 0 and len(data) == 84 + 50 * count:
        payload = data  # binary STL, consistent size
    elif data.lstrip().startswith(b"solid") and b"vertex" in data:
        triangles = _ascii_stl_triangles(data)
        if len(triangles) == 0:
            raise InputError(label, None, "the ASCII STL has no triangles", "re-export the mesh")
        payload = _binary_stl(triangles)
    else:
        raise InputError(label, None, "is neither a binary nor an ASCII STL (or has no triangles)", "re-export the mesh as STL")
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
