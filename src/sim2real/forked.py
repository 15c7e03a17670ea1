"""Work side by side on the threads a rule declares, in forked processes that share the caller's inputs.

The fit's inputs (the nominal Pinocchio model, signals holding their regressors) are large and not all
picklable; a forked process inherits them as they are, and only its result travels back. Each piece of
work is the computation one process would do, so the numbers are the same as one after the other
(BLAS is held to one thread, :func:`sim2real.identification.sysid.run_sysid`). Where fork is unavailable, or one
worker is asked for, the work runs in the calling process.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

_SHARED: dict[str, Any] = {}  # a pool worker's inputs, inherited at fork (set by _share in each worker)


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


def _share(fn: Callable[..., Any], inputs: Mapping[str, Any]) -> None:
    _SHARED.update(fn=fn, inputs=inputs)


def _call_shared(item: Any) -> Any:
    return _SHARED["fn"](item, **_SHARED["inputs"])


def map_forked(fn: Callable[..., Any], items: Sequence[Any], workers: int, inputs: Mapping[str, Any]) -> list[Any]:
    """``[fn(item, **inputs) for item in items]`` on up to ``workers`` forked processes."""
    workers = min(int(workers), len(items))
    if workers <= 1 or not can_fork():
        return [fn(item, **inputs) for item in items]
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_share, initargs=(fn, inputs)) as pool:
        return list(pool.map(_call_shared, items))


class Forked:
    """``fn(*args)`` started in a forked process; :meth:`result` waits for it (or runs it here when
    ``fork`` is false). The process is a daemon, so ``fn`` must not start processes of its own."""

    def __init__(self, fn: Callable[..., Any], *args: Any, fork: bool = True) -> None:
        self.fn, self.args = fn, args
        self.process = None
        if fork and can_fork():
            context = multiprocessing.get_context("fork")
            self.receive, send = context.Pipe(duplex=False)
            # daemon: if the caller fails before it asks for the result, the process ends with it
            self.process = context.Process(target=self._run, args=(send,), daemon=True)
            self.process.start()
            send.close()

    def _run(self, send: Any) -> None:
        try:
            send.send((True, self.fn(*self.args)))
        except BaseException as exc:  # noqa: BLE001 - the caller's process raises it again
            send.send((False, exc))
        finally:
            send.close()

    def result(self) -> Any:
        if self.process is None:
            return self.fn(*self.args)
        ok, value = self.receive.recv()
        self.process.join()
        if not ok:
            raise value
        return value
