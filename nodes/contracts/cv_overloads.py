"""Two pitfalls of how OpenCV's Python binding picks an overload, and their way round.

Stop signals: when a call's arguments do not fit the first overload tried, the binding turns the
conversion error into text with ``PyObject_Str``, which runs Python signal handlers, and uses the
result unchecked; a handler that raises (``stereograph run`` makes SIGINT and SIGTERM a
``KeyboardInterrupt``) then crashes the process. Call OpenCV with its first overload's arguments,
or within :func:`stop_signals_held`. A 1x1 image beside a number: OpenCV 5.1 reads both as
Scalars and returns 4x1; call such element-wise functions through :func:`scalar_op`.
Public: :func:`stop_signals_held`, :func:`scalar_op`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator

import numpy as np

__all__ = ["scalar_op", "stop_signals_held"]

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


def scalar_op(fn: Callable[..., np.ndarray], img: np.ndarray, *args, **kwargs) -> np.ndarray:
    """``fn(img, *args, **kwargs)``, an OpenCV element-wise call with a number among ``args``,
    with the result the shape of ``img`` whatever its size.

    OpenCV 5.1's binding takes a 1x1 array next to a number for a Scalar too (the result is 4x1),
    so a 1x1 ``img`` (a one-pixel region) is widened to 1x2 for the call and its first column
    kept.
    """
    if img.shape[:2] != (1, 1):
        return fn(img, *args, **kwargs)
    return fn(np.repeat(img, 2, axis=1), *args, **kwargs)[:, :1]
