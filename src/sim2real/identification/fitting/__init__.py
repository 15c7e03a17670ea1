"""The fitting core: torque data, the nominal model, one rung's fit, its prediction and holdout metrics.

The fit works in the torque domain. The judged torque (measured ``tau``, else the command
``tau_cmd``) is predicted as

    tau_judged(t) = [tau_nominal + sum_e A_e(nl_e) theta_e + offsets](t + delay)

where ``tau_nominal`` is Pinocchio's inverse dynamics of the URDF (with the MJCF armature),
``A_e`` are the regressor columns of each effect (:mod:`sim2real.identification.effects`), linear in its
parameters ``theta_e``, ``nl_e`` its few nonlinear parameters (a friction smoothing velocity) and
``delay`` the actuation delay when the model has one. Steps of :func:`fit`:

1. nonlinear refinement of the nonlinear parameters by bounded least squares with the linear
   parameters projected out (variable projection), started from a coarse grid for the delay;
   parameters of effects already in the model can be held (a ladder rung refines only its own);
2. the linear parameters: unconstrained least squares (columns scaled, minimum-norm, link
   inertias as base parameters) and the physically consistent fit (:mod:`sim2real.identification.inertial`: one
   convex program with the pseudo-inertia LMIs and sign bounds), which the rung reports;
3. uncertainty by a block bootstrap of the fit samples (residuals are correlated in time, so whole
   blocks of time are resampled), the delay by a linearised step per replicate, the other nonlinear
   parameters held, with a small-sample correction for the few blocks a run has
   (:func:`small_sample_stretch`);
4. judgement on the ``role: holdout`` runs (:func:`holdout_metrics`).

The ladder (:mod:`sim2real.identification.sysid`) and the diagnosis (:mod:`sim2real.identification.diagnosis`) both call this
package; it imports neither. Its modules, each importing only those above it:

* :mod:`~sim2real.identification.fitting.data`: the torque data (:class:`RunSamples` stacked by :func:`stack_runs` into :class:`TorqueData`);
* :mod:`~sim2real.identification.fitting.nominal`: the nominal model (:func:`load_nominal`) and its signals;
* :mod:`~sim2real.identification.fitting.problem`: the design at given nonlinear parameters (``_Problem``), shared by
  the fit, its consistent variant and the bootstrap, and the fitted values (:class:`FitResult`);
* :mod:`~sim2real.identification.fitting.linear`: the linear solve, joint by joint (a long log's design never whole);
* :mod:`~sim2real.identification.fitting.refine`: the nonlinear refinement (variable projection);
* :mod:`~sim2real.identification.fitting.bootstrap`: the block bootstrap and its intervals;
* :mod:`~sim2real.identification.fitting.scoring`: noise-floor units, the prediction and the holdout metrics;
* :mod:`~sim2real.identification.fitting.consistent`: the physically consistent fit of a rung's linear coefficients;
* :mod:`~sim2real.identification.fitting.rung`: one rung's fit (:func:`fit`, :func:`fit_on_the_previous`);
* :mod:`sim2real.cache` (beside the package, which the gap report uses without importing the fit): fits kept
  between rounds of the loop, by the digest of their inputs.

The package exports its public names; a private one (``_Problem``, ``_values``, ``_intervals``) is imported from its
module.
"""

from sim2real.identification.fitting.bootstrap import (  # noqa: F401  (re-exported: the package's names)
    DELAY_STEP_S, replicate_intervals, small_sample_stretch,
)
from sim2real.identification.fitting.data import (  # noqa: F401  (re-exported: the package's names)
    RunSamples, TorqueData, kept_segments, link_side, stack_runs,
)
from sim2real.identification.fitting.scoring import (  # noqa: F401  (re-exported: the package's names)
    MIN_FLOOR_FRACTION, floor_units, holdout_metrics, joint_weights, judged_floors, lag_score, predict,
)
from sim2real.identification.fitting.nominal import (  # noqa: F401  (re-exported: the package's names)
    NominalModel, body_ellipsoids, body_hulls, load_nominal, make_signals, resolve_armature,
)
from sim2real.identification.fitting.problem import FitResult, subset_signals  # noqa: F401
from sim2real.identification.fitting.refine import Nonlinear, Refinements, refinement_rows  # noqa: F401
from sim2real.identification.fitting.consistent import INERTIA_PRIOR_FALLBACK, PRIOR_START_SETTING  # noqa: F401
from sim2real.identification.fitting.rung import (  # noqa: F401  (re-exported: the package's names)
    DEFAULT_SETTINGS, EFFECT_JOINTS_SETTING, STILL_JOINTS_SETTING, better_way, effect_joints_of, fit,
    fit_on_the_previous, way_inputs, fit_way, previous_nonlinear, previous_ways,
)
from sim2real.identification.fitting.context import FitContext  # noqa: F401
