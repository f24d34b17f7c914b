"""Gap measurement on the array model: how far an edge's 3D curve and its faces' boundaries disagree.

For every non-degenerate edge e with 3D curve C and faces f (each with surface S_f and pcurve
pc_f, same-parameter with C), at the parameters w of ``track_params``: ``Tolerances.gap_samples``
equally spaced ones plus ``PER_SPAN`` inside every knot span of C and of the pcurves (knots crowd
where a curve turns or changes speed, and a pcurve that runs at another speed than C over a short
stretch near an end is missed by equal steps alone; see ``sameparam``):

- ``curve_gap``  = max_w max_f |C(w) - S_f(pc_f(w))|
- ``face_gap``   = max_w max_{f != g} |S_f(pc_f(w)) - S_g(pc_g(w))| (seams: both pcurves of the face)
- ``gap``        = the larger of the two.

The samples ("tracks") come either from the kernel on the input shape (``occ.extract.sample_tracks``,
what the report shows) or from the array model (``model_tracks``, which measures what the
conversion to arrays changed). The measurement itself is the same numpy code for both.
"""

from __future__ import annotations

import functools
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from .core.bernstein import basis
from .model import BSplineCurve, BSplineSurface, Model
from .tolerances import Tolerances

#: Samples inside every knot span of an edge's 3D curve and pcurves, on top of the equal steps.
PER_SPAN = 3


def track_params(a: float, b: float, uniform: int, knot_vectors, per_span: int = PER_SPAN) -> np.ndarray:
    """Sorted parameters in [a, b]: ``uniform`` equal steps (ends included) plus ``per_span`` points
    inside every knot span (of any of ``knot_vectors``) that meets [a, b].

    The result is read-only and shared between calls with the same arguments: most edges of a
    converted model ask for the same samples (occ22470's output: 16 distinct requests among 16783
    edges), and building them took 0.12 ms an edge."""
    key = tuple(np.ascontiguousarray(k, dtype=float).tobytes() for k in knot_vectors)
    return _track_params(float(a), float(b), int(uniform), key, int(per_span))


@functools.lru_cache(maxsize=4096)
def _track_params(a: float, b: float, uniform: int, knot_bytes: tuple[bytes, ...],
                  per_span: int) -> np.ndarray:
    out = [np.linspace(a, b, uniform)]
    inner = (np.arange(per_span) + 0.5) / per_span
    for kb in knot_bytes:
        u = np.unique(np.clip(np.frombuffer(kb, dtype=float), a, b))
        if len(u) > 1:
            out.append((u[:-1, None] + np.diff(u)[:, None] * inner[None, :]).ravel())
    w = np.unique(np.concatenate(out))
    w.flags.writeable = False
    return w


@dataclass(frozen=True)
class EdgeGap:
    edge: int
    faces: tuple[int, ...]
    uses: int
    curve_gap: float
    face_gap: float
    tolerance: float
    where: tuple[float, float, float]  # the sample point of the largest gap, on the 3D curve

    @property
    def gap(self) -> float:
        return max(self.curve_gap, self.face_gap)


Tracks = dict[int, tuple[np.ndarray | None, list[tuple[int, np.ndarray]]]]
"""Per edge index: (C(w) (k, 3) or None, [(face index, S_f(pc_f(w)) (k, 3)), ...])."""


def model_tracks(model: Model, tol: Tolerances, params: dict[int, np.ndarray] | None = None) -> Tracks:
    """Sample the array model's edges the same way the kernel sampler does (``occ.sample_tracks``),
    or at ``params`` (per edge index; the kernel sampler's, so the two measure the same points).

    All samples of one face are evaluated in one vectorized call.
    """
    requests: dict[int, list[tuple[int, object]]] = defaultdict(list)
    knots: dict[int, list[np.ndarray]] = {e.index: [] if e.curve is None else [e.curve.knots]
                                          for e in model.edges if not e.degenerate}
    for f in model.faces:
        for loop in f.loops:
            for ce in loop.coedges:
                if ce.edge in knots and ce.pcurve is not None:
                    requests[f.index].append((ce.edge, ce.pcurve))
                    knots[ce.edge].append(ce.pcurve.knots)
    given = params or {}
    params = {ei: given[ei] if ei in given else
              track_params(model.edges[ei].first, model.edges[ei].last, tol.gap_samples, kv)
              for ei, kv in knots.items()}
    curves = {ei: model.edges[ei].curve for ei in params}
    out: Tracks = {ei: (None if curves[ei] is None else _curve_at(curves[ei], w), [])
                   for ei, w in params.items()}
    for fi, reqs in requests.items():
        uv = np.concatenate([_curve_at(pc, params[ei]) for ei, pc in reqs])
        pts = _surface_at(model.faces[fi].surface, uv)
        cuts = np.cumsum([len(params[ei]) for ei, _ in reqs])[:-1]
        for (ei, _), p in zip(reqs, np.split(pts, cuts), strict=True):
            out[ei][1].append((fi, p))
    return out


@functools.lru_cache(maxsize=4096)
def _span_basis(degree: int, k0: float, k1: float, w_bytes: bytes) -> np.ndarray:
    """Bernstein basis (k, degree+1) of the one span [k0, k1] at the parameters ``w_bytes``."""
    w = np.frombuffer(w_bytes, dtype=float)
    return basis(degree, (w - k0) / (k1 - k0))


def _curve_at(curve: BSplineCurve, w: np.ndarray, shared: bool = True) -> np.ndarray:
    """``curve.evaluate(w)``; a one-span curve (every curve of a converted model) by its Bernstein
    basis at ``w``, shared between the many edges sampled at the same parameters (a scipy spline
    per call cost 20-30 us an edge). ``shared`` False: parameters that no other call asks for
    (``boundary``'s searches), whose bases would only fill the cache."""
    n = curve.degree + 1
    if len(curve.poles) != n or len(curve.knots) != 2 * n:
        return curve.evaluate(w)
    k0, k1 = float(curve.knots[0]), float(curve.knots[-1])
    w = np.ascontiguousarray(w, dtype=float)
    if shared:
        b = _span_basis(curve.degree, k0, k1, w.tobytes())
    else:
        b = basis(curve.degree, (w - k0) / (k1 - k0))
    h = b @ curve.homogeneous()
    return h[:, :-1] / h[:, -1:] if curve.rational else h


def _surface_at(surface: BSplineSurface, uv: np.ndarray) -> np.ndarray:
    """``surface.evaluate(uv)``; a Bezier patch by its Bernstein bases in u and v."""
    if not surface.is_bezier:
        return surface.evaluate(uv)
    u0, u1, v0, v1 = surface.domain
    bu = basis(surface.udegree, (uv[:, 0] - u0) / (u1 - u0))
    bv = basis(surface.vdegree, (uv[:, 1] - v0) / (v1 - v0))
    H = surface.homogeneous()
    h = (bu @ H.reshape(H.shape[0], -1)).reshape(len(uv), H.shape[1], H.shape[2])  # BLAS along u
    h = np.einsum("kj,kjd->kd", bv, h)
    return h[:, :-1] / h[:, -1:] if surface.rational else h


def track_gap(c: np.ndarray | None, tr: list[tuple[int, np.ndarray]]) -> tuple[float, float, np.ndarray]:
    """(curve-to-face gap, face-to-face gap, location of the larger) of one edge's tracks."""
    curve_gap, face_gap, where, worst = 0.0, 0.0, None, -1.0
    if c is not None:
        for _, p in tr:
            d = np.linalg.norm(p - c, axis=1)
            i = int(np.argmax(d))
            curve_gap = max(curve_gap, float(d[i]))
            if d[i] > worst:
                worst, where = d[i], c[i]
    for a in range(len(tr)):
        for b in range(a + 1, len(tr)):
            d = np.linalg.norm(tr[a][1] - tr[b][1], axis=1)
            i = int(np.argmax(d))
            face_gap = max(face_gap, float(d[i]))
            if d[i] > worst:
                worst, where = d[i], tr[a][1][i]
    if where is None:
        ref = c if c is not None else (tr[0][1] if tr else np.zeros((1, 3)))
        where = ref[len(ref) // 2]
    return curve_gap, face_gap, where


def max_gap(tracks: Tracks) -> float:
    """The largest gap over all edges of a set of tracks."""
    return max((max(track_gap(c, tr)[:2]) for c, tr in tracks.values()), default=0.0)


def edge_gaps(model: Model, tracks: Tracks) -> list[EdgeGap]:
    """Per-edge gaps from sampled tracks, in edge order (degenerate edges are skipped)."""
    out = []
    for e in model.edges:
        if e.degenerate or e.index not in tracks:
            continue
        curve_gap, face_gap, where = track_gap(*tracks[e.index])
        out.append(EdgeGap(e.index, e.faces, e.uses, curve_gap, face_gap, e.tolerance,
                           tuple(float(x) for x in where)))
    return out


#: a vertex is an outlier when the centre of the other points is this much nearer to all of them
_OUTLIER = 0.25


def vertex_corners(model: Model, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the patch corners at each vertex go, and the input's own gap there.

    The input offers several points for a vertex: its own point, the ends of the edge curves
    that meet there, and each face's surface(pcurve) at those ends. The corner is the vertex's
    point, unless the vertex stands off all the others by more than ``eps`` (the tolerance) while
    they agree among themselves: the centre of their bounding box is within ``_OUTLIER`` of that
    distance from all of them. Such a vertex would otherwise drag every corner onto it and shear
    each curve that ends there (in gmsh__917_fusee.stp one vertex stands 0.0099 from its three
    curve ends, which agree to 1e-13, and its faces moved by twice their edges' gap). A vertex on
    one of the ends stays (moving it to the middle halves the largest move but shears every curve
    there: on gmsh__Block.stp and gmsh__U_Joint_2.stp that opened gaps and free edges elsewhere).
    Returns (points (k, 3), gap (k,)): gap is the largest distance from the chosen point to any
    of those points, how far a corner there must move at least (0 where nothing ends).
    """
    points = np.array(model.vertices, dtype=float, copy=True)
    gap = np.zeros(len(points))
    ends: dict[int, list[np.ndarray]] = defaultdict(list)
    for e in model.edges:
        if e.curve is None or e.degenerate:
            continue
        for v, p in zip(e.vertices, e.curve.evaluate(np.array([e.first, e.last])), strict=True):
            if v >= 0:
                ends[v].append(p)
    for f in model.faces:
        uses = [(model.edges[c.edge], c.pcurve) for lp in f.loops for c in lp.coedges
                if c.pcurve is not None and not model.edges[c.edge].degenerate]
        if not uses:
            continue
        uv = np.concatenate([pc.evaluate(np.array([e.first, e.last])) for e, pc in uses])
        xyz = f.surface.evaluate(uv).reshape(len(uses), 2, 3)
        for (e, _), pair in zip(uses, xyz, strict=True):
            for v, p in zip(e.vertices, pair, strict=True):
                if v >= 0:
                    ends[v].append(p)
    for v, pts in ends.items():
        E = np.array(pts)
        centre = 0.5 * (E.min(axis=0) + E.max(axis=0))
        off_vertex = float(np.linalg.norm(E - points[v], axis=1).max())
        off_centre = float(np.linalg.norm(E - centre, axis=1).max())
        outlier = off_vertex > eps and off_centre <= _OUTLIER * off_vertex
        if outlier:
            points[v] = centre
        gap[v] = off_centre if outlier else off_vertex
    return points, gap
