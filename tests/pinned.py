"""Numbers pinned across machines: compared within what the fit can promise, words exactly (issue 33).

The fit's last bits depend on the CPU (BLAS kernels chosen per CPU, the order of their sums): on another machine a
coefficient moves by about 1e-15 of itself, and ladder.json, which rounds every float to 6 significant digits,
then shows it one unit off in its last digit when the value sits near a rounding boundary. So a pinned number is
the same when it differs by at most

* one unit in its 6th significant digit, or a relative 1e-6 (:data:`RELATIVE`), whichever is larger, or
* a relative 1e-6 of the largest magnitude among its siblings (the other numbers of the same list or mapping):
  a coefficient that is zero up to round-off beside others of order one is judged on their scale.

Strings (verdicts, statuses, effect and joint names), booleans, integers, None and the shape of the document
(keys, lengths) must be equal. Byte identity of two builds on one machine is a separate test (tests/test_fit_cache.py,
tests/test_gap.py): there the bits are fixed.
"""

from __future__ import annotations

import math
from typing import Any

RELATIVE = 1e-6
DIGITS = 6  # ladder.json's round_floats


def tolerance(expected: float, sibling_scale: float) -> float:
    """How far ``expected`` may move across machines (see the module docstring)."""
    magnitude = abs(expected)
    last_digit = 10.0 ** (math.floor(math.log10(magnitude)) - (DIGITS - 1)) if magnitude > 0 else 0.0
    return max(RELATIVE * magnitude, last_digit, RELATIVE * sibling_scale)


def _is_number(value: Any) -> bool:
    return isinstance(value, float) or (isinstance(value, int) and not isinstance(value, bool))


def _scale(values: list[Any]) -> float:
    numbers = [abs(v) for v in values if _is_number(v)]
    return max(numbers, default=0.0)


def differences(expected: Any, got: Any, path: str = "", sibling_scale: float = 0.0) -> list[str]:
    """Every place where ``got`` differs from ``expected`` beyond :func:`tolerance`, one line each (path, values)."""
    if isinstance(expected, dict):
        if not isinstance(got, dict) or set(expected) != set(got):
            return [f"{path or '/'}: keys {sorted(expected) if isinstance(expected, dict) else expected!r} != "
                    f"{sorted(got) if isinstance(got, dict) else got!r}"]
        scale = _scale(list(expected.values()))
        return [line for key in sorted(expected) for line in differences(expected[key], got[key], f"{path}/{key}", scale)]
    if isinstance(expected, list):
        if not isinstance(got, list) or len(expected) != len(got):
            return [f"{path}: {expected!r} != {got!r}"]
        scale = _scale(expected)
        return [line for k, (a, b) in enumerate(zip(expected, got, strict=True))
                for line in differences(a, b, f"{path}/{k}", scale)]
    if isinstance(expected, float) and _is_number(got) and not isinstance(got, bool):
        allowed = tolerance(expected, sibling_scale)
        if abs(float(got) - expected) > allowed * (1 + 1e-9):  # the tolerance itself, in floating point
            return [f"{path}: {got!r} != {expected!r} (beyond {allowed:.3g})"]
        return []
    if type(expected) is not type(got) or expected != got:
        return [f"{path}: {got!r} != {expected!r}"]
    return []
