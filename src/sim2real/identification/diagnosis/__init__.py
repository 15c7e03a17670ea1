"""Diagnosis: which physical effect is the model missing, and what kind of thing is left when none is.

* :mod:`~sim2real.identification.diagnosis.candidates`: every effect of the library not in the model fitted on top of it as
  its rung would be, ranked by the holdout residual it removes (each joint in units of its own floor), ties
  and confounded pairs called so, the verdict;
* :mod:`~sim2real.identification.diagnosis.lags`: when a lag (a delay, a first-order lag) is worth a trial, and what a
  verdict says of its two shapes;
* :mod:`~sim2real.identification.diagnosis.caveats`: what keeps a verdict from being a clean decision (ties, inertias left
  implausible, trades with the model) and what it must then say;
* :mod:`~sim2real.identification.diagnosis.ceiling`: the model-free ceiling, a flexible learner on the motion fitted to the
  last rung's residual: how much any function of the motion could still explain, and, when that is little,
  what the rest follows (time within a run, the run, the history since a reversal).

The diagnosis never looks at the lab's truth.yaml: it sees only runs.
"""

from sim2real.identification.diagnosis.candidates import (  # noqa: F401  (re-exported: the package's names)
    CONFOUNDED_NOISE_FRACTION, DEFAULT_DIAGNOSIS, LINK_TEXT, add_line, candidates_to_try, diagnose,
    trial_fits,
)
from sim2real.identification.diagnosis.caveats import NESTED_IN  # noqa: F401
from sim2real.identification.diagnosis.ceiling import model_free_ceiling  # noqa: F401
