"""The fits kept between rounds of the loop (sim2real.cache): a rung read back is the rung refitted,
to the last bit; a change of any input refits it."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from sim2real.identification import fitting
from sim2real.identification import side_ladder, sysid
from sim2real.cache import ROUND_MARK, FitCache, digest
from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run
from test_sysid import _write_real_log


def test_digest_follows_every_value_and_nothing_else():
    data = fitting.stack_runs([make_run("a", {}, 1, duration=2.0)], PANDA_JOINTS)
    same = fitting.stack_runs([make_run("a", {}, 1, duration=2.0)], PANDA_JOINTS)
    assert digest(data, ["coulomb_friction"]) == digest(same, ["coulomb_friction"])
    moved = dataclasses.replace(data, tau=data.tau.copy())
    moved.tau[5, 3] = np.nextafter(moved.tau[5, 3], np.inf)  # one bit of one sample
    assert digest(moved, ["coulomb_friction"]) != digest(data, ["coulomb_friction"])
    assert digest(data, ["coulomb_friction"]) != digest(data, ["viscous_friction"])
    assert digest({"a": 1, "b": 2.0}) == digest({"b": 2.0, "a": 1})
    assert digest({"a": 1}) != digest({"a": 1.0})  # an int is not its float
    assert digest([1, 2]) != digest((1, 2)) and digest(np.zeros(3)) != digest(np.zeros(3, dtype=np.float32))
    with pytest.raises(TypeError, match="no digest"):
        digest({1, 2})


def test_an_entry_is_computed_once_read_back_and_pruned_when_unused(tmp_path):
    calls = []

    def work(value):
        calls.append(value)
        return {"value": np.arange(3) * value}

    cache = FitCache(tmp_path / "fits")
    first = cache.get_or_compute("rung", digest("a"), lambda: work(2))
    again = FitCache(tmp_path / "fits").get_or_compute("rung", digest("a"), lambda: work(2))
    assert calls == [2] and np.array_equal(first["value"], again["value"])
    # an unreadable entry (a disk filled midway) is computed again, never an error
    (entry,) = (tmp_path / "fits").iterdir()
    entry.write_bytes(b"not a pickle")
    assert np.array_equal(FitCache(tmp_path / "fits").get_or_compute("rung", digest("a"), lambda: work(2))["value"],
                          first["value"])
    assert calls == [2, 2]
    # a later round that uses only another entry removes this one
    past = entry.stat().st_mtime - 10.0
    os.utime(entry, (past, past))
    later = FitCache(tmp_path / "fits")
    later.get_or_compute("rung", digest("b"), lambda: work(3))
    later.prune()
    kept = [p.name.split("-")[0] for p in (tmp_path / "fits").iterdir() if p.name != ROUND_MARK]
    assert kept == ["rung"] and not entry.exists()
    assert FitCache(None).get_or_compute("rung", "", lambda: work(4))["value"][1] == 4  # None keeps nothing


def test_a_round_keeps_what_it_and_the_round_before_used_so_an_undone_round_refits_nothing(tmp_path):
    calls = []
    t0 = 1.7e9  # rounds a minute apart: an entry's mtime is when a round last read or wrote it

    def round_(start: float, used: list[str]) -> list[str]:
        cache = FitCache(tmp_path / "fits")
        cache.started = start
        for name in used:
            cache.get_or_compute("rung", digest(name), lambda name=name: calls.append(name) or name)
            os.utime(cache._path("rung", digest(name)), (start, start))
        cache.prune()
        return [name for name in "abc" if cache._path("rung", digest(name)).exists()]

    assert round_(t0, ["a"]) == ["a"]
    assert round_(t0 + 60, ["a", "b"]) == ["a", "b"]  # a line added: b is new
    assert round_(t0 + 120, ["a"]) == ["a", "b"]  # removed again: read back; b stays for one more round
    assert calls == ["a", "b"]
    assert round_(t0 + 180, ["a", "c"]) == ["a", "c"]  # another line: b was used two rounds ago, and is gone
    assert round_(t0 + 240, ["a", "b"]) == ["a", "b", "c"] and calls == ["a", "b", "c", "b"]  # c: the round before
    assert (tmp_path / "fits" / ROUND_MARK).read_text() == repr(t0 + 240)


def test_a_round_after_one_added_line_refits_only_the_new_rung_and_writes_the_same_bytes(tmp_path, monkeypatch):
    for name, seed in (("a", 7), ("b", 8)):
        _write_real_log(tmp_path / f"{name}.csv", make_run(name, {"coulomb_friction": [0.6] * 7}, seed,
                                                            duration=6.0, rate=500.0), with_repeats=False)
    (tmp_path / "measurements.yaml").write_text(yaml.safe_dump({"runs": [
        {"name": "a", "path": "a.csv", "role": "fit"}, {"name": "b", "path": "b.csv", "role": "holdout"}]}))
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump({"armature": {"panda_joint*": 0.1}, "flange": "panda_link8"}))
    settings = "fit: {bootstrap_replicates: 10, fit_rate_hz: 100}\ndiagnosis: {}\n"
    fitted = []
    original = fitting.fit_on_the_previous

    def counted(effects, *args, **kwargs):
        fitted.append(list(effects))
        return original(effects, *args, **kwargs)

    monkeypatch.setattr(side_ladder, "fit_on_the_previous", counted)

    def round_(effects, out, cache):
        model = tmp_path / "model.yaml"
        model.write_text(yaml.safe_dump({"effects": effects}) + settings)
        fitted.clear()
        sysid.run_sysid("panda", sysid.SysidFiles(PANDA_URDF, tmp_path / "robot.yaml", model,
                                                  tmp_path / "measurements.yaml", out / "ladder.json",
                                                  out / "params.yaml", out / "calibration.yaml", root=tmp_path),
                        cache_dir=cache)
        return [(out / name).read_bytes() for name in ("ladder.json", "params.yaml", "calibration.yaml")]

    fits = tmp_path / "fits"
    round_(["coulomb_friction"], tmp_path / "r1", fits)
    assert fitted == [[], ["coulomb_friction"]]
    added = round_(["coulomb_friction", "viscous_friction"], tmp_path / "r2", fits)
    assert fitted == [["coulomb_friction", "viscous_friction"]]  # the rungs before it are read back
    assert added == round_(["coulomb_friction", "viscous_friction"], tmp_path / "fresh", None)  # the same bytes
    assert fitted == [[], ["coulomb_friction"], ["coulomb_friction", "viscous_friction"]]
    # a measurement that changed (one sample of the fit run) refits every rung
    run = tmp_path / "a.csv"
    lines = run.read_text().splitlines()
    cells = lines[10].split(",")
    cells[-1] = repr(float(cells[-1]) + 0.25)
    run.write_text("\n".join([*lines[:10], ",".join(cells), *lines[11:]]) + "\n")
    round_(["coulomb_friction", "viscous_friction"], tmp_path / "r3", fits)
    assert fitted == [[], ["coulomb_friction"], ["coulomb_friction", "viscous_friction"]]


def test_the_bodies_mesh_bounds_are_kept_and_follow_the_meshes(tmp_path, monkeypatch):
    """load_nominal reads the collision meshes (and imports trimesh) only when the URDF or a mesh changed."""
    from sim2real.identification.fitting import nominal as nominal_module
    from sim2real.assets.urdf import resolve_package_uri

    urdf = tmp_path / "panda.urdf"
    shutil.copy(PANDA_URDF, urdf)
    text = urdf.read_text()
    meshes = sorted(set(re.findall(r'filename="([^"]+\.(?:stl|obj|dae))"', text)))
    assert meshes, "the test URDF names collision meshes"
    calls = []
    real = nominal_module._mesh_bounds
    monkeypatch.setattr(nominal_module, "_mesh_bounds", lambda *a: calls.append(1) or real(*a))
    plain = fitting.load_nominal(urdf, PANDA_JOINTS)
    assert calls == []  # without a cache they are read when first asked for: a friction fit never reads them
    plain_ellipsoids = plain.info["mesh_bounds"].ellipsoids
    cache = FitCache(tmp_path / "fits")
    kept = [fitting.load_nominal(urdf, PANDA_JOINTS, cache=FitCache(tmp_path / "fits")) for _ in range(2)]
    assert len(calls) == 2  # once without the cache, once to fill it
    assert digest(kept[1].info) == digest(plain.info)
    assert all((a is None and b is None) or np.array_equal(a, b)
               for a, b in zip(kept[1].info["mesh_bounds"].ellipsoids, plain_ellipsoids, strict=True))
    assert any(q is not None for q in plain_ellipsoids) and len(calls) == 2
    # a mesh whose bytes change (same name) is read again
    collision = next(m for m in meshes if m.endswith("collision/link1.stl"))  # the first moving body's
    source = resolve_package_uri(collision, source=PANDA_URDF)
    local = tmp_path / Path(source).name
    shutil.copy(source, local)
    urdf.write_text(text.replace(f'filename="{collision}"', f'filename="{local.name}"'))
    fitting.load_nominal(urdf, PANDA_JOINTS, cache=cache)
    assert len(calls) == 3
    fitting.load_nominal(urdf, PANDA_JOINTS, cache=cache)
    assert len(calls) == 3
    local.write_bytes(local.read_bytes() + b"\n")
    fitting.load_nominal(urdf, PANDA_JOINTS, cache=cache)
    assert len(calls) == 4
