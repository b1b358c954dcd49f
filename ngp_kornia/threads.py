"""The pipeline's thread policy: its small tensors run on one CPU thread unless asked otherwise.

The parser's tensors are small (a few thousand candidates, a 224x224 FSNet input), so torch's intra-op threads
gain nothing on an idle machine and spin against every other process on a busy one: on two loaded cores the
default call took 8-10x lu-vp-detect's time with two threads and 1.0-1.14x with one (BENCHMARKS.md). :func:`calibrate`,
:class:`~ngp_kornia.pipeline.NeuralGeometricParser` and ``ngp predict`` therefore run inside :func:`pipeline_threads`,
which sets torch's (and OpenCV's) thread count for the duration of the call and restores the caller's afterwards,
also when the call raises.

A call also uses the process's other cores where they are free, on helper threads that never change a result:
line detection runs LSD's strips side by side (:mod:`~ngp_kornia.pipeline.segments`); in
:func:`~ngp_kornia.calibrate` of a file
or an array, the thread whose strip ends first resizes the image for FSNet (:func:`while_waiting`); and FSNet's
shared trunk runs while the caller's thread samples and scores the frames (:func:`run_beside`). The helpers take the
caller's thread count and autograd mode; :func:`helper_threads` caps how many threads one call uses (``ngp predict``
gives each of its processes its share of the cores).

How many threads: ``ParserConfig.num_threads`` (``calibrate(image, config=ParserConfig(num_threads=N))``) when
given; else the environment variable ``NGP_NUM_THREADS``; else 1. ``0`` leaves the caller's setting alone (the
parser then runs with whatever ``torch.get_num_threads()`` says, as a layer of a larger model may want). With one
thread the results do not depend on the machine's thread count; with more, sums may differ in the last bits from
run to run of differently configured processes.

Threads: ``torch.set_num_threads`` and ``cv2.setNumThreads`` are process-wide, not per Python thread. While a call
runs, other Python threads of the same process that use torch see its thread count too. Calls that overlap in
several Python threads share one setting: the first to enter saves the caller's counts, the last to leave restores
them, so the caller's setting is never lost; the count in force is that of the most recent call to enter.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Hashable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import cv2
import torch

__all__ = [
    "ENV_VAR",
    "Beside",
    "Deferred",
    "Lookahead",
    "helper_threads",
    "pipeline_threads",
    "resolve_num_threads",
    "run_beside",
    "thread_budget",
    "usable_cores",
    "while_waiting",
]

#: environment variable with the default thread count of the pipeline (a positive integer, or 0: do not change)
ENV_VAR = "NGP_NUM_THREADS"

_lock = threading.Lock()
_depth = 0
_saved: tuple[int, int] | None = None
_cap: int | None = None
_pools: dict[int, ThreadPoolExecutor] = {}
_waiting = threading.local()  # per thread: the jobs it runs while it would wait for a helper (while_waiting)


def resolve_num_threads(num_threads: int | None = None) -> int:
    """The thread count the pipeline uses: ``num_threads`` if given, else ``$NGP_NUM_THREADS``, else 1.

    Returns:
        a count >= 1, or 0 for "leave the caller's setting alone".

    Raises:
        ValueError: a negative count, or an environment value that is not a non-negative integer.

    Example:
        >>> resolve_num_threads(3)
        3
    """
    if num_threads is None:
        raw = os.environ.get(ENV_VAR, "").strip()
        if not raw:
            return 1
        try:
            num_threads = int(raw)
        except ValueError:
            raise ValueError(f"{ENV_VAR}={raw!r} is not an integer; set it to a thread count such as 1 or 4") from None
        source = f"{ENV_VAR}={raw}"
    else:
        source = f"num_threads={num_threads}"
    if isinstance(num_threads, bool) or not isinstance(num_threads, int) or num_threads < 0:
        raise ValueError(f"{source}: expected a thread count >= 1, or 0 to keep the caller's setting")
    return num_threads


@contextmanager
def pipeline_threads(num_threads: int | None = None) -> Iterator[int]:
    """Run a block with torch's and OpenCV's thread counts set to :func:`resolve_num_threads` ``(num_threads)``,
    restoring the caller's counts on the way out (also on an exception).

    Nested and concurrent uses are counted, so only the outermost exit restores (see the module's notes on
    threads). A count of 0 changes nothing.

    Yields:
        the thread count in force inside the block.

    Example:
        >>> before = torch.get_num_threads()
        >>> with pipeline_threads(1):
        ...     torch.get_num_threads()
        1
        >>> torch.get_num_threads() == before
        True
    """
    global _depth, _saved
    n = resolve_num_threads(num_threads)
    if n == 0:
        yield torch.get_num_threads()
        return
    with _lock:
        if _depth == 0:
            _saved = (torch.get_num_threads(), cv2.getNumThreads())
        _depth += 1
        _set(n, n)
    try:
        yield n
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _saved is not None:
                _set(*_saved)
                _saved = None


def _set(torch_threads: int, cv2_threads: int) -> None:
    if torch.get_num_threads() != torch_threads:
        torch.set_num_threads(torch_threads)
    if cv2.getNumThreads() != cv2_threads:
        cv2.setNumThreads(cv2_threads)


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one, else the core count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


@contextmanager
def helper_threads(count: int | None) -> Iterator[None]:
    """Let one call use at most ``count`` threads, its own included, inside the block (None: as many as the
    process's CPU cores): the strips of line detection and the part of FSNet that runs beside the frame search.
    ``ngp predict`` gives each of its processes its share of the cores this way; no result changes."""
    global _cap
    saved, _cap = _cap, count
    try:
        yield
    finally:
        _cap = saved


def thread_budget(wanted: int) -> int:
    """How many of ``wanted`` threads a call may use, its own included: at least 1, at most the process's cores
    (or the count of :func:`helper_threads`)."""
    return max(1, min(wanted, usable_cores() if _cap is None else _cap))


def _helper_pool() -> ThreadPoolExecutor:
    # keyed by process: a pool's threads do not survive a fork, and a forked child must not wait for them. As many
    # threads as the process may use besides a caller's own, started only when needed: calls from several threads
    # of one process then run their work side by side instead of queueing for one thread
    pid = os.getpid()
    if pid not in _pools:
        _pools[pid] = ThreadPoolExecutor(max_workers=max(1, usable_cores() - 1), thread_name_prefix="ngp-helper")
    return _pools[pid]


def _run_on_helpers(fn: Callable[..., Any], *args: Any) -> Future:
    """``fn(*args)`` on a helper thread (see :func:`helper_threads`)."""
    return _helper_pool().submit(fn, *args)


def _modes() -> tuple[int, bool, bool]:
    """This thread's torch thread count and autograd modes, for work done on its behalf in another thread."""
    return torch.get_num_threads(), torch.is_grad_enabled(), torch.is_inference_mode_enabled()


def _in_modes(modes: tuple[int, bool, bool], fn: Callable[..., Any], *args: Any) -> Any:
    # torch's thread count and autograd modes belong to each thread: a helper takes the caller's, so the
    # arithmetic, and the result to the last bit, are those of the caller's thread
    threads, grad, inference = modes
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    with torch.inference_mode(inference), torch.set_grad_enabled(grad):
        return fn(*args)


class Beside:
    """``fn(*args)`` computed on a helper thread while the caller goes on (:func:`run_beside`); :meth:`result`
    returns it, or computes it in the caller's thread where no helper has started on it yet."""

    def __init__(self, fn: Callable[..., Any], args: tuple, parallel: bool) -> None:
        self._fn, self._args, self._future = fn, args, None
        if parallel:
            self._future = _run_on_helpers(_in_modes, _modes(), fn, *args)
            for job in _waiting_jobs():  # the helper takes them up when done with fn, unless this thread has
                self._future.add_done_callback(job.take_up)

    @classmethod
    def inline(cls, fn: Callable[..., Any], *args: Any) -> Beside:
        """``fn(*args)``, computed in the caller's thread when :meth:`result` asks for it."""
        return cls(fn, args, parallel=False)

    @classmethod
    def start(cls, fn: Callable[..., Any], *args: Any) -> Beside:
        """``fn(*args)`` handed to a helper thread now, whatever the autograd mode (work without gradients)."""
        return cls(fn, args, parallel=True)

    def result(self) -> Any:
        if self._future is None or self._future.cancel():  # not started: the helper is busy with other work
            return self._fn(*self._args)
        if not self._future.done():  # the helper is still at it: this thread does its waiting jobs first
            for job in _waiting_jobs():
                job.take_up()
        return self._future.result()


def _waiting_jobs() -> list[Deferred]:
    return _waiting.__dict__.setdefault("jobs", [])


class Deferred:
    """``fn(*args)`` computed once, by the first thread to take it up (:meth:`run`, :meth:`result`, or a helper done
    with its work, see :func:`while_waiting`); an exception is kept and raised by :meth:`result`, so a job done
    while waiting never breaks the work waited for."""

    def __init__(self, fn: Callable[..., Any], args: tuple) -> None:
        self._fn, self._args, self._outcome = fn, args, None
        self._lock = threading.Lock()
        self._modes = _modes()
        self.open = True  # whether a thread that would wait, or a helper done with its work, may take it up

    @property
    def ran(self) -> bool:
        """Whether it has been computed (or is being computed) by now."""
        return self._outcome is not None or self._lock.locked()

    def take_up(self, _done: Future | None = None) -> None:
        """Compute it now where it is open and no thread has taken it up (a helper's done-callback)."""
        if self.open:
            self.run(wait=False)

    def run(self, wait: bool = True) -> None:
        """Compute it unless it is done; where another thread is computing it, wait for that (or, with ``wait``
        False, return at once)."""
        if self._outcome is not None or not self._lock.acquire(blocking=wait):
            return
        try:
            if self._outcome is None:
                self._outcome = (True, _in_modes(self._modes, self._fn, *self._args))
        except Exception as err:
            self._outcome = (False, err)
        finally:
            self._lock.release()

    def result(self) -> Any:
        self.run()
        ok, value = self._outcome
        if not ok:
            raise value
        return value


@contextmanager
def while_waiting(fn: Callable[..., Any], *args: Any) -> Iterator[Deferred]:
    """Inside the block, ``fn(*args)`` fills the first gap in this thread's work shared with helpers: where this
    thread would wait for a helper (:meth:`Beside.result`) it computes it itself, and a helper done with the work
    it was handed (:meth:`Beside.start`) before that takes it up. :meth:`Deferred.result` returns it, computed then
    or on demand. Line detection's strips end unevenly, and the thread that ends first would otherwise wait idle.

    Example:
        >>> with while_waiting(lambda a: a * 2, 21) as job:
        ...     pass
        >>> job.result()
        42
    """
    job = Deferred(fn, args)
    jobs = _waiting_jobs()
    jobs.append(job)
    try:
        yield job
    finally:
        jobs.remove(job)
        job.open = False


def run_beside(fn: Callable[..., Any], *args: Any) -> Beside:
    """Start ``fn(*args)`` on a helper thread when the call may use two threads (:func:`thread_budget`) and autograd
    is off (a gradient never crosses threads here), else leave it to :meth:`Beside.result`. Meant for torch or
    OpenCV work that releases the GIL while the caller's thread runs other work.

    Example:
        >>> run_beside(lambda a, b: a + b, 2, 3).result()
        5
    """
    return Beside(fn, args, thread_budget(2) > 1 and not torch.is_grad_enabled())


class Lookahead:
    """Computes ``fn(key)`` for the key a caller will ask for next on one background thread, while the caller works
    on the current one: reading an image and detecting its lines (C code that releases the GIL) then overlaps the
    parser's work on the previous image.

    :meth:`get` returns ``fn(key)`` in the caller's thread, exceptions included (raised there, for that key only),
    whether it was computed ahead or not, so the results are those of ``fn`` called in order. Use it as a context
    manager: on the way out a computation not yet started is dropped and a running one is waited for (it reads one
    file), so nothing of it runs on after the caller returns. The thread is per process (a forked child starts
    its own).

    Example:
        >>> with Lookahead(lambda k: k * k) as ahead:
        ...     [ahead.get(k, k + 1) for k in range(4)]
        [0, 1, 4, 9]
    """

    def __init__(self, fn: Callable[[Any], Any]) -> None:
        self.fn = fn
        self._pid: int | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._pending: tuple[Hashable, Future] | None = None

    def get(self, key: Hashable, upcoming: Hashable | None = None) -> Any:
        """``fn(key)``; ``upcoming``, when given, is the key to compute next, in the background."""
        if self._pid != os.getpid():  # a fork copied a parent's state: its thread is not here
            self._pid, self._executor, self._pending = os.getpid(), None, None
        pending, self._pending = self._pending, None
        if pending is not None and pending[0] != key:
            pending[1].cancel()
            pending = None
        if upcoming is not None:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ngp-ahead")
            self._pending = (upcoming, self._executor.submit(self.fn, upcoming))
        return self.fn(key) if pending is None else pending[1].result()

    def close(self) -> None:
        """Drop the computation not yet started, wait for a running one and end the thread. (A decode redirects
        the process's stderr for its duration: a message printed after an interrupted run must not fall into it.)"""
        if self._pending is not None:
            self._pending[1].cancel()
            self._pending = None
        executor, self._executor = self._executor, None
        if executor is not None and self._pid == os.getpid():
            executor.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> Lookahead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
