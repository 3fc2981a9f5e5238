"""``prefetch``: run an iterator in a background thread a bounded number of items ahead of its consumer.

Shared by the cache writer (solve block k+1 while block k is written) and the stream (solve batch k+1
while batch k is trained on). JAX releases the GIL while it computes, so the two overlap.
"""

from __future__ import annotations

import atexit
import queue
import threading
from collections.abc import Callable, Iterable, Iterator

_DONE = object()
_LIVE: set = set()  # (stop event, thread) of every running producer


@atexit.register
def _stop_all() -> None:
    # A script may exit with a stream still open (break out of the loop, never close it). Daemon threads
    # are killed at interpreter exit, and one killed inside a JAX call aborts the process ("terminate
    # called..."): stop every producer and let its call in flight finish first.
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
    stop flag, never blocking forever, and the close waits for the item in flight to finish (a JAX call
    torn down at interpreter exit aborts the process instead of exiting cleanly).
    """
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
        raise ValueError(f"depth={depth!r} not allowed: need an integer >= 1")
    ready: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:  # False once the consumer has gone
        while not stop.is_set():
            try:
                ready.put(item, timeout=0.1)
                return True
            except queue.Full:
                pass
        return False

    def work() -> None:
        try:
            for item in make():
                if not put(item):
                    return
            put(_DONE)
        except BaseException as err:  # re-raised by the consumer
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
        thread.join()
        _LIVE.discard((stop, thread))
