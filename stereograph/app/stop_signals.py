"""Stop signals for ``run`` and ``compare``: SIGINT and SIGTERM both end the command as Ctrl-C
does, whatever the process inherited, and a loop learns where the signal landed.

Public: :func:`stop_signals_as_interrupt`, :func:`stop_requested`.
"""

from __future__ import annotations

import contextlib
import os
import signal

_STOP: list[str] = []  # where each stop signal of this command landed (frame), in order


def stop_requested() -> str | None:
    return _STOP[0] if _STOP else None


@contextlib.contextmanager
def stop_signals_as_interrupt():
    """For ``run`` and ``compare``: SIGINT and SIGTERM both end the command as Ctrl-C does, as a
    ``KeyboardInterrupt`` raised in the running node (its cleanup runs: an arm is held, the run's
    ``run.json`` is written, the same command resumes), whatever the process inherited: a job
    started with ``&`` by a non-interactive shell inherits SIGINT *ignored*, and a supervisor may
    start it with the signals blocked. A worker process forked while this is installed keeps the
    default action."""
    main_pid = os.getpid()
    _STOP.clear()

    def on_signal(signum, frame):
        if os.getpid() != main_pid:  # a pool's worker: end as before (its pool is ended for it)
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        # where it landed: a loop that finds this set at its next node stops there
        # (stereograph.app.loop)
        _STOP.append(
            f"{frame.f_code.co_name} ({frame.f_code.co_filename}:{frame.f_lineno})"
            if frame
            else "?"
        )
        raise KeyboardInterrupt("SIGTERM" if signum == signal.SIGTERM else "")

    try:
        old = {
            signal.SIGTERM: signal.signal(signal.SIGTERM, on_signal),
            signal.SIGINT: signal.signal(signal.SIGINT, on_signal),
        }
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        for signum, handler in old.items():
            signal.signal(signum, handler)
