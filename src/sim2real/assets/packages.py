"""Resolution of ``package://`` URIs: where the packages a robot's files name live.

The built URDF keeps ``package://`` URIs (no absolute path reaches an output); validation resolves
them with :func:`resolve_package_uri`, the one place that knows where packages live.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from sim2real.errors import InputError

PROJECT_ROOT = Path(__file__).resolve().parents[3]
PACKAGE_PREFIX = "package://"


def package_search_dirs(robots_dir: str | Path | None = None) -> list[Path]:
    """Directories that may hold a package, in search order.

    1. ``<site-packages>/cmeel.prefix/share`` (example-robot-data installs there),
    2. the project's ``robots/`` directory (``package://panda/...`` = ``robots/panda/...``),
    3. every entry of ``ROS_PACKAGE_PATH``.
    """
    dirs: list[Path] = []
    for entry in sys.path:
        share = Path(entry or ".") / "cmeel.prefix" / "share"
        if share.is_dir() and share.resolve() not in dirs:
            dirs.append(share.resolve())
    dirs.append(Path(robots_dir) if robots_dir is not None else PROJECT_ROOT / "robots")
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            dirs.append(Path(entry))
    return dirs


def resolve_package_uri(
    uri: str,
    *,
    source: str | Path | None = None,
    where: str | None = None,
    robots_dir: str | Path | None = None,
) -> Path:
    """Absolute path of ``package://NAME/rel`` (or of a plain relative/absolute path).

    A package that no search directory holds is an :class:`InputError` naming ``source``/``where``.
    The file itself need not exist (callers check that, to give their own message).
    """
    if not uri.startswith(PACKAGE_PREFIX):
        if uri.startswith("file://"):
            uri = uri[len("file://"):]
        path = Path(uri)
        if not path.is_absolute() and source is not None:
            path = Path(source).parent / path
        return path
    package, _, relative = uri[len(PACKAGE_PREFIX):].partition("/")
    searched = package_search_dirs(robots_dir)
    for base in searched:
        candidate = base / package
        if candidate.is_dir():
            return candidate / relative
    raise InputError(
        source,
        where,
        f"unknown package '{package}' in '{uri}' (searched {', '.join(str(d) for d in searched)})",
        "use package://example-robot-data/... for the example-robot-data meshes, put the package under "
        "robots/, or add its parent directory to ROS_PACKAGE_PATH",
    )
