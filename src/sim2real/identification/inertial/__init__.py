"""Physically consistent inertial identification: one convex program for a whole model rung.

The rung's prediction is linear in its coefficients ``x`` (link inertial corrections, friction,
armature, bias, ...), so the fit is a least-squares problem. Physical consistency enters as convex
constraints (Wensing, Kim and Slotine 2017, "Linear Matrix Inequalities for Physically Consistent
Inertial Parameter Identification"):

* every corrected body's 4x4 pseudo-inertia ``J(pi) = [[Sigma, h], [h^T, m]]`` is positive definite,
  which implies m > 0, the triangle inequalities and a density that exists;
* where the body's bounding ellipsoid is known from its meshes, ``tr(J Q) >= 0``: the mass lies
  inside the ellipsoid (centre of mass inside the body), a strictly stronger condition;
* per-coefficient lower bounds (friction, damping and armature totals >= 0, payload mass >= 0).

A regulariser keeps what the data cannot see at the CAD values: the entropic (Bregman) divergence
of Lee and Park 2018, ``d(J, J0) = tr(J0^-1 J) - log det(J J0^-1) - 4``, summed over bodies. It is
geometric (invariant to the body's frame and units), zero at the CAD body and a barrier at the
boundary of the consistent set, so the solution is strictly consistent. Its weight is a fraction of
the noise floor's variance: a correction the data see costs far more in the data term than in the
divergence, a direction they do not see is pulled to CAD. The fraction is chosen on held-out blocks
of the fit runs (:func:`choose_prior_weight`): the strongest pull whose held-out error is within 1%
of the best, not a number set by hand.

Why a semidefinite program (Clarabel; its conic form in :mod:`~.conic`, checked against cvxpy) rather than the
log-Cholesky parametrisation with scipy's least squares (Rucker and Wensing 2022, ``pin.LogCholeskyParameters``): the problem is
convex, so the SDP returns the global optimum with a certificate and no start point, with the
friction/armature bounds and the ellipsoid LMIs as plain constraints. It works on the p x p Gram
matrix of the design (p ~ 90 coefficients on a 7-joint arm), so its size does not grow with the
number of samples. Measured on the Panda (``benchmarks/bench_sysid.py``): the solve takes tens of
milliseconds, beside the ~1 s that computing the regressor and the nonlinear refinement take, so the
consistent rung costs about the same as the unconstrained one. Log-Cholesky is unconstrained but
non-convex in the data term, needs a start inside the set and handles bounds only by clipping.

Its modules: :mod:`~.geometry` (pseudo-inertia, divergence, ellipsoids), :mod:`~.rows` (a design a chunk of
rows at a time), :mod:`~.program` (the convex program), :mod:`~.conic` (its conic form for Clarabel) and
:mod:`~.prior` (the prior's weight).
"""

from sim2real.identification.inertial.geometry import (  # noqa: F401  (re-exported: the package's names)
    PARAMS_PER_BODY, PD_MARGIN, InertialBlock, bounding_ellipsoid, ellipsoid_matrix, entropic_divergence,
    inside_ellipsoids, min_eigenvalues, physically_consistent, pseudo_inertia,
)
from sim2real.identification.inertial.prior import (  # noqa: F401
    PRIOR_BLOCKS, PRIOR_BOUNDS, PRIOR_GRID, PRIOR_TOLERANCE, PriorChoice, choose_prior_weight, grid_around,
)
from sim2real.identification.inertial.program import (  # noqa: F401
    ConsistentSolution, InfeasibleFit, import_solver, solve_consistent,
)
from sim2real.identification.inertial.rows import DesignRows, column_norms  # noqa: F401
