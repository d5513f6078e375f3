"""Figures as PNG bytes: what every result's ``plot()`` and every report embeds."""

from __future__ import annotations

import io

from vts_hw.files import write_atomic


def figure_png(fig, path=None, dpi: float = 110) -> bytes:
    """PNG bytes of a matplotlib figure (no metadata beyond the image); also written to
    ``path`` when given (what every result's ``plot(path)`` does), whole or not at all
    (:func:`vts_hw.files.write_atomic`: on a full disk WriteFailed names the file, no cut PNG)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    png = buf.getvalue()
    if path is not None:
        write_atomic(path, png)
    return png
