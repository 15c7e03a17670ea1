"""Atomic, deterministic file output and validated YAML/JSON input.

Outputs are written to a temporary file beside the target and renamed into place, so a
failure never leaves a partial output behind.
"""

from __future__ import annotations

import contextlib
import copy
import enum
import json
import os
import shutil
import tempfile
from collections.abc import Collection, Iterable, Iterator, Mapping
from functools import cache
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from sim2real.errors import InputError

SCHEMA_DIR = Path(__file__).resolve().parents[2] / "schemas"
# libyaml's emitter and parser where PyYAML has them: the same events, the same text, several times faster (a
# designed excitation's trajectory, 0.7 MB of YAML, is written in 0.4 s instead of 2 s; each rule reads its schema,
# and Snakemake's input functions read the configs at every start: the Panda's lab.yaml in 12 ms instead of 120).


class _YAML_DUMPER(getattr(yaml, "CSafeDumper", yaml.SafeDumper)):  # type: ignore[misc]
    """The safe dumper, writing a string enum's member as its value (``torque_sensor: link``)."""


_YAML_DUMPER.add_multi_representer(enum.StrEnum, lambda dumper, member: dumper.represent_str(str(member)))
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@contextlib.contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path; move it onto ``target`` only if the block succeeds."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); outputs get the usual permissions.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(target: str | Path) -> Iterator[Path]:
    """Yield a temporary directory; it replaces ``target`` only if the block succeeds."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def relative_path(path: str | Path, start: str | Path) -> str:
    """``path`` relative to the directory ``start``, with forward slashes: what an output written in ``start``
    names another by (a mesh in the MJCF, a figure in gap.md), the same on every machine."""
    return Path(os.path.relpath(Path(path).resolve(), Path(start).resolve())).as_posix()


def write_text(target: str | Path, text: str) -> None:
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes(target: str | Path, data: bytes) -> None:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


ARCHIVE_TIME = (1980, 1, 1, 0, 0, 0)  # every member of an archive: the same arrays give the same bytes


def write_array_archive(target: str | Path, arrays: Iterable[tuple[str, Any]] | Mapping[str, Any],
                        header: Mapping[str, Any]) -> None:
    """A zip of ``.npy`` members (in the order given) and ``header.json`` last, with fixed member times: the
    same arrays and header give the same bytes. :func:`read_array_archive` reads it back."""
    import io as _io
    import zipfile

    import numpy as np

    items = arrays.items() if isinstance(arrays, Mapping) else arrays
    with atomic_path(target) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as archive:
        for name, value in items:
            buffer = _io.BytesIO()
            np.lib.format.write_array(buffer, np.asarray(value), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=ARCHIVE_TIME), buffer.getvalue())
        archive.writestr(zipfile.ZipInfo("header.json", date_time=ARCHIVE_TIME),
                         json.dumps(header, sort_keys=True, indent=1))


def read_array_archive(path: str | Path, wanted: Any = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(header, arrays) of a file of :func:`write_array_archive`; ``wanted(name)`` says which arrays to read
    (default: all). Raises OSError, KeyError, ValueError or zipfile.BadZipFile on a file of another kind."""
    import zipfile

    import numpy as np

    with zipfile.ZipFile(path) as archive:
        header = json.loads(archive.read("header.json"))
        arrays = {member[:-4]: np.lib.format.read_array(archive.open(member), allow_pickle=False)
                  for member in archive.namelist()
                  if member.endswith(".npy") and (wanted is None or wanted(member[:-4]))}
    return header, arrays


def write_json(target: str | Path, data: Any) -> None:
    """Deterministic JSON: sorted keys, fixed indentation, trailing newline."""
    write_text(target, json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n")


def dump_yaml(data: Any, **options: Any) -> str:
    """YAML text of plain data (what ``yaml.safe_dump`` writes, with the same ``options``)."""
    return yaml.dump(data, Dumper=_YAML_DUMPER, **options)


def write_yaml(target: str | Path, data: Any) -> None:
    write_text(target, dump_yaml(data, sort_keys=True, default_flow_style=False))


def read_yaml(path: str | Path) -> Any:
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, "file does not exist", "create it or correct the path")
    text = path.read_text(encoding="utf-8")
    try:
        return yaml.load(text, Loader=_YAML_LOADER)
    except yaml.YAMLError:
        pass  # libyaml's message is terser ("found character that cannot start any token"): PyYAML's names it
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else None
        raise InputError(path, where, f"is not valid YAML ({getattr(exc, 'problem', exc)})", "fix the YAML syntax") from exc


@cache
def load_schema(name: str) -> dict[str, Any]:
    """Load ``schemas/<name>`` (YAML or JSON)."""
    path = SCHEMA_DIR / name
    return yaml.load(path.read_text(encoding="utf-8"), Loader=_YAML_LOADER)


def validate(data: Any, schema_name: str, path: str | Path | None = None) -> Any:
    """Validate ``data`` against ``schemas/<schema_name>``; the error names the key path.

    Reports the most specific error: a failed ``allOf`` branch also makes ``unevaluatedProperties``
    flag every sibling key, which would hide the real culprit.
    """
    validator = jsonschema.Draft202012Validator(load_schema(schema_name))
    errors = list(validator.iter_errors(data))
    if errors:
        specific = [e for e in errors if e.validator != "unevaluatedProperties"] or errors
        err = max(specific, key=lambda e: (len(e.absolute_path), list(map(str, e.absolute_path))))
        key_path = "/".join(str(p) for p in err.absolute_path) or "<top level>"
        raise InputError(
            path,
            f"key '{key_path}'",
            f"{err.message} (schema {schema_name})",
            f"make '{key_path}' match schemas/{schema_name} (see the descriptions there)",
        )
    return data


def read_validated_yaml(path: str | Path, schema_name: str) -> Any:
    data = read_yaml(path)
    return validate(data, schema_name, path)


def merge_settings(base: Mapping[str, Any], override: Mapping[str, Any], replace: Collection[str] = ()) -> dict[str, Any]:
    """``override`` merged into a copy of ``base``, nested maps key by key (a config's ``defaults`` under each
    entry); the keys in ``replace`` are taken whole from ``override`` (a scenario's own ``effects``)."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping) and key not in replace:
            out[key] = merge_settings(out[key], value, replace)
        else:
            out[key] = copy.deepcopy(value)
    return out
