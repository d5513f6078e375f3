"""Analysis reports as PDF pages: a title with the state, then headings, text, tables and the
plot flowed over A4 landscape pages, the way the drift PDF is made (matplotlib figures, one a
page, through :func:`vts_hw.report.pdf.pdf_bytes`).

A report is a list of blocks: :class:`Heading`, :class:`Text`, :class:`Table` (monospace
columns; long cells wrap in their column, a long table goes on over more pages with its header
repeated) and :class:`Image` (a PNG, scaled to the page's width). Nothing is measured by
guesswork: each block's height is the height matplotlib gives its text.
"""

from __future__ import annotations

import io
import textwrap
from dataclasses import dataclass, field

import matplotlib
import matplotlib.image
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from vts_hw.report.pdf import A4_LANDSCAPE, MARGIN, pdf_bytes
from vts_hw.report.plots import FONT, STATE_COLOURS

TOP, FLOOR = 0.93, 0.05
GAP = 0.018
TEXT_PT, TABLE_PT = 9.0, 7.0
KEEP_WITH_NEXT = 0.15  # a heading needs this much of the page below it
TABLE_CHARS = 175  # monospace characters across the page at TABLE_PT
CELL_MAX = 48  # a column is at most this wide; longer cells wrap
MUTED = "#5f6b7a"


@dataclass
class Heading:
    text: str


@dataclass
class Text:
    text: str
    muted: bool = False


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    empty: str = "none"


@dataclass
class Image:
    png: bytes
    alt: str = "plot"


@dataclass
class Page:
    fig: Figure
    y: float = TOP
    renderer: object = field(default=None)


def table_lines(header: list[str], rows: list[list[str]], width: int = TABLE_CHARS) -> tuple[list[str], list[str]]:
    """Header lines (then a blank one; none for a header of blanks) and body lines of a
    monospace table; cells wrap within their column."""
    n = len(header)
    widths = [min(CELL_MAX, max(len(str(r[j])) for r in [header, *rows])) for j in range(n)]
    while sum(widths) + 2 * (n - 1) > width and max(widths) > 8:
        widths[widths.index(max(widths))] -= 1

    def lines_of(cells) -> list[str]:
        wrapped = [textwrap.wrap(str(c), w, break_long_words=True) or [""] for c, w in zip(cells, widths)]
        depth = max(len(x) for x in wrapped)
        return [
            "  ".join((x[k] if k < len(x) else "").ljust(w) for x, w in zip(wrapped, widths)).rstrip()
            for k in range(depth)
        ]

    head = lines_of(header) + [""] if any(h.strip() for h in header) else []
    return head, [line for r in rows for line in lines_of(r)]


class _Flow:
    def __init__(self, title: str):
        self.title = title
        self.pages: list[Page] = []
        self.new_page()

    def new_page(self) -> Page:
        fig = Figure(figsize=A4_LANDSCAPE)
        page = Page(fig, TOP, FigureCanvasAgg(fig).get_renderer())
        if self.pages:
            fig.text(MARGIN, 0.965, f"{self.title} (continued)", fontsize=8, color=MUTED, va="top")
        self.pages.append(page)
        return page

    @property
    def page(self) -> Page:
        return self.pages[-1]

    def height(self, text) -> float:
        bb = text.get_window_extent(self.page.renderer)
        return bb.height / self.page.fig.bbox.height

    def put(self, x: float, s: str, **kw) -> float:
        """Write ``s`` at the flow's place (a new page when it does not fit); its height."""
        t = self.page.fig.text(x, self.page.y, s, va="top", **kw)
        h = self.height(t)
        if self.page.y - h < FLOOR and self.page.y < TOP:
            t.remove()
            self.new_page()
            t = self.page.fig.text(x, self.page.y, s, va="top", **kw)
        self.page.y -= h + GAP / 2
        return h

    def line_height(self, size: float) -> float:
        t = self.page.fig.text(0, 0, "Xg", fontsize=size, family="monospace", linespacing=1.25)
        h = self.height(t)
        t.remove()
        return h

    def table(self, block: Table) -> None:
        if not block.rows:
            self.put(MARGIN, block.empty, fontsize=TEXT_PT, color=MUTED)
            return
        head, body = table_lines(block.header, block.rows)
        per = self.line_height(TABLE_PT)
        while body:
            room = int((self.page.y - FLOOR) / per) - len(head)
            if room < 3 and self.page.y < TOP:
                self.new_page()
                continue
            take, body = body[: max(room, 1)], body[max(room, 1) :]
            self.put(MARGIN, "\n".join(head + take), fontsize=TABLE_PT, family="monospace", linespacing=1.25)

    def image(self, block: Image) -> None:
        if not block.png:
            self.put(MARGIN, f"({block.alt}: no plot)", fontsize=TEXT_PT, color=MUTED)
            return
        img = matplotlib.image.imread(io.BytesIO(block.png), format="png")
        w = 1 - 2 * MARGIN
        h = w * img.shape[0] / img.shape[1] * A4_LANDSCAPE[0] / A4_LANDSCAPE[1]
        if h > TOP - FLOOR:
            w, h = w * (TOP - FLOOR) / h, TOP - FLOOR
        if self.page.y - h < FLOOR:
            self.new_page()
        ax = self.page.fig.add_axes((MARGIN, self.page.y - h, w, h))
        ax.imshow(img, interpolation="lanczos")
        ax.set_axis_off()
        self.page.y -= h + GAP


def render_pages(title: str, state: str, meta: str, blocks: list, pdf_meta: dict) -> bytes:
    """The report as PDF bytes: the title, the state in its colour, ``meta`` (a muted line),
    then ``blocks`` in order."""
    with matplotlib.rc_context(FONT):
        flow = _Flow(title)
        flow.put(MARGIN, title, fontsize=20, fontweight="bold")
        flow.put(MARGIN, textwrap.fill(meta, 160), fontsize=8.5, color=MUTED)
        flow.page.y -= GAP / 2
        flow.put(
            MARGIN,
            f" {state} ",
            fontsize=13,
            fontweight="bold",
            color="white",
            bbox={"boxstyle": "round,pad=0.35", "fc": STATE_COLOURS.get(state, "#9aa3ad"), "ec": "none"},
        )
        flow.page.y -= GAP / 2
        for b in blocks:
            if isinstance(b, Heading):
                if flow.page.y - FLOOR < KEEP_WITH_NEXT:  # never a heading alone at a page's foot
                    flow.new_page()
                flow.page.y -= GAP / 2
                flow.put(MARGIN, b.text, fontsize=12.5, fontweight="bold")
            elif isinstance(b, Text):
                flow.put(
                    MARGIN,
                    textwrap.fill(b.text, 150),
                    fontsize=TEXT_PT,
                    linespacing=1.4,
                    color=MUTED if b.muted else "#1d2733",
                )
            elif isinstance(b, Table):
                flow.table(b)
            elif isinstance(b, Image):
                flow.image(b)
            else:
                raise TypeError(f"not a report block: {b!r}")
    return pdf_bytes([p.fig for p in flow.pages], pdf_meta)


__all__ = ["Heading", "Text", "Table", "Image", "render_pages", "table_lines"]
