"""Wrap cells: no slab line through the u-extremum of a trimming curve (stage 1, numpy only).

The slab decomposition of ``untrim`` puts a u-iso line through every u-extremum of a pcurve. There
the line is tangent to the curve, so the cells on the far side of the line have a corner of zero
angle at the extremum: two sides of one patch leave the tip together and part only as the square
of the distance from it (plate_with_holes: the line x = -5 and the hole of radius 3 around
(-2, 10), tangent at (-5, 10)). A patch like that has a singular parameterization at the corner,
and any check that pairs boundary samples with the nearest other boundary (the independent
checker's) finds the neighbour across the line nearer than the true partner across the curve.

Where the material lies on the outer side of the bulge (a hole's leftmost point, not the leftmost
point of an outer loop), the bulge is wrapped instead:

- the edge plan cuts the curve where it has turned ``_TURN`` (45 degrees in 3D, by the span's speed
  bounds) from the iso direction on either side of the extremum, or where it first crosses a u-knot
  line, or at a vertex (``wrap_sites``), so the arc between stays within 45 degrees of the u-iso
  direction; a face that stage 1 turned is not wrapped (its plan was cut for the face as it was;
  gmsh__wing_fuselage.step's face 12 left a gap of 1.5e-6 and a free edge);
- the arc is replaced, for the slab decomposition, by a three-sided notch: a v-iso line from each of
  its ends to the nearest slab line beyond the tip, and that slab line between them (``wrapped``);
- the region between the notch and the arc is cut by v-iso lines through the arc's piece ends (the
  tip among them) into cells turned by 90 degrees: their rungs are v-iso, their sides the arc piece
  and the slab line. They are made in the transposed face (``untrim.transpose_face``) by the usual
  ruled map and turned back (``turned_patches``).

Every corner there then has an angle of at least about 45 degrees. A site is used only where the
region is free of other pieces and lies in one span in u (a tip on a knot line cannot be wrapped:
the cells must end on the knot line, which is tangent to the curve there); otherwise the face keeps
the slab line through the tip (the cuts the plan made for the site stay, as ordinary corners).

The turned cells' rungs end on the notch's slab line, and the cells beyond it are cut there: many
T-vertices on the long sides of their neighbours, and sides that stage 2 shares, then moves with a
T-vertex (``substitute._share_inner`` shares those again).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .core.bernstein import basis, product, scalar_fn
from .model import Face, Model
from .untrim import (
    Patch,
    Side,
    _coedges,
    _coord_fn,
    _deriv_h,
    _eval,
    _extrema,
    _FaceContext,
    _FaceGeometry,
    _Lazy,
    _Piece,
    _roots,
    _span_pieces,
    transpose_face,
)

__all__ = ["wrap_sites", "wrapped", "turned_patches"]

#: tan of the angle from the u-iso direction at which a wrap's arc ends: 45 degrees, so that the
#: corners at the arc's ends (the v-iso rung against the arc, the slab line beyond against the
#: pcurve) both have about 45 degrees
_TURN = 1.0
#: a wrap's slab line stands at least this many ``ueps_lines`` from the tip
_CLEAR = 4.0
#: where ``_arc_cuts`` looks at the curve on both sides of a span break (share of each span)
_NEAR = 1e-3


def _turn_fn(H: np.ndarray, su: float, sv: float):
    """f(t) = (u' su)^2 - (v' sv tan)^2 (times W^4): negative where the piece runs within the angle
    ``_TURN`` of the u-iso direction, zero where it has turned that far."""
    D = _deriv_h(H)
    du = product(D[:, 0], H[:, 2]) - product(H[:, 0], D[:, 2])
    dv = product(D[:, 1], H[:, 2]) - product(H[:, 1], D[:, 2])
    coef = product(du, du) * su**2 - product(dv, dv) * (sv * _TURN) ** 2
    k = len(coef) - 1

    def f(t):
        return basis(k, np.atleast_1d(t)) @ coef

    f.scalar = _Lazy(lambda: scalar_fn(coef))
    return f


def _events(ce, g: _FaceGeometry, always: bool = False) -> list[tuple[float, int]]:
    """The coedge's events in w order: (w, 0) at its interior u-extrema, (w, 1) where it has turned
    ``_TURN`` from the u-iso direction or crosses a u-knot line (an arc ends there: the turned
    cells must lie in one span; ``_needs`` cuts the curve there too), (w, 2) at its two ends.
    Extrema inside a pcurve span as ``_needs`` finds them (the same floats), and at a span break
    where the curve turns back in u by more than ``ueps`` (a circle's quarter points). Empty for a
    coedge that ``_flatten`` lays on a u-iso line (its extrema are no cuts), and unless ``always``,
    for one without extrema (the turns are sought only where an arc may end)."""
    pieces = list(_span_pieces(ce, np.array([])))
    if not pieces:
        return []
    if 0.5 * np.ptp(np.concatenate([H[:, 0] / H[:, 2] for _, _, H in pieces])) <= g.flat[0]:
        return []
    events = [(w0 + r * (w1 - w0), 0) for w0, w1, H in pieces for r in _extrema(H, 0, g.ueps)]
    for (_, w, a), (_, _, b) in zip(pieces[:-1], pieces[1:], strict=True):
        if _turns_back(a, b, g.ueps):
            events.append((w, 0))
    if not events and not always:
        return []
    events += [(pieces[0][0], 2), (pieces[-1][1], 2)]
    for w0, w1, H in pieces:
        uv = H[:, :2] / H[:, 2:3]
        su, sv = g.speed_over(uv)
        events += [(w0 + r * (w1 - w0), 1) for r in _roots(_turn_fn(H, su, sv))]
        lo, hi = uv[:, 0].min(), uv[:, 0].max()
        events += [(w0 + r * (w1 - w0), 1) for c in g.breaks[0] if lo < c < hi
                   for r in _roots(_coord_fn(H, 0, c))]
    return sorted(events)


def _turns_back(a: np.ndarray, b: np.ndarray, eps: float) -> bool:
    """Whether the curve turns back in u where piece ``a`` (homogeneous Bezier) ends and ``b``
    begins: both run to the same side of that point's u close to it, and by more than ``eps``
    at their middles."""
    u = a[-1, 0] / a[-1, 2]
    da = float(_eval(a, 1.0 - _NEAR)[0, 0]) - u
    db = float(_eval(b, _NEAR)[0, 0]) - u
    deep = min(abs(float(_eval(a, 0.5)[0, 0]) - u), abs(float(_eval(b, 0.5)[0, 0]) - u))
    return da * db > 0 and deep > eps


def _steep(H: np.ndarray, t: float, g: _FaceGeometry) -> bool:
    """Whether a piece runs within ``_TURN`` of the u-iso direction at t."""
    return float(_turn_fn(H, *g.speed_over(H[:, :2] / H[:, 2:3]))(t)[0]) < 0


def _inside(spans: list[np.ndarray], q: np.ndarray, toward: float) -> bool:
    """Whether uv point ``q`` lies in the face: the parity of the crossings of the ray from ``q``
    along u (``toward`` -1 or +1) with the face's pcurve pieces (``spans``, homogeneous Bezier)."""
    n = 0
    for H in spans:
        uv = H[:, :2] / H[:, 2:3]
        if not uv[:, 1].min() < q[1] < uv[:, 1].max():
            continue
        if (uv[:, 0].max() - q[0]) * toward <= 0 and (uv[:, 0].min() - q[0]) * toward <= 0:
            continue
        for r in _roots(_coord_fn(H, 1, float(q[1]))):
            n += (float(_eval(H, r)[0, 0]) - q[0]) * toward > 0
    return n % 2 == 1


#: a wrap site: the arc's pieces as (edge, w from, w to) intervals, and the tip's uv
Site = tuple[tuple[tuple[int, float, float], ...], tuple[float, float]]


def _tips(face: Face, model: Model, g: _FaceGeometry):
    """Candidate tips: (intervals, tip uv, uv of the arc's two ends). Inside a coedge, every
    extremum of ``_events`` with a turn or knot crossing next on both sides; at a vertex where one
    coedge ends and the next begins (a closed circle's one vertex among them), where the loop turns
    back in u and runs within ``_TURN`` of the u-iso direction on both sides."""
    ces = _coedges(face, model)
    ok = [not ce.degenerate and not model.edges[ce.edge].seam for ce in ces]
    events = [_events(ce, g) if k else [] for ce, k in zip(ces, ok, strict=True)]
    for ce, ev in zip(ces, events, strict=True):
        for k, (w, kind) in enumerate(ev):
            if kind == 0 and 0 < k < len(ev) - 1 and ev[k - 1][1] and ev[k + 1][1]:
                lo, hi = ev[k - 1][0], ev[k + 1][0]
                uv = ce.curve.evaluate(np.array([lo, w, hi]))
                yield ((ce.edge, lo, hi),), uv[1], uv[[0, 2]]
    for li in range(len(face.loops)):
        idx = [k for k, ce in enumerate(ces) if ce.loop == li]
        for a, b in zip(idx, idx[1:] + idx[:1], strict=True):
            pa = _vertex_turn(ces[a], ces[b], g) if ok[a] and ok[b] else None
            if pa is None:
                continue
            for k in (a, b):
                if not events[k]:
                    events[k] = _events(ces[k], g, always=True)
            site = _vertex_arc(ces[a], events[a], ces[b], events[b], pa)
            if site is not None:
                yield site


def _vertex_turn(ca, cb, g: _FaceGeometry) -> np.ndarray | None:
    """The uv of the vertex where coedge ``ca`` ends and ``cb`` begins (loop order), when the loop
    turns back in u there and runs within ``_TURN`` of the u-iso direction on both sides."""
    sa = list(_span_pieces(ca, np.array([])))
    sb = list(_span_pieces(cb, np.array([])))
    if not sa or not sb:
        return None
    # the pieces at the vertex, in loop order (a coedge runs from last to first when reversed)
    Ha = sa[0][2][::-1] if ca.reversed else sa[-1][2]
    Hb = sb[-1][2][::-1] if cb.reversed else sb[0][2]
    pa, pb = Ha[-1, :2] / Ha[-1, 2], Hb[0, :2] / Hb[0, 2]
    if abs(pa[0] - pb[0]) > g.ueps_lines or abs(pa[1] - pb[1]) > 1e3 * g.veps:
        return None  # apart in uv (a seam between, or a gap the loop closing has to close)
    if not (_turns_back(Ha, Hb, g.ueps) and _steep(Ha, 1.0, g) and _steep(Hb, 0.0, g)):
        return None
    return pa


def _vertex_arc(ca, ea, cb, eb, pa: np.ndarray):
    """The tip at the vertex ``pa`` where ``ca`` ends and ``cb`` begins, as ``_tips`` yields it: on
    each side the interval from the vertex to the nearest event, which must be a turn or a knot
    crossing (None where an extremum or the coedge's other end comes first)."""
    if len(ea) < 2 or len(eb) < 2:
        return None
    end_a = ca.first if ca.reversed else ca.last
    start_b = cb.last if cb.reversed else cb.first
    near_a = ea[-2] if not ca.reversed else ea[1]
    near_b = eb[1] if not cb.reversed else eb[-2]
    if near_a[1] == 0 or near_b[1] == 0:
        return None
    ia = (ca.edge, min(end_a, near_a[0]), max(end_a, near_a[0]))
    ib = (cb.edge, min(start_b, near_b[0]), max(start_b, near_b[0]))
    far = np.concatenate([ca.curve.evaluate(np.array([near_a[0]])), cb.curve.evaluate(np.array([near_b[0]]))])
    return (ia, ib), pa, far


def wrap_sites(face: Face, model: Model, g: _FaceGeometry) -> list[Site]:
    """The u-extrema of the face's loops to wrap: those of ``_tips`` where the face lies beyond
    the tip (tested a little off it, between the tip and the nearer arc end's u). Seam edges are
    left alone (two pcurves of one edge in one face), and so are turned faces. Kept on ``g`` for
    its face: the edge plan asks first, then every decomposition of the face (gmsh__Block.stp's
    stage 1 asks 1455 times for its 533 faces, and 596 are computed; all of them take about 4 s)."""
    cached = getattr(g, "_wrap_sites", None)
    if cached is not None and cached[0] is face:
        return cached[1]
    out = _wrap_sites(face, model, g)
    g._wrap_sites = (face, out)
    return out


def _wrap_sites(face: Face, model: Model, g: _FaceGeometry) -> list[Site]:
    out: list[Site] = []
    if face.turned:
        return out
    spans = None
    for intervals, tip, far in _tips(face, model, g):
        bulge = np.sign(far[0, 0] - tip[0])  # the arc lies towards +u (+1) or -u (-1) of the tip
        if bulge == 0 or np.sign(far[1, 0] - tip[0]) != bulge:
            continue
        if spans is None:
            spans = [H for c in _coedges(face, model) for _, _, H in _span_pieces(c, np.array([]))]
        depth = min(abs(far[0, 0] - tip[0]), abs(far[1, 0] - tip[0]))
        q = np.array([tip[0] - 0.5 * bulge * depth, tip[1] + 1e-3 * (far[1, 1] - far[0, 1])])
        if _inside(spans, q, -bulge):
            out.append((intervals, (float(tip[0]), float(tip[1]))))
    return out


def _arc(pieces: list[_Piece], intervals, model: Model) -> list[int] | None:
    """Indices of the pieces that make up the intervals, when they cover each end to end."""
    out = []
    for e, lo, hi in intervals:
        edge = model.edges[e]
        tw = 1e-9 * max(abs(edge.last - edge.first), 1e-300)
        idx = [k for k, p in enumerate(pieces) if p.edge == e and not p.degenerate and not p.virtual
               and min(p.w0, p.w1) >= lo - tw and max(p.w0, p.w1) <= hi + tw]
        idx.sort(key=lambda k: min(pieces[k].w0, pieces[k].w1))
        if not idx:
            return None
        ranges = [sorted((pieces[k].w0, pieces[k].w1)) for k in idx]
        if abs(ranges[0][0] - lo) > tw or abs(ranges[-1][1] - hi) > tw:
            return None
        if any(abs(a[1] - b[0]) > tw for a, b in zip(ranges[:-1], ranges[1:], strict=True)):
            return None
        out += idx
    return out


def _up(p: _Piece) -> _Piece:
    """The same piece running with v increasing."""
    if p.H[-1, 1] / p.H[-1, 2] >= p.H[0, 1] / p.H[0, 2]:
        return p
    return _Piece(p.H[::-1].copy(), p.edge, p.w1, p.w0, p.degenerate, p.pcurve)


def _absorbed(arc: list[_Piece], veps: float) -> list[_Piece] | None:
    """The arc (pieces running with v increasing, in order) with every piece no taller than
    ``veps`` joined to its neighbour: the neighbour's end control point moves to the small piece's
    far end (by at most about ``veps``, as loop closing moves ends) and takes its edge parameter.
    sphere_cut_box: ``_monotone`` cut a piece 2.8e-13 long in w off an arc's first end. None when
    no piece is taller."""
    out = list(arc)
    k = 0
    while k < len(out):
        p = out[k]
        if p.H[-1, 1] / p.H[-1, 2] - p.H[0, 1] / p.H[0, 2] > veps:
            k += 1
            continue
        if len(out) == 1:
            return None
        if k + 1 < len(out):  # into the next piece, at its start
            q = out[k + 1]
            H = q.H.copy()
            H[0, :2] = p.H[0, :2] / p.H[0, 2] * H[0, 2]
            out[k + 1] = _Piece(H, q.edge, p.w0, q.w1, q.degenerate, q.pcurve)
        else:  # the last piece: into the previous one, at its end
            q = out[k - 1]
            H = q.H.copy()
            H[-1, :2] = p.H[-1, :2] / p.H[-1, 2] * H[-1, 2]
            out[k - 1] = _Piece(H, q.edge, q.w0, p.w1, q.degenerate, q.pcurve)
        del out[k]
    return out


def _free(pieces: list[_Piece], skip: set[int], box: tuple[float, float, float, float], c: float,
          eps: tuple[float, float]) -> bool:
    """No piece but those in ``skip`` enters the open box (u0, u1, v0, v1) (control polygons), and
    none touches the line u = c between v0 and v1 (within ``eps`` = (u, v)): not an end on it, and
    not a piece along it (ec_turbine's cylinder: a notch on the seam left the turned cells' sides
    there inner sides beside the seam's own, 125 free edges)."""
    u0, u1, v0, v1 = box
    for k, p in enumerate(pieces):
        if k in skip:
            continue
        uv = p.H[:, :2] / p.H[:, 2:3]
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        if hi[0] > u0 and lo[0] < u1 and hi[1] > v0 and lo[1] < v1:
            return False
        if lo[0] <= c + eps[0] and hi[0] >= c - eps[0] and hi[1] >= v0 - eps[1] and lo[1] <= v1 + eps[1]:
            return False
    return True


def wrapped(face: Face, pieces: list[_Piece], sites: list[Site], model: Model, g: _FaceGeometry):
    """The face's pieces with each usable site's arc replaced by its notch (three pieces without an
    edge, ``virtual``), the turned cells of the wraps as (c, side, arc piece running with v
    increasing) with side +1 where the slab line ``c`` lies above the arc in u, and the (u, v) points
    on the slab lines at which the cells beside the notch must be cut (the wraps' rung ends)."""
    cells: list[tuple[float, int, _Piece]] = []
    cuts: list[tuple[float, float]] = []
    for intervals, tip_uv in sites:
        idx = _arc(pieces, intervals, model)
        if idx is None:
            continue
        arc = _absorbed(sorted((_up(pieces[k]) for k in idx), key=lambda p: p.H[0, 1] / p.H[0, 2]), g.veps)
        if arc is None:
            continue
        ends = np.array([arc[0].H[0]] + [p.H[-1] for p in arc])
        us, vs = ends[:, 0] / ends[:, 2], ends[:, 1] / ends[:, 2]
        if np.any(np.diff(vs) <= 0):
            continue  # not monotone in v along the arc
        k = int(np.argmin(np.hypot(us - tip_uv[0], vs - tip_uv[1])))
        bulge = float(np.sign(us[0] - us[k]))  # +1: the arc lies towards +u of its tip
        if not 0 < k < len(arc) or bulge == 0 or np.sign(us[-1] - us[k]) != bulge:
            continue
        tip, far = float(us[k]), float(us.max() if bulge > 0 else us.min())
        skip = set(idx)
        c = _notch_line(pieces, skip, tip, far, (float(vs[0]), float(vs[-1])), bulge, g)
        if c is None:
            continue
        pb = arc[0].H[0, :2] / arc[0].H[0, 2]
        pa = arc[-1].H[-1, :2] / arc[-1].H[-1, 2]
        notch = [np.array([[pb[0], pb[1], 1.0], [c, pb[1], 1.0]]),
                 np.array([[c, pb[1], 1.0], [c, pa[1], 1.0]]),
                 np.array([[c, pa[1], 1.0], [pa[0], pa[1], 1.0]])]
        keep = [p for k, p in enumerate(pieces) if k not in skip]
        pieces = keep + [_Piece(H, None, 0.0, 0.0, False, None, virtual=True) for H in notch]
        side = -1 if bulge > 0 else 1
        cells += [(c, side, p) for p in arc]
        cuts += [(c, float(v)) for v in vs]
    return pieces, cells, cuts


def _notch_line(pieces: list[_Piece], skip: set[int], tip: float, far: float, span: tuple[float, float],
                bulge: float, g: _FaceGeometry) -> float | None:
    """The u of the slab line that closes a wrap's notch beyond its tip (the arc lies between
    ``tip`` and ``far`` in u, between ``span`` in v): the nearest line beyond the tip (a piece end or
    a knot line), or where a piece lies on it or before it, a new line between (as far from the tip
    as the arc is wide, at most halfway). None where neither is free, or the arc crosses a knot line
    (the turned cells must lie in one span)."""
    inner_u = [float(x) for x in g.ub[1:-1]]
    margin = _CLEAR * g.ueps_lines
    # a knot on the tip itself counts too (plate_with_holes: a circle's vertex tip lies exactly on
    # the u-knot 0.74777, and turned cells from a line before it to the arc straddled the knot)
    if any((x - tip) * bulge > -margin and (far - x) * bulge > 0 for x in inner_u):
        return None
    ends = [float(x) for k, p in enumerate(pieces) if k not in skip
            for x in (p.H[0, 0] / p.H[0, 2], p.H[-1, 0] / p.H[-1, 2])]
    cands = [x for x in ends + inner_u if (tip - x) * bulge > margin]
    if not cands:
        return None
    near = max(cands) if bulge > 0 else min(cands)
    new = tip - bulge * min(abs(far - tip), 0.5 * abs(tip - near))
    for c in (near, new) if abs(new - tip) > margin else (near,):
        if _free(pieces, skip, (min(c, far), max(c, far), *span), c, (g.ueps_lines, g.veps)):
            return c
    return None


def _transposed_side(H: np.ndarray, edge, w0: float, w1: float) -> Side:
    return Side(np.ascontiguousarray(H[:, [1, 0, 2]]), False, edge, w0, w1)


def _turned_back(p: Patch, pcurve) -> Patch:
    """A patch made in the transposed face, in the face's own uv: s reversed (the transposition
    turned the orientation), sides swapped back to (u, v) and reversed with it."""
    def side(sd: Side) -> Side:
        H = np.ascontiguousarray(sd.H[::-1][:, [1, 0, 2]])
        return Side(H, False, sd.edge, sd.w1, sd.w0, sd.degenerate, pcurve if sd.edge is not None else None)

    return replace(p, ctrl=np.ascontiguousarray(p.ctrl[::-1]), bottom=side(p.bottom), top=side(p.top))


def turned_patches(face: Face, cells, model: Model, tol, fr) -> list[Patch]:
    """The patches of the wraps' turned cells (``wrapped``), made by the ruled map in the transposed
    face and turned back."""
    if not cells:
        return []
    turned = transpose_face(face)
    gt = _FaceGeometry(turned, model.diagonal, tol)
    ctx = _FaceContext(turned, gt, tol.approx_rel * model.diagonal, tol.max_degree)
    out = []
    for c, side, p in cells:
        v0, v1 = float(p.H[0, 1] / p.H[0, 2]), float(p.H[-1, 1] / p.H[-1, 2])
        line = Side(np.array([[v0, c, 1.0], [v1, c, 1.0]]), True)
        arc = _transposed_side(p.H, p.edge, p.w0, p.w1)
        bot, top = (line, arc) if side < 0 else (arc, line)
        out += [_turned_back(q, p.pcurve) for q in ctx.cell_patches(v0, v1, bot, top, fr)]
    return out
