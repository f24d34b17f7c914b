"""Topology-blind boundary gap: how far each face's boundary lies from the boundaries of the other faces.

The edge gaps (``gaps``) measure what the topology pairs: an edge's curve against the faces that
use it. A model can be closed geometrically with broken topology, or share edges that its geometry
does not follow. This measure looks at geometry alone:

- every face's boundary (surface(pcurve) of each coedge) is sampled at ``per_edge`` points inside
  every edge (the independent checker looks up 15);
- each sample's distance to the nearest boundary of *another* face (or of the same face across a
  seam, which is another coedge of the same edge) is found exactly: every boundary curve that can be
  within reach is a candidate, not only the one whose sample happens to lie nearest. Candidates
  come from the boundary polylines (``_DENSE`` points per coedge): a curve at distance D from a
  sample has a polyline segment whose midpoint lies within D plus the segment's length; segments
  are looked up in classes of similar length, so a long edge with sparse samples is never passed
  over for a short one nearby. Each candidate is projected on by a scan and a bracketing search on
  the curve itself (to rounding, about 1e-15 of the curve's size);
- samples farther than ``match`` from every other boundary are free boundary (an open shell's rim,
  or a gap wider than ``match``); the largest distance of the other samples is the gap.

A sample's nearest other boundary can be a third face's boundary running close by (a thin strip,
two edges leaving a vertex almost tangent); that boundary is still measured exactly, so the figure
is the distance to the nearest boundary, never to an arbitrary one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .gaps import _curve_at, _surface_at
from .model import Model

#: samples looked up inside every edge of every face's boundary (the independent checker's 15)
PER_EDGE = 15
#: polyline points per coedge for the candidate search
_DENSE = 65
#: nearest polyline points looked at first, for an upper bound of each sample's distance
_FIRST = 16
#: bracketing rounds of the projection onto one curve, and the points of each
_ROUNDS = 7
_ROUND_POINTS = 17


@dataclass(frozen=True)
class BoundaryGap:
    samples: int  # boundary samples measured
    matched_max: float  # largest distance of a matched sample to another face's boundary
    where: tuple[float, float, float] | None  # that sample
    unmatched: int  # samples with no other boundary within ``match``
    match: float  # the distance that separates the two (model units)
    over: int  # matched samples farther than ``limit``
    limit: float


class _Boundaries:
    """The boundary curves of a model's faces: (face, pcurve, first, last) per coedge, evaluated as
    surface(pcurve)."""

    def __init__(self, model: Model):
        self.model = model
        self.face, self.edge, self.curves = [], [], []
        for f in model.faces:
            for loop in f.loops:
                for ce in loop.coedges:
                    if model.edges[ce.edge].degenerate or ce.pcurve is None:
                        continue
                    self.face.append(f.index)
                    self.edge.append(ce.edge)
                    self.curves.append((f.index, ce.pcurve, float(ce.first), float(ce.last)))
        self.face = np.array(self.face, dtype=int)
        self.edge = np.array(self.edge, dtype=int)

    def other(self, mine: np.ndarray, theirs: np.ndarray) -> np.ndarray:
        """Whether curve ``theirs`` is another boundary for a sample of curve ``mine``: a curve of
        another face, or the face's other coedge of the same (seam) edge."""
        seam = (self.edge[theirs] == self.edge[mine]) & (theirs != mine)
        return (self.face[theirs] != self.face[mine]) | seam

    def at(self, ci: int, s: np.ndarray) -> np.ndarray:
        """Points of curve ``ci`` at fractions ``s`` (any shape) of its parameter range."""
        fi, pc, a, b = self.curves[ci]
        s = np.asarray(s, dtype=float)
        uv = _curve_at(pc, a + np.ravel(s) * (b - a))
        return _surface_at(self.model.faces[fi].surface, uv).reshape(s.shape + (3,))

    def sample(self, fractions: np.ndarray) -> np.ndarray:
        """(curves, len(fractions), 3): every curve at the same fractions, one call per face."""
        out = np.empty((len(self.curves), len(fractions), 3))
        start = 0
        while start < len(self.curves):
            stop = start
            while stop < len(self.curves) and self.face[stop] == self.face[start]:
                stop += 1
            fi = int(self.face[start])
            uv = np.concatenate([_curve_at(pc, a + fractions * (b - a))
                                 for _, pc, a, b in self.curves[start:stop]])
            out[start:stop] = _surface_at(self.model.faces[fi].surface, uv).reshape(stop - start, -1, 3)
            start = stop
        return out

    def project(self, ci: int, p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Distances (k,) from points ``p`` (k, 3) to curve ``ci``, each searched for in its bracket
        [lo, hi] (fractions of the range) by ``_ROUNDS`` scans of ``_ROUND_POINTS`` points, each
        round narrowing to the two steps around the nearest, then the foot on the last chord."""
        row = np.arange(len(p))
        t = np.linspace(0.0, 1.0, _ROUND_POINTS)
        best = np.full(len(p), np.inf)
        for _ in range(_ROUNDS):
            S = lo[:, None] + (hi - lo)[:, None] * t[None]
            d = np.linalg.norm(self.at(ci, S) - p[:, None], axis=2)
            k = np.argmin(d, axis=1)
            best = np.minimum(best, d[row, k])
            lo, hi = S[row, np.maximum(k - 1, 0)], S[row, np.minimum(k + 1, _ROUND_POINTS - 1)]
        A, B = self.at(ci, lo), self.at(ci, hi)
        AB = B - A
        w = np.clip(np.einsum("ij,ij->i", p - A, AB) / np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300),
                    0.0, 1.0)
        return np.minimum(best, np.linalg.norm(A + w[:, None] * AB - p, axis=1))


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances from points ``p`` to segments [a, b] (all (k, 3))."""
    ab = b - a
    w = np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    w = np.clip(w, 0.0, 1.0)
    return np.linalg.norm(a + w[:, None] * ab - p, axis=1)


def boundary_gap(model: Model, per_edge: int = PER_EDGE, match_rel: float = 1e-6,
                 limit_rel: float = 1e-9) -> BoundaryGap:
    """The topology-blind boundary gap of ``model`` (module docstring). ``match_rel`` and
    ``limit_rel`` are relative to the model's diagonal (the independent checker's 1e-6 and 1e-9)."""
    diag = model.diagonal or 1.0
    match, limit = match_rel * diag, limit_rel * diag
    bd = _Boundaries(model)
    if not bd.curves:
        return BoundaryGap(0, 0.0, None, 0, match, 0, limit)
    n, m = len(bd.curves), _DENSE - 1
    coarse = bd.sample(np.arange(1, per_edge + 1) / (per_edge + 1)).reshape(-1, 3)
    owner = np.repeat(np.arange(n), per_edge)
    poly = bd.sample(np.linspace(0.0, 1.0, _DENSE))
    half = bd.sample((np.arange(m) + 0.5) / m)
    a, b = poly[:, :-1].reshape(-1, 3), poly[:, 1:].reshape(-1, 3)
    mid, length = 0.5 * (a + b), np.linalg.norm(b - a, axis=1)
    # how far the curve strays from its chord: twice the midpoint's distance (exact for a parabola)
    sag = 2.0 * np.linalg.norm(half.reshape(-1, 3) - mid, axis=1) + 1e-15 * diag
    seg_curve = np.repeat(np.arange(n), m)

    # candidate segments: a curve within ``match`` of a sample has a segment whose midpoint lies
    # within match + sag + half its length; looked up per class of similar length
    cls = np.floor(np.log2(np.maximum(length, 1e-300))).astype(int)
    found_s, found_g = [], []
    for c in np.unique(cls):
        sel = np.flatnonzero(cls == c)
        reach = match + float((0.5 * length[sel] + sag[sel]).max())
        k = min(_FIRST, len(sel))
        _, nb = cKDTree(mid[sel]).query(coarse, k=k, distance_upper_bound=reach)
        nb = nb.reshape(len(coarse), k)
        rows, cols = np.nonzero(nb < len(sel))
        g = sel[nb[rows, cols]]
        keep = bd.other(owner[rows], seg_curve[g])
        found_s.append(rows[keep])
        found_g.append(g[keep])
    ps, pg = np.concatenate(found_s), np.concatenate(found_g)
    best = np.full(len(coarse), np.inf)
    if len(ps):
        dseg = _segment_distance(coarse[ps], a[pg], b[pg])
        upper = np.full(len(coarse), np.inf)
        np.minimum.at(upper, ps, dseg + sag[pg])
        need = dseg - sag[pg] <= upper[ps]  # segments that may hold the nearest point
        ps, pg = ps[need], pg[need]
        # one bracket per (sample, curve): the segments it may lie on, widened by one on each side
        pc = seg_curve[pg]
        j = pg - pc * m
        key = ps.astype(np.int64) * n + pc
        order = np.lexsort((j, key))
        key, j = key[order], j[order]
        first = np.r_[True, key[1:] != key[:-1]]
        last = np.r_[key[1:] != key[:-1], True]
        lo = np.maximum(j[first] - 1, 0) / m
        hi = np.minimum(j[last] + 2, m) / m
        key = key[first]
        s_of, c_of = key // n, key % n
        dist = np.empty(len(key))
        order = np.argsort(c_of, kind="stable")
        cuts = np.flatnonzero(np.diff(c_of[order])) + 1
        for grp in np.split(order, cuts):
            if len(grp):
                dist[grp] = bd.project(int(c_of[grp[0]]), coarse[s_of[grp]], lo[grp], hi[grp])
        np.minimum.at(best, s_of, dist)
    free = best > match
    matched = best[~free]
    i = int(np.flatnonzero(~free)[np.argmax(matched)]) if len(matched) else None
    return BoundaryGap(len(coarse), float(matched.max()) if len(matched) else 0.0,
                       None if i is None else tuple(float(x) for x in coarse[i]),
                       int(free.sum()), match, int((matched > limit).sum()), limit)
