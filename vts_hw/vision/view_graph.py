"""Which camera saw which checkerboard view, and whether the views tie every camera together.

Two cameras are joined when they saw a view together; the N-camera calibration needs every
camera joined to the reference camera through such views (no view needs all of them). The
initial poses are chained along the spanning tree that :meth:`ViewGraph.spanning_tree` grows
from the reference camera, taking first the edges with the most shared views.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from vts_hw.errors import DataError


class ViewGraph:
    """``seen``: camera name → the names of the views in which it found the board."""

    def __init__(self, cameras: Iterable[str], seen: Mapping[str, Iterable[str]]):
        self.cameras = list(cameras)
        self.seen = {c: sorted(set(seen.get(c, ()))) for c in self.cameras}
        views = sorted({v for vs in self.seen.values() for v in vs})
        self.views = views
        self.seen_by = {v: [c for c in self.cameras if v in self.seen[c]] for v in views}

    # ---- structure --------------------------------------------------------------------
    def shared(self, a: str, b: str) -> list[str]:
        """Views both cameras saw."""
        sb = set(self.seen[b])
        return [v for v in self.seen[a] if v in sb]

    def edges(self) -> dict[tuple[str, str], int]:
        """(a, b) → the number of views both saw, for every pair that shares one."""
        out = {}
        for i, a in enumerate(self.cameras):
            for b in self.cameras[i + 1 :]:
                n = len(self.shared(a, b))
                if n:
                    out[(a, b)] = n
        return out

    def components(self) -> list[list[str]]:
        """The groups of cameras joined through shared views, the reference camera's first."""
        edges = self.edges()
        left = list(self.cameras)
        groups = []
        while left:
            group, todo = [], [left[0]]
            while todo:
                c = todo.pop()
                if c in group:
                    continue
                group.append(c)
                todo += [b if a == c else a for (a, b) in edges if c in (a, b)]
            groups.append([c for c in self.cameras if c in group])
            left = [c for c in left if c not in group]
        return groups

    @property
    def connected(self) -> bool:
        return len(self.components()) == 1

    def spanning_tree(self, reference: str | None = None) -> list[tuple[str, str]]:
        """(parent, child) edges reaching every camera from ``reference`` (default the first),
        each time the edge with the most shared views out of the cameras reached so far."""
        reference = reference or self.cameras[0]
        edges = self.edges()
        reached, tree = [reference], []
        while len(reached) < len(self.cameras):
            best = None
            for (a, b), n in edges.items():
                for p, ch in ((a, b), (b, a)):
                    if p in reached and ch not in reached and (best is None or n > best[0]):
                        best = (n, p, ch)
            if best is None:
                break
            reached.append(best[2])
            tree.append((best[1], best[2]))
        return tree

    # ---- checks -----------------------------------------------------------------------
    def check(self) -> None:
        """DataError in one sentence unless every camera shares a view with another and the
        shared views connect every camera."""
        alone = [c for c in self.cameras if not any(len(self.seen_by[v]) >= 2 for v in self.seen[c])]
        if alone:
            which = ", ".join(alone)
            raise DataError(
                f"camera{'s' if len(alone) > 1 else ''} {which} found the board in no view"
                " that another camera also saw, so it cannot be placed in the common frame:"
                " add views showing the board to it and a neighbour at once."
            )
        groups = self.components()
        if len(groups) > 1:
            parts = " | ".join(", ".join(g) for g in groups)
            raise DataError(
                f"the checkerboard views do not connect the cameras: {parts} share no view"
                " across the groups; add views that a camera of each group sees together."
            )

    def data(self) -> dict:
        """JSON-ready: who saw what, the shared-view counts, connectedness."""
        return {
            "cameras": {c: list(v) for c, v in self.seen.items()},
            "views": {v: list(c) for v, c in self.seen_by.items()},
            "edges": [{"cameras": [a, b], "shared_views": n} for (a, b), n in self.edges().items()],
            "connected": self.connected,
            "components": self.components(),
        }

    def text(self) -> str:
        lines = ["View graph (views each camera found the board in; shared views per pair):"]
        for c in self.cameras:
            lines.append(f"  {c}: {len(self.seen[c])} views")
        for (a, b), n in self.edges().items():
            lines.append(f"  {a} - {b}: {n} shared")
        groups = self.components()
        lines.append(
            "  connected: yes"
            if len(groups) == 1
            else "  connected: NO (" + " | ".join(", ".join(g) for g in groups) + ")"
        )
        return "\n".join(lines)
