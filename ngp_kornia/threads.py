"""The thread policy of a call and the read-ahead of lists: the pipeline's small tensors run on one torch thread.

The parser's tensors are small (a few thousand candidates, a 224x224 FSNet input), so torch's intra-op threads
gain nothing on an idle machine and spin against every other process on a busy one (BENCHMARKS.md).
:func:`ngp_kornia.calibrate` and ``ngp predict`` therefore run inside :func:`pipeline_threads`, which sets the
calling thread's torch thread count for the duration of the call and restores it afterwards, also when the call
raises. In torch's OpenMP builds (Linux, Windows) that count belongs to the calling thread: other threads of the
process are not affected. The parser module itself never changes it (as a layer of a larger model it runs with
whatever ``torch.get_num_threads()`` says).

How many threads: ``calibrate(..., num_threads=N)`` when given; else the environment variable ``NGP_NUM_THREADS``;
else 1. ``0`` leaves the caller's setting alone. With one thread the results do not depend on the machine's thread
count.

Two more threads earn their place (BENCHMARKS.md): line detection runs LSD's strips side by side
(:mod:`~ngp_kornia.pipeline.segments`), and a list of images (and ``ngp predict``) reads the next file and detects
its lines while the parser works on the current one (:class:`Lookahead`). The parser also hands a few jobs of C
code to a helper thread (:func:`beside`: FSNet's resized image, the orientation check, FSNet's trunk beside the frame
candidates). None changes a result.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import torch

from ngp_kornia.errors import InputError, shown

__all__ = ["ENV_VAR", "Lookahead", "beside", "pipeline_threads", "resolve_num_threads", "usable_cores"]

#: the environment variable read when a call does not say how many threads to use
ENV_VAR = "NGP_NUM_THREADS"


def resolve_num_threads(num_threads: int | None = None) -> int:
    """The thread count a call uses: ``num_threads`` if given, else ``$NGP_NUM_THREADS``, else 1.

    Returns:
        a count >= 1, or 0 for "leave the caller's setting alone".

    Raises:
        InputError: a negative count, a bool, a non-integer, or an environment value that is not a non-negative
            integer (an :class:`~ngp_kornia.errors.NGPError`, and a ``ValueError``).

    Example:
        >>> resolve_num_threads(3)
        3
    """
    if num_threads is None:
        raw = os.environ.get(ENV_VAR, "").strip()
        if not raw:
            return 1
        try:
            return _checked(int(raw), f"{ENV_VAR}={raw}")
        except ValueError:
            raise InputError(f"{ENV_VAR}={raw!r} is not a thread count; set it to 1, 4, ... or 0") from None
    return _checked(num_threads, f"num_threads={shown(num_threads)}")


def _checked(count: object, source: str) -> int:
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise InputError(f"{source}: expected a thread count >= 1, or 0 to keep the caller's setting")
    return count


@contextmanager
def pipeline_threads(num_threads: int | None = None) -> Iterator[int]:
    """Run a block with the calling thread's torch thread count set to :func:`resolve_num_threads`
    ``(num_threads)``, restoring it on the way out (also on an exception). A count of 0 changes nothing.

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
    n = resolve_num_threads(num_threads)
    saved = torch.get_num_threads()
    if n == 0 or n == saved:
        yield saved
        return
    torch.set_num_threads(n)
    try:
        yield n
    finally:
        torch.set_num_threads(saved)


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one, else the core count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


#: the helper thread of each process that runs the parser's side jobs (a pool's thread does not survive a fork)
_helpers: dict[int, ThreadPoolExecutor] = {}


def beside(fn: Callable[..., Any], *args: Any) -> Callable[[], Any]:
    """Start ``fn(*args)`` on the process's helper thread and return the function that gives its result: computed
    there, or here where that thread has not started on it when asked (the same computation either way). Jobs run
    one after the other, in the order they were given; the caller decides whether a second core is free for them.

    Example:
        >>> beside(sum, [1, 2, 3])()
        6
    """
    pid = os.getpid()
    if pid not in _helpers:
        _helpers[pid] = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ngp-beside")
    pending = _helpers[pid].submit(fn, *args)
    return lambda: fn(*args) if pending.cancel() else pending.result()


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
        """Drop the computation not yet started, wait for a running one and end the thread."""
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
