"""Excitation design: an optimised, collision-checked identification trajectory as a build output.

``configs/{robot}/excitation.yaml`` names designs; each is a periodic finite Fourier series per joint
(Swevers et al. 1997) that starts and ends at rest at the start pose. Its coefficients are chosen by
IPOPT (through CasADi) to make the identification problem of the current model well posed: the base
inertial parameters plus the effects of ``configs/{robot}/model.yaml`` (friction columns included),
each joint scaled by its noise floor where one is known. Joint position, velocity, acceleration and
torque limits (from the built URDF, with the configured margins) are constraints; so is the distance
to collision, checked by MuJoCo on the built MJCF with its CoACD collision parts and the configured
obstacles.

Modules: :mod:`.config` (the file, its checks), :mod:`.fourier` (the series and its linear maps),
:mod:`.information` (identification columns, base selection, objectives and their gradients),
:mod:`.clearance` (distance to collision with MuJoCo), :mod:`.design` (the nonlinear program),
:mod:`.files` (CSV, ROS 2 JointTrajectory, report).
"""
