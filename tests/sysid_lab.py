"""Virtual-lab data for the sysid/diagnosis tests, generated once per test session (fast settings).

The lab (sim2real.lab) implements its hidden effects itself; these tests only see its runs,
never truth.yaml, exactly like the pipeline.
"""

from __future__ import annotations

import copy
import os
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd
import yaml
from threadpoolctl import threadpool_limits

from gap_fixtures import build_dev_iiwa14, build_dev_panda, build_dev_ur5, short_lab_config
from sim2real.identification import fitting
from sim2real.identification import sides, sysid
from sim2real.identification.fitting import FitContext
from sim2real.identification.model_config import ModelConfig, parse_model_config
from sim2real.report.verdicts import worded
from sim2real.cache import FitCache
from sim2real.lab import load_lab_config, run_lab_scenario_run, scenario_runs
from sim2real.measurements import noise_floor_of, load_prepared_runs

# Fast settings: decimated fit grid, few bootstrap replicates, a small refinement subset.
FAST_FIT = {"fit_rate_hz": 100.0, "bootstrap_replicates": 20, "refine_max_samples": 1500}
LAB_DURATION_S = 8.0
# The fits spread their candidates and links over the machine's cores, as the sysid rule does with its
# threads: the same numbers on any count (tests/test_loop_pinned.py), in less wall time.
WORKERS = min(2, os.cpu_count() or 1)


DEV_ARMS = {"panda": build_dev_panda, "ur5": build_dev_ur5, "iiwa14": build_dev_iiwa14}


class Lab:
    """A dev arm (``robot``: a Panda, a UR5 or the shipped iiwa 14; its URDF + the MJCF MuJoCo makes of it), its short lab config
    (configs/<robot>/lab.yaml), runs on demand."""

    def __init__(self, directory: Path, robot: str = "panda") -> None:
        self.dir = directory
        self.robot = robot
        self.urdf, self.mjcf = DEV_ARMS[robot](directory)
        self.lab_config = short_lab_config(directory, duration_s=LAB_DURATION_S, robot=robot)
        self.joints = list(load_lab_config(self.lab_config)["joints"])
        # The dev MJCF comes straight from the URDF: no extra armature, the flange is the last link.
        self.nominal = fitting.load_nominal(self.urdf, self.joints)
        self._data: dict[str, tuple[fitting.TorqueData, fitting.TorqueData]] = {}
        self._followed: dict[tuple[str, int, tuple[str, ...]], list[dict[str, Any]]] = {}
        # Documents already fitted, by what was asked: the fits are deterministic, so a test asking again (another
        # parameter of the same test, the first round of a scenario another test followed) gets a copy of the same.
        self._documents: dict[tuple[Any, ...], dict[str, Any]] = {}

    def measurement_list(self, scenario: str) -> Path:
        out = self.dir / scenario
        runs = []
        for run in scenario_runs(self.lab_config, scenario):
            path = out / f"{run['name']}.csv"
            if not path.exists():
                run_lab_scenario_run(self.mjcf, self.lab_config, self.robot, scenario, run["name"], path)
            runs.append({"name": run["name"], "path": str(path), "role": run["role"]})
        listing = out / "measurements.yaml"
        listing.write_text(yaml.safe_dump({"runs": runs}), encoding="utf-8")
        return listing

    def without_sensor(self, scenario: str) -> Path:
        """The scenario's runs with their ``tau`` columns removed (an arm without torque sensors)."""
        source = self.measurement_list(scenario)
        out = self.dir / f"{scenario}_without_tau"
        out.mkdir(exist_ok=True)
        listing = yaml.safe_load(source.read_text(encoding="utf-8"))
        for run in listing["runs"]:
            path = Path(run["path"])
            table = pd.read_csv(path)
            table.drop(columns=[c for c in table.columns if c.startswith("tau.")]).to_csv(out / path.name, index=False)
            shutil.copy(path.with_suffix(".yaml"), out / path.with_suffix(".yaml").name)
            run["path"] = str(out / path.name)
        target = out / "measurements.yaml"
        target.write_text(yaml.safe_dump(listing), encoding="utf-8")
        return target

    def prepared(self, measurement_list: Path) -> dict[str, list[Any]]:
        """Prepared runs of a measurement list, by role."""
        prepared = load_prepared_runs(measurement_list, self.joints, "/")
        return {"fit": list(prepared.fit), "holdout": list(prepared.holdout)}

    def cache(self, scenario: str) -> FitCache:
        """The scenario's fit cache: every model and ladder fitted on its runs reads back the rungs and diagnoses
        another test (or round) already fitted, as the sysid rule does between rounds. A hit is what the fit would
        compute (its key digests the data, effects, settings and code), so sharing it changes no number; a test that
        patches the code at run time fits through ``side_ladder`` instead."""
        return FitCache(self.dir / f"{scenario}_fits")

    def model(self, scenario: str, effects: list[str], with_sensor: bool = True,
              cache: FitCache | None = None, kept_on: dict[str, str] | None = None,
              on_joints: dict[str, list[str]] | None = None) -> dict[str, Any]:
        """ladder.json content of both sides, with its words (``sysid.fit_model``, :func:`sim2real.report.verdicts.worded`); ``with_sensor=False`` drops tau; ``cache``:
        rungs and diagnoses of earlier rounds read back, as the sysid rule does (None: :meth:`cache`); ``kept_on``: the drive lines
        model.yaml keeps on one link (``- asymmetric_friction: actuator``); ``on_joints``: the lines kept on some joints
        (``- coulomb_friction: {joints: [...]}``)."""
        # the actuator link's settings too: a test may change them to see another way of fitting
        key = ("model", scenario, tuple(effects), with_sensor, repr(sorted(sides.DRIVE_FIT_SETTINGS.items())),
               tuple(sorted((kept_on or {}).items())), repr(sorted((on_joints or {}).items())))
        if key not in self._documents:
            listing = self.measurement_list(scenario) if with_sensor else self.without_sensor(scenario)
            with threadpool_limits(limits=1, user_api="blas"):  # one BLAS thread per worker, as in run_sysid
                document = sysid.fit_model(model_config(effects, kept_on=kept_on, on_joints=on_joints), self.nominal,
                                           self.prepared(listing), self.robot, workers=WORKERS,
                                           cache=cache if cache is not None else self.cache(scenario)).document
                self._documents[key] = worded(document, self.robot)
        return copy.deepcopy(self._documents[key])

    def follow(self, scenario: str, rounds: int = 7,
               report: Callable[[dict[str, Any], int, float], None] | None = None,
               start: Sequence[str] = ()) -> list[dict[str, Any]]:
        """The user's loop from an empty ``effects:`` (or from ``start``, a model declared up front): each round adds
        what each link's verdict asks (the top candidate where the status is add_effect), until no verdict asks for
        more; every round's document. A line whose verdict says it leaves the other link worse, or that the other link
        holds it already, is written as that note advises, kept on the link that named it
        (``- asymmetric_friction: actuator``); a line the verdict (or the advice for offsets) keeps on some joints
        is written so (``- coulomb_friction: {joints: [...]}``).
        Rounds read earlier rungs back from a fit cache, as the sysid rule does; ``report(document, round,
        seconds)`` is called after each round. Without ``report``, a scenario is followed once per lab (the
        documents are the same bytes whoever asks: a copy for each)."""
        if report is None:
            key = (scenario, rounds, tuple(start))
            if key not in self._followed:
                self._followed[key] = self.follow(scenario, rounds, report=lambda *_: None, start=start)
            return copy.deepcopy(self._followed[key])
        cache = self.cache(scenario)
        effects: list[str] = list(start)
        kept_on: dict[str, str] = {}
        on_joints: dict[str, list[str]] = {}
        documents: list[dict[str, Any]] = []
        for k in range(rounds + 1):
            started = time.perf_counter()
            documents.append(self.model(scenario, effects, cache=cache, kept_on=kept_on, on_joints=on_joints))
            if report is not None:
                report(documents[-1], k, time.perf_counter() - started)
            sections = [documents[-1], documents[-1].get("actuator") or {}]
            tops = [s["diagnosis"]["candidates"][0] for s in sections if s and s["diagnosis"]["status"] == "add_effect"]
            wanted = [w for w in dict.fromkeys(top["effect"] for top in tops) if w not in effects]
            declared = []
            if not wanted:  # nothing named: the verdict's advice for offsets of each run's own, if it gives one
                declared = [d for d in ((s["diagnosis"].get("model_free") or {}).get("declare") for s in sections if s)
                            if d and d["effect"] not in effects][:1]
                wanted = [d["effect"] for d in declared]
            if not wanted:
                break
            # the lines a named effect holds go, as its verdict says (diagnosis.trials.replaced_by)
            removed = {line for top in tops for line in top.get("replaces", [])}
            effects = [e for e in effects if e not in removed] + wanted
            kept_on = {e: link for e, link in kept_on.items() if e in effects}
            on_joints = {e: joints for e, joints in on_joints.items() if e in effects}
            on_joints.update({top["effect"]: list(top["kept_to"]) for top in tops
                              if top.get("kept_to") and top["effect"] in wanted})
            on_joints.update({d["effect"]: list(d["kept_to"]) for d in declared if d.get("kept_to")})
            named = [(s["diagnosis"]["candidates"][0]["effect"], s["diagnosis"].get("link")) for s in sections
                     if s and s["diagnosis"]["status"] == "add_effect"
                     and (s["diagnosis"].get("other_link_note") or s["diagnosis"].get("held_note"))]
            for effect, link in named:
                if effect in wanted and [e for e, _ in named].count(effect) == 1:
                    kept_on[effect] = link
        return documents

    def data(self, scenario: str) -> tuple[fitting.TorqueData, fitting.TorqueData]:
        if scenario not in self._data:
            prepared = load_prepared_runs(self.measurement_list(scenario), self.joints, "/")
            self._data[scenario] = tuple(
                fitting.stack_runs([fitting.RunSamples.of(run, noise_floor_of(run)) for run in runs], self.joints,
                                 FAST_FIT["fit_rate_hz"])
                for runs in (prepared.fit, prepared.holdout))
        return self._data[scenario]

    def ladder(self, scenario: str, effects: list[str], diagnose: bool = True,
               candidates: Sequence[str] | None = None) -> dict[str, Any]:
        """The body side's ladder.json content, with its words (``sysid.fit_ladder``); ``candidates``: the effects its diagnosis tries
        (None: the library), a test's switch to withhold one."""
        key = ("ladder", scenario, tuple(effects), diagnose, None if candidates is None else tuple(candidates))
        if key not in self._documents:
            fit_data, holdout_data = self.data(scenario)
            with threadpool_limits(limits=1, user_api="blas"):
                context = FitContext.on_nominal(self.nominal, fit_data, holdout_data,
                                                {**fitting.DEFAULT_SETTINGS, **FAST_FIT}, workers=WORKERS)
                side = sysid.fit_ladder(effects, context, diagnosed=diagnose, candidates=candidates,
                                        cache=self.cache(scenario))
                self._documents[key] = worded({"robot": self.robot, **side.as_document()}, self.robot)
        return copy.deepcopy(self._documents[key])


def model_config(effects: Sequence[str], fit: dict[str, Any] | None = None,
                 kept_on: dict[str, str] | None = None, on_joints: dict[str, list[str]] | None = None) -> ModelConfig:
    """model.yaml's content as :func:`sim2real.identification.model_config.parse_model_config` reads it: the effects
    (``kept_on``: drive lines kept on one side, ``- asymmetric_friction: actuator``; ``on_joints``: lines kept on some
    joints, ``- coulomb_friction: {joints: [...]}``) and the fit settings (the fast ones by default)."""
    kept_on, on_joints = kept_on or {}, on_joints or {}

    def line(name: str) -> str | dict[str, Any]:
        if name in on_joints:
            return {name: {"joints": list(on_joints[name]), **({"side": kept_on[name]} if name in kept_on else {})}}
        return {name: kept_on[name]} if name in kept_on else name

    lines = [line(name) for name in effects]
    return parse_model_config({"effects": lines, "fit": dict(FAST_FIT if fit is None else fit)}, "model.yaml")


def side_ladder(effects: Sequence[str], nominal: Any, fit_data: Any, holdout_data: Any,
                fit_settings: dict[str, Any] | None = None, robot: str = "panda", **options: Any) -> tuple[dict[str, Any], Any]:
    """The body side's ladder.json content with its words, and its last rung's fit (``sysid.fit_ladder`` on the
    nominal model's signals; ``fit_settings`` over the defaults; ``options``: ``workers`` and fit_ladder's own)."""
    context = FitContext.on_nominal(nominal, fit_data, holdout_data,
                                    {**fitting.DEFAULT_SETTINGS, **(fit_settings or {})},
                                    workers=options.pop("workers", 1))
    side = sysid.fit_ladder(list(effects), context, **options)
    return worded({"robot": robot, **side.as_document()}, robot), side.result


def overall(rung: dict[str, Any]) -> float:
    return float(rung["metrics"]["torque_rmse"]["overall"])
