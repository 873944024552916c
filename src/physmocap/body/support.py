"""Support polygons on the floor: a pure 2D kernel on the few contact points of a frame, shared by the physics'
balance test (every frame, so plain floats) and the viewer's support polygons."""

from __future__ import annotations

from collections.abc import Iterable


def convex_hull_2d(points: Iterable[Iterable[float]]) -> list[tuple[float, float]]:
    """(n, 2) points in metres (an array or nested sequences) -> the hull's vertices counter-clockwise, from the
    smallest (x, y), without repeated or collinear points (Andrew's monotone chain: for the four sole points, a
    hundred times quicker than Qhull). Fewer than three distinct points come back sorted (a point or a segment)."""
    unique = sorted({(float(x), float(y)) for x, y in points})
    if len(unique) < 3:
        return unique

    def half(ordered: list[tuple[float, float]]) -> list[tuple[float, float]]:
        chain: list[tuple[float, float]] = []
        for p in ordered:
            while len(chain) >= 2 and ((chain[-1][0] - chain[-2][0]) * (p[1] - chain[-2][1])
                                       - (chain[-1][1] - chain[-2][1]) * (p[0] - chain[-2][0])) <= 0.0:
                chain.pop()
            chain.append(p)
        return chain[:-1]

    return half(unique) + half(unique[::-1])
