"""Convex decomposition of collision meshes with CoACD, and how well the parts follow the source.

One call of :func:`decompose` turns one source mesh (a built visual mesh directory or a coarse
collision STL) into a directory of convex parts plus a ``parts.json`` manifest that also carries
the shape-fidelity measures of :func:`shape_fidelity`. Everything in that directory is a pure
function of the source bytes and the settings (fixed CoACD seed, fixed sampling seed), so a rebuild
is byte-identical. Wall-clock time is returned separately so it never enters the byte-compared
outputs.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.errors import InputError
from sim2real.files import atomic_dir, write_json, write_text

if TYPE_CHECKING:
    import trimesh

PARTS_MANIFEST = "parts.json"
SOURCES = ("visual", "collision")
SURFACE_SAMPLES = 3000  # points per surface for the distance measures; enough for ~0.1 mm stable means
SAMPLE_SEED = 0
VOXELS_PER_EXTENT = 80  # solid voxel model of the source: ~2-3 mm on a Panda link (collision.voxels_per_extent)


@dataclass(frozen=True)
class CoacdSettings:
    """CoACD parameters (names as in ``coacd.run_coacd``); defaults are CoACD's own except max hulls."""

    threshold: float = 0.05
    max_convex_hull: int = 24
    preprocess_mode: str = "auto"
    preprocess_resolution: int = 50
    resolution: int = 2000
    mcts_nodes: int = 20
    mcts_iterations: int = 150
    mcts_max_depth: int = 3
    merge: bool = True
    max_ch_vertex: int = 256
    seed: int = 0


@dataclass(frozen=True)
class Tolerance:
    """A part set is flagged when it misses the source shape by more than this."""

    hausdorff_mm: float = 15.0
    volume_ratio_min: float = 0.85
    volume_ratio_max: float = 1.6


@dataclass(frozen=True)
class MeshSettings:
    """Everything that decides one mesh's decomposition and its measures: the source kind, CoACD parameters and
    the resolution of the source's voxel solid the fidelity measures use."""

    source: str = "visual"
    coacd: CoacdSettings = field(default_factory=CoacdSettings)
    voxels_per_extent: int = VOXELS_PER_EXTENT

    def as_params(self) -> dict[str, Any]:
        """Plain dict for Snakemake ``params`` (a change reruns only this mesh's job)."""
        return {"source": self.source, "voxels_per_extent": self.voxels_per_extent, **asdict(self.coacd)}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> MeshSettings:
        values = dict(params)
        source = values.pop("source", "visual")
        voxels = values.pop("voxels_per_extent", VOXELS_PER_EXTENT)
        return cls(source=source, coacd=CoacdSettings(**values), voxels_per_extent=voxels)


def mesh_settings(collision_config: Mapping[str, Any] | None, mesh_name: str, config_path: str | Path | None = None) -> MeshSettings:
    """Settings of one mesh: defaults < ``collision.coacd`` / ``collision.source`` < ``collision.overrides.<mesh>``.

    ``collision_config`` is the ``collision:`` section of ``configs/<robot>/robot.yaml`` (schema-validated).
    """
    section = dict(collision_config or {})
    source = section.get("source", "visual")
    coacd_values: dict[str, Any] = dict(section.get("coacd", {}))
    override = dict(section.get("overrides", {}).get(mesh_name, {}))
    source = override.pop("source", source)
    coacd_values.update(override)
    if source not in SOURCES:
        raise InputError(config_path, f"collision source of mesh '{mesh_name}'", f"'{source}' is not a source kind",
                         f"use one of {', '.join(SOURCES)}")
    known = set(CoacdSettings.__dataclass_fields__)
    unknown = sorted(set(coacd_values) - known)
    if unknown:
        raise InputError(config_path, f"collision settings of mesh '{mesh_name}'", f"unknown key(s) {', '.join(unknown)}",
                         f"use only {', '.join(sorted(known))}")
    voxels = int(section.get("voxels_per_extent", VOXELS_PER_EXTENT))
    return MeshSettings(source=source, coacd=CoacdSettings(**coacd_values), voxels_per_extent=voxels)


def tolerance(collision_config: Mapping[str, Any] | None) -> Tolerance:
    values = dict((collision_config or {}).get("tolerance", {}))
    return Tolerance(**values)


# --------------------------------------------------------------------------------------------- source


def load_source_mesh(source: str | Path) -> trimesh.Trimesh:
    """One triangle mesh from a mesh file, or from a built visual mesh directory (all its OBJ parts).

    Vertices shared by several material submeshes are merged so CoACD sees one connected surface.
    """
    import trimesh
    source = Path(source)
    if source.is_dir():
        manifest_path = source / PARTS_MANIFEST
        if manifest_path.exists():
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
            files = [source / part["file"] for part in manifest["parts"]]
        else:
            files = sorted(source.glob("*.obj"))
        if not files:
            raise InputError(source, None, "holds no mesh parts", "rebuild the visual meshes of this robot")
    elif source.exists():
        files = [source]
    else:
        raise InputError(source, None, "mesh file does not exist", "build the meshes first or correct the path")
    meshes = []
    for path in files:
        try:
            loaded = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # trimesh raises assorted errors on bad files
            raise InputError(path, None, f"cannot be read as a mesh ({exc})", "re-export the mesh") from exc
        if len(loaded.faces):
            meshes.append(trimesh.Trimesh(loaded.vertices, loaded.faces, process=False))
    if not meshes:
        raise InputError(source, None, "has no triangles", "check the source mesh")
    mesh = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
    mesh.merge_vertices()
    mesh.remove_unreferenced_vertices()
    return mesh


# ---------------------------------------------------------------------------------------- decompose


def run_coacd(mesh: trimesh.Trimesh, settings: CoacdSettings) -> list[trimesh.Trimesh]:
    """CoACD parts as trimesh meshes, in CoACD's (deterministic, seeded) order."""
    import trimesh
    import coacd

    coacd.set_log_level("error")
    raw = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32)),
        threshold=settings.threshold,
        max_convex_hull=settings.max_convex_hull,
        preprocess_mode=settings.preprocess_mode,
        preprocess_resolution=settings.preprocess_resolution,
        resolution=settings.resolution,
        mcts_nodes=settings.mcts_nodes,
        mcts_iterations=settings.mcts_iterations,
        mcts_max_depth=settings.mcts_max_depth,
        merge=settings.merge,
        max_ch_vertex=settings.max_ch_vertex,
        seed=settings.seed,
    )
    parts = []
    for vertices, faces in raw:
        part = trimesh.Trimesh(np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64), process=False)
        part.fix_normals()  # outward winding, so volume and inside tests are signed correctly
        parts.append(part)
    return parts


@dataclass(frozen=True)
class Decomposition:
    parts_dir: Path
    part_files: list[Path]
    fidelity: dict[str, Any]
    seconds: float  # wall clock of CoACD + measures: never written into parts_dir


def decompose(source: str | Path, settings: MeshSettings, out_dir: str | Path, mesh_name: str | None = None) -> Decomposition:
    """Decompose ``source`` into convex parts under ``out_dir`` (atomically replaced).

    ``out_dir`` holds ``part_NN.stl`` (binary STL, link frame, metres) and ``parts.json`` with the
    settings, the part list and the fidelity measures.
    """
    out_dir = Path(out_dir)
    name = mesh_name or out_dir.name
    start = time.perf_counter()
    mesh = load_source_mesh(source)
    parts = run_coacd(mesh, settings.coacd)
    if not parts:
        raise InputError(source, f"mesh '{name}'", "CoACD returned no convex part", "check that the mesh is closed or lower the threshold")
    fidelity = shape_fidelity(mesh, parts, settings.voxels_per_extent)
    seconds = time.perf_counter() - start
    files = [f"part_{index:02d}.stl" for index in range(len(parts))]
    with atomic_dir(out_dir) as tmp:
        for file, part in zip(files, parts, strict=True):
            (tmp / file).write_bytes(part.export(file_type="stl"))
        manifest = {
            "mesh": name,
            "source_kind": settings.source,
            "settings": settings.as_params(),
            "parts": [{"file": file, "vertices": len(part.vertices), "faces": len(part.faces)} for file, part in zip(files, parts, strict=True)],
            "fidelity": fidelity,
        }
        write_json(tmp / PARTS_MANIFEST, manifest)
    return Decomposition(out_dir, [out_dir / f for f in files], fidelity, seconds)


def part_files(parts_dir: str | Path) -> list[Path]:
    """The convex part files of a decomposition directory, in manifest order (for MJCF and USD)."""
    parts_dir = Path(parts_dir)
    manifest_path = parts_dir / PARTS_MANIFEST
    if not manifest_path.exists():
        raise InputError(manifest_path, None, "collision parts manifest is missing", "rerun the collision decomposition rule")
    manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    return [parts_dir / part["file"] for part in manifest["parts"]]


def parts_by_uri(parts_dirs: Mapping[str, str | Path]) -> dict[str, list[str]]:
    """{collision mesh URI: its convex part files} from {URI: decomposition directory}."""
    return {uri: [str(f) for f in part_files(d)] for uri, d in parts_dirs.items()}


# ----------------------------------------------------------------------------------------- fidelity


def _inside_any(points: np.ndarray, hulls: Sequence[trimesh.Trimesh], tol: float = 1e-9) -> np.ndarray:
    """Whether each point lies in at least one convex part (half-space test, exact for convex parts)."""
    inside = np.zeros(len(points), dtype=bool)
    for hull in hulls:
        normals = hull.face_normals
        offsets = np.einsum("ij,ij->i", normals, hull.triangles[:, 0, :])
        outside = np.flatnonzero(~inside)  # a point inside one part needs no other
        inside[outside] = np.all(points[outside] @ normals.T - offsets <= tol, axis=1)
    return inside


def _distance_to_parts(points: np.ndarray, parts: Sequence[trimesh.Trimesh]) -> np.ndarray:
    """Distance from each point to the union of the convex parts (0 inside)."""
    import trimesh
    union = trimesh.util.concatenate(list(parts)) if len(parts) > 1 else parts[0]
    distance = np.zeros(len(points))
    outside = ~_inside_any(points, parts)  # only these have a distance to look for
    if outside.any():
        distance[outside] = trimesh.proximity.closest_point(union, points[outside])[1]
    return distance


def solid_voxels(source: trimesh.Trimesh, voxels_per_extent: int = VOXELS_PER_EXTENT) -> trimesh.voxel.VoxelGrid:
    """The source as a filled voxel solid: enclosed cavities of a CAD shell count as material.

    Collision shapes may fill a sealed cavity without any effect on contacts, so the measures treat
    the inside of that solid as source. It also gives a volume for sources that are not closed.
    """
    pitch = float(np.max(source.extents)) / voxels_per_extent
    return source.voxelized(pitch).fill()


def shape_fidelity(source: trimesh.Trimesh, parts: Sequence[trimesh.Trimesh],
                   voxels_per_extent: int = VOXELS_PER_EXTENT) -> dict[str, Any]:
    """How closely the parts follow the source surface, in mm, plus a volume ratio.

    Two one-sided distances on seeded surface samples:
    - ``source_to_parts``: source surface outside every part (shape the parts miss);
    - ``parts_to_source``: outer surface of the parts (samples not inside another part and not inside
      the source solid) to the source surface (concavities the parts fill).
    ``hausdorff_mm`` is the larger maximum, ``mean_mm`` the mean over both sample sets.
    ``volume_ratio`` is the summed part volume (overlaps count twice) over the source volume: exact
    for a closed source, else the filled voxel volume (``source_watertight`` says which).
    """
    import trimesh
    solid = solid_voxels(source, voxels_per_extent)
    source_points, _ = trimesh.sample.sample_surface(source, SURFACE_SAMPLES, seed=SAMPLE_SEED)
    miss = _distance_to_parts(source_points, parts)
    outer_points = []
    for index, part in enumerate(parts):
        points, _ = trimesh.sample.sample_surface(part, max(50, SURFACE_SAMPLES // len(parts)), seed=SAMPLE_SEED + index)
        others = [p for j, p in enumerate(parts) if j != index]
        if others:
            # strictly inside another part: an internal face, not part of the collision surface
            points = points[~_inside_any(points, others, tol=-1e-6)]
        outer_points.append(points)
    outer = np.concatenate(outer_points)
    closest, fill, triangle = trimesh.proximity.closest_point(source, outer)
    fill = np.asarray(fill)
    # Part surface inside the source solid (a cut face between parts, a sealed cavity) fills nothing;
    # nor does part surface behind the nearest source face (side from its normal, for open meshes).
    side = np.einsum("ij,ij->i", outer - closest, source.face_normals[triangle])
    fill[(side < 0) | solid.is_filled(outer)] = 0.0
    both = np.concatenate([miss, fill])
    watertight = bool(source.is_watertight)
    source_volume = float(abs(source.volume)) if watertight else float(solid.volume)
    parts_volume = float(sum(abs(p.volume) for p in parts))
    return {
        "hulls": len(parts),
        "hausdorff_mm": round(float(both.max()) * 1e3, 3),
        "mean_mm": round(float(both.mean()) * 1e3, 3),
        "source_to_parts_max_mm": round(float(miss.max()) * 1e3, 3),
        "parts_to_source_max_mm": round(float(fill.max()) * 1e3, 3),
        "volume_ratio": round(parts_volume / source_volume, 4) if source_volume > 0 else None,
        "source_volume_cm3": round(source_volume * 1e6, 3),
        "parts_volume_cm3": round(parts_volume * 1e6, 3),
        "source_watertight": watertight,
        "source_faces": len(source.faces),
    }


def flag_reasons(fidelity: Mapping[str, Any], limit: Tolerance) -> list[str]:
    """Why a part set misses the shape (empty when within tolerance)."""
    reasons = []
    if fidelity["hausdorff_mm"] > limit.hausdorff_mm:
        reasons.append(f"Hausdorff {fidelity['hausdorff_mm']:.1f} mm > {limit.hausdorff_mm:g} mm")
    ratio = fidelity.get("volume_ratio")
    if ratio is not None and not limit.volume_ratio_min <= ratio <= limit.volume_ratio_max:
        reasons.append(f"volume ratio {ratio:.3f} outside [{limit.volume_ratio_min:g}, {limit.volume_ratio_max:g}]")
    return reasons


# ------------------------------------------------------------------------------------------- report


def write_timing(target: str | Path, mesh_name: str, seconds: float) -> None:
    """Per-mesh wall clock, kept apart from the deterministic outputs."""
    write_json(target, {"mesh": mesh_name, "seconds": round(seconds, 3)})


def collision_report(
    parts_dirs: Mapping[str, str | Path],
    timing_files: Mapping[str, str | Path],
    limit: Tolerance,
    out_json: str | Path,
    out_table: str | Path,
) -> dict[str, Any]:
    """Aggregate per-mesh manifests into ``report.json`` (deterministic) and a TSV table (with times).

    Times live only in the table: they differ run to run, ``report.json`` must not.
    """
    meshes: dict[str, Any] = {}
    rows = ["mesh\tsource\thulls\tvolume_ratio\thausdorff_mm\tmean_mm\tseconds\tflag"]
    for name in sorted(parts_dirs):
        manifest = json.loads((Path(parts_dirs[name]) / PARTS_MANIFEST).read_text(encoding="utf-8"))
        fidelity = manifest["fidelity"]
        reasons = flag_reasons(fidelity, limit)
        meshes[name] = {
            **fidelity,
            "source_kind": manifest["source_kind"],
            "settings": manifest["settings"],
            "flagged": bool(reasons),
            "flag_reasons": reasons,
        }
        seconds = json.loads(Path(timing_files[name]).read_text(encoding="utf-8"))["seconds"] if name in timing_files else float("nan")
        rows.append(
            f"{name}\t{manifest['source_kind']}\t{fidelity['hulls']}\t{fidelity['volume_ratio']}\t"
            f"{fidelity['hausdorff_mm']}\t{fidelity['mean_mm']}\t{seconds:.2f}\t{'; '.join(reasons) or 'ok'}"
        )
    report = {
        "tolerance": asdict(limit),
        "meshes": meshes,
        "flagged": sorted(name for name, entry in meshes.items() if entry["flagged"]),
        "total_hulls": sum(entry["hulls"] for entry in meshes.values()),
    }
    write_json(out_json, report)
    write_text(out_table, "\n".join(rows) + "\n")
    return report
