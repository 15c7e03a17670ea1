"""The excitation design: the nonlinear program solved by IPOPT through CasADi, and its checks.

Modules: :mod:`.adapters` (the CasADi callbacks and sparse matrices), :mod:`.program` (the active-set program),
:mod:`.checks` (every sample of the written trajectory, the motion scaled until all pass), :mod:`.run` (one
design end to end and its report).
"""

from sim2real.excitation.design.checks import Trajectory, check_trajectory
from sim2real.excitation.design.program import DesignRobot
from sim2real.excitation.design.run import DesignResult, design_start, design_trajectory

__all__ = ["DesignResult", "DesignRobot", "Trajectory", "check_trajectory", "design_start", "design_trajectory"]
