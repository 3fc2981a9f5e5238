"""``prefetch``: run an iterator in a background thread a bounded number of items ahead of its consumer.

Shared by the cache writer (solve block k+1 while block k is written) and the stream (solve batch k+1
while batch k is trained on). JAX releases the GIL while it computes, so the two overlap.

Stopping is prompt: the producer's solves stop at their next bounded call once the consumer has gone
(``generator.sampler.cancel_on``), and the consumer waits at most JOIN_S for that, so a Ctrl-C is not held up
by a long solve in flight. The producer's solves report their progress to the ``meter.progress_to`` callback of
the thread that first iterates the prefetch (the consumer's).
"""

from __future__ import annotations

import atexit
import queue
import threading
from collections.abc import Callable, Iterable, Iterator

from pdestream import meter

_DONE = object()
_LIVE: set = set()  # (stop event, thread) of every running producer
JOIN_S = 1.5  # how long closing waits for the producer's call in flight (a compile can take longer)


@atexit.register
def _stop_all() -> None:
    # A script may exit with a stream still open (break out of the loop, never close it). Daemon threads
    # are killed at interpreter exit, and one killed inside a JAX call aborts the process ("terminate
    # called..."): stop every producer and let its call in flight finish first (one bounded call, or a
    # compile; a CLI that must leave sooner ends with os._exit after its clean-up, see cli.main).
    for stop, thread in list(_LIVE):
        stop.set()
        thread.join()


class _Raised:
    """An exception of the producer, carried to the consumer (an item may itself be an exception object)."""

    def __init__(self, err: BaseException):
        self.err = err


def prefetch(make: Callable[[], Iterable], depth: int = 1, name: str = "pdestream-prefetch") -> Iterator:
    """Yield the items of ``make()``, produced by a daemon thread at most ``depth`` items ahead.

    The producer's exception (e.g. generator.BlowUpError) is raised in the consumer. Closing the generator
    (``.close()``, or an error or Ctrl-C in the consumer) stops the producer: every hand-over waits on the
    stop flag, never blocking forever, its solves stop at their next bounded call (``cancel_on``), and the
    close waits up to JOIN_S for that; a producer still busy then (compiling) finishes on its own and is
    waited for at interpreter exit (a JAX call torn down at exit aborts the process).
    """
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
        raise ValueError(f"depth={depth!r} not allowed: need an integer >= 1")
    ready: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    progress = meter.current()  # the producer's solves report to the consumer thread's progress callback

    def put(item) -> bool:  # False once the consumer has gone
        while not stop.is_set():
            try:
                ready.put(item, timeout=0.1)
                return True
            except queue.Full:
                pass
        return False

    def work() -> None:
        from . import _bridge

        try:
            _bridge.cancel_solves_on(stop)  # a solve of this thread stops at its next call once we are closed
            with meter.progress_to(progress):
                for item in make():
                    if not put(item):
                        return
            put(_DONE)
        except BaseException as err:  # re-raised by the consumer (nobody reads it once stopped: no-op then)
            put(_Raised(err))

    thread = threading.Thread(target=work, daemon=True, name=name)
    _LIVE.add((stop, thread))
    thread.start()
    try:
        while (item := ready.get()) is not _DONE:
            if isinstance(item, _Raised):
                raise item.err
            yield item
    finally:
        stop.set()
        thread.join(JOIN_S)
        if not thread.is_alive():
            _LIVE.discard((stop, thread))
