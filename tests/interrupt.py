"""A training run stopped part-way as Ctrl-C stops it: the shared set-up of the resume tests."""

import contextlib

from pdestream.surrogate import train as T


@contextlib.contextmanager
def interrupted_at(monkeypatch, batch: int):
    """Inside the block, training raises KeyboardInterrupt when it asks for its ``batch``-th batch (from 1)."""
    real = T.forever

    def dying(loader):
        for n, b in enumerate(real(loader), 1):
            if n == batch:
                raise KeyboardInterrupt
            yield b

    monkeypatch.setattr(T, "forever", dying)
    try:
        yield
    finally:
        monkeypatch.setattr(T, "forever", real)
