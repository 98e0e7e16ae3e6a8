"""Drawing helpers shared by every node that saves a picture: titled images and matplotlib figures.

``caption(img, lines)`` puts text in a band *above* the image, wrapped to the image's width, so a
long refusal reason is never cut at the image edge and never hides the pixels it explains.
``figure_bgr(fig)`` renders a matplotlib figure (Agg) to the BGR ``uint8`` array that an ``Image``
output carries. Matplotlib is imported only by the functions that need it (start-up time).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

FONT_SCALE = 0.5
LINE_PX = 18  # text line height at FONT_SCALE (px)


def wrap(text: str, width_px: int, scale: float = FONT_SCALE) -> list[str]:
    """Split ``text`` into lines that fit ``width_px`` at OpenCV's Hershey simplex font."""
    import cv2

    out: list[str] = []
    for para in str(text).split("\n"):
        line = ""
        for word in para.split(" "):
            trial = f"{line} {word}" if line else word
            if (
                cv2.getTextSize(trial, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] <= width_px
                or not line
            ):
                line = trial
            else:
                out.append(line)
                line = word
            while (
                cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > width_px
                and len(line) > 1
            ):
                # a single word wider than the image (a long path): cut it, keep every character
                full = cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
                cut = max(1, int(len(line) * width_px / full))
                out.append(line[:cut])
                line = line[cut:]
        out.append(line)
    return out


def caption(
    img: np.ndarray,
    lines: Iterable[str | tuple[str, tuple[int, int, int]]],
    background: tuple[int, int, int] = (255, 255, 255),
) -> np.ndarray:
    """``img`` (BGR or grey uint8) with a band of text above it.

    ``lines``: text, or ``(text, bgr_colour)``; each is wrapped to the image width. Returns a new
    BGR image, taller by the band.
    """
    import cv2

    base = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img[..., :3]
    w = base.shape[1]
    k_scale = max(1.0, w / 900)  # text stays readable when a wide image is shown scaled down
    scale, line_px, thick = (
        FONT_SCALE * k_scale,
        int(round(LINE_PX * k_scale)),
        max(1, int(round(k_scale))),
    )
    rows: list[tuple[str, tuple[int, int, int]]] = []
    for item in lines:
        text, colour = (item, (0, 0, 0)) if isinstance(item, str) else item
        rows += [(t, colour) for t in wrap(text, w - 12, scale)]
    band = np.full((line_px * len(rows) + 8, w, 3), background, np.uint8)
    for k, (text, colour) in enumerate(rows):
        cv2.putText(
            band,
            text,
            (6, line_px * (k + 1)),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            colour,
            thick,
            cv2.LINE_AA,
        )
    return np.ascontiguousarray(np.vstack([band, base]))


def load_figures() -> None:
    """Import what :func:`new_figure` and :func:`figure_bgr` use (~1 s: matplotlib, its Agg canvas
    and font list). A node that draws declares it as its ``prepare`` (stereograph.api.node): a run
    may then load it while the process would wait for its workers, not alone at the end."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401


def new_figure(width_in: float, height_in: float, dpi: int = 90) -> Any:
    """A matplotlib Figure on the Agg canvas (no pyplot, no global state)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def figure_bgr(fig: Any) -> np.ndarray:
    """Render a Figure made by :func:`new_figure` to a BGR uint8 image."""
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[..., [2, 1, 0]])
