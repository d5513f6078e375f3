"""The QA history (report/history.py) drawn: an HTML section per procedure (a table of the last
runs and a small trend plot) and a PDF page with the same tables and plots."""

from __future__ import annotations

import base64
from html import escape

from vts_hw import catalog
from vts_hw.figures import figure_png
from vts_hw.report.history import LAST_N, ProcedureHistory
from vts_hw.report.plots import FONT, STATE_COLOURS
from vts_hw.report.times import fmt_datetime, utc


def _fmt(v, spec: str) -> str:
    return "–" if v is None else format(v, spec)


def trend_figure(h: ProcedureHistory, figsize=(7.5, 1.9), ax=None):
    """The trend figure of every completed run of the period, points coloured by their state,
    the tolerance (dashed) and action (solid) limits of the window in effect now."""
    import matplotlib
    from matplotlib.figure import Figure

    with matplotlib.rc_context(FONT):
        fig = None
        if ax is None:
            fig = Figure(figsize=figsize)
            ax = fig.add_subplot()
        pts = h.trend_points()
        xs = [utc(t) for t, _, _ in pts]
        ax.plot(xs, [v for _, v, _ in pts], color="#8a94a0", lw=0.8, zorder=1)
        ax.scatter(xs, [v for _, v, _ in pts], c=[STATE_COLOURS.get(s, "#5f6b7a") for _, _, s in pts], s=14, zorder=2)
        w = h.window_now
        if w is not None:
            for level, colour, style in (
                (w.tolerance_high, STATE_COLOURS["TOLERANCE"], "--"),
                (w.tolerance_low, STATE_COLOURS["TOLERANCE"], "--"),
                (w.action_high, STATE_COLOURS["ACTION"], "-"),
                (w.action_low, STATE_COLOURS["ACTION"], "-"),
            ):
                if level is not None:
                    ax.axhline(level, color=colour, ls=style, lw=0.9, zorder=0)
        ax.set_ylabel(h.trend_figure.label, fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        if fig is not None:
            fig.autofmt_xdate()
            fig.tight_layout()
    return fig


def history_plot_count(history) -> int:
    return sum(1 for h in history if h.has_plot)


def history_html(history: list[ProcedureHistory], show_rig: bool = False) -> str:
    """The report's "QA history" section ("" without any such runs)."""
    if not history:
        return ""

    parts = []
    for h in history:
        figs = h.spec.figures
        head = (
            "<th>Started</th>"
            + ("<th>Room</th>" if show_rig else "")
            + "<th>What</th><th>Run</th><th>State</th>"
            + "".join(f"<th class=num>{escape(f.label)}</th>" for f in figs)
        )
        rows = []
        for r in h.shown:
            cells = "".join(
                f'<td class="num{" s-" + escape(s) if s and s != "OK" else ""}">{_fmt(v, f.fmt)}</td>'
                for f, (v, s) in zip(figs, r.values)
            )
            rows.append(
                f"<tr><td>{fmt_datetime(r.started)}</td>"
                + (f"<td>{escape(r.rig)}</td>" if show_rig else "")
                + f"<td>{escape(catalog.label(r.procedure))}</td><td>{r.id}</td>"
                f'<td><span class="badge {escape(r.status)}">{escape(r.status)}</span></td>{cells}</tr>'
            )
        more = len(h.runs) - len(h.shown)
        img = ""
        if h.has_plot:
            png = base64.b64encode(figure_png(trend_figure(h))).decode("ascii")
            img = (
                f'<img class="plot" alt="{escape(h.title)}: {escape(h.trend_figure.label)} of each run over time, '
                f'coloured by state" src="data:image/png;base64,{png}">'
            )
        parts.append(
            f'<h3>{escape(h.title)}</h3>{img}<div class="scroll"><table data-history="{escape(h.spec.key)}">'
            f"<thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div>"
            + (f'<p class="muted">… and {more} earlier run(s) in the period.</p>' if more > 0 else "")
        )
    return (
        '<section class="card" id="history"><h2>QA history</h2><p class="muted">Sync checks, SPECT '
        f"mappings, camera calibrations and motion analyses of the period: the last {LAST_N} runs of each, "
        "newest first; the plot shows every run's first figure with the limits in effect now.</p>"
        + "".join(parts)
        + "</section>"
    )


def history_figure(history: list[ProcedureHistory], figsize=(11.69, 8.27)):
    """A PDF page: per procedure its trend plot and the last runs as lines of text."""
    import matplotlib
    from matplotlib.figure import Figure

    with matplotlib.rc_context(FONT):
        fig = Figure(figsize=figsize)
        fig.text(0.05, 0.94, "QA history", fontsize=16, fontweight="bold")
        n = max(len(history), 1)
        band = 0.86 / n
        for i, h in enumerate(history):
            top = 0.90 - i * band
            fig.text(0.05, top, h.title, fontsize=10, fontweight="bold", va="top")
            lines = [
                f"{fmt_datetime(r.started)}  run {r.id:<5} {r.status:<9} "
                + "  ".join(f"{f.label} {_fmt(v, f.fmt)}" for f, (v, _) in zip(h.spec.figures, r.values))
                for r in h.shown[: max(2, int(band * 60) - 2)]
            ]
            fig.text(0.05, top - 0.025, "\n".join(lines), fontsize=6.5, family="monospace", va="top")
            if h.has_plot:
                ax = fig.add_axes((0.62, top - band + 0.04, 0.34, band - 0.07))
                trend_figure(h, ax=ax)
    return fig


__all__ = ["history_html", "history_figure", "history_plot_count", "trend_figure"]
