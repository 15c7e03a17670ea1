"""The demo loop's numbers, pinned (issue 20): a speed-up changes no number.

The demo's ladder (configs/panda/model.yaml's effects, on the lab's real_arm_like arm) is fitted at the
fast settings of the sysid tests, both links with their diagnoses, the candidates fitted side by side
on two processes as the rule does. Every number of the ladder and the diagnoses (rounded to 6 digits,
as ladder.json writes them) must match the pinned ones in tests/data/loop_pinned.json, which were
written with the candidates fitted one after the other. Numbers are compared within what the fit can promise
across machines, words exactly (tests/pinned.py): another CPU's last bits pass, a real change fails.

A change that is meant to move the numbers (a new model, a fix) writes the file again:
``python tests/test_loop_pinned.py`` and says why in its commit.
"""

from __future__ import annotations

import copy
import json
import math
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))

from pinned import differences  # noqa: E402
from sysid_lab import FAST_FIT, Lab  # noqa: E402

from sim2real.identification import sysid  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PINNED = ROOT / "tests" / "data" / "loop_pinned.json"
SCENARIO = "real_arm_like"


def demo_effects() -> list[str]:
    return list(yaml.safe_load((ROOT / "configs" / "panda" / "model.yaml").read_text())["effects"])


def pinned_numbers(document: dict[str, Any]) -> dict[str, Any]:
    """What the loop shows of a ladder.json: each rung's errors, each diagnosis's ranking and promises. Not a
    candidate's trial coefficients: a candidate the data barely determine (a Stribeck law on a joint that hardly
    slides) ends its trial fit anywhere along a flat valley, 30 % apart on two CPUs, with the same promise; the
    coefficients of the candidate a user adds are pinned as the next rung's params."""

    def link(section: dict[str, Any]) -> dict[str, Any]:
        diagnosis = section.get("diagnosis", {})
        return {
            "ladder": [{"effects": r["effects"], "metrics": r["metrics"], "params": r["params"]}
                       for r in section["ladder"]],
            "diagnosis": {
                "status": diagnosis.get("status"),
                "verdict": diagnosis.get("verdict"),
                "candidates": [{key: c[key] for key in ("effect", "explained", "explained_beyond_noise", "joints")}
                               | {key: c["evidence"][key] for key in ("rmse_after", "x_floor_after")}
                               for c in diagnosis.get("candidates", [])],
            },
        }

    return {"body": link(document), **({"actuator": link(document["actuator"])} if "actuator" in document else {})}


def loop_document(lab: Lab, workers: int) -> dict[str, Any]:
    """Both links' ladder.json content for the demo's effects (BLAS on one thread, as run_sysid holds it)."""
    with threadpool_limits(limits=1, user_api="blas"):
        document, _ = sysid.fit_model(demo_effects(), lab.nominal, lab.prepared(lab.measurement_list(SCENARIO)),
                                      {"fit": FAST_FIT}, "panda", workers=workers)
    return json.loads(json.dumps(document))


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Lab:
    return Lab(tmp_path_factory.mktemp("pinned_lab"))


def test_demo_ladder_and_diagnosis_numbers_are_pinned(lab):
    expected = json.loads(PINNED.read_text(encoding="utf-8"))
    assert expected["effects"] == demo_effects(), "configs/panda/model.yaml changed: write the pinned file again"
    got = pinned_numbers(loop_document(lab, workers=2))
    found = differences(expected["numbers"], got)
    assert not found, "the demo's numbers moved (tests/pinned.py says by how much they may):\n" + "\n".join(found)


def test_the_comparison_fails_beyond_its_tolerance_and_on_any_word():
    """The pinned comparison is not blind: a number moved beyond its tolerance, a changed verdict or effect
    name, a missing key all fail; a move in the last printed digit, as another CPU gives, passes."""
    expected = json.loads(PINNED.read_text(encoding="utf-8"))["numbers"]
    assert differences(expected, copy.deepcopy(expected)) == []
    rung = expected["body"]["ladder"][-1]["metrics"]["torque_rmse"]
    joint = sorted(rung["per_joint"])[0]
    value = rung["per_joint"][joint]

    def moved(by: float) -> dict[str, Any]:
        changed = copy.deepcopy(expected)
        changed["body"]["ladder"][-1]["metrics"]["torque_rmse"]["per_joint"][joint] = value + by
        return changed

    last_digit = 10.0 ** (math.floor(math.log10(abs(value))) - 5)
    assert differences(expected, moved(last_digit)) == [], "one unit in the last printed digit is another CPU"
    assert differences(expected, moved(1e-4 * value)), "a number moved by 1e-4 of itself fails"
    assert differences(expected, moved(-1e-4 * value)), "either way"
    reworded = copy.deepcopy(expected)
    reworded["body"]["diagnosis"]["verdict"] += " "
    assert differences(expected, reworded)
    renamed = copy.deepcopy(expected)
    renamed["body"]["ladder"][-1]["effects"][-1] = "viscous_friction"
    assert differences(expected, renamed)
    dropped = copy.deepcopy(expected)
    dropped["body"]["ladder"].pop()
    assert differences(expected, dropped)


def test_a_coefficient_at_zero_is_judged_on_the_scale_of_its_siblings():
    assert differences({"a": [1.25, 0.0]}, {"a": [1.25, 3e-16]}) == []
    assert differences({"a": [1.25, 0.0]}, {"a": [1.25, 1e-3]})
    assert differences({"a": [1.25, 1e-9]}, {"a": [1.25, 2e-9]}) == []


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as directory:
        numbers = pinned_numbers(loop_document(Lab(Path(directory)), workers=1))
    PINNED.parent.mkdir(exist_ok=True)
    PINNED.write_text(json.dumps({"effects": demo_effects(), "scenario": SCENARIO, "settings": FAST_FIT,
                                  "numbers": numbers}, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    print(f"wrote {PINNED}")
