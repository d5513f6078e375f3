"""Figures as PNG bytes: what every result's ``plot()`` and every report embeds."""

from __future__ import annotations

import io


def figure_png(fig, path=None, dpi: int = 110) -> bytes:
    """PNG bytes of a matplotlib figure (no metadata beyond the image); also written to
    ``path`` when given (what every result's ``plot(path)`` does)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    png = buf.getvalue()
    if path is not None:
        from pathlib import Path
        Path(path).write_bytes(png)
    return png
