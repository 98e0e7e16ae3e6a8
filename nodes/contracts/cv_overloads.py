"""Stop signals held back across OpenCV calls that try more than one overload.

When a call's arguments do not fit the first overload OpenCV's Python binding tries, the binding
turns the conversion error into text with ``PyObject_Str`` and uses the result unchecked. Python
runs signal handlers inside ``PyObject_Str``: a stop signal whose handler raises at that moment
(``stereograph run`` makes SIGINT and SIGTERM a ``KeyboardInterrupt``) kills the process with a
segmentation fault. Call OpenCV with its first overload's arguments where you can; where you
cannot (``cv2.FileStorage.write`` of anything but an int), call it within
:func:`stop_signals_held`. Public: :func:`stop_signals_held`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

__all__ = ["stop_signals_held"]

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_signals_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back until the block ends, then raise each again.

    The handlers in place when the block began see a held signal as if it had just arrived, at
    the block's end. Only the main thread runs Python's signal handlers, so elsewhere (and where
    a handler was not set from Python) nothing is held.
    """
    before = {s: signal.getsignal(s) for s in _STOP_SIGNALS}
    if threading.current_thread() is not threading.main_thread() or None in before.values():
        yield
        return
    held: list[int] = []
    for s in _STOP_SIGNALS:
        signal.signal(s, lambda signum, _frame: held.append(signum))
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)
        for s in dict.fromkeys(held):
            signal.raise_signal(s)
