"""The model the loop ends with can be trusted (issue 30, "Done when"), followed from an empty ``effects:``.

Lab arms that differ from their URDF the way real ones do (CAD inertias off, a heavier hand, a wrong armature,
Gaz friction with Stribeck humps, noise, jitter): ``real_arm_like`` (motor-side sensor), ``link_side_sensor``
(after the gearbox, part of the friction after the sensor) and ``sensor_gains`` (each joint's torque sensor a few
percent off, beside the CAD errors). A user follows every verdict (:meth:`sysid_lab.Lab.follow`, fast settings,
rounds read earlier rungs back as the rule does); at the last rung of every link: every joint within 1.5x its
own floor, no inertia flagged implausible, and the inertial prior's weight chosen inside its searched range, on
every rung.
"""

from __future__ import annotations

import pytest

from sysid_lab import Lab

FACTOR = 1.5


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Lab:
    return Lab(tmp_path_factory.mktemp("trustworthy_lab"))


@pytest.mark.parametrize("scenario", ["real_arm_like", "link_side_sensor", "sensor_gains"])
def test_the_loop_ends_at_the_floor_with_plausible_inertias(lab, scenario):
    documents = lab.follow(scenario)
    last = documents[-1]
    assert len(documents) > 2, "the loop added effects round after round"
    for name, section in (("body", last), ("actuator", last.get("actuator"))):
        if not section:
            continue
        assert section["diagnosis"]["status"] == "at_noise_floor", (name, section["diagnosis"]["verdict"])
        rung = section["ladder"][-1]
        x_floor = rung["metrics"]["torque_x_floor"]["per_joint"]
        assert all(x <= FACTOR for x in x_floor.values()), (name, x_floor)
        link = (rung.get("params") or {}).get("link_inertia")
        if link:
            assert not link["implausible_bodies"], (name, {b: link["bodies"][b]["implausible"]
                                                           for b in link["implausible_bodies"]})
    for document in documents:
        for rung in document["ladder"]:
            prior = (rung.get("consistency") or {}).get("inertia_prior")
            if prior and "grid" in prior:
                assert prior["inside_searched_range"], (rung["effects"], prior["grid"], prior["scores"])
