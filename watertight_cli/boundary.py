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
  sample has a polyline segment whose midpoint lies within D, half the segment's length and the
  curve's distance from the segment (taken as twice its distance at the segment's middle, exact
  for a parabola); segments are looked up in classes of similar length, so a long edge with sparse
  samples is never passed over for a short one nearby. Each candidate is projected on by a scan
  and Newton steps on the curve itself (the plate_with_holes output's largest distance, 4.70767e-12,
  is what eight rounds of scans, each narrowing the bracket eightfold, give);
- samples farther than ``match`` from every other boundary are free boundary (an open shell's rim,
  or a gap wider than ``match``); the largest distance of the other samples is the gap.

The curves are the model's arrays (``model``): exact for B-spline and Bezier faces (every face of
a converted model), within ``Tolerances.convert_rel`` of the diagonal for faces and pcurves with
angular parameters (cylinders, cones, spheres, tori, circles), which an input's figure then
includes (``assembly.step``: 2.9e-9 between the B-spline forms of a cylinder and a plane along
their circle, 6.5e-11 of the diagonal, where the kernel's own surfaces agree to 1.7e-12).

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
#: segments looked up first per sample and length class (four times as many while all are in reach)
_FIRST = 16
#: the projection onto one curve: points scanned in the bracket, Newton steps, and the central
#: differences' step (a fraction of the curve's range: C'' is then good to 1e-16 x size / step^2)
_SCAN = 9
_NEWTON = 4
_STEP = 1e-5
#: samples looked up at a time (bounds the memory of the candidate lists)
_CHUNK = 20_000


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

    def sample(self, fractions: np.ndarray) -> np.ndarray:
        """(curves, len(fractions), 3): every curve at the same fractions, one call per face."""
        out = np.empty((len(self.curves), len(fractions), 3))
        start = 0
        while start < len(self.curves):
            stop = start
            while stop < len(self.curves) and self.face[stop] == self.face[start]:
                stop += 1
            fi = int(self.face[start])
            uv = np.concatenate([_curve_at(pc, a + fractions * (b - a), shared=False)
                                 for _, pc, a, b in self.curves[start:stop]])
            out[start:stop] = _surface_at(self.model.faces[fi].surface, uv).reshape(stop - start, -1, 3)
            start = stop
        return out

    def at_pairs(self, curve: np.ndarray, S: np.ndarray) -> np.ndarray:
        """Points (k, m, 3) of curves ``curve`` (k,), all of one face, at fractions ``S`` (k, m)."""
        uv = np.empty(S.shape + (2,))
        order = np.argsort(curve, kind="stable")
        cuts = np.flatnonzero(np.diff(curve[order])) + 1
        for grp in np.split(order, cuts):
            _, pc, a, b = self.curves[int(curve[grp[0]])]
            uv[grp] = _curve_at(pc, a + S[grp].ravel() * (b - a), shared=False).reshape(len(grp), -1, 2)
        fi = int(self.face[curve[0]])
        return _surface_at(self.model.faces[fi].surface, uv.reshape(-1, 2)).reshape(S.shape + (3,))

    def project(self, curve: np.ndarray, p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Distances (k,) from points ``p`` (k, 3) to curves ``curve`` (k,) of one face, each searched
        for in its bracket [lo, hi] (fractions of the range): the nearest of ``_SCAN`` points, then
        ``_NEWTON`` Newton steps on (C(w) - p) . C'(w) = 0, with C' and C'' by central differences,
        kept inside the bracket. At the root C(w) - p is normal to the curve up to the differences'
        error in the tangent's direction, which changes the distance only to second order."""
        row = np.arange(len(p))
        S = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, _SCAN)[None]
        d = np.linalg.norm(self.at_pairs(curve, S) - p[:, None], axis=2)
        k = np.argmin(d, axis=1)
        best, w = d[row, k], S[row, k]
        h = _STEP
        for _ in range(_NEWTON):
            C = self.at_pairs(curve, w[:, None] + np.array([-h, 0.0, h])[None])
            c1, c2 = (C[:, 2] - C[:, 0]) / (2 * h), (C[:, 2] - 2 * C[:, 1] + C[:, 0]) / (h * h)
            r = C[:, 1] - p
            best = np.minimum(best, np.linalg.norm(r, axis=1))
            f, df = np.einsum("ij,ij->i", r, c1), np.einsum("ij,ij->i", c1, c1) + np.einsum("ij,ij->i", r, c2)
            step = np.where(df > 0, -f / np.where(df > 0, df, 1.0), 0.0)
            w = np.clip(w + step, lo, hi)
        return np.minimum(best, np.linalg.norm(self.at_pairs(curve, w[:, None])[:, 0] - p, axis=1))


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances from points ``p`` to segments [a, b] (all (k, 3))."""
    ab = b - a
    w = np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    w = np.clip(w, 0.0, 1.0)
    return np.linalg.norm(a + w[:, None] * ab - p, axis=1)


def _brackets(bd: _Boundaries, pts: np.ndarray, owner: np.ndarray, first: int, classes, a, b, sag,
              m: int):
    """For samples ``pts`` (numbered from ``first``): (sample, curve, lo, hi) of every curve of
    another face that may hold the sample's nearest point, lo and hi bracketing the fractions of
    its segments that may (widened by one segment each way)."""
    found_s, found_g = [], []
    for sel, tree, reach in classes:
        ask, k = np.arange(len(pts)), _FIRST
        while len(ask):  # all k within reach: there may be more, ask again for four times as many
            k = min(k, len(sel))
            _, nb = tree.query(pts[ask], k=k, distance_upper_bound=reach)
            nb = nb.reshape(len(ask), k)
            full = nb[:, -1] < len(sel)
            if k < len(sel):
                nb, done = nb[~full], ask[~full]
            else:
                done, full = ask, np.zeros(len(ask), dtype=bool)
            rows, cols = np.nonzero(nb < len(sel))
            g = sel[nb[rows, cols]]
            rows = done[rows]
            keep = bd.other(owner[rows], g // m)
            found_s.append(rows[keep])
            found_g.append(g[keep])
            ask, k = ask[full], 4 * k
    ps, pg = np.concatenate(found_s), np.concatenate(found_g)
    if not len(ps):
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0)
    dseg = _segment_distance(pts[ps], a[pg], b[pg])
    upper = np.full(len(pts), np.inf)
    np.minimum.at(upper, ps, dseg + sag[pg])
    need = dseg - sag[pg] <= upper[ps]  # segments that may hold the nearest point
    ps, pg = ps[need], pg[need]
    n = len(bd.curves)
    pc, j = pg // m, pg % m
    key = ps.astype(np.int64) * n + pc
    order = np.lexsort((j, key))
    key, j = key[order], j[order]
    head = np.r_[True, key[1:] != key[:-1]]
    tail = np.r_[key[1:] != key[:-1], True]
    lo, hi = np.maximum(j[head] - 1, 0) / m, np.minimum(j[tail] + 2, m) / m
    key = key[head]
    return key // n + first, key % n, lo, hi


def boundary_gap(model: Model, per_edge: int = PER_EDGE, match_rel: float = 1e-6,
                 limit_rel: float = 1e-9) -> BoundaryGap:
    """The topology-blind boundary gap of ``model`` (module docstring). ``match_rel`` and
    ``limit_rel`` are relative to the model's diagonal (the independent checker's 1e-6 and 1e-9)."""
    diag = model.diagonal or 1.0
    match, limit = match_rel * diag, limit_rel * diag
    coarse, _, best = nearest_boundaries(model, per_edge, match)
    free = best > match
    matched = best[~free]
    i = int(np.flatnonzero(~free)[np.argmax(matched)]) if len(matched) else None
    return BoundaryGap(len(coarse), float(matched.max()) if len(matched) else 0.0,
                       None if i is None else tuple(float(x) for x in coarse[i]),
                       int(free.sum()), match, int((matched > limit).sum()), limit)


def nearest_boundaries(model: Model, per_edge: int, match: float):
    """(points (k, 3), their faces (k,), distances (k,)): ``per_edge`` points inside every edge of
    every face's boundary and each one's distance to the nearest boundary of another face (inf
    where none lies within ``match``, model units)."""
    diag = model.diagonal or 1.0
    bd = _Boundaries(model)
    if not bd.curves:
        return np.zeros((0, 3)), np.zeros(0, dtype=int), np.zeros(0)
    n, m = len(bd.curves), _DENSE - 1
    coarse = bd.sample(np.arange(1, per_edge + 1) / (per_edge + 1)).reshape(-1, 3)
    owner = np.repeat(np.arange(n), per_edge)
    poly = bd.sample(np.linspace(0.0, 1.0, _DENSE))
    half = bd.sample((np.arange(m) + 0.5) / m)
    a, b = poly[:, :-1].reshape(-1, 3), poly[:, 1:].reshape(-1, 3)
    mid, length = 0.5 * (a + b), np.linalg.norm(b - a, axis=1)
    # how far the curve strays from its chord: twice the midpoint's distance (exact for a parabola)
    sag = 2.0 * np.linalg.norm(half.reshape(-1, 3) - mid, axis=1) + 1e-15 * diag

    # candidate segments: a curve within ``match`` of a sample has a segment whose midpoint lies
    # within match + sag + half its length; looked up per class of similar length
    cls = np.floor(np.log2(np.maximum(length, 1e-300))).astype(int)
    classes = []
    for c in np.unique(cls):
        sel = np.flatnonzero(cls == c)
        classes.append((sel, cKDTree(mid[sel]), match + float((0.5 * length[sel] + sag[sel]).max())))
    brackets = [_brackets(bd, coarse[i:i + _CHUNK], owner[i:i + _CHUNK], i, classes, a, b, sag, m)
                for i in range(0, len(coarse), _CHUNK)]
    s_of, c_of, lo, hi = (np.concatenate([br[k] for br in brackets]) for k in range(4))
    best = np.full(len(coarse), np.inf)
    if len(s_of):
        dist = np.empty(len(s_of))
        f_of = bd.face[c_of]
        order = np.argsort(f_of, kind="stable")
        cuts = np.flatnonzero(np.diff(f_of[order])) + 1
        for grp in np.split(order, cuts):
            dist[grp] = bd.project(c_of[grp], coarse[s_of[grp]], lo[grp], hi[grp])
        np.minimum.at(best, s_of, dist)
    best[best > match] = np.inf
    return coarse, bd.face[owner], best
