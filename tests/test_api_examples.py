"""The Examples sections of the public entry points run as doctests, on a two-run measurement list this module
writes: the Panda's URDF (example-robot-data, ``urdf`` in the examples) and, in ``example_dir``, a fit and a holdout
run of its seven joints, three seconds each, whose torque is the URDF's inverse dynamics plus viscous friction and
noise. A failing example fails its module's test (the doctest report names the line)."""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from sysid_synthetic import PANDA_JOINTS, PANDA_URDF

from sim2real.assets.dynamics import RigidBodyModel

# The public entry points (docs/python.md's API reference), by module; resolve_config resolves dr.yaml into dr.json.
ENTRY_POINTS = {
    "sim2real.measurements.runs.measurement_list": ["read_runs"],
    "sim2real.measurements.prepare": ["prepare_run"],
    "sim2real.identification.sysid": ["fit_model", "run_sysid"],
    "sim2real.identification.diagnosis.candidates": ["diagnose"],
    "sim2real.report.gap": ["compute_gap"],
    "sim2real.excitation.design.run": ["design_trajectory"],
    "sim2real.dr.resolve": ["resolve_config"],
}
MODULES = list(ENTRY_POINTS)
SECTIONS = ("Parameters\n    ----------", "Returns\n    -------", "Examples\n    --------")


def write_run(directory: Path, name: str, seed: int, duration_s: float = 3.0, rate_hz: float = 250.0) -> None:
    """``<name>.csv`` and ``<name>.yaml``: a smooth motion of every joint inside its limits, the measured torque."""
    model = RigidBodyModel(PANDA_URDF, PANDA_JOINTS)
    rng = np.random.default_rng(seed)
    time = np.arange(0.0, duration_s, 1.0 / rate_hz)
    center, half = 0.5 * (model.lower + model.upper), 0.5 * (model.upper - model.lower)
    omega = 2.0 * np.pi * rng.uniform(0.3, 0.8, size=len(PANDA_JOINTS))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=len(PANDA_JOINTS))
    amplitude = 0.3 * half
    q = center + amplitude * np.sin(omega * time[:, None] + phase)
    qd = amplitude * omega * np.cos(omega * time[:, None] + phase)
    qdd = -amplitude * omega**2 * np.sin(omega * time[:, None] + phase)
    tau = model.inverse_dynamics(q, qd, qdd) + 0.5 * qd + rng.normal(0.0, 0.02, size=q.shape)
    table = {"time": time, **{f"q.{j}": q[:, i] for i, j in enumerate(PANDA_JOINTS)},
             **{f"tau.{j}": tau[:, i] for i, j in enumerate(PANDA_JOINTS)}}
    pd.DataFrame(table).to_csv(directory / f"{name}.csv", index=False)
    (directory / f"{name}.yaml").write_text(yaml.safe_dump(
        {"robot": "panda", "source": "synthetic", "control_mode": "torque"}))


@pytest.fixture(scope="module")
def example_dir(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("api_examples")
    for seed, role in enumerate(("fit", "holdout")):
        write_run(directory, role, seed)
    listing = {"runs": [{"name": role, "path": f"{role}.csv", "role": role} for role in ("fit", "holdout")]}
    (directory / "measurements.yaml").write_text(yaml.safe_dump(listing))
    return directory


@pytest.mark.parametrize("module_name", MODULES)
def test_the_examples_of_the_entry_points_run(module_name, example_dir):
    module = importlib.import_module(module_name)
    namespace = {"example_dir": example_dir, "urdf": PANDA_URDF}
    result = doctest.testmod(module, extraglobs=namespace, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             report=True, raise_on_error=False)
    assert result.attempted > 0, f"{module_name} has no example"
    assert result.failed == 0, f"{result.failed} of {result.attempted} example lines of {module_name} failed"


@pytest.mark.parametrize("module_name", MODULES)
def test_each_entry_point_has_its_sections_and_an_example_that_runs(module_name):
    module = importlib.import_module(module_name)
    for name in ENTRY_POINTS[module_name]:
        doc = getattr(module, name).__doc__ or ""
        missing = [section.split("\n")[0] for section in SECTIONS if section not in doc]
        assert not missing, f"{module_name}.{name} lacks the numpydoc section(s) {missing}"
        examples = doctest.DocTestParser().get_examples(doc)
        run = [e for e in examples if not e.options.get(doctest.SKIP)]
        assert run and any(e.want for e in run), f"{module_name}.{name}: no example runs and checks an output"
