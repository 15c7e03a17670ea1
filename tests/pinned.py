"""The demo's numbers pinned across machines, each at the precision the method gives it (issues 33, 59).

A fit's last bits depend on the CPU: BLAS kernels are chosen per CPU and so is the order of their sums. A
least-squares coefficient moves by about 1e-15 of itself, but what follows an SDP solved to Clarabel's
tolerances, a nonlinear refinement whose iterates depend on that order, a bootstrap's percentiles, or a parameter
the data barely determine moves by far more, legitimately. A pinned document (:func:`pinned_numbers`) is
therefore compared kind by kind (:func:`judged`); ``benchmarks/bench_pinned_spread.py`` measures how far each kind
moves across OpenBLAS kernel families (SkylakeX, Haswell/Zen, SandyBridge, Nehalem, Core2/Prescott), one or two
processes and the SDP solved to 1e-9..1e-11, and prints the largest move against each tolerance (the figures are
in docs/performance.md and tests/test_loop_pinned.py):

* **Words exactly**: verdicts, statuses, recommended lines, effect and joint names, the ladder's rungs, which
  bodies moved or are implausible, booleans, integers, None, and the document's keys and lengths.
  A number inside a verdict is judged as the metric it quotes; inside a body's implausibility note, it is a
  derived inertial number (below) and only the words count.
* **Held-out metrics** (torque RMSE and fit RMSE in N*m, the unconstrained fit's RMSE, a candidate's
  ``rmse_after``) within :data:`METRIC_RELATIVE` of themselves or :data:`METRIC_FLOOR_SHARE` of their joint's
  holdout noise floor (the pinned ``noise_floor``), whichever is larger; the same in floor units for the x floor
  (``torque_x_floor``, ``x_floor_after``): 1 % or 0.025. A real change of behaviour of 3 % fails everywhere a
  metric is at least 0.83 of its floor, which every one is (the lowest 0.92); another kernel moved them by at most
  0.73 % (a wrist's RMSE on the Stribeck rung), 0.38 of the tolerance.
* **Shares** of a candidate (``explained``: the share of the current holdout residual energy it removes,
  ``explained_beyond_noise``: the same energy as a share of what lies above the floors): ``explained`` within
  :data:`EXPLAINED_ENERGY` (half a percent of the residual energy, a quarter of what a 1 % move of the
  candidate's residual does); ``explained_beyond_noise`` within the same energy in units of the excess above the
  floors, i.e. times the link's total/excess ratio (from the last rung's per-joint x floor: 14 on the demo's body
  link). Near the floor the second is a ratio of small numbers, and its tolerance says so.
* **Identified parameters** within :data:`INTERVAL_SHARE` of the width of their pinned block-bootstrap interval
  (each rung's ``intervals``), and the intervals' bounds the same. A parameter without an interval of positive
  width is one the bootstrap does not determine: the nonlinear parameters (friction slopes and offsets, Stribeck
  velocities, held during the bootstrap, so their intervals are points), a CAD-held link's mass, the condition
  number, a body's divergence. It is judged by what it does (its rung's metrics), not by its value: it must stay
  a number (or None), nothing more. A Stribeck velocity on a wrist moved from 0.165 to 0.499 on another CPU.

Every tolerance is at least one unit of the last digit ladder.json prints the number with (6 significant digits,
a few values to 4 decimals): a value near a rounding boundary shows one unit off there. Byte identity of two
builds on one machine is a separate test (tests/test_fit_cache.py, tests/test_gap.py): there the bits are fixed.
"""

from __future__ import annotations

import json
import math
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sysid_lab import FAST_FIT, Lab, model_config  # noqa: E402

from sim2real.identification import sysid  # noqa: E402
from sim2real.report.verdicts import worded  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PINNED = ROOT / "tests" / "data" / "loop_pinned.json"
SCENARIO = "real_arm_like"
DIGITS = 6  # ladder.json's round_floats

METRIC_RELATIVE = 0.01
METRIC_FLOOR_SHARE = 0.025
EXPLAINED_ENERGY = 0.005
# Interval widths a parameter may move, per kind: a link inertial parameter comes out of an SDP solved to
# Clarabel's tolerances with a prior weight chosen by cross-validation, and its interval is conditional on both
# and on the nonlinear parameters (it moved by up to 0.52 widths); the other parameters moved by at most 0.19.
INTERVAL_SHARE = {"link inertial parameter": 1.5, "derived inertial number": 0.5, "parameter": 0.5}
UNDETERMINED = None  # the tolerance of a number judged by what it does, not by its value


def demo_effects() -> list[str]:
    return list(yaml.safe_load((ROOT / "configs" / "panda" / "model.yaml").read_text())["effects"])


def loop_document(lab: Lab, workers: int) -> dict[str, Any]:
    """Both sides' ladder.json content for the demo's effects, with its words (BLAS on one thread, as run_sysid holds it)."""
    with threadpool_limits(limits=1, user_api="blas"):
        document = sysid.fit_model(model_config(demo_effects()), lab.nominal,
                                   lab.prepared(lab.measurement_list(SCENARIO)), "panda", workers=workers).document
    return json.loads(json.dumps(worded(document, "panda")))


CANDIDATE_KEYS = ("effect", "add", "decisive", "decided_on", "joints", "explained", "explained_beyond_noise")


def _known(intervals: Any) -> Any:
    """``intervals`` without a body's divergence: whether the bootstrap writes one at all (for a body held at CAD
    it spans -65..81 where it does) depends on the replicates' last bits; the divergence is judged by what it
    does."""
    if isinstance(intervals, dict):
        return {k: _known(v) for k, v in intervals.items() if k != "divergence"}
    return intervals


def pinned_numbers(document: dict[str, Any]) -> dict[str, Any]:
    """What the loop shows of a ladder.json: each link's holdout noise floor (what its errors are judged
    against), each rung's errors, parameters and their intervals, each diagnosis's ranking and promises. Not a
    candidate's trial coefficients: a candidate the data barely determine (a Stribeck law on a joint that hardly
    slides) ends its trial fit anywhere along a flat valley, 30 % apart on two CPUs, with the same promise; the
    coefficients of the candidate a user adds are pinned as the next rung's params."""

    def link(section: dict[str, Any]) -> dict[str, Any]:
        diagnosis = section.get("diagnosis", {})
        return {
            "noise_floor": section["noise_floor"]["torque_rmse"],
            "ladder": [{"effects": r["effects"], "metrics": r["metrics"], "params": r["params"],
                        "intervals": _known(r["intervals"])} for r in section["ladder"]],
            "diagnosis": {
                "status": diagnosis.get("status"),
                "verdict": diagnosis.get("verdict"),
                "candidates": [{key: c[key] for key in CANDIDATE_KEYS}
                               | {key: c["evidence"][key] for key in ("rmse_after", "x_floor_after")}
                               for c in diagnosis.get("candidates", [])],
            },
        }

    return {"body": link(document), **({"actuator": link(document["actuator"])} if "actuator" in document else {})}


def write_pinned(numbers: dict[str, Any]) -> None:
    """tests/data/loop_pinned.json: the demo's pinned numbers with what they were fitted from."""
    PINNED.parent.mkdir(exist_ok=True)
    PINNED.write_text(json.dumps({"effects": demo_effects(), "scenario": SCENARIO, "settings": FAST_FIT,
                                  "numbers": numbers}, indent=1, sort_keys=True) + "\n", encoding="utf-8")


# --- the comparison ---------------------------------------------------------------------------------------------

Path_ = tuple[Any, ...]


def printed_unit(value: float) -> float:
    """One unit in the last digit ``value`` is printed with: its 6th significant digit, or its last decimal when
    it is printed with fewer (0.0004 -> 1e-4); 0 for zero."""
    magnitude = abs(value)
    if magnitude == 0:
        return 0.0
    significant = 10.0 ** (math.floor(math.log10(magnitude)) - (DIGITS - 1))
    text = repr(float(value))
    decimal = 10.0 ** -len(text.split(".")[1]) if "e" not in text and not float(value).is_integer() else 0.0
    return max(significant, decimal)


def _at(document: Any, path: Path_) -> Any:
    for key in path:
        if isinstance(document, dict) and key in document:
            document = document[key]
        elif isinstance(document, list) and isinstance(key, int) and key < len(document):
            document = document[key]
        else:
            return None
    return document


def _width(interval: Any) -> float:
    """The width of a pinned [low, high] interval; 0 for a point, None or no interval."""
    if isinstance(interval, list) and len(interval) == 2 and all(_is_number(v) for v in interval):
        return float(interval[1]) - float(interval[0])
    return 0.0


def total_over_excess(link: dict[str, Any]) -> float:
    """The link's current residual energy over its part above the floors (floor units, the last rung's per-joint
    x floor): what turns a share of the whole into a share of the excess (the diagnosis's ``excess_now``)."""
    x_floor = link["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values()
    total = sum(x * x for x in x_floor)
    excess = sum(max(x * x - 1.0, 0.0) for x in x_floor)
    return total / excess if excess > 0 else 1.0  # nothing above the floors: the share is 0 by definition


def judged(expected: dict[str, Any], path: Path_) -> tuple[str, float | None]:
    """The kind of the pinned number at ``path`` (in :func:`pinned_numbers`' document) and how far it may move
    (None: not by its value); see the module docstring."""
    value = float(_at(expected, path))
    link = expected[path[0]]
    kind, allowed = _kind(link, path[1:], value)
    return kind, None if allowed is None else max(allowed, printed_unit(value))


def _kind(link: dict[str, Any], path: Path_, value: float) -> tuple[str, float | None]:
    if path[0] == "noise_floor":
        return "noise floor (N*m)", METRIC_RELATIVE * abs(value)
    if path[0] == "diagnosis":
        key = path[-1]
        if key == "rmse_after":
            return _metric(link, "rmse_after", "overall", value)
        if key == "x_floor_after":
            return _metric(link, "torque_x_floor", "overall", value)
        if key == "explained":
            return "share: explained", EXPLAINED_ENERGY
        return "share: explained beyond noise", EXPLAINED_ENERGY * total_over_excess(link)
    rung = link["ladder"][path[1]]
    part, rest = path[2], path[3:]
    if part == "metrics":
        return _metric(link, rest[0], rest[-1] if rest[1] == "per_joint" else "overall", value)
    label = ("derived inertial number" if rest[:2] == ("link_inertia", "bodies")
             else "link inertial parameter" if rest[0] == "link_inertia" else "parameter")
    if part == "intervals":
        return "interval bound", UNDETERMINED
    width = _width(_at(rung["intervals"], rest))
    if width > 0:
        return f"{label} (interval widths)", INTERVAL_SHARE[label] * width
    return f"undetermined: {label}", UNDETERMINED


def _metric(link: dict[str, Any], name: str, joint: str, value: float) -> tuple[str, float]:
    if name == "torque_x_floor":
        return "held-out metric (x floor)", max(METRIC_RELATIVE * abs(value), METRIC_FLOOR_SHARE)
    floors = link["noise_floor"]
    floor = floors["overall"] if joint == "overall" else floors["per_joint"][joint]
    return "held-out metric (N*m)", max(METRIC_RELATIVE * abs(value), METRIC_FLOOR_SHARE * floor)


NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?")  # not the digits of a name (panda_joint2)


def _text_differences(expected: str, got: str, path: Path_) -> list[str]:
    """Words exactly; a number a verdict quotes within the metric's relative tolerance or one unit of its last
    printed digit; the numbers of a body's implausibility note (derived inertial numbers) not by value."""
    where = "/" + "/".join(map(str, path))
    if NUMBER.sub("#", expected) != NUMBER.sub("#", got):
        return [f"{where}: {got!r} != {expected!r}"]
    if "params" in path:
        return []
    for a, b in zip(NUMBER.findall(expected), NUMBER.findall(got), strict=True):
        decimals = len(a.split(".")[1]) if "." in a else 0
        if abs(float(b) - float(a)) > max(METRIC_RELATIVE * abs(float(a)), 10.0**-decimals) * (1 + 1e-9):
            return [f"{where}: {got!r} != {expected!r} (the number {b} against {a})"]
    return []


def _is_number(value: Any) -> bool:
    return isinstance(value, float) or (isinstance(value, int) and not isinstance(value, bool))


def moves(expected: dict[str, Any], got: dict[str, Any]) -> Iterator[tuple[Path_, str, float, float, float | None]]:
    """Every pinned float with its counterpart in ``got`` where the two documents have the same shape: (path,
    kind, pinned, got, tolerance)."""
    for path, pinned, value in _pairs(expected, got, ()):
        if isinstance(pinned, float) and _is_number(value):
            kind, allowed = judged(expected, path)
            yield path, kind, pinned, float(value), allowed


def _pairs(expected: Any, got: Any, path: Path_) -> Iterator[tuple[Path_, Any, Any]]:
    if isinstance(expected, dict) and isinstance(got, dict):
        for key in sorted(set(expected) & set(got)):
            yield from _pairs(expected[key], got[key], (*path, key))
    elif isinstance(expected, list) and isinstance(got, list):
        for k, (a, b) in enumerate(zip(expected, got)):
            yield from _pairs(a, b, (*path, k))
    else:
        yield path, expected, got


def differences(expected: dict[str, Any], got: dict[str, Any]) -> list[str]:
    """Every place where ``got`` differs from the pinned ``expected`` beyond what :func:`judged` allows, one line
    each (path, values): shape and words exactly, numbers by their kind."""
    found = _shape_differences(expected, got, ())
    for path, pinned, value in _pairs(expected, got, ()):
        where = "/" + "/".join(map(str, path))
        if isinstance(pinned, float) and _is_number(value):
            _, allowed = judged(expected, path)
            if allowed is not None and abs(float(value) - pinned) > allowed * (1 + 1e-9):  # in floating point
                found.append(f"{where}: {value!r} != {pinned!r} (beyond {allowed:.3g})")
        elif isinstance(pinned, str) and isinstance(value, str):
            found += _text_differences(pinned, value, path)
        elif type(pinned) is not type(value) or pinned != value:
            found.append(f"{where}: {value!r} != {pinned!r}")
    return found


def _shape_differences(expected: Any, got: Any, path: Path_) -> list[str]:
    where = "/" + "/".join(map(str, path))
    if isinstance(expected, dict):
        if not isinstance(got, dict) or set(expected) != set(got):
            return [f"{where}: keys {sorted(got) if isinstance(got, dict) else got!r} != {sorted(expected)}"]
        return [line for key in sorted(expected) for line in _shape_differences(expected[key], got[key], (*path, key))]
    if isinstance(expected, list):
        if not isinstance(got, list) or len(expected) != len(got):
            return [f"{where}: {got!r} != {expected!r}"]
        return [line for k, (a, b) in enumerate(zip(expected, got, strict=True))
                for line in _shape_differences(a, b, (*path, k))]
    return []
