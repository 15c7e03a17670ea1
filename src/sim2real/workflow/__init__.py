"""What the Snakemake workflow reads (``rules/common.smk``): where a robot's configs and built files are, what of its
configs each job takes as params, and each stage's final outputs.

Plain functions of a robot's name and of wildcard values, returning paths (relative to the workflow's directory,
where Snakemake runs) and plain data. The Snakemake objects, ``wildcards`` and ``checkpoints``, stay in
``common.smk``, whose ``get_*`` input functions hand their values to these. A config is read once per process
(``functools.cache``): Snakemake evaluates input functions many times while it builds the DAG.

- :mod:`sim2real.workflow.configs`: a robot's config files and the settings the jobs take from them.
- :mod:`sim2real.workflow.paths`: the built files a job reads, given its wildcards.
- :mod:`sim2real.workflow.targets`: every stage's final outputs (``snakemake all``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def of_wildcards(function: Callable[..., Any], *names: str) -> Callable[[Any], Any]:
    """An input function for a rule: ``function`` called with the job's wildcard values ``names``, in order.

    >>> from types import SimpleNamespace
    >>> of_wildcards(lambda robot, campaign: f"results/{robot}/{campaign}gap.md", "robot", "campaign")(
    ...     SimpleNamespace(robot="panda", campaign="arm-b/"))
    'results/panda/arm-b/gap.md'
    """

    def input_function(wildcards: Any) -> Any:
        return function(*(getattr(wildcards, name) for name in names))

    input_function.__name__ = input_function.__qualname__ = getattr(function, "__name__", "input_function")
    return input_function
