"""Identification: the model ladder of ``configs/{robot}/model.yaml`` fitted to measured runs, and the diagnosis of
the effect it lacks (the rule ``sysid``, ``rules/sysid.smk``).

* :mod:`~sim2real.identification.sysid`: the rule's entry: both sides of the model fitted and diagnosed, the files;
* :mod:`~sim2real.identification.side_ladder`: one side's ladder, every rung fitted and judged, and its diagnosis;
* :mod:`~sim2real.identification.ladder_rows`: a rung of ``ladder.json`` as a typed row (its keys written and read
  there alone);
* :mod:`~sim2real.identification.sides`: the two sides of the model (actuator and body), what the runs tell apart;
* :mod:`~sim2real.identification.effects`: the library of physical effects (columns, MJCF, calibration, evidence);
* :mod:`~sim2real.identification.fitting`: one rung's fit (nonlinear refinement, consistent fit, bootstrap);
* :mod:`~sim2real.identification.inertial`: physically consistent inertias (the semidefinite program, the prior);
* :mod:`~sim2real.assets.dynamics`: the rigid-body model (Pinocchio);
* :mod:`~sim2real.identification.diagnosis`: which effect is missing, ties, and what kind of thing is left.
"""
