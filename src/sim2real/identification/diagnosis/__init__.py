"""Diagnosis: which physical effect is the model missing, and what kind of thing is left when none is.

* :mod:`~sim2real.identification.diagnosis.trials`: every effect of the library not in the model fitted on top of it as
  its rung would be;
* :mod:`~sim2real.identification.diagnosis.candidates`: those trials ranked by the holdout residual each removes (each
  joint in units of its own floor), ties and confounded pairs called so (:func:`diagnose`);
* :mod:`~sim2real.identification.diagnosis.ranking`: their order, and the pairs these runs cannot tell apart;
* :mod:`~sim2real.identification.diagnosis.raises`: no recommended rung raises a joint beyond the noise (a candidate
  that would is kept on the joints it helps, ``- coulomb_friction: {joints: [...]}``, or withheld);
* :mod:`~sim2real.identification.diagnosis.promise`: the recommended candidate's figures after, its rung's own (the
  rung chooses the inertial prior's weight again, its trial held the current rung's);
* :mod:`~sim2real.identification.diagnosis.result`: what it returns, a typed :class:`Diagnosis` whose notes are records;
* :mod:`~sim2real.identification.diagnosis.current`: the current residual as every decision reads it;
* :mod:`~sim2real.identification.diagnosis.lags`, :mod:`~sim2real.identification.diagnosis.screens`: when a lag or a
  ripple is worth a trial;
* :mod:`~sim2real.identification.diagnosis.caveats`: what keeps a verdict from being a clean decision (ties, inertias
  left implausible or at their bounds, trades with the model);
* :mod:`~sim2real.identification.diagnosis.across`: the rules that look across the two sides of a joint's torque (the
  other side's trial of a line, a line kept on one side, lags, the sensor's placement);
* :mod:`~sim2real.identification.diagnosis.ceiling`: the model-free ceiling, a flexible learner on the motion fitted to the
  last rung's residual: how much any function of the motion could still explain, and, when that is little,
  what the rest follows (time within a run, the run, the history since a reversal).
  The features its learners read: :mod:`~sim2real.identification.diagnosis.ceiling_features`.

Nothing here writes a sentence: :mod:`sim2real.report.verdicts` words the diagnosis. The diagnosis never looks at the
lab's truth.yaml: it sees only runs.
"""

from sim2real.identification.diagnosis.candidates import (
    CONFOUNDED_NOISE_FRACTION, DEFAULT_DIAGNOSIS, HARM_TOLERANCE, diagnose,
)
from sim2real.identification.diagnosis.raises import add_line
from sim2real.identification.diagnosis.caveats import NESTED_IN
from sim2real.identification.diagnosis.ceiling import model_free_ceiling
from sim2real.identification.diagnosis.result import Candidate, Diagnosis, candidate_named
from sim2real.identification.diagnosis.trials import candidates_to_try, trial_fits

__all__ = ["CONFOUNDED_NOISE_FRACTION", "DEFAULT_DIAGNOSIS", "HARM_TOLERANCE", "NESTED_IN", "Candidate", "Diagnosis",
           "add_line", "candidate_named", "candidates_to_try", "diagnose", "model_free_ceiling", "trial_fits"]
