"""Numerics shared by the stages: BLAS on one thread, where a result must be the same bytes on any machine, and
the chunk size of long sums."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

# Rows of a (samples x joints, coefficients) design summed at a time: a long log's data term costs a chunk's
# memory, not the log's. A design of up to this many rows (the demo's; a log of about 45 s at the fit's
# 200 Hz on 7 joints) is summed in one product, as it always was.
CHUNK_ROWS = 1 << 16

P = ParamSpec("P")
R = TypeVar("R")


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with BLAS on one thread whatever the environment says: the last digits of a product
    depend on how its sums are split among threads, and an output is byte-identical on any machine (and from
    any caller, inside a rule or not) only if they never are."""
    @functools.wraps(function)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return wrapper
