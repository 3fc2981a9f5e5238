"""Ctrl-C for the ``pdestream`` commands: one interrupt cleans up, later ones wait for it; what a command created.

``run(call, standalone)`` runs one command under these rules and returns its exit status: 0, 2 for a user error
(one line ``pdestream: error: ...``), 130 after an interrupt (one line saying what was kept). ``snapshot`` and
``remove_created`` let a command remove only what it created when it is interrupted. No JAX, no torch.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import warnings
from pathlib import Path

# The errors a user can fix (bad names, values, paths): one line and exit status 2, no traceback.
USER_ERRORS = (ValueError, FileExistsError, FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)


def first_interrupt(signum, frame) -> None:
    """SIGINT handler: the first Ctrl-C raises KeyboardInterrupt; later ones are ignored, so the clean-up it
    starts (removing a half-made cache, stopping solver threads) runs to its end and a second Ctrl-C cannot
    tear the interpreter down inside a JAX call ("terminate called ...", exit 134)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def redeliver_interrupt(unraisable) -> None:
    """sys.unraisablehook: a Ctrl-C whose KeyboardInterrupt was raised where Python cannot raise (inside a gc
    callback of JAX's, a __del__) is sent again, instead of being printed and lost while the SIGINTs after it
    are ignored (a compare kept training); other unraisable errors go to the default hook."""
    if issubclass(unraisable.exc_type, KeyboardInterrupt):
        signal.signal(signal.SIGINT, first_interrupt)
        # from another thread, a little later: sent from here it would be handled in this hook, and dropped again
        threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()
        return
    sys.__unraisablehook__(unraisable)


def one_line_warnings(shown):
    """A warnings.showwarning for a command: pdestream's own warnings (a category declared in the package, e.g.
    an under-resolved setting) as one line ``pdestream: warning: ...`` on stderr, without the source path and
    line Python adds; every other warning through ``shown`` (the hook it replaces)."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        if category.__module__.split(".")[0] == "pdestream":
            print(f"pdestream: warning: {message}", file=sys.stderr if file is None else file)
        else:
            shown(message, category, filename, lineno, file, line)

    return show


def leave(code: int) -> None:
    """The command's exit after an interrupt's clean-up (caches, producers and clusters closed by then): at
    once, since a solver thread may still be inside a call or a compile, which interpreter shutdown would wait
    for (seconds) or tear down inside JAX (an abort). multiprocessing's exit hook still runs, so semaphores
    and child processes are released."""
    import multiprocessing.util

    multiprocessing.util._exit_function()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def run(call, standalone: bool) -> int:
    """Run ``call()`` as a command: its exit status (0; 2 after a user error; 130 after Ctrl-C), each failure in
    one line on stderr. ``standalone``: the process is this command (``pdestream ...``), which then leaves at once
    after an interrupt and keeps ignoring SIGINT until then; an in-process caller (tests) gets its handler back."""
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, first_interrupt) if in_main else None
    hook = sys.unraisablehook
    if in_main:
        sys.unraisablehook = redeliver_interrupt
    interrupted = False
    shown = warnings.showwarning
    warnings.showwarning = one_line_warnings(shown)
    try:
        call()
    except USER_ERRORS as err:
        print(f"pdestream: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        interrupted = True
        print(f"pdestream: interrupted{f'; {err}' if str(err) else ''}", file=sys.stderr)
        if standalone:
            leave(130)
        return 130
    except BrokenPipeError:  # output piped into `head`
        sys.stderr.close()
        return 0
    finally:
        # the command keeps ignoring SIGINT after an interrupt until it has exited (a Ctrl-C during interpreter
        # shutdown would kill it or abort it); an in-process caller gets its handler back
        warnings.showwarning = shown
        if in_main and not (interrupted and standalone):
            signal.signal(signal.SIGINT, previous if previous is not None else signal.default_int_handler)
            sys.unraisablehook = hook
    return 0


def check_writable_dir(d, option: str = "--out") -> None:
    """One-line PermissionError (NotADirectoryError) when the directory ``d`` cannot be written or created: checked
    before a command starts its work, so a read-only place is refused at once and nothing is created."""
    d = Path(d)
    there = d
    while not there.exists() and there != there.parent:  # the nearest existing ancestor: where ``d`` is created
        there = there.parent if str(there.parent) else Path(".")
    if not there.is_dir():
        raise NotADirectoryError(f"{option} {d}: {there} is not a directory")
    if not os.access(there, os.W_OK | os.X_OK):
        raise PermissionError(f"{option} {d}: directory {there} is not writable")


def check_not_in_zarr(d, option: str = "--out") -> None:
    """One-line ValueError when the directory ``d`` is a Zarr store (a cache) or lies inside one: a run or a
    comparison written there mixed its files with the arrays (`train --source X.zarr --out X.zarr` ran, rc 0), which
    a later `generate --overwrite` refuses as foreign entries."""
    d = Path(d)
    for p in (d.absolute(), *d.absolute().parents):
        if (p / "zarr.json").is_file() or (p / ".zgroup").is_file():
            where = "is a Zarr cache" if p == d.absolute() else f"is inside the Zarr cache {p}"
            raise ValueError(f"{option} {d} {where}; write the run to a directory of its own")


def snapshot(d) -> dict[str, tuple[int, int]] | None:
    """{name: (inode, mtime ns)} of the entries of directory ``d``, or None when there is no such directory (the
    command will create it): what was there before a command, so an interrupt removes only what it created."""
    d = Path(d)
    if not d.is_dir():
        return None
    return {e.name: (e.stat().st_ino, e.stat().st_mtime_ns) for e in os.scandir(d)}


def remove_created(d, before: dict[str, tuple[int, int]] | None) -> None:
    """Remove what the command created in directory ``d``: ``d`` itself if it did not exist before (``before`` is
    None), else its new entries and the files replaced since (atomic writes make a new inode); entries that were
    there and are unchanged, or directories that were there, stay."""
    import shutil

    d = Path(d)
    if before is None:
        shutil.rmtree(d, ignore_errors=True)
        return
    for e in list(os.scandir(d)) if d.is_dir() else []:
        if e.name in before and (e.is_dir(follow_symlinks=False) or before[e.name] == (e.stat().st_ino,
                                                                                        e.stat().st_mtime_ns)):
            continue
        if e.is_dir(follow_symlinks=False):
            shutil.rmtree(e.path, ignore_errors=True)
        else:
            Path(e.path).unlink(missing_ok=True)
