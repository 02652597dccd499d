"""Checks that a drawn matplotlib figure is readable: no text overprints another, none is cut off.

Measured with the Agg renderer (`get_window_extent`), in display pixels.
"""

from __future__ import annotations

from itertools import combinations

from matplotlib.figure import Figure
from matplotlib.text import Text
from matplotlib.transforms import Bbox


def _in_view(lo: float, hi: float, value: float) -> bool:
    return min(lo, hi) - 1e-9 <= value <= max(lo, hi) + 1e-9


def drawn_texts(fig: Figure) -> list[Text]:
    """Every non-empty text the figure draws: titles, labels, tick labels in view, annotations,
    legends (the axes' and the figure's), figure texts."""
    fig.canvas.draw()
    out: list[Text] = list(fig.texts)
    for legend in fig.legends:
        out += legend.get_texts()
    for ax in fig.axes:
        out += list(ax.texts)
        out += [ax.title, ax._left_title, ax._right_title]  # private: no public getter
        legend = ax.get_legend()
        if legend is not None:
            out += legend.get_texts()
        if not ax.axison:
            continue
        out += [ax.xaxis.label, ax.yaxis.label]
        for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            for tick in axis.get_major_ticks():
                if tick.label1.get_visible() and _in_view(lo, hi, tick.get_loc()):
                    out.append(tick.label1)
    return [t for t in out if t.get_visible() and t.get_text().strip()]


def boxes(fig: Figure) -> list[tuple[str, Bbox]]:
    """(text, display box) of every drawn text."""
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    return [(t.get_text(), t.get_window_extent(renderer)) for t in drawn_texts(fig)]


def overlaps(fig: Figure, slack: float = 0.5) -> list[tuple[str, str]]:
    """Pairs of drawn texts whose boxes overlap by more than `slack` pixels each way."""
    found = []
    for (a, ba), (b, bb) in combinations(boxes(fig), 2):
        w = min(ba.x1, bb.x1) - max(ba.x0, bb.x0)
        h = min(ba.y1, bb.y1) - max(ba.y0, bb.y0)
        if w > slack and h > slack:
            found.append((a, b))
    return found


def cut_off(fig: Figure, slack: float = 0.5) -> list[str]:
    """Drawn texts that reach outside the figure."""
    frame = fig.bbox
    return [
        text
        for text, b in boxes(fig)
        if b.x0 < frame.x0 - slack
        or b.y0 < frame.y0 - slack
        or b.x1 > frame.x1 + slack
        or b.y1 > frame.y1 + slack
    ]


def assert_readable(fig: Figure) -> None:
    """No two texts overlap and none is cut off by the figure's edge."""
    clash = overlaps(fig)
    assert not clash, f"overlapping text: {clash[:5]}"
    out = cut_off(fig)
    assert not out, f"text outside the figure: {out[:5]}"


def titles_overhanging(fig: Figure, slack: float = 0.5) -> list[str]:
    """Axes titles (centre, left, right) that reach past their own axes' left or right edge: a
    long title is clipped by the figure, or runs over the panel beside it."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    found = []
    for ax in fig.axes:
        frame = ax.get_window_extent(renderer)
        for title in (ax.title, ax._left_title, ax._right_title):  # private: no public getter
            if not (title.get_visible() and title.get_text().strip()):
                continue
            box = title.get_window_extent(renderer)
            if box.x0 < frame.x0 - slack or box.x1 > frame.x1 + slack:
                found.append(title.get_text())
    return found
