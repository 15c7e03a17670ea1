"""Domain randomization: validate ``configs/{robot}/dr.yaml`` against the built MJCF, resolve it
to ``results/{robot}/dr.json``, and apply it in memory at runtime.

Layers, each usable without Snakemake, one module each:

* :mod:`~sim2real.dr.parameters` -- what can be randomized (:data:`PARAMETERS`, :data:`NOISE_TERMS`)
  and where it lives in an ``MjModel`` (:func:`get_values`, :func:`set_values`, selectable elements).
* :mod:`~sim2real.dr.config` -- the checks on dr.yaml that need no model: schema, modes, range
  order, distributions, physical bounds of declared values, curriculum.
* :mod:`~sim2real.dr.resolve` -- :func:`resolve_config` / :func:`resolve_files`: selectors against
  the MJCF, absolute ranges per element -> the resolved document (dr.json, read back by
  :func:`load_resolved`).
* :mod:`~sim2real.dr.randomizer` -- :class:`DomainRandomizer`: from ``dr.json`` and a base
  ``MjModel``, a randomized model in memory per episode (no file written), reproducible under a
  seed; action delay through MuJoCo's actuator ``delay`` (history buffer, :func:`load_model`);
  observation noise per step.
* :mod:`~sim2real.dr.coverage` -- :func:`check_coverage`: identified values from
  ``results/{robot}/sysid/params.yaml`` that a randomization touches must lie inside its range (the
  shape read is documented at :func:`read_identified`).
* :mod:`~sim2real.dr.summary` -- :func:`build_summary`: coverage, summary table and figure.

Sampling happens in the *declared* space (a mass scale, a friction value, an offset) and the
operation maps it onto the element's nominal value: ``scale`` -> nominal * x, ``add`` -> nominal + x,
``abs`` -> x. Curriculum levels shrink each range toward the nominal model:
``level range = nominal + s * (declared range - nominal)`` (in declared space the nominal is 1 for
``scale``, 0 for ``add`` and the element's MJCF value for ``abs``); a noise std is multiplied by ``s``.
"""

from __future__ import annotations

from sim2real.dr.config import PHYSICS_MODES, SCHEMA_NAME
from sim2real.dr.coverage import (
    GLOBAL_ELEMENT,
    IDENTIFIED_ALIASES,
    SYSID_QUANTITIES,
    IdentifiedValue,
    check_coverage,
    coverage_summary,
    read_identified,
)
from sim2real.dr.parameters import (
    NOISE_TERMS,
    PARAMETER_BY_CHANNEL,
    PARAMETERS,
    SELECTOR_KEY,
    NoiseTerm,
    Parameter,
    candidate_elements,
    geom_id,
    geom_label,
    get_values,
    set_values,
)
from sim2real.dr.randomizer import DomainRandomizer, load_model
from sim2real.dr.resolve import FORMAT_VERSION, load_resolved, required_history_samples, resolve_config, resolve_files
from sim2real.dr.summary import build_summary, plot_summary, summary_rows, summary_table

__all__ = [
    "FORMAT_VERSION", "GLOBAL_ELEMENT", "IDENTIFIED_ALIASES", "NOISE_TERMS", "PARAMETERS", "PARAMETER_BY_CHANNEL",
    "PHYSICS_MODES", "SCHEMA_NAME", "SELECTOR_KEY", "SYSID_QUANTITIES",
    "DomainRandomizer", "IdentifiedValue", "NoiseTerm", "Parameter",
    "build_summary", "candidate_elements", "check_coverage", "coverage_summary", "geom_id", "geom_label",
    "get_values", "load_model", "load_resolved", "plot_summary", "read_identified", "required_history_samples",
    "resolve_config", "resolve_files", "set_values", "summary_rows", "summary_table",
]
