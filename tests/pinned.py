"""Numbers pinned across machines: compared within what the fit can promise, words exactly (issue 33).

The fit's last bits depend on the CPU (BLAS and the SDP solver's kernels are chosen per CPU, and so is the order of
their sums). A least-squares coefficient moves by about 1e-15 of itself; the consistent fit's SDP is solved to
Clarabel's tolerances, and on another CPU (an AMD EPYC where the pins were written on another) its solution, and
what follows from it, moved by up to 1.4e-5 of itself. ladder.json rounds every float (6 significant digits, a few
values to 4 decimals), so a value near a rounding boundary then shows one unit off in its last printed digit. A
pinned number is the same when it differs by at most

* one unit in its last printed digit (6th significant digit, or the last decimal it is printed with), or a
  relative 5e-5 (:data:`RELATIVE`), whichever is larger, or
* a relative 5e-5 of the largest magnitude among its siblings (the other numbers of the same list or mapping):
  a coefficient that is zero up to round-off beside others of order one is judged on their scale.

A move of 1e-4 of a number still fails (tests/test_loop_pinned.py checks the comparison itself). Strings (verdicts,
statuses, effect and joint names), booleans, integers, None and the shape of the document (keys, lengths) must be
equal. Byte identity of two builds on one machine is a separate test (tests/test_fit_cache.py, tests/test_gap.py):
there the bits are fixed.
"""

from __future__ import annotations

import math
from typing import Any

RELATIVE = 5e-5
DIGITS = 6  # ladder.json's round_floats


def tolerance(expected: float, sibling_scale: float) -> float:
    """How far ``expected`` may move across machines (see the module docstring)."""
    magnitude = abs(expected)
    last_digit = 10.0 ** (math.floor(math.log10(magnitude)) - (DIGITS - 1)) if magnitude > 0 else 0.0
    return max(RELATIVE * magnitude, last_digit, last_printed_unit(expected), RELATIVE * sibling_scale)


def last_printed_unit(value: float) -> float:
    """One unit in the last decimal ``value`` is printed with (0.0004 -> 1e-4); 0 for a whole number or one
    printed with an exponent (the significant-digit rule covers those)."""
    text = repr(float(value))
    if "e" in text or float(value).is_integer():
        return 0.0
    return 10.0 ** -len(text.split(".")[1])


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
