"""Work side by side on the threads a rule declares, in forked processes that share the caller's inputs.

The fit's inputs (the nominal Pinocchio model, signals holding their regressors) are large and not all
picklable; a forked process inherits them as they are, and only its result travels back. Each piece of
work is the computation one process would do, so the numbers are the same as one after the other
(BLAS is held to one thread, :func:`sim2real.identification.sysid.run_sysid`). Where fork is unavailable, or one
worker is asked for, the work runs in the calling process.

:func:`call_limited` runs untrusted work (a pull request's Xacro) in a child held to a time and a memory limit.
"""

from __future__ import annotations

import gc
import multiprocessing
import resource
import signal
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
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


# --- a child held to limits -------------------------------------------------------------------------------------------

# How long the caller waits past a child's own time limit before it kills it: the child's timer raises in Python code
# and the child answers with where it was; a child stuck in one C call (a huge integer power) cannot, and is killed.
KILL_GRACE_S = 5.0


@dataclass(frozen=True)
class Limits:
    """What a child process may take: wall-clock seconds, and memory beyond the address space it inherits at fork."""

    seconds: float
    memory_bytes: int


class TimeLimit(BaseException):
    """Raised in a child when its time is up. A BaseException, as KeyboardInterrupt is: code that catches Exception
    to try another reading of a value (Xacro does) must not swallow it."""


class ChildGaveNoAnswer(RuntimeError):
    """The child held to limits did not answer: killed past its time limit (``timed_out``), or ended without a word
    (the kernel's OOM killer, a signal)."""

    def __init__(self, limits: Limits, timed_out: bool, exitcode: int | None) -> None:
        self.limits, self.timed_out, self.exitcode = limits, timed_out, exitcode
        super().__init__(f"the child gave no answer within {limits.seconds:g} s" if timed_out
                         else f"the child ended without an answer (exit code {exitcode})")


def _address_space_bytes() -> int | None:
    """This process's virtual address space (Linux: /proc/self/statm); None where it cannot be read."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return pages * resource.getpagesize()


def _raise_time_limit(signum: int, frame: Any) -> None:
    raise TimeLimit


def _hold_to(limits: Limits) -> None:
    """In the child: an address-space limit of what it inherited plus ``limits.memory_bytes`` (relative, because a
    child of a large process inherits its mappings), and a timer that raises :class:`TimeLimit`."""
    inherited = _address_space_bytes()
    if inherited is not None:
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        cap = inherited + limits.memory_bytes
        if hard != resource.RLIM_INFINITY:
            cap = min(cap, hard)
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    signal.signal(signal.SIGALRM, _raise_time_limit)
    signal.setitimer(signal.ITIMER_REAL, limits.seconds)


def _run_limited(send: Any, fn: Callable[..., Any], args: tuple[Any, ...], limits: Limits) -> None:
    # No cyclic collection in the child: a signal's handler runs between bytecodes, and one full collection over the
    # millions of objects a runaway expansion makes (a macro that doubles itself) is one C call that can hold the
    # timer's TimeLimit for seconds on a loaded machine, past the caller's grace. The child is short-lived and its
    # memory is bounded by the limit.
    gc.disable()
    try:
        _hold_to(limits)
        answer: tuple[bool, Any] = (True, fn(*args))
    except BaseException as exc:  # noqa: BLE001 - the caller's process raises it again
        answer = (False, exc)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    try:
        send.send(answer)
    except Exception as exc:  # an answer that does not pickle: its words travel instead
        send.send((False, RuntimeError(f"{type(answer[1]).__name__}: {answer[1]} (unpicklable: {exc})")))
    finally:
        send.close()


def call_limited(fn: Callable[..., Any], *args: Any, limits: Limits) -> Any:
    """``fn(*args)`` in a forked process held to ``limits``; its result, or its exception raised here again.

    The child's timer raises :class:`TimeLimit` in its Python code and a memory limit makes its allocations fail
    (MemoryError), so ``fn`` can say where it was; a child that gives no answer within ``limits.seconds`` and
    :data:`KILL_GRACE_S` is killed, and one that ends without an answer is reported: :class:`ChildGaveNoAnswer`.
    Where fork is unavailable, ``fn`` runs here, unlimited.
    """
    if not can_fork():
        return fn(*args)
    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    process = context.Process(target=_run_limited, args=(send, fn, args, limits), daemon=True)
    process.start()
    send.close()
    answer = None
    try:
        if receive.poll(limits.seconds + KILL_GRACE_S):
            answer = receive.recv()
    except EOFError:  # the child ended without a word
        pass
    finally:
        if answer is None and process.is_alive():
            process.kill()
        process.join()
        receive.close()
    if answer is None:
        raise ChildGaveNoAnswer(limits, timed_out=process.exitcode == -signal.SIGKILL, exitcode=process.exitcode)
    ok, value = answer
    if isinstance(value, TimeLimit):  # fn let its timer's exception through: said as the caller's own
        raise ChildGaveNoAnswer(limits, timed_out=True, exitcode=process.exitcode)
    if not ok:
        raise value
    return value
