"""Stage 1, untrim: every trimmed face becomes Bezier patches on [0, 1]^2 (numpy only, no OCP).

The pipeline, per model (see ``../shared/DESIGN.md``, "Stage 1"):

1. **Pieces and the edge plan.** Every pcurve is cut into Bezier pieces at its knots, at its crossings
   with the surface's interior knot lines and at its u- and v-extrema. The parameters that any face of
   an edge needs, plus the knots of the edge's 3D curve, form the edge's plan ``W_e``; every face then
   cuts the edge at all of ``W_e``, so both faces of an edge see the same pieces.
2. **Slabs and cells.** A face's domain is cut into vertical slabs by the iso-lines u = const through
   every piece end and every interior u-knot. Inside a slab each piece is the graph of a function of u;
   sorted by v, consecutive pairs (even-odd rule) bound the regions of the face. Interior v-knot lines
   cut each region further, so every cell lies in one Bezier span of the surface and is bounded by two
   u-iso rungs and a bottom and a top side, each a pcurve piece or a v-iso line. The slab lines also cut
   pieces of other edges; those cuts are local to the face (recorded as ``local_cuts``). A line that no
   piece end between a region's bottom and top put there (another pcurve's end elsewhere in u), and that
   is no knot line, does not cut that region: its bottom and top run through it, and the cell spans
   several slabs (``_through_lines``), so ends of pcurves that fall close in u do not chop the whole
   face into strips. A plan cut that only a neighbour needs and that ends a strip across a slab (a
   cell far longer than wide, beside a knot line or a vertex) is left out where that leaves fewer
   strips (``_without_strip_cuts``): the face's side runs through it, a T-vertex of the neighbour.
   No slab line passes through a u-extremum of a pcurve beyond which the face lies (it would be
   tangent to the curve there, a corner of zero angle): the arc around it is wrapped by cells turned
   by 90 degrees instead (``wrap``).
3. **Maps.** A cell whose bottom and top are iso-lines is a sub-box: de Casteljau/blossoming. Otherwise
   the ruled map phi(s, t) = (1 - t) B(s) + t T(s) joins the bottom B and the top T, each in its own
   (pcurve = edge) parameter, so the trimming side keeps the edge's parameter. S o phi is composed
   exactly (polynomial or rational) in the Bernstein basis. The Jacobian of phi is checked on a grid; a
   folded cell is cut in two at its middle u-line.
4. **Degree budget.** Where the exact bidegree exceeds ``max_degree`` the cell is approximated: the
   surface span is cut to the cell's box and its degree reduced, the pieces' degree is reduced with
   their ends held, and if the certified bound exceeds the tolerance the cell is halved and tried again.

Rungs along edges: a boundary edge along a u-iso line is the rung of the cells beside it. Those
cells are cut at the edge's plan parameters, so each rung lies on one plan piece; it takes the
edge's curve in stage 2 where the edge's parameter is affine along it (or close enough that the
curve slides by at most ``RUNG_SLIDE`` of the tolerance). A face that still leaves rungs unshared is
decomposed turned as well (u and v swapped, ``transpose_face``) and kept so when that leaves fewer.

Real files need repairs before step 2, each bounded and added to the face's bound: loops whose
consecutive pcurves leave uv gaps are closed (``_close_loops``); pcurves, or stretches of them, that
wiggle around an iso-line within half the tolerance become exact iso-lines (``_flatten``); pieces that
closing turned back are cut again at their extrema (``_monotone``). Slab lines closer than a sliver
(``Tolerances.sliver_rel``) merge, and so do lines closer than ``Tolerances.thin_rel`` where every
end on them is passed through (``_thin_merge_rules``); a folded cell that halving cannot mend is
given lower-degree sides within the tolerance (``_unfold``) or, when thinner than a sliver, dropped.

Every patch records the exact cell map (its two sides, in the face's global uv) so that the own verify
step can compare the patch with S(phi) evaluated independently.
"""

from __future__ import annotations

import functools
import time
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import brentq
from scipy.special import comb

from .core.approx import fit_points
from .core.bernstein import basis, product, scalar_fn
from .core.bezier import curve_segment, elevate_curve, surface_subbox
from .core.bspline import surface_to_bezier, to_bezier
from .core.compose import compose
from .core.reduce import reduce_curve, reduce_surface
from .errors import WatertightError
from .model import BSplineCurve, BSplineSurface, Face, Loop, Model
from .tolerances import Tolerances

__all__ = ["Patch", "FaceResult", "UntrimResult", "untrim", "edge_plan", "UntrimError", "patch_points"]

#: rung cuts tried in turn until a face's cells have no problem (``_cells``, ``_face_or_problem``)
_RUNG_CUTS = ("plan", "vertices", "none")
#: share of the tolerance by which a rung may slide along its side when it takes an edge's curve whose
#: parameter is not affine in v (stage 2, ``substitute._rung_ref``); the move enters the bound
RUNG_SLIDE = 0.1
#: a pcurve end (or a cut's end) inside a neighbouring cell's rung closer than this share of the
#: rung's height to its end cuts that cell along the v-iso line through it (``_align_rungs``), where
#: the line stays between the cell's
#: bottom and top. Stage 2 moves such an end onto the edge's curve (by the input's gap there) and
#: would have to bend the long rung through it: a polynomial within degree 25 that moves one
#: point a hair from an end bulges more than twice that move (``substitute._bump``, at 0.0095)
_NEAR_END = 0.02
#: how far (x ``ueps_lines``, in u) a piece end may lie from a knot line and still be put on it
#: when it is within a sliver of it in 3D where it is (``_ends_onto_knots``)
_KNOT_SNAP = 4.0
#: a cell's bottom and top both leave a rung with a u-speed under this share of the slab's width
#: over their parameter: the patch's Jacobian (nearly) vanishes along that rung (``_tangent_rung_cuts``)
_TANGENT_RUNG = 1e-3
#: where a pole cap ends (``_pole_caps``): this share of the way from the pole to the lowest side or
#: cut of its run's cells (not all the way: the cells beyond must not be slivers)
_CAP = 0.8
_MAX_SPLIT_DEPTH = 14  # halvings of a cell to meet the tolerance
_MAX_FOLD_DEPTH = 6  # halvings of a folded cell before it is reported
_FLATTEN = 0.5  # share of the tolerance that flattening near-iso pcurves may use (see _flatten)
#: share of ``Tolerances.thin_rel`` within which a lone piece that turns back on a slab line is
#: laid on it (``_flatten_runs``)
_LONE = 0.25
_ROOT_SAMPLES = 48
_COMPACT_DIFF = 1e-8  # relative size of a power coefficient that counts as zero (differences lose ~2^d)
_COMPACT_REL = 1e-13  # bound (relative to the patch size) below which a degree reduction changes nothing


class UntrimError(WatertightError):
    """A face that stage 1 cannot decompose (for example a loop without pcurves)."""


# ---------------------------------------------------------------------------------------- containers


@dataclass
class Side:
    """The bottom or top of a cell, in the face's global uv, oriented with u increasing.

    H : (k+1, 3) homogeneous planar Bezier [X, Y, W] (W = 1 for polynomial pieces)
    iso : v-iso line (a knot line, or a piece lying on one); then H is linear [(a, c, 1), (b, c, 1)]
    edge, w0, w1 : for a pcurve piece, its edge and the edge parameters at s = 0 and s = 1; the
        piece's own parameter s is affine in w (pieces are Bezier segments of the pcurve)
    """

    H: np.ndarray
    iso: bool
    edge: int | None = None
    w0: float = 0.0
    w1: float = 0.0
    degenerate: bool = False
    pcurve: BSplineCurve | None = None  # the coedge's pcurve, for verification (seams have two)


@dataclass
class Patch:
    """One output patch. ctrl is (ds+1, dt+1, 3), or (.., 4) homogeneous when rational.

    bottom, top : the exact cell sides (global uv) that define the cell map, for verification
    bound : certified (or, when ``estimated``, sampled) deviation bound from the face, model units
    """

    face: int
    ctrl: np.ndarray
    rational: bool
    bottom: Side
    top: Side
    bound: float = 0.0
    estimated: bool = False
    approximated: bool = False
    box: bool = False  # a sub-box of a span: u runs linearly between the rungs on both sides
    # weight functions stage 2 multiplied the net by, as (axis, Bernstein coefficients / first)
    factors: list = field(default_factory=list)

    @property
    def degrees(self) -> tuple[int, int]:
        return self.ctrl.shape[0] - 1, self.ctrl.shape[1] - 1


@dataclass
class FaceResult:
    face: int
    patches: list[Patch] = field(default_factory=list)
    bound: float = 0.0
    approximated: bool = False
    estimated: bool = False
    folds: int = 0
    local_cuts: int = 0
    pole_caps: int = 0  # runs of wedges at a pole made one cell below a common cut (_pole_caps)
    strip_cuts: int = 0  # plan cuts left out because they ended strips across slabs (_without_strip_cuts)
    closure: float = 0.0  # deviation bound of closing the loops' uv gaps and snapping (model units)
    flattened: float = 0.0  # the part of ``closure`` spent on flattening near-iso pcurves (_flatten)
    snapped: int = 0  # pieces treated as iso-lines though they wiggle (by less than the snap)
    wraps: int = 0  # u-extrema of pcurves wrapped by turned cells instead of cut by a slab line (``wrap``)
    slivers: int = 0  # pieces narrower than a sliver (Tolerances.sliver_rel) left on a slab line
    problems: list[str] = field(default_factory=list)
    # pieces that lie on a slab line (u-iso): the rungs of the cells beside them are on their edges
    iso_pieces: list = field(default_factory=list)
    eps: tuple[float, float] | None = None  # (u, v) distances below which uv values are one line
    # where two of the face's pcurves cross a hair before the vertex they meet at (``_uncross``): per
    # crossing, for the cell's bottom and top, (edge, w at the crossing, w at the tip); the strip
    # between the crossing and the tip is no part of the face, so there the face's two neighbours
    # meet each other (the edge plan cuts them at the crossing, stage 2 gives them one curve)
    crossings: list = field(default_factory=list)
    # seconds spent on the face: "cells" (pieces and cell decomposition), "reparam" (composition,
    # approximation and compaction of the cells' patches)
    times: dict[str, float] = field(default_factory=lambda: {"cells": 0.0, "reparam": 0.0})


@dataclass
class UntrimResult:
    faces: list[FaceResult]
    plan: dict[int, np.ndarray]
    tolerance: float
    max_degree: int
    plan_time: float = 0.0  # seconds spent on the face geometries and the edge plan
    # per face, the plan cuts that only its own crossings put there (edge -> parameters): the face
    # ends its cell at the crossing by itself, and a cut there would give it the inverted strip
    # beyond as a cell of its own (``plan_for``)
    own_cuts: dict[int, dict[int, set[float]]] = field(default_factory=dict)
    # per edge, the plan cuts that some face of it leaves out (``_without_strip_cuts``): that face's
    # side runs through them, so a curve fitted per plan piece (the midway curve) has no break there
    strip_cuts: dict[int, set[float]] = field(default_factory=dict)

    def shared_cuts(self, e: int) -> np.ndarray:
        """The plan's parameters on edge e at which every face of the edge cuts it."""
        plan = self.plan.get(e, np.zeros(0))
        out = self.strip_cuts.get(e)
        return plan if not out else np.array([w for w in plan if float(w) not in out])

    def plan_for(self, face: int) -> dict[int, np.ndarray]:
        """The edge plan a face is decomposed with: ``plan`` less the face's own crossing cuts and
        the cuts it leaves out beside strips."""
        return _plan_without(self.plan, self.own_cuts.get(face, {}))

    @property
    def patches(self) -> list[Patch]:
        return [p for f in self.faces for p in f.patches]

    def timings(self) -> dict[str, float]:
        """Seconds per sub-stage: plan, cells, reparam."""
        return {"plan": self.plan_time,
                "cells": sum(f.times["cells"] for f in self.faces),
                "reparam": sum(f.times["reparam"] for f in self.faces)}


# ------------------------------------------------------------------------------------- small helpers


def _h(poles: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """Homogeneous [X, Y, W] poles of a planar curve (W = 1 when polynomial)."""
    if weights is None:
        return np.concatenate([poles, np.ones((poles.shape[0], 1))], axis=1)
    return np.concatenate([poles * weights[:, None], weights[:, None]], axis=1)


def _eval(H: np.ndarray, t) -> np.ndarray:
    """Cartesian uv of a homogeneous planar Bezier at t (k,) -> (k, 2)."""
    h = basis(H.shape[0] - 1, np.atleast_1d(np.asarray(t, dtype=float))) @ H
    return h[:, :2] / h[:, 2:3]


def _deriv_h(H: np.ndarray) -> np.ndarray:
    k = H.shape[0] - 1
    return k * np.diff(H, axis=0) if k > 0 else np.zeros((1, H.shape[1]))


def _coord_fn(H: np.ndarray, axis: int, c: float):
    """f(t) = X_axis(t) - c W(t): its roots are where the curve crosses the line coordinate = c."""
    coef = H[:, axis] - c * H[:, 2]
    k = H.shape[0] - 1

    def f(t):
        return basis(k, np.atleast_1d(t)) @ coef

    f.scalar = _Lazy(lambda: scalar_fn(coef))  # the same polynomial at one float, for Brent's method
    return f


def _extremum_fn(H: np.ndarray, axis: int):
    """f(t) = X' W - X W' for coordinate ``axis``: zero at the extrema of X / W."""
    D = _deriv_h(H)
    k, kd = H.shape[0] - 1, D.shape[0] - 1

    def f(t):
        t = np.atleast_1d(t)
        b, bd = basis(k, t), basis(kd, t)
        return (bd @ D[:, axis]) * (b @ H[:, 2]) - (b @ H[:, axis]) * (bd @ D[:, 2])

    # the same function as one Bernstein polynomial of degree 2k - 1, for Brent's method
    f.scalar = _Lazy(lambda: scalar_fn(product(D[:, axis], H[:, 2]) - product(H[:, axis], D[:, 2])))
    return f


def _extrema(H: np.ndarray, axis: int, eps: float) -> list[float]:
    """Parameters in (0, 1) of the extrema of a piece's coordinate ``axis`` (none where it varies by
    at most ``eps``), without an end's noise: the extremum nearest an end, with no other between,
    where the coordinate there differs from that end's by at most ``eps`` (the piece overshoots
    and comes back by less than what ``_FaceGeometry`` calls noise). gmsh__917_fusee.stp face 44:
    edge 253 runs nearly along v = const and dips 1.4e-11 in v (3e-8 in 3D) 1e-8 in u (6.5e-6 in
    3D) before its end, the face's corner; cut there, the slab line through the dip bounded a
    strip that wide and 25.8 long, which stage 2 closed into a triangle at one end."""
    X = H[:, axis] / H[:, 2]
    if np.ptp(X) <= eps:
        return []
    rs = _roots(_extremum_fn(H, axis))
    if not rs:
        return rs

    def at(t: float) -> float:
        h = basis(len(H) - 1, np.array([t]))[0] @ H
        return float(h[axis] / h[2])

    if abs(at(rs[0]) - X[0]) <= eps:
        rs = rs[1:]
    if rs and abs(at(rs[-1]) - X[-1]) <= eps:
        rs = rs[:-1]
    return rs


class _Lazy:
    """A function of one float made on its first call: the scalar forms for Brent's method are
    needed only where the grid finds a sign change (861 of 62399 functions made in stage 1 of
    occt__occ22470.igs; making them all, two Bernstein products each, took 1.5 s)."""

    __slots__ = ("_make", "_fn")

    def __init__(self, make):
        self._make, self._fn = make, None

    def __call__(self, t: float) -> float:
        if self._fn is None:
            self._fn = self._make()
        return self._fn(t)


def _roots(f, lo: float = 0.0, hi: float = 1.0, n: int = _ROOT_SAMPLES) -> list[float]:
    """Sign changes of f on a grid of n+1 points in [lo, hi], refined by Brent's method (open interval)."""
    ts = np.linspace(lo, hi, n + 1)
    ys = np.asarray(f(ts), dtype=float)
    scale = float(np.max(np.abs(ys))) if ys.size else 0.0
    if not scale > 0:
        return []
    out = []
    for i in range(n):
        a, b, ya, yb = ts[i], ts[i + 1], ys[i], ys[i + 1]
        if ya == 0.0 and 0 < i:
            out.append(a)
        elif ya * yb < 0:
            fs = getattr(f, "scalar", None) or (lambda x: float(f(x)[0]))
            out.append(brentq(fs, a, b, xtol=1e-15, rtol=1e-15))
    return [r for r in out if lo < r < hi]


def _merge(values, lo: float, hi: float, eps: float) -> np.ndarray:
    """Sorted values in (lo, hi), dropping those within eps of an end or of the previous one."""
    out: list[float] = []
    for x in sorted(values):
        if x <= lo + eps or x >= hi - eps:
            continue
        if out and x - out[-1] <= eps:
            continue
        out.append(float(x))
    return np.array(out)


def _interior_breaks(knots: np.ndarray, degree: int) -> np.ndarray:
    u = np.unique(knots[degree : len(knots) - degree])
    return u[1:-1]


# ------------------------------------------------------------------------------------ pieces and plan


@dataclass
class _Coedge:
    edge: int
    degenerate: bool
    curve: BSplineCurve
    first: float
    last: float
    breaks: np.ndarray  # pcurve Bezier breaks
    spans: np.ndarray  # (k, p+1, 3) homogeneous
    loop: int = 0
    reversed: bool = False


def _coedges(face: Face, model: Model) -> list[_Coedge]:
    out = []
    for li, loop in enumerate(face.loops):
        for ce in loop.coedges:
            edge = model.edges[ce.edge]
            if ce.pcurve is None:
                raise UntrimError(f"face {face.index}: edge {ce.edge} has no pcurve on it")
            c = ce.pcurve
            br, spans = to_bezier(c.knots, c.degree, _h(c.poles, c.weights))
            out.append(_Coedge(ce.edge, edge.degenerate, c, ce.first, ce.last, br, spans, li, ce.reversed))
    return out


def _span_pieces(ce: _Coedge, params: np.ndarray):
    """Yield (w0, w1, H) Bezier pieces of the coedge's pcurve between consecutive params (sorted, with
    the ends), each inside one pcurve span."""
    br = ce.breaks
    cuts = np.unique(np.concatenate([[ce.first, ce.last], params, br[(br > ce.first) & (br < ce.last)]]))
    eps = 1e-13 * max(ce.last - ce.first, 1e-300)
    keep = [cuts[0]]
    for x in cuts[1:]:
        if x - keep[-1] > eps:
            keep.append(x)
    keep[-1] = ce.last
    for w0, w1 in zip(keep[:-1], keep[1:], strict=True):
        j = int(np.clip(np.searchsorted(br, 0.5 * (w0 + w1), side="right") - 1, 0, len(ce.spans) - 1))
        x0, x1 = br[j], br[j + 1]
        H = curve_segment(ce.spans[j], (w0 - x0) / (x1 - x0), (w1 - x0) / (x1 - x0))
        yield float(w0), float(w1), H


def _needs(ce: _Coedge, surface_breaks: tuple[np.ndarray, np.ndarray], eps=(0.0, 0.0),
           flat=(0.0, 0.0)) -> list[float]:
    """Edge parameters this face needs on the coedge: pcurve knots, knot-line crossings, extrema.

    eps : (u, v) below which a coordinate's variation over a span is noise (see ``_FaceGeometry``):
    a pcurve that runs along an iso-line with 1e-11 wiggles has no extrema worth a cut.
    flat : (u, v) half-widths of the band within which ``_flatten`` lays the whole coedge on an
    iso-line (``_FaceGeometry.flat``); its extrema in that coordinate are then wiggles that the
    flattening takes out, and no cut. Extrema that turn back by noise before a piece's end are no
    cut either (``_extrema``)."""
    out: list[float] = []
    pieces = list(_span_pieces(ce, np.array([])))
    if pieces:
        uv = np.concatenate([H[:, :2] / H[:, 2:3] for _, _, H in pieces])
        laid = [0.5 * np.ptp(uv[:, a]) <= flat[a] for a in (0, 1)]
        if all(laid):
            laid = [False, False]  # a point-like coedge: ``_flatten`` leaves it to the loop closing
    for w0, w1, H in pieces:
        out.append(w0)
        uv = H[:, :2] / H[:, 2:3]
        rs = [r for a in (0, 1) if not laid[a] for r in _extrema(H, a, eps[a])]
        for axis in (0, 1):
            lo, hi = uv[:, axis].min(), uv[:, axis].max()
            for c in surface_breaks[axis]:
                if lo < c < hi:
                    rs.extend(_roots(_coord_fn(H, axis, c)))
        out.extend(w0 + r * (w1 - w0) for r in rs)
    return out


class _FaceGeometry:
    """A face's surface as Bezier spans, its speed bounds and the snapping thresholds.

    Real pcurves that run along an iso-line wiggle around it by 1e-11 or so. A coordinate
    variation that moves the surface point by less than ``snap`` (0.1 x ``exact_rel`` x diagonal)
    is treated as none: ``ueps = snap / max|dS/du|`` (and the same in v). Pieces narrower than
    ``ueps`` lie on a slab line; sides flatter than ``veps`` are iso-lines. The deviation this
    causes is at most ``snap`` and is added to the face's bound when it happens. Slab lines
    closer than ``ueps_lines`` (``Tolerances.sliver_rel``) merge, so no cell is a sliver.
    """

    def __init__(self, face: Face, diagonal: float, tol: Tolerances):
        s = face.surface
        self.rational = s.rational
        self.m, self.n = s.udegree, s.vdegree
        self.ub, self.vb, self.spans = surface_to_bezier(s.uknots, s.vknots, s.udegree, s.vdegree,
                                                         s.homogeneous())
        du, dv = np.diff(self.ub), np.diff(self.vb)
        su = sv = 0.0
        self.span_speed = np.zeros((len(du), len(dv), 2))  # |dS/du| and |dS/dv| bounds per span
        for i in range(len(du)):
            for j in range(len(dv)):
                lu, lv = _lipschitz(self.spans[i, j], self.rational)
                su, sv = max(su, lu / du[i]), max(sv, lv / dv[j])
                self.span_speed[i, j] = lu / du[i], lv / dv[j]
        self.su, self.sv = float(su), float(sv)  # bounds of |dS/du| and |dS/dv|
        self.speed = su + sv  # bound of |dS/du| + |dS/dv| over the surface
        self.snap = 0.1 * tol.exact_rel * diagonal
        u0, u1, v0, v1 = face.uv_bounds
        self.ueps = max(1e-11 * max(u1 - u0, 1e-300), self.snap / su if su > 0 else 0.0)
        self.veps = max(1e-11 * max(v1 - v0, 1e-300), self.snap / sv if sv > 0 else 0.0)
        # slab lines closer than a sliver merge (see Tolerances.sliver_rel)
        self.ueps_lines = max(self.ueps, tol.sliver_rel * diagonal / su if su > 0 else 0.0)
        self.sliver = tol.sliver_rel * diagonal
        self.diagonal = diagonal
        self.thin = max(tol.thin_rel * diagonal, self.sliver)
        self.breaks = (_interior_breaks(s.uknots, s.udegree), _interior_breaks(s.vknots, s.vdegree))
        # the half-widths (u, v) within which ``_face_pieces`` flattens a coedge onto an iso-line
        budget = _FLATTEN * tol.approx_rel * diagonal
        self.flat = (budget / su if su > 0 else 0.0, budget / sv if sv > 0 else 0.0)

    def speed_over(self, points: np.ndarray) -> np.ndarray:
        """Bounds of (|dS/du|, |dS/dv|) over the spans that the bounding box of uv ``points`` meets
        (end spans extend past the domain, as the B-spline does)."""
        lo, hi = points.min(axis=0), points.max(axis=0)
        i0, i1 = (int(np.clip(np.searchsorted(self.ub, x, side="right") - 1, 0, len(self.ub) - 2))
                  for x in (lo[0], hi[0]))
        j0, j1 = (int(np.clip(np.searchsorted(self.vb, x, side="right") - 1, 0, len(self.vb) - 2))
                  for x in (lo[1], hi[1]))
        return self.span_speed[i0:i1 + 1, j0:j1 + 1].reshape(-1, 2).max(axis=0)


def edge_plan(model: Model, geoms: list[_FaceGeometry], sliver: float = 0.0,
              thin: float = 0.0, wrap: bool = False) -> dict[int, np.ndarray]:
    """Every non-degenerate edge's sorted split parameters, agreed by all its faces (see module doc).
    ``sliver``, ``thin``: see ``_thin_plan``. ``wrap``: cut the arcs that ``wrap`` wraps
    (``Tolerances.wrap_tips``)."""
    from .wrap import wrap_sites

    raw: dict[int, list[float]] = {}
    own: dict[int, set[float]] = {}  # per edge, the knots of its faces' pcurves
    for face, g in zip(model.faces, geoms, strict=True):
        for ce in _coedges(face, model):
            if ce.degenerate:
                continue
            raw.setdefault(ce.edge, []).extend(_needs(ce, g.breaks, (g.ueps, g.veps), g.flat))
            own.setdefault(ce.edge, set()).update(float(x) for x in ce.breaks[1:-1])
        for intervals, _ in wrap_sites(face, model, g) if wrap else ():  # the ends of the arcs to wrap
            for e, lo, hi in intervals:
                raw[e].extend((lo, hi))
    plan = {}
    for e, vals in raw.items():
        edge = model.edges[e]
        if edge.curve is not None:
            vals = vals + list(_interior_breaks(edge.curve.knots, edge.curve.degree))
        eps = 1e-11 * max(edge.last - edge.first, 1e-300)
        plan[e] = _merge(vals, edge.first, edge.last, eps)
        if edge.curve is not None and len(plan[e]) and sliver > 0:
            plan[e] = _thin_plan(plan[e], edge, sliver, thin, own.get(e, set()))
    return plan


def _thin_plan(params: np.ndarray, edge, sliver: float, thin: float = 0.0,
               knots: set[float] = frozenset()) -> np.ndarray:
    """Drop split parameters that stand less than a sliver (in 3D, along the edge's curve) from the
    previous one or from the edge's ends: two faces computing the same crossing on their own
    surfaces need the same cut, and two cuts that close make a cell narrower than a sliver. A knot
    of a face's pcurve (``knots``) goes within ``thin`` of the previous one as well: that face
    cuts its own pcurve there anyway (its cells leave that cut out within a sliver of the plan's,
    ``_knot_cuts_dropped``; farther, its corner there is a T-vertex of the neighbour), while kept in
    the plan it cut every face of the edge (trj8 edge 116: its two faces' pcurve knots, one pcurve
    re-timed, stand 1.3e-6 to 8.9e-6 apart at every eighth of the edge, a strip that wide and 2
    long across the other face at each, which stage 2 made a wedge at 0.75)."""
    pts = edge.curve.evaluate(np.concatenate([[edge.first], params, [edge.last]]))
    keep, last = [], pts[0]
    for w, x in zip(params, pts[1:-1], strict=True):
        near = sliver if float(w) not in knots or not keep else max(sliver, thin)
        if np.linalg.norm(x - last) > near and np.linalg.norm(x - pts[-1]) > sliver:
            keep.append(w)
            last = x
    return np.array(keep)


# ---------------------------------------------------------------------------------------- slabs/cells


@dataclass
class _Piece:
    H: np.ndarray
    edge: int | None  # None: a side of the domain made of several edges (``_join_t_sides``)
    w0: float
    w1: float
    degenerate: bool
    pcurve: BSplineCurve | None = None
    virtual: bool = False  # a side of a wrap's notch (``wrap.wrapped``), no part of the loops


def _orient_u(p: _Piece) -> _Piece:
    """The same piece running with u increasing."""
    if p.H[-1, 0] / p.H[-1, 2] >= p.H[0, 0] / p.H[0, 2]:
        return p
    return _Piece(p.H[::-1].copy(), p.edge, p.w1, p.w0, p.degenerate, p.pcurve, p.virtual)


def _split(p: _Piece, t: float) -> tuple[_Piece, _Piece]:
    w = p.w0 + t * (p.w1 - p.w0)
    return (
        _Piece(curve_segment(p.H, 0.0, t), p.edge, p.w0, w, p.degenerate, p.pcurve, p.virtual),
        _Piece(curve_segment(p.H, t, 1.0), p.edge, w, p.w1, p.degenerate, p.pcurve, p.virtual),
    )


def _t_at_u(H: np.ndarray, u: float, axis: int = 0) -> float:
    """Parameter of a piece monotone in coordinate ``axis`` (u by default) where it reaches u
    (clamped to the piece)."""
    f = _coord_fn(H, axis, u).scalar
    a, b = f(0.0), f(1.0)
    if a == 0.0:
        return 0.0
    if b == 0.0:
        return 1.0
    if a * b > 0:
        return 0.0 if abs(a) < abs(b) else 1.0
    return brentq(f, 0.0, 1.0, xtol=1e-15, rtol=1e-15)


def _cluster(values: list[float], exact: set[float], eps: float) -> np.ndarray:
    vs = sorted(values)
    groups: list[list[float]] = []
    for x in vs:
        if groups and x - groups[-1][-1] <= eps:
            groups[-1].append(x)
        else:
            groups.append([x])
    out = []
    for g in groups:
        ex = [x for x in g if x in exact]
        out.append(ex[0] if ex else g[len(g) // 2])
    return np.array(out)


def _ends_onto_knots(ends_uv: np.ndarray, knots: list[float], face: Face, g: _FaceGeometry) -> list[float]:
    """The u of each piece end, or of the knot line next to it where the end lies within a sliver
    of that line in 3D, at its own v, and within ``_KNOT_SNAP`` x ``ueps_lines`` of it in u.

    ``ueps_lines`` measures u by the surface's largest speed, so it misses an end a hair off a
    knot line where the surface is slower: an edge plan cut that stands for a knot crossing of
    the face (the edge's own knot, which the input's pcurve places 9.3e-9 off in parameter) lands
    1e-8 off the knot line at its end, 5.6e-7 away there, while the two lines stand 9.9e-7 apart
    at the face's far side; as two slab lines they made a sliver cell (filleted_freeform's face
    0: four cells, 46 long and 1e-6 wide), which no tessellation resolves and which a second
    conversion cannot join. Snapped, the end moves by at most a sliver, as ``ueps_lines`` allows."""
    u = ends_uv[:, 0].astype(float)
    if not knots or g.sliver <= 0 or not len(u):
        return [float(x) for x in u]
    ks = np.asarray(knots, dtype=float)
    c = ks[np.abs(u[:, None] - ks[None, :]).argmin(axis=1)]
    off = np.abs(u - c)
    cand = np.flatnonzero((off > 0) & (off <= _KNOT_SNAP * g.ueps_lines))
    if len(cand):
        v = ends_uv[cand, 1]
        pa = face.surface.evaluate(np.column_stack([u[cand], v]))
        pb = face.surface.evaluate(np.column_stack([c[cand], v]))
        close = cand[np.linalg.norm(pa - pb, axis=1) <= g.sliver]
        u[close] = c[close]
    return [float(x) for x in u]


def _merge_thin(lines: np.ndarray, exact: set[float], face: Face, g: _FaceGeometry,
                links: dict[int, int], pinned: set[int]) -> tuple[np.ndarray, np.ndarray]:
    """Merge consecutive slab lines that stand less than a sliver apart in 3D all along the face's
    v-range. ``ueps_lines`` merges by the surface's largest speed; where the surface is much slower
    (near a pole) two lines 2e-7 apart in u were 0 to 7e-8 apart in 3D, a slab below the edge
    tolerance that read back as a gap (filleted_freeform's face 7). A knot line wins.

    Lines up to ``g.thin`` apart (``Tolerances.thin_rel``) merge too, into the group's first line,
    when no line of the group is ``pinned`` and no piece joins two of its lines (``links``: line ->
    the highest lower line that a piece joins it to): see ``_thin_merge_rules``. Returns the lines
    and, for every line given, the index of the line it became."""
    if len(lines) < 2 or g.sliver <= 0:
        return lines, np.arange(len(lines))
    u0, u1, v0, v1 = face.uv_bounds
    vs = np.linspace(v0, v1, 17)
    near = 1e-3 * max(u1 - u0, 1e-300)
    out, index = [float(lines[0])], [0]
    start = 0  # the first of the given lines that out[-1] stands for
    for i, x in enumerate(map(float, lines[1:]), start=1):
        a = out[-1]
        if x - a <= near:
            pa = face.surface.evaluate(np.column_stack([np.full(len(vs), a), vs]))
            pb = face.surface.evaluate(np.column_stack([np.full(len(vs), x), vs]))
            apart = float(np.linalg.norm(pa - pb, axis=1).max())
            if apart <= g.sliver or (apart <= g.thin and links.get(i, -1) < start
                                     and not pinned.intersection(range(start, i + 1))):
                if x in exact and a not in exact:
                    out[-1] = x
                index.append(len(out) - 1)
                continue
        out.append(x)
        index.append(len(out) - 1)
        start = i
    return np.array(out), np.array(index)


def _thin_merge_rules(lines: np.ndarray, pieces: list[_Piece], at: list[tuple[int, int]],
                      knots: set[float]) -> tuple[dict, set]:
    """What keeps slab lines from merging beyond a sliver (``_merge_thin``).

    A merged line passes through the ends on it, bent by up to ``Tolerances.thin_rel``; the cells
    on both sides take the straight segment between their bottom's and top's ends as their rung,
    and they share it when every end on the line is passed through: one piece leaves it to the
    left and one to the right. Lines that hold a turning end (both pieces on one side: the other
    side's cell would run straight past it, a thin triangle uncovered), an iso piece (it would be
    left off the line), or a knot line (cells must stay within one span) are ``pinned``. A piece
    running from one line of a group to another would become an iso piece: ``links`` maps each
    line to the highest lower line that a piece joins it to. ``at``: per piece, the lines of its
    first and last end."""
    links: dict[int, int] = {}
    pinned = {k for k, x in enumerate(lines) if float(x) in knots}
    sides: dict[tuple[float, float], list[int]] = {}
    for p, (i, j) in zip(pieces, at, strict=True):
        if i == j:
            pinned.add(i)
            continue
        links[max(i, j)] = max(links.get(max(i, j), -1), min(i, j))
        for k, towards in ((0, j - i), (-1, i - j)):
            end = (float(p.H[k, 0] / p.H[k, 2]), float(p.H[k, 1] / p.H[k, 2]))
            sides.setdefault(end, []).append(1 if towards > 0 else -1)
    for end, sd in sides.items():
        if len(sd) != 2 or sum(sd) != 0:
            pinned.add(_nearest(lines, end[0]))
    return links, pinned


def _iso_side(a: float, b: float, c: float) -> Side:
    return Side(np.array([[a, c, 1.0], [b, c, 1.0]]), True)


def _as_side(p: _Piece, veps: float) -> Side:
    uv = p.H[:, :2] / p.H[:, 2:3]
    iso = bool(np.ptp(uv[:, 1]) <= veps)
    return Side(p.H, iso, p.edge, p.w0, p.w1, p.degenerate, p.pcurve)


def _cells(face: Face, pieces: list[_Piece], g: _FaceGeometry, fr: FaceResult, rung_cuts: str = "plan",
           plan: dict[int, np.ndarray] | None = None, wrap_ends=()):
    """Yield (ua, ub, bottom Side, top Side) cells of a face from its pieces (see module doc).
    ``plan``: the edge plan, which tells the ends of rung pieces at a plan parameter from those at
    a knot of the face's own pcurve only (``_knot_cuts_dropped``). ``wrap_ends``: (u, v) points on
    slab lines where the wraps' turned cells end (``wrap.wrapped``); the cells beside are cut there."""
    ub, vb, ueps, veps = g.ub, g.vb, g.ueps_lines, g.veps
    ends_uv = np.array([p.H[k, :2] / p.H[k, 2] for p in pieces for k in (0, -1)])
    lo, hi = float(ends_uv[:, 0].min()), float(ends_uv[:, 0].max())
    inner_u = [float(x) for x in ub[1:-1] if lo + ueps < x < hi - ueps]
    ends = _ends_onto_knots(ends_uv, inner_u, face, g)
    knots = set(inner_u)
    uknots = knots  # ``knots`` is reused for each cell's v cuts below
    first = _cluster(ends + inner_u, knots, ueps)
    # every end was clustered into a line: a piece runs from its first end's line to its last
    # end's line, so one rule decides both the lines and which pieces lie on a line
    at = [(_nearest(first, float(p.H[0, 0] / p.H[0, 2])), _nearest(first, float(p.H[-1, 0] / p.H[-1, 2])))
          for p in pieces]
    lines, index = _merge_thin(first, knots, face, g, *_thin_merge_rules(first, pieces, at, knots))
    crossing: list[_Piece] = []  # the pieces that run from one slab line to another, u increasing
    spans: list[tuple[int, int]] = []  # their first and last slab line
    ends_on: dict[int, list[float]] = {}  # slab line -> v of every piece end on it
    for p, ends_at in zip(pieces, at, strict=True):
        for k in (0, -1):
            ends_on.setdefault(int(index[ends_at[k]]), []).append(float(p.H[k, 1] / p.H[k, 2]))
        p = _orient_u(p)
        a, b = p.H[0, 0] / p.H[0, 2], p.H[-1, 0] / p.H[-1, 2]
        # oriented with u increasing, the piece runs from the lower of its two lines
        i, j = int(index[min(ends_at)]), int(index[max(ends_at)])
        if i == j:
            if p.virtual:
                continue  # a wrap's notch on its slab line: the cells beside it are cut at wrap_ends
            fr.iso_pieces.append(p)
            if b - a > g.ueps:
                fr.slivers += 1  # narrower than a sliver: its strip is left to the neighbours
            else:
                fr.snapped += b - a > 0
            continue  # a u-iso piece: it lies on a slab line
        crossing.append(p)
        spans.append((i, j))
    parts, pairs = _slab_pairs(crossing, spans, lines, set(), face)
    through = _through_lines(parts, pairs, lines, knots, ends_on, veps)
    if through:
        joined = _slab_pairs(crossing, spans, lines, through, face)
        if joined is not None:
            parts, pairs = joined
    fr.local_cuts += len(parts) - len(crossing)
    # rung cuts: a cell whose rung runs along a u-iso boundary piece is cut by v-iso lines at that
    # piece's ends (the edge plan's parameters and the edge's vertices), so each rung lies on one
    # plan piece and stage 2 can put that piece's curve into it. ``rung_cuts`` "vertices" cuts
    # only where two edges meet, "none" not at all (the fallbacks of ``_face_or_problem``).
    ranges = {ce.edge: (min(ce.first, ce.last), max(ce.first, ce.last))
              for lp in face.loops for ce in lp.coedges}
    vertex_ends = []
    plan_only: set[float] = set()  # v of the ends that are plan cuts, not vertices of the face
    at_vertex: set[float] = set()
    planned: set[float] = set()  # v of the ends at a parameter of the edge's plan
    for q in fr.iso_pieces:
        lo, hi = ranges.get(q.edge, (np.inf, -np.inf))
        tol_w = 1e-9 * max(hi - lo, 1e-300)
        ws = plan.get(q.edge) if plan is not None and q.edge is not None else None
        for k, w in ((0, q.w0), (-1, q.w1)):
            vertex = abs(w - lo) <= tol_w or abs(w - hi) <= tol_w
            if rung_cuts == "plan" or vertex:
                v = float(q.H[k, 1] / q.H[k, 2])
                vertex_ends.append((q.H[k, 0] / q.H[k, 2], v))
                (plan_only if not vertex else at_vertex).add(v)
                if ws is None or (len(ws) and float(np.abs(ws - w).min()) <= tol_w):
                    planned.add(v)
    plan_only -= at_vertex
    knot_only = plan_only - planned  # ends at a knot of the pcurve that the plan thinned away
    vertex_ends = np.array((vertex_ends if rung_cuts != "none" else []) + list(wrap_ends)).reshape(-1, 2)
    # ends of the other pieces (where a pcurve starts, ends or turns on a slab line) that fall
    # inside a neighbouring cell's rung a hair from its end: see _NEAR_END. A part from line a to
    # line b has its first point (k = 0) on line a and its last (k = 1) on line b
    near_ends = [] if rung_cuts == "none" else [
        (line, float(q.H[-k, 1] / q.H[-k, 2])) for _, a, b, q in parts for k, line in ((0, a), (1, b))]
    cells = []
    owners: list[tuple[int, int] | None] = []  # per cell, the pieces of its bottom and top
    slants: dict[int, dict[float, float]] = {}  # per cell, its slanted cuts (``_slanted_cuts``)
    for j, jr, x, y in pairs:
        bot, top = parts[x][3], parts[y][3]
        cua, cub = float(lines[j]), float(lines[jr])
        uncrossed = _uncross(bot, top, g)
        owners.append((parts[x][0], parts[y][0]) if uncrossed is None else None)
        if uncrossed is not None:
            fr.crossings.append(tuple(_tail(p, q) for p, q in zip((bot, top), uncrossed, strict=True)))
            bot, top = uncrossed
            fr.slivers += 1  # the inverted strip beyond the crossing is left out
            cua, cub = float(bot.H[0, 0] / bot.H[0, 2]), float(bot.H[-1, 0] / bot.H[-1, 2])
        bside, tside = _as_side(bot, veps), _as_side(top, veps)
        for sd in (bside, tside):
            fr.snapped += sd.iso and float(np.ptp(sd.H[:, 1] / sd.H[:, 2])) > 0
        # A knot line c cuts the region iff min B < c < max T. Pieces are monotone in v (cut at
        # their v-extrema), so their ends give their v-range exactly (the control polygon can
        # overshoot it), and they never cross a knot line: c may touch B or T at one end only,
        # which leaves a cell with one collapsed rung.
        bv, tv = (sorted(float(q.H[i, 1] / q.H[i, 2]) for i in (0, -1)) for q in (bot, top))
        knots = [float(c) for c in vb[1:-1] if bv[0] + veps < c < tv[1] - veps]
        # the knot lines run between the cell's rungs (the straight segments joining the ends
        # of bottom and top), which may stand a sliver off the slab lines
        b0, b1 = bot.H[0, :2] / bot.H[0, 2], bot.H[-1, :2] / bot.H[-1, 2]
        t0, t1 = top.H[0, :2] / top.H[0, 2], top.H[-1, :2] / top.H[-1, 2]
        rungs: dict[float, set[int]] = {}
        cuts = _vertex_cuts(knots, vertex_ends, (b0, t0), (b1, t1), bv[0], tv[1], ueps, veps, rungs)
        if len(cuts) > len(knots):
            cuts = _sliver_cuts_dropped(cuts, set(knots), plan_only, face, (b0, t0), (b1, t1), g)
            cuts = _knot_cuts_dropped(cuts, knot_only, face, (b0, t0), (b1, t1), g)
            cuts, slant = _slanted_cuts(cuts, set(knots), rungs, face, (b0, t0), (b1, t1), g)
            if slant:
                slants[len(cells)] = slant
        knots = cuts
        cells.append([cua, cub, bside, tside, (b0, t0), (b1, t1), bv[1], tv[0], knots, j, jr])
    caps = _pole_caps(cells, owners, lines, uknots, veps) if rung_cuts != "none" else []
    if rung_cuts != "none":
        _tangent_rung_cuts(cells, veps, slants)
        # the cuts made so far end on both rungs of their cells: those ends may fall near the end
        # of a neighbour's rung too (fusee face 37: a vertex cut beside a rung 1.77 long, 0.0086
        # of it from its end, and the bend refused left a free edge)
        near_ends += [(line, v) for i, c in enumerate(cells) for line, v in _cut_points(c, slants.get(i))]
    _align_rungs(cells, near_ends, veps, slants)
    capped: dict[int, set[bool]] = {}  # cell -> True: its lowest sub-cell is in a cap, False: its highest
    for below, c, run in caps:
        for members in _cap_runs(cells, run, below, c, veps):
            for i in members:
                capped.setdefault(i, set()).add(below)
            fr.pole_caps += 1
            yield _cap_cell(cells, members, below, c)
    for i, (ua, ubb, bside, tside, left, right, _, _, knots, _, _) in enumerate(cells):
        slant = slants.get(i, {})
        inner = []
        for c in knots:
            d = slant.get(c, c)
            if d == c:
                inner.append(_iso_side(_rung_u(*left, c), _rung_u(*right, c), c))
            else:
                ends = [[_rung_u(*left, c), c, 1.0], [_rung_u(*right, d), d, 1.0]]
                inner.append(Side(np.array(ends), False))
        sides = [bside] + inner + [tside]
        pairs_of = list(zip(sides[:-1], sides[1:], strict=True))
        if i in capped:  # its sub-cells beside a pole are parts of caps
            pairs_of = pairs_of[(True in capped[i]):len(pairs_of) - (False in capped[i])]
        for s0, s1 in pairs_of:
            yield ua, ubb, s0, s1


def _pole_caps(cells: list, owners: list, lines: np.ndarray, uknots: set[float],
               veps: float) -> list[tuple[bool, float, list[int]]]:
    """Runs of cells side by side whose bottom (or top) is one pole: the same degenerate v-iso piece,
    cut only at slab lines that are no knot lines (the ends of the pieces on the other side put
    them there). Each such cell is a wedge from the pole, and side by side they converge on it:
    a sphere notched by a plane whose pcurve runs nearly along u = const
    (``sphere_cut_box.step``) gave 21 wedges meeting at each pole, the narrowest 0.0011 rad wide, 336
    of the independent checker's boundary samples unmatched, and 42 triangles for stage 2 to remake.
    Every cell of a run is cut along one v-iso line c, ``_CAP`` of the way from the pole to the
    lowest (highest) thing above (below) it in the run: its other side or a cut; below (above) c the
    run is one cell, the cap (``_cap_runs``, ``_cap_cell``), whose side at c holds the corners of the
    cells beyond as T-vertices. The cells beyond are no wedges but strips, whose long sides stage 2
    splits where they are slender (``core.slender``): the higher the cap, the shorter they are
    (sphere_cut_box: 84 patches at 0.5, 60 at 0.8, 48 at 0.9). Returns (below, c, cell indices in
    u order) per run of two cells or more; the cut c is added to each cell's cuts."""
    caps = []
    for below in (True, False):
        k = 2 if below else 3  # the side at the pole
        cand = sorted((i for i, cell in enumerate(cells) if owners[i] is not None
                       and cell[k].degenerate and cell[k].iso and cell[1] > cell[0]),
                      key=lambda i: cells[i][0])
        runs: list[list[int]] = []
        for i in cand:
            last = runs[-1][-1] if runs else None
            if (last is not None and cells[last][10] == cells[i][9]
                    and float(lines[cells[i][9]]) not in uknots
                    and owners[last][k - 2] == owners[i][k - 2]):
                runs[-1].append(i)
            else:
                runs.append([i])
        for run in runs:
            if len(run) < 2:
                continue
            if below:
                lo = max(cells[i][6] for i in run)
                hi = min(min([cells[i][7]] + list(cells[i][8])) for i in run)
            else:
                lo = max(max([cells[i][6]] + list(cells[i][8])) for i in run)
                hi = min(cells[i][7] for i in run)
            if hi - lo <= 8.0 * veps:
                continue
            c = lo + _CAP * (hi - lo) if below else hi - _CAP * (hi - lo)
            for i in run:
                cells[i][8] = _merge_cuts(cells[i][8], [c], veps)
            caps.append((below, c, run))
    return caps


def _cap_runs(cells: list, run: list[int], below: bool, c: float, veps: float) -> list[list[int]]:
    """The stretches (two cells or more) of a pole cap's run whose cut nearest the pole is still c:
    ``_align_rungs`` may have cut a cell between c and the pole since, and that cell stays whole."""
    out: list[list[int]] = [[]]
    for i in run:
        cuts = cells[i][8]
        nearest = (min(cuts) if below else max(cuts)) if cuts else None
        if nearest is not None and abs(nearest - c) <= veps:
            out[-1].append(i)
        elif out[-1]:
            out.append([])
    return [m for m in out if len(m) >= 2]


def _cap_cell(cells: list, members: list[int], below: bool, c: float):
    """The cap of ``members`` (see ``_pole_caps``): (ua, ub, bottom, top), its side at the pole the
    pole's piece from the first cell's rung to the last's, its other side the v-iso line c."""
    first, last = cells[members[0]], cells[members[-1]]
    ua, ub = first[0], last[1]
    k = 2 if below else 3
    a, b = first[k], last[k]
    v = float(a.H[0, 1] / a.H[0, 2])
    pole = Side(np.array([[a.H[0, 0] / a.H[0, 2], v, 1.0], [b.H[-1, 0] / b.H[-1, 2], v, 1.0]]), True,
                a.edge, a.w0, b.w1, True, a.pcurve)
    across = _iso_side(_rung_u(*first[4], c), _rung_u(*last[5], c), c)
    return (ua, ub, pole, across) if below else (ua, ub, across, pole)


def _cut_points(cell: list, slant: dict[float, float] | None) -> list[tuple[int, float]]:
    """(slab line, v) of every end of the cell's cuts: a slanted cut ends at other v on its right."""
    slant = slant or {}
    return [pt for c in cell[8] for pt in ((cell[9], c), (cell[10], slant.get(c, c)))]


def _slab_pairs(pieces: list[_Piece], spans: list[tuple[int, int]], lines: np.ndarray,
                through: set[tuple[int, int]], face: Face):
    """The pieces cut at the slab lines they cross, and the cells between them.

    Each piece is cut at every line strictly between its first and last (``spans``), except at the
    (piece, line) pairs in ``through``. Returns (parts, pairs): parts as (piece index, first line,
    last line, piece), pairs as (first line, last line, bottom part, top part), one per cell, found
    slab by slab by sorting the parts over the slab by v (even-odd rule). A cell spans several slabs
    where its bottom and top both run through the lines between. None when that does not hold:
    two parts paired over one slab that do not span the same lines (``through`` was not taken by
    both pieces of a cell)."""
    parts: list[tuple[int, int, int, _Piece]] = []
    for n, (p, (i, j)) in enumerate(zip(pieces, spans, strict=True)):
        rest, a = p, i
        for k in range(i + 1, j):
            if (n, k) in through:
                continue
            left, rest = _split(rest, _t_at_u(rest.H, float(lines[k])))
            parts.append((n, a, k, left))
            a = k
        parts.append((n, a, j, rest))
    active: list[list[int]] = [[] for _ in range(len(lines) - 1)]
    for x, (_, a, b, _) in enumerate(parts):
        for s in range(a, b):
            active[s].append(x)
    pairs: list[tuple[int, int, int, int]] = []
    top_of: dict[int, int] = {}
    for s, act in enumerate(active):
        if not act:
            continue
        um = 0.5 * (float(lines[s]) + float(lines[s + 1]))
        if len(act) % 2:
            raise UntrimError(
                f"face {face.index}: the trimming loops do not close in the parameter domain "
                f"({len(act)} crossings of u = {um:.6g})"
            )
        vs = [float(_eval(parts[x][3].H, _t_at_u(parts[x][3].H, um))[0, 1]) for x in act]
        order = np.argsort(vs, kind="stable")
        for k in range(0, len(act), 2):
            x, y = act[order[k]], act[order[k + 1]]
            if parts[x][1] == s and parts[y][1] == s and parts[x][2] == parts[y][2]:
                pairs.append((s, parts[x][2], x, y))
                top_of[x] = y
            elif top_of.get(x) != y or parts[x][1] == s:
                return None
    return parts, pairs


def _through_lines(parts, pairs, lines: np.ndarray, knots: set[float], ends_on: dict[int, list[float]],
                   veps: float) -> set[tuple[int, int]]:
    """(piece, slab line) pairs at which a piece need not be cut: where the cells on both sides of
    the line lie between the same two pieces and no piece end (a vertex, a plan parameter, an
    extremum, an iso piece) lies on the line between them, the two cells are one region, and the
    line, which some other piece's end put there, only cut it.

    Joined, they make one cell. Cut, they made slab-wide strips wherever the ends of two pcurves
    of a face fall close in u (bspline_boolean's face with a hole: the edge plan's parameters on
    the hole's upper and lower halves cut the whole face, 156 of its 546 patches more than 1000
    times longer than wide), and each cut put a corner on the edges above and below, a T-vertex on
    their neighbours. Knot lines cut every cell (a patch lies in one span)."""
    start = {(a, parts[x][0]): (b, x, y) for a, b, x, y in pairs}
    through: set[tuple[int, int]] = set()
    for _, k, x, y in pairs:
        nxt = start.get((k, parts[x][0]))
        if nxt is None or float(lines[k]) in knots or parts[nxt[2]][0] != parts[y][0]:
            continue
        vb = float(parts[x][3].H[-1, 1] / parts[x][3].H[-1, 2])
        vt = float(parts[y][3].H[-1, 1] / parts[y][3].H[-1, 2])
        lo, hi = min(vb, vt) - veps, max(vb, vt) + veps
        if any(lo <= v <= hi for v in ends_on.get(k, ())):
            continue
        through.update(((parts[x][0], k), (parts[y][0], k)))
    return through


# where _uncross looks for a crossing: evenly, and geometrically closer to either end (the
# inverted strip of fusee face 110 is 1/170 of its cell)
_TIP_GRID = np.unique(np.concatenate([np.linspace(0.0, 1.0, 33), 2.0 ** -np.arange(6, 41),
                                      1.0 - 2.0 ** -np.arange(6, 41)]))


def _t_at_us(H: np.ndarray, us: np.ndarray) -> np.ndarray:
    """``_t_at_u`` at many u at once, by bisection on all of them together (the piece is monotone
    in u and spans every u asked): 56 halvings leave t within 1.4e-17."""
    k = H.shape[0] - 1
    lo, hi = np.zeros(len(us)), np.ones(len(us))
    rising = H[-1, 0] / H[-1, 2] >= H[0, 0] / H[0, 2]
    for _ in range(56):
        mid = 0.5 * (lo + hi)
        h = basis(k, mid) @ H
        below = (h[:, 0] - us * h[:, 2] < 0) == rising  # u(mid) < u (W > 0)
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def _v_at_us(H: np.ndarray, us: np.ndarray) -> np.ndarray:
    return _eval(H, _t_at_us(H, us))[:, 1]


def _uncross(bot: _Piece, top: _Piece, g: _FaceGeometry) -> tuple[_Piece, _Piece] | None:
    """A cell's bottom and top (both running with u increasing) that meet at one end of the slab
    (a tangential corner) but cross just before it: the trimming loop turns inside out over a strip
    thinner than a sliver. fusee face 110: two pcurves meet at a vertex, 2.1e-5 in u after crossing,
    and top runs up to 3.4e-9 in v (2.4e-7 in 3D) below bottom in between; the cell, judged thin
    as a whole, was dropped and left three free edges. The sides are cut where they cross, so the
    cell ends in a collapsed rung there and the inverted strip is no part of the face. None when
    the sides do not cross so (no tip, no crossing, or an inverted strip wider than a sliver)."""
    bu = bot.H[[0, -1], 0] / bot.H[[0, -1], 2]
    tu = top.H[[0, -1], 0] / top.H[[0, -1], 2]
    lo, hi = max(bu[0], tu[0]), min(bu[1], tu[1])
    if not hi > lo:
        return None
    # the sides' v at both ends of the common span: piece ends where they are there (nearly
    # always: the pieces are cut at the slab lines), else found on the piece
    ends = np.empty((2, 2))
    for r, (p, pu) in enumerate(((bot, bu), (top, tu))):
        for c, (u, i) in enumerate(((lo, 0), (hi, -1))):
            ends[r, c] = (p.H[i, 1] / p.H[i, 2] if pu[i] == u
                          else float(_eval(p.H, _t_at_u(p.H, float(u)))[0, 1]))
    tips = np.abs(ends[1] - ends[0]) * g.sv <= g.sliver  # (at lo, at hi)
    if not tips.any():
        return None  # the sides meet at neither end: nothing to look for (almost every cell)
    us = lo + (hi - lo) * _TIP_GRID
    d = _v_at_us(top.H, us) - _v_at_us(bot.H, us)
    # round-off of the two sides' v at one u (near the tip)
    zero = 1e-13 * (1.0 + float(np.abs(bot.H[:, 1] / bot.H[:, 2]).max()))
    for tip_at_hi in (True, False):
        if not tips[1 if tip_at_hi else 0]:
            continue
        dd, uu = (d, us) if tip_at_hi else (d[::-1], us[::-1])  # from the open end to the tip
        neg = dd < -zero
        if not neg.any():
            continue
        k = int(np.argmax(neg))
        if (k == 0 or not (dd[:k] >= -zero).all() or dd[k - 1] <= 0 or (dd[k:] > zero).any()
                or -dd.min() * g.sv > g.sliver):
            continue

        def gap(u: float) -> float:
            return float(_v_at_us(top.H, np.array([u]))[0] - _v_at_us(bot.H, np.array([u]))[0])

        a, b = sorted((float(uu[k - 1]), float(uu[k])))
        ux = float(brentq(gap, a, b, xtol=1e-15, rtol=1e-15))
        cut = [_split(q, _t_at_u(q.H, ux)) for q in (bot, top)]
        return (cut[0][0], cut[1][0]) if tip_at_hi else (cut[0][1], cut[1][1])
    return None


def _tail(whole: _Piece, kept: _Piece) -> tuple[int, float, float]:
    """(edge, w at the crossing, w at the tip) of a piece that ``_uncross`` cut to ``kept``."""
    tip_at_hi = kept.H[-1, 0] / kept.H[-1, 2] < whole.H[-1, 0] / whole.H[-1, 2]
    return (whole.edge, kept.w1, whole.w1) if tip_at_hi else (whole.edge, kept.w0, whole.w0)


def _u_speeds(H: np.ndarray) -> tuple[float, float]:
    """|du/ds| of a piece (homogeneous [X, Y, W], oriented with u increasing) at s = 0 and s = 1."""
    k = H.shape[0] - 1
    if k < 1:
        return 0.0, 0.0
    (x0, _, w0), (x1, _, w1) = H[0], H[1]
    (y0, _, v0), (y1, _, v1) = H[-1], H[-2]
    return abs(k * (x1 * w0 - x0 * w1) / w0**2), abs(k * (y0 * v1 - y1 * v0) / v0**2)


def _tangent_rung_cuts(cells: list, veps: float, slants: dict[int, dict[float, float]] | None = None) -> None:
    """Cut a cell without cuts along a v-iso line where its bottom and top both leave one of its
    rungs tangent to it (their u-speed there under ``_TANGENT_RUNG`` x the slab's width over their
    parameter): the cell map (1 - t) B(s) + t T(s) then has S_s along the rung all the way up it,
    and the patch's Jacobian vanishes on that whole side. OCCT's mesher leaves such a face
    without a triangulation (gmsh__Block.stp face 410, a plane with two round holes whose lowest
    points lie on one slab line: the cell between them, 0.0098 wide and 16 long, six times over).
    Each half has the straight cut as its other side and a Jacobian that vanishes at one corner
    only. The cut goes where a neighbouring cell on that slab line already has one (no new
    T-vertex there), else half way between the pieces; a cell whose pieces overlap in v has no
    line between them and stays as it is."""
    by_line: dict[int, list[float]] = {}
    for i, cell in enumerate(cells):
        for line, v in _cut_points(cell, (slants or {}).get(i)):
            by_line.setdefault(line, []).append(v)
    for cell in cells:
        ua, ub, bside, tside, _, _, bmax, tmin, knots, j, jr = cell
        if knots or tmin - bmax <= 4.0 * veps or ub <= ua:
            continue
        width = ub - ua
        sb, st = _u_speeds(bside.H), _u_speeds(tside.H)
        for k in (0, 1):
            if max(sb[k], st[k]) > _TANGENT_RUNG * width:
                continue
            lo, hi, mid = bmax + veps, tmin - veps, 0.5 * (bmax + tmin)
            near = [v for v in by_line.get((j, jr)[k], ()) if lo < v < hi]
            c = min(near, key=lambda v: abs(v - mid)) if near else mid
            knots.append(c)
            for line in (j, jr):
                by_line.setdefault(line, []).append(c)
            break


def _align_rungs(cells: list, ends: list[tuple[int, float]], veps: float,
                 slants: dict[int, dict[float, float]] | None = None) -> None:
    """Cut cells along v-iso lines (where the line stays between the cell's bottom and top) so
    that stage 2 can make the patch sides along each slab line meet:

    - at every point of ``ends`` (slab line index, v) strictly inside one of the cell's rungs
      within _NEAR_END of its end (measured on the whole rung: measured on the pieces between
      the cell's cuts, points beside knot lines spread thin strips across whole faces, and
      occt__trj8_k1-db-214.stp went from 7413 to 11991 patches);
    - where a rung piece and a piece on the other side of the line overlap with neither holding
      the other (fusee faces 93 and 165: the cuts at a boundary edge's plan points met a thin
      slab's rungs out of step, and stage 2 shares a side only with a side that holds it), at the
      other piece's end inside this one.

    A cut puts a new point on the cell's other rung, which may call for a cut of the cell beside it
    in turn: the cuts spread from cell to cell until none is needed. Points are matched to rungs by
    their slab line, not by their u: a slab narrower than the lines' clustering distance would
    otherwise lend its corners to the rungs of the line beside it. ``cells`` holds [ua, ub, bottom,
    top, left rung, right rung, highest bottom v, lowest top v, cuts, left slab line, right slab
    line]. ``slants``: per cell index, its slanted cuts ({v on the left rung: v on the right rung}, see
    ``_slanted_cuts``); a new cut that falls between the two ends of one makes it two v-iso cuts."""
    slants = {} if slants is None else slants
    on_line: dict[int, list[int]] = {}
    for i, cell in enumerate(cells):
        for line in (cell[9], cell[10]):
            on_line.setdefault(line, []).append(i)
    pending = ends
    for _ in range(4 * len(cells) + 1):
        by_line: dict[int, list[float]] = {}
        for line, v in pending:
            by_line.setdefault(line, []).append(v)
        # only the cells on a line that has new points can need a cut (the first round: all)
        todo = sorted({i for line in by_line for i in on_line.get(line, ())})
        # their rung pieces on those lines, per (line, side of the line the cell lies on: 1 right)
        subs = []
        pieces: dict[tuple[int, int], list[tuple[float, float]]] = {}
        for i in todo:
            left, right, _, _, cuts, j, jr = cells[i][4:]
            slant = slants.get(i, {})
            sub = []
            for line, side, (b, t) in ((j, 1, left), (jr, 0, right)):
                lo, hi = min(b[1], t[1]), max(b[1], t[1])
                if line not in by_line or hi - lo <= veps:
                    continue
                on = cuts if side == 1 else sorted(slant.get(c, c) for c in cuts)
                pts = [lo] + [c for c in on if lo + veps < c < hi - veps] + [hi]
                sub.append((line, side, pts))
                pieces.setdefault((line, side), []).extend(zip(pts[:-1], pts[1:], strict=True))
            subs.append(sub)
        index = {}
        for key, ps in pieces.items():
            ps.sort()
            index[key] = (np.array([p for p, _ in ps]), np.array([q for _, q in ps]))
        pending = []
        for i, sub in zip(todo, subs, strict=True):
            cell = cells[i]
            extra = []
            for line, side, pts in sub:
                lo, hi = pts[0], pts[-1]
                extra.extend(v for v in by_line[line] if lo + veps < v < hi - veps
                             and min(v - lo, hi - v) < _NEAR_END * (hi - lo))
                if (line, 1 - side) not in index:
                    continue
                starts, stops = index[(line, 1 - side)]
                for p, q in zip(pts[:-1], pts[1:], strict=True):
                    for e in (p, q):
                        # the other side's piece that holds this end strictly inside
                        k = int(np.searchsorted(starts, e - veps)) - 1
                        if k < 0 or not (starts[k] < e - veps and stops[k] > e + veps):
                            continue
                        x = stops[k] if e == p else starts[k]  # its end on this piece's side
                        if min(p, q) + veps < x < max(p, q) - veps:
                            extra.append(float(x))
            bmax, tmin, knots = cell[6], cell[7], cell[8]
            extra = [v for v in extra if bmax + veps < v < tmin - veps]
            slant = slants.get(i, {})
            for vl, vr in list(slant.items()):
                if any(min(vl, vr) - veps <= v <= max(vl, vr) + veps for v in extra):
                    del slant[vl]  # the new cut would cross it: two v-iso cuts again
                    extra.append(vr)
                    pending.extend(((cell[10], vl), (cell[9], vr)))
            if extra:
                cuts = _merge_cuts(knots, extra, veps)
                pending.extend((line, c) for c in set(cuts) - set(knots) for line in (cell[9], cell[10]))
                cell[8] = cuts
        if not pending:
            return


def _merge_cuts(knots: list[float], extra: list[float], veps: float) -> list[float]:
    """The sorted cuts ``knots`` + ``extra``; values closer than ``veps`` merge (a knot line wins)."""
    out: list[float] = []
    for v in sorted(set(knots) | set(extra)):
        if out and v - out[-1] <= veps:
            if v in knots and out[-1] not in knots:
                out[-1] = v
            continue
        out.append(v)
    return out


def _vertex_cuts(knots: list[float], ends: np.ndarray, left, right, bmin: float, tmax: float,
                 ueps: float, veps: float, rungs: dict[float, set[int]] | None = None) -> list[float]:
    """A cell's knot lines plus the v of every vertex in ``ends`` that lies on one of its rungs
    strictly inside it; values closer than ``veps`` merge (a knot line wins). ``rungs`` (if given)
    receives, per vertex v, the rungs it lies on (0 left, 1 right)."""
    if len(ends) == 0:
        return knots
    extra = []
    for k, (b, t) in enumerate((left, right)):
        if abs(b[0] - t[0]) > 2 * ueps:
            continue
        lo, hi = min(b[1], t[1]), max(b[1], t[1])
        v = ends[:, 1]
        on = (np.abs(ends[:, 0] - b[0]) <= 2 * ueps) & (v > lo + veps) & (v < hi - veps)
        for x in v[on]:
            if bmin + veps < x < tmax - veps:
                extra.append(float(x))
                if rungs is not None:
                    rungs.setdefault(float(x), set()).add(k)
    return _merge_cuts(knots, extra, veps) if extra else knots


def _slanted_cuts(cuts: list[float], knots: set[float], rungs: dict[float, set[int]], face: Face, left,
                  right, g: _FaceGeometry) -> tuple[list[float], dict[float, float]]:
    """Two neighbouring cuts of a cell, one at a vertex on its left rung only and one at a vertex on
    its right rung only, that stand closer than ``Tolerances.thin_rel`` (in 3D, on both rungs) become
    one straight cut from the one to the other: as two v-iso lines they bounded a band below the
    tolerance across the cell (ec_turbine face 13: its two sides, edges whose neighbours cut them
    2e-6 apart in v, gave eight bands 1 wide). Returns the cuts (each by its v on the left rung)
    and {left v: right v} for the slanted ones."""
    out: list[float] = []
    slant: dict[float, float] = {}
    cs = sorted(cuts)
    i = 0
    while i < len(cs):
        x = cs[i]
        if i + 1 < len(cs):
            y = cs[i + 1]
            rx, ry = rungs.get(x, set()), rungs.get(y, set())
            if x not in knots and y not in knots and len(rx) == 1 and len(ry) == 1 and rx != ry:
                vl, vr = (x, y) if rx == {0} else (y, x)
                pts = face.surface.evaluate(np.array([[_rung_u(*left, x), x], [_rung_u(*left, y), y],
                                                      [_rung_u(*right, x), x], [_rung_u(*right, y), y]]))
                if (np.linalg.norm(pts[0] - pts[1]) <= g.thin and np.linalg.norm(pts[2] - pts[3]) <= g.thin):
                    out.append(vl)
                    slant[vl] = vr
                    i += 2
                    continue
        out.append(x)
        i += 1
    return out, slant


def _sliver_cuts_dropped(cuts: list[float], knots: set[float], plan_only: set[float], face: Face, left,
                         right, g: _FaceGeometry) -> list[float]:
    """A cell's cuts without those at an edge plan's parameter (``plan_only``: not at a vertex of
    the face) that stand within a sliver (``Tolerances.sliver_rel``, in 3D) of a knot line, or of
    a cut kept before them, on both rungs: the cell between two such straight lines would be a
    sliver all along. Only cuts farther than the distance at which stage 2 makes corners one
    (``topology.MERGE_REL``) somewhere: thinner cells are dropped as flat, their corners joined,
    and dropping their cuts as well left U_Joint_2 with 8 free edges (as did dropping cuts at a
    vertex: a T-vertex a hair from the corner beside it). The knot line
    must stay (a patch spans no knot); the vertex's corner then lies on it, and stage 2 puts that
    corner at the plan's parameter (``substitute._snap_params``). The test in uv (``veps``, from
    the surface's largest speed) misses this where the surface is slow: U_Joint_2 face 103 had a
    cell 2.8e-8 high in v beside a knot line, 6.5e-7 wide in 3D at most, which stage 2 could only
    keep as a triangle (a plan cut from the neighbouring face, whose pcurve puts that parameter a
    hair off this face's knot)."""
    if not knots:
        return cuts
    span = float(max(np.ptp([p[1] for p in (*left, *right)]), 1e-300))
    # only cuts this close in v to a knot line can be a sliver from it (a cheap first test)
    near = [c for c in sorted(cuts)
            if c in plan_only and c not in knots and min(abs(c - k) for k in knots) <= 1e-3 * span]
    if not near:
        return cuts

    def points(c: float) -> np.ndarray:
        return face.surface.evaluate(np.array([[_rung_u(*left, c), c], [_rung_u(*right, c), c]]))

    from .topology import MERGE_REL

    merge = MERGE_REL * g.diagonal
    lines = [points(c) for c in knots]
    dropped = set()
    for c in near:
        x = points(c)
        d = [np.linalg.norm(x - y, axis=1) for y in lines]
        if any(np.all(e <= g.sliver) and np.any(e > merge) for e in d):
            dropped.add(c)
        else:
            lines.append(x)
    return [c for c in cuts if c not in dropped]


def _knot_cuts_dropped(cuts: list[float], knot_only: set[float], face: Face, left, right,
                       g: _FaceGeometry) -> list[float]:
    """A cell's cuts without those at an end of a rung piece that is a knot of the face's pcurve
    but no parameter of the edge's plan (``knot_only``), where it stands within a sliver (in 3D,
    on both rungs) of the cut beside it. The edge's plan keeps one of two parameters that close
    (``_thin_plan``; on trj8 the two faces' pcurve knots for one point, a hair apart in parameter
    after one pcurve was re-timed), but the pcurve is still cut at its own knot; cut across the cell there
    too, the band between the two lines was a sliver all along, and stage 2 made needles of it
    that a tessellation welded at a sliver collapses (occt__trj8_k1-db-214.stp faces 44, 54 and
    55: bands 1.6e-7 to 1.3e-6 wide, 0.006 to 0.19 long). Without the cut, the rung runs over the
    two pieces of its edge that meet there (``substitute.IsoPieces.pair``), and the neighbour,
    which has no vertex there, pairs with it. Only where the band is wider than
    ``topology.MERGE_REL`` somewhere, as ``_sliver_cuts_dropped``: a thinner one is dropped as
    flat later and its corners joined."""
    near = [c for c in cuts if c in knot_only]
    if not near or len(cuts) < 2:
        return cuts
    from .topology import MERGE_REL

    merge = MERGE_REL * g.diagonal
    cs = sorted(cuts)
    uv = np.array([[_rung_u(*side, c), c] for c in cs for side in (left, right)])
    pts = face.surface.evaluate(uv).reshape(len(cs), 2, 3)
    dropped: set[int] = set()
    for i, c in enumerate(cs):
        if c not in knot_only:
            continue
        for j in (i - 1, i + 1):
            if 0 <= j < len(cs) and j not in dropped:
                e = np.linalg.norm(pts[i] - pts[j], axis=1)
                if np.all(e <= g.sliver) and np.any(e > merge):
                    dropped.add(i)
                    break
    return [c for i, c in enumerate(cs) if i not in dropped]


def _rung_u(b: np.ndarray, t: np.ndarray, c: float) -> float:
    """u where the rung from b to t (uv points) crosses v = c."""
    dv = t[1] - b[1]
    if dv == 0:
        return float(b[0])
    return float(b[0] + (t[0] - b[0]) * np.clip((c - b[1]) / dv, 0.0, 1.0))


def _nearest(lines: np.ndarray, x: float) -> int:
    k = int(np.clip(np.searchsorted(lines, x), 1, len(lines) - 1))
    return k - 1 if x - lines[k - 1] <= lines[k] - x else k


# ------------------------------------------------------------------------------------------ the maps


def _localize(H: np.ndarray, u0: float, du: float, v0: float, dv: float) -> np.ndarray:
    out = H.copy()
    out[:, 0] = (H[:, 0] - u0 * H[:, 2]) / du
    out[:, 1] = (H[:, 1] - v0 * H[:, 2]) / dv
    return out


def _polynomial(H: np.ndarray) -> bool:
    return bool(np.all(H[:, 2] == 1.0))


def _map_grids(B: np.ndarray, T: np.ndarray):
    """(U, V, W|None) Bernstein grids (k+1, 2) of phi(s, t) = (1 - t) B(s) + t T(s)."""
    if _polynomial(B) and _polynomial(T):
        k = max(B.shape[0], T.shape[0]) - 1
        Be = elevate_curve(B[:, :2], k - (B.shape[0] - 1))
        Te = elevate_curve(T[:, :2], k - (T.shape[0] - 1))
        return np.stack([Be[:, 0], Te[:, 0]], 1), np.stack([Be[:, 1], Te[:, 1]], 1), None
    # (1-t) XB/WB + t XT/WT = [(1-t) XB WT + t XT WB] / (WB WT)
    XB = product(B[:, :2], T[:, 2])
    XT = product(T[:, :2], B[:, 2])
    W = product(B[:, 2], T[:, 2])
    return (np.stack([XB[:, 0], XT[:, 0]], 1), np.stack([XB[:, 1], XT[:, 1]], 1), np.stack([W, W], 1))


_JAC_GRID = np.concatenate([[0.005, 0.02, 0.05], np.linspace(0.1, 0.9, 9), [0.95, 0.98, 0.995]])


def _phi_jacobian(U, V, W) -> np.ndarray:
    """det d(u, v)/d(s, t) of the map on an interior grid, denser towards the sides (where a side
    that turns near its end folds a thin cell)."""
    s = _JAC_GRID
    n = len(s)
    a = U.shape[0] - 1
    Bs, Bt = basis(a, s), basis(1, s)
    dBs = a * (basis(a - 1, s) @ (np.eye(a + 1)[1:] - np.eye(a + 1)[:-1])) if a > 0 else np.zeros((n, 1))
    dBt = np.stack([-np.ones(n), np.ones(n)], 1)

    def ev(G, bs, bt):
        return bs @ G @ bt.T

    if W is None:
        us, ut = ev(U, dBs, Bt), ev(U, Bs, dBt)
        vs, vt = ev(V, dBs, Bt), ev(V, Bs, dBt)
        return us * vt - ut * vs
    w, ws, wt = ev(W, Bs, Bt), ev(W, dBs, Bt), ev(W, Bs, dBt)
    x, xs, xt = ev(U, Bs, Bt), ev(U, dBs, Bt), ev(U, Bs, dBt)
    y, ys, yt = ev(V, Bs, Bt), ev(V, dBs, Bt), ev(V, Bs, dBt)
    us, ut = (xs * w - x * ws) / w**2, (xt * w - x * wt) / w**2
    vs, vt = (ys * w - y * ws) / w**2, (yt * w - y * wt) / w**2
    return us * vt - ut * vs


def _own_parameter(side: Side) -> bool:
    """An edge side whose parameter is not affine in u (its u control values are not evenly spaced),
    so a sub-box (u linear in s) would not carry the edge's parameter."""
    if side.edge is None:
        return False
    H = side.H
    u = H[:, 0] / H[:, 2]
    k = len(u) - 1
    even = u[0] + (u[-1] - u[0]) * np.arange(k + 1) / max(k, 1)
    atol = 1e-12 * max(abs(u[-1] - u[0]), 1e-300)
    return not (_polynomial(H) and np.allclose(u, even, rtol=0.0, atol=atol))


def _split_side(side: Side, u: float) -> tuple[Side, Side]:
    if side.iso and side.edge is None:
        a, b, c = side.H[0, 0], side.H[-1, 0], side.H[0, 1]
        return _iso_side(a, u, c), _iso_side(u, b, c)
    t = _t_at_u(side.H, u)
    w = side.w0 + t * (side.w1 - side.w0)
    return (
        Side(curve_segment(side.H, 0.0, t), side.iso, side.edge, side.w0, w, side.degenerate, side.pcurve),
        Side(curve_segment(side.H, t, 1.0), side.iso, side.edge, w, side.w1, side.degenerate, side.pcurve),
    )


def _heights(ua: float, ubb: float, bot: Side, top: Side):
    """The cell's height v_top - v_bottom at 9 u's across it, one at a time (callers stop early)."""
    for u in np.linspace(ua, ubb, 9):
        yield _eval(top.H, _t_at_u(top.H, float(u)))[0, 1] - _eval(bot.H, _t_at_u(bot.H, float(u)))[0, 1]


class _FaceContext:
    def __init__(self, face: Face, g: _FaceGeometry, tol: float, max_degree: int):
        self.face = face
        self.rational = g.rational
        self.ub, self.vb, self.spans = g.ub, g.vb, g.spans
        self.m, self.n = g.m, g.n
        self.g = g
        self.tol = tol
        self.max_degree = max_degree

    def span_of(self, u: float, v: float) -> tuple[int, int]:
        i = int(np.clip(np.searchsorted(self.ub, u, side="right") - 1, 0, len(self.ub) - 2))
        j = int(np.clip(np.searchsorted(self.vb, v, side="right") - 1, 0, len(self.vb) - 2))
        return i, j

    def cell_patches(self, ua: float, ubb: float, bot: Side, top: Side, fr: FaceResult, depth: int = 0):
        um = 0.5 * (ua + ubb)
        vm = 0.5 * (_eval(bot.H, _t_at_u(bot.H, um))[0, 1] + _eval(top.H, _t_at_u(top.H, um))[0, 1])
        i, j = self.span_of(um, vm)
        U0, du = self.ub[i], self.ub[i + 1] - self.ub[i]
        V0, dv = self.vb[j], self.vb[j + 1] - self.vb[j]
        P = self.spans[i, j]
        if bot.iso and top.iso:
            own_b, own_t = _own_parameter(bot), _own_parameter(top)
            ends_b = bot.H[[0, -1], 0] / bot.H[[0, -1], 2]
            ends_t = top.H[[0, -1], 0] / top.H[[0, -1], 2]
            # a box needs both sides over the same u-range; after sliver merging a side may end
            # a little off the slab line, and then the ruled map below joins the true ends
            # (np.allclose with rtol 0, without its 90 us a call)
            same = bool(np.all(np.abs(ends_b - ends_t) <= 1e-12 * (self.ub[-1] - self.ub[0])))
            if not (own_b or own_t) and same:
                c0, c1 = bot.H[0, 1] / bot.H[0, 2], top.H[0, 1] / top.H[0, 2]
                (a0, a1) = ends_b
                ctrl = surface_subbox(P, (a0 - U0) / du, (a1 - U0) / du, (c0 - V0) / dv, (c1 - V0) / dv)
                return [Patch(self.face.index, ctrl, self.rational, bot, top, box=True)]
            if own_b != own_t:
                out = self._follow(bot if own_b else top, bot, top, P, (U0, du, V0, dv))
                if out is not None:
                    return [out]
        B = _localize(bot.H, U0, du, V0, dv)
        T = _localize(top.H, U0, du, V0, dv)
        U, V, W = _map_grids(B, T)
        k = U.shape[0] - 1
        ds, dt = (self.m + self.n) * k, self.m + self.n
        if max(ds, dt) > self.max_degree:
            return self._approximate(ua, ubb, bot, top, P, (U0, du, V0, dv), fr, depth)
        det = _phi_jacobian(U, V, W)
        if not np.all(det > 0):
            if self._thin(ua, ubb, bot, top):
                fr.slivers += 1  # thinner than a sliver all along (a tangential corner): dropped
                return []
            if depth >= _MAX_FOLD_DEPTH:
                out = self._unfold(bot, top, P, (U0, du, V0, dv))
                if out is not None:
                    return [out]
                fr.folds += 1
                fr.problems.append(f"a folded cell near u = {um:.6g}, v = {vm:.6g} could not be split away")
            else:
                return self._halve(ua, ubb, bot, top, fr, depth)
        ctrl, rational = self._compose(P, U, V, W)
        return [Patch(self.face.index, ctrl, rational, bot, top)]

    def _compose(self, P, U, V, W) -> tuple[np.ndarray, bool]:
        """S o phi for the span net P: polynomial map (W None) or rational map (U/W, V/W), which makes
        even a polynomial surface's patch rational."""
        if W is None:
            return compose(P, U, V), self.rational
        Ph = P if self.rational else np.concatenate([P, np.ones(P.shape[:2] + (1,))], axis=-1)
        return compose(Ph, U, V, W=W), True

    def _unfold(self, bot: Side, top: Side, P, frame) -> Patch | None:
        """A cell that stays folded after the deepest split (its sides turn against each other near
        a rung, typical of a wiggly near-iso pcurve): the lowest-degree replacement of the sides
        that unfolds it within the tolerance, as an approximated patch. None when there is none."""
        U0, du, V0, dv = frame
        B = _localize(bot.H, U0, du, V0, dv)
        T = _localize(top.H, U0, du, V0, dv)
        speeds = _lipschitz(P, self.rational)
        for q in range(1, 4):
            if (self.m + self.n) * q > self.max_degree:
                return None
            sides, bound, est = _reduce_sides((B, T), q, speeds)
            if bound > self.tol:
                return None
            U, V, W = _map_grids(*sides)
            if np.all(_phi_jacobian(U, V, W) > 0):
                ctrl, rational = self._compose(P, U, V, W)
                return Patch(self.face.index, ctrl, rational, bot, top, bound, est, True)
        return None

    def _thin(self, ua: float, ubb: float, bot: Side, top: Side) -> bool:
        """Bottom and top closer than a sliver (in 3D, through the surface's v-speed) at every u."""
        return all(abs(h) * self.g.sv <= self.g.sliver for h in _heights(ua, ubb, bot, top))

    def _inverted(self, ua: float, ubb: float, bot: Side, top: Side) -> bool:
        """The top below the bottom (in v) at every u of the cell's samples."""
        return all(h < 0.0 for h in _heights(ua, ubb, bot, top))

    def _follow(self, E: Side, bot: Side, top: Side, P, frame) -> Patch | None:
        """A cell between two v-iso lines where one side is an edge whose parameter is not affine in
        u: phi(s, t) = ((1 - t) u_B(s) + t u_T(s), (1 - t) c0 + t c1), where the edge side keeps its
        own parameter and the other side runs linearly in u, as a sub-box's side does. Neighbours
        across that other side (boxes, or cells following another edge) then meet it at the same
        parameter, so stage 2 can share it exactly. u_s > 0 and v_t > 0 everywhere: no fold.
        Bidegree (m k, m + n), against (m + n) k for the general ruled map; None over the budget."""
        U0, du, V0, dv = frame
        k = E.H.shape[0] - 1
        if not _polynomial(E.H) or max(self.m * k, self.m + self.n) > self.max_degree:
            return None
        c0, c1 = bot.H[0, 1] / bot.H[0, 2], top.H[0, 1] / top.H[0, 2]
        other = top if E is bot else bot
        lin = np.linspace(other.H[0, 0] / other.H[0, 2], other.H[-1, 0] / other.H[-1, 2], k + 1)
        ue, ul = (E.H[:, 0] - U0) / du, (lin - U0) / du
        U = np.stack([ue, ul] if E is bot else [ul, ue], 1)
        ctrl = compose(P, U, np.array([[(c0 - V0) / dv, (c1 - V0) / dv]]))
        line = Side(np.array([[other.H[0, 0] / other.H[0, 2], other.H[0, 1] / other.H[0, 2], 1.0],
                              [other.H[-1, 0] / other.H[-1, 2], other.H[-1, 1] / other.H[-1, 2], 1.0]]),
                    True, other.edge, other.w0, other.w1, other.degenerate, other.pcurve)
        return Patch(self.face.index, ctrl, self.rational, E if E is bot else line, E if E is top else line)

    def _halve(self, ua, ubb, bot, top, fr, depth):
        um = 0.5 * (ua + ubb)
        b0, b1 = _split_side(bot, um)
        t0, t1 = _split_side(top, um)
        fr.local_cuts += (bot.edge is not None) + (top.edge is not None)
        left = self.cell_patches(ua, um, b0, t0, fr, depth + 1)
        return left + self.cell_patches(um, ubb, b1, t1, fr, depth + 1)

    def _approximate(self, ua, ubb, bot: Side, top: Side, P, frame, fr: FaceResult, depth: int):
        """Over the degree budget: reduce the surface on the cell's box and the sides' degrees; halve
        the cell while the certified bound exceeds the tolerance."""
        U0, du, V0, dv = frame
        B = _localize(bot.H, U0, du, V0, dv)
        T = _localize(top.H, U0, du, V0, dv)
        pts = np.concatenate([B[:, :2] / B[:, 2:3], T[:, :2] / T[:, 2:3]])
        (a0, b0), (a1, b1) = pts.min(axis=0), pts.max(axis=0)
        if not (a1 > a0 and b1 > b0):
            return []  # a cell without area
        Q = surface_subbox(P, a0, a1, b0, b1)
        Bq = _localize(B, a0, a1 - a0, b0, b1 - b0)
        Tq = _localize(T, a0, a1 - a0, b0, b1 - b0)
        budget = 0.5 * self.tol
        Qr, mr, nr, serr, est = self._reduce_surface(Q, budget * 0.5)
        q = max(1, self.max_degree // (mr + nr))
        sides, perr, pest = _reduce_sides((Bq, Tq), q, _lipschitz(Qr, self.rational))
        total = serr + perr
        if total > self.tol or mr + nr > self.max_degree:
            if depth >= _MAX_SPLIT_DEPTH:
                fr.problems.append(
                    f"cell near u = {0.5 * (ua + ubb):.6g} stays above the tolerance ({total:.3g}) "
                    "after the deepest split"
                )
            else:
                return self._halve(ua, ubb, bot, top, fr, depth)
        U, V, W = _map_grids(*sides)
        det = _phi_jacobian(U, V, W)
        # a cell whose top runs below its bottom all along stays so in both halves: halving it to
        # the deepest split made 2^14 inverted cells (ec_turbine face 33 with plan rung cuts, 27 s)
        inverted = bool(np.all(det < 0)) and self._inverted(ua, ubb, bot, top)
        if not np.all(det > 0) and depth < _MAX_SPLIT_DEPTH and not inverted:
            return self._halve(ua, ubb, bot, top, fr, depth)
        if not np.all(det > 0):
            fr.folds += 1
            what = "an inverted (top below bottom)" if inverted else "a folded"
            fr.problems.append(f"{what} approximated cell near u = {0.5 * (ua + ubb):.6g}")
        ctrl, rational = self._compose(Qr, U, V, W)
        return [Patch(self.face.index, ctrl, rational, bot, top, total, est or pest, True)]

    def _reduce_surface(self, Q, budget):
        """Smallest bidegree (m', n') whose reduction of Q stays within budget (polynomial surfaces;
        rational ones are kept as they are). Returns (net, m', n', bound, estimated)."""
        m, n = Q.shape[0] - 1, Q.shape[1] - 1
        if self.rational:
            return Q, m, n, 0.0, False
        best = (Q, m, n, 0.0)
        mr = m
        for mt in range(1, m):
            R, e = reduce_surface(Q, mt, n, fix_boundary=False)
            if e <= 0.5 * budget:
                best, mr = (R, mt, n, e), mt
                break
        for nt in range(1, n):
            R, e = reduce_surface(Q, mr, nt, fix_boundary=False)
            if e <= budget:
                best = (R, mr, nt, e)
                break
        R, mr, nr, e = best
        return R, mr, nr, e, False


def _true_degree(c: np.ndarray) -> int:
    """Degree of the polynomial whose Bernstein coefficients are the rows of ``c`` (d+1, k): the
    highest j whose power coefficient C(d, j) Delta^j c_0 is above rounding. All the forward
    differences at once: one product with the signed binomial matrix (``_differences``)."""
    scale = float(np.abs(c).max()) or 1.0
    above = np.flatnonzero(np.abs(_differences(c.shape[0] - 1) @ c).max(axis=1) > _COMPACT_DIFF * scale)
    return int(above[-1]) if len(above) else 0


@functools.cache
def _differences(d: int) -> np.ndarray:
    """(d+1, d+1): row j holds the coefficients of the j-th forward difference at 0, (-1)^(j-i) C(j, i)."""
    j, i = np.meshgrid(np.arange(d + 1), np.arange(d + 1), indexing="ij")
    m = np.where(i <= j, comb(j, i) * (-1.0) ** (j - i), 0.0)
    m[0] = 0.0  # the degree counts differences from the first on
    return m


def compact(ctrl: np.ndarray, rational: bool) -> np.ndarray:
    """The same patch at its true bidegree: composition writes S o phi at (m + n) k, which is more than
    the polynomial needs when S is affine in a direction (planes, the straight lines of cylinders
    and cones). The reduction is accepted only when its certified bound is at rounding level, so
    the patch does not change; lower degrees leave room for stage 2 (weights, elevation)."""
    scale = float(np.ptp((ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl).reshape(-1, 3), axis=0).max())
    wmin = float(ctrl[..., 3].min()) if rational else 1.0
    out = ctrl
    for axis in (0, 1):
        c = np.moveaxis(out, axis, 0)
        d = c.shape[0] - 1
        flat = c.reshape(d + 1, -1)
        # the estimate can be a little low (small power coefficients read as zero): try upwards
        for r in range(max(_true_degree(flat), 1), min(d, max(_true_degree(flat), 1) + 3)):
            red, bound = reduce_curve(flat, r, fix_ends=1)
            if bound <= _COMPACT_REL * scale * wmin:
                out = np.moveaxis(red.reshape((r + 1,) + c.shape[1:]), 0, axis)
                break
    return np.ascontiguousarray(out)


def _lipschitz(Q: np.ndarray, rational: bool) -> tuple[float, float]:
    """Bounds of |dS/du| and |dS/dv| over [0, 1]^2 for a Bezier net: the hodograph's convex hull,
    m max |P_i+1,j - P_ij| (and the same in v). For rational nets the factor (w_max / w_min)^2 of the
    rational derivative bound (Floater 1992) multiplies the Cartesian control-point differences."""
    if rational:
        w = Q[..., -1]
        P = Q[..., :-1] / w[..., None]
        f = (w.max() / w.min()) ** 2
    else:
        P, f = Q, 1.0
    m, n = P.shape[0] - 1, P.shape[1] - 1
    lu = m * np.max(np.linalg.norm(np.diff(P, axis=0), axis=-1)) if m else 0.0
    lv = n * np.max(np.linalg.norm(np.diff(P, axis=1), axis=-1)) if n else 0.0
    return float(f * lu), float(f * lv)


def _reduce_sides(sides, q: int, speeds: tuple[float, float]) -> tuple[list[np.ndarray], float, bool]:
    """Both sides of a cell at degree q (``_reduce_side``), with the 3D bound of the change: per axis,
    |du| x u-speed + |dv| x v-speed (a thin tall cell has a large v-speed but its sides barely move
    in v). Returns (sides, bound, estimated)."""
    lu, lv = speeds
    out, bound, est = [], 0.0, False
    for S in sides:
        R, (eu, ev), es = _reduce_side(S, q)
        out.append(R)
        bound = max(bound, lu * eu + lv * ev)
        est |= es
    return out, bound, est


def _reduce_side(S: np.ndarray, q: int) -> tuple[np.ndarray, tuple[float, float], bool]:
    """Degree-q polynomial side for the homogeneous side S (ends kept). Returns (H, (u bound, v bound),
    estimated); the bounds are parametric (same s on both curves), per coordinate."""
    k = S.shape[0] - 1
    if _polynomial(S):
        if k <= q:
            return S, (0.0, 0.0), False
        R, _ = reduce_curve(S[:, :2], q, fix_ends=1)
        # convex hull of the difference at the common degree, per coordinate: certified
        d = np.max(np.abs(elevate_curve(R, k - q) - S[:, :2]), axis=0)
        return np.concatenate([R, np.ones((q + 1, 1))], axis=1), (float(d[0]), float(d[1])), False
    # rational: least squares on samples, ends interpolated; the bound is sampled (estimated)
    t = np.linspace(0, 1, 8 * (q + 1) + 1)
    pts = _eval(S, t)
    R = fit_points(t, pts, q)
    tt = np.linspace(0, 1, 257)
    d = 1.5 * np.max(np.abs(_eval(S, tt) - basis(q, tt) @ R), axis=0)
    return np.concatenate([R, np.ones((q + 1, 1))], axis=1), (float(d[0]), float(d[1])), True


# --------------------------------------------------------------------------------------------- driver


def _set_point(H: np.ndarray, row: int, uv: np.ndarray) -> None:
    H[row, :2] = uv * H[row, 2]


def _flatten(chains, g: _FaceGeometry, budget: float) -> tuple[dict[int, tuple], float]:
    """Make near-iso coedges exact iso-lines: a coedge whose u (or v) stays within a band whose
    half-width moves the surface point by at most ``budget`` gets that coordinate set to the band's
    middle. Exporters approximate straight iso pcurves by splines that wiggle around the line
    (1e-7 of the domain is common), and a wiggly near-vertical curve cannot bound slabs.
    Returns ({id(coedge): (u or None, v or None)}, largest 3D move bound)."""
    fixed: dict[int, tuple] = {}
    worst = 0.0
    for chain in chains:
        for ce, ps in chain:
            if ce.degenerate:
                continue
            uv = np.concatenate([p.H[:, :2] / p.H[:, 2:3] for p in ps])
            vals: list[float | None] = [None, None]
            for axis, speed in ((0, g.su), (1, g.sv)):
                lo, hi = float(uv[:, axis].min()), float(uv[:, axis].max())
                half = 0.5 * (hi - lo)
                if half * speed <= budget:
                    c = 0.5 * (lo + hi)
                    for p in ps:
                        p.H[:, axis] = c * p.H[:, 2]
                    vals[axis] = c
                    worst = max(worst, half * speed)
            if vals[0] is not None and vals[1] is not None:
                vals = [None, None]  # a point-like coedge: leave it to the loop closing
            if vals != [None, None]:
                fixed[id(ce)] = tuple(vals)
            if vals[0] is None and g.su > 0:
                # in u only: slabs need near-vertical stretches to be vertical; in v a moved end
                # could cross a knot line that the edge plan cut at before
                worst = max(worst, g.su * _flatten_runs(ps, 0, budget / g.su, _LONE * g.thin / g.su))
    return fixed, worst


def _flatten_runs(ps: list[_Piece], axis: int, half: float, single: float = 0.0) -> float:
    """Within one coedge, flatten every run of two or more consecutive pieces whose ``axis``
    coordinate stays in a band of half-width ``half`` (a stretch of a long pcurve that runs along
    an iso-line and wiggles around it); the neighbours' adjoining end points move onto the line.

    A piece alone is flattened when its band is narrower than ``single`` (``_LONE`` x
    ``Tolerances.thin_rel`` in 3D), it has a neighbour on the coedge at both ends and the pcurve
    turns back at one of them (``_turning_end``): as it is, its two ends stand on two slab lines
    that close, and the cells
    between them are a strip below the tolerance all along the face (bspline_boolean face 0: a
    pcurve's extremum and its knot 6e-5 further in v stood 3e-8 apart in u, a strip 3e-6 wide and
    33 long). It goes onto the line through the turning end, so the neighbour there stays
    monotone. A short piece inside a bend is left alone: it is not near an iso-line, only short,
    and made iso (ec_turbine has 17 such, 2e-6 to 1e-5 long) it left sides 1.3e-7 off their
    neighbours (I2). Up to the whole thin width, fusee's 18 such pieces left 4 free edges (I3);
    up to a quarter of it (bspline_boolean's piece takes 0.17), none.
    Returns the largest move in uv (a band's half-width), 0.0 when nothing moved."""
    worst_band = 0.0
    i, n = 0, len(ps)
    while i < n:
        lo = hi = None
        j = i
        while j < n:
            c = ps[j].H[:, axis] / ps[j].H[:, 2]
            nlo = c.min() if lo is None else min(lo, c.min())
            nhi = c.max() if hi is None else max(hi, c.max())
            if 0.5 * (nhi - nlo) > half:
                break
            lo, hi, j = nlo, nhi, j + 1
        alone = False
        if j - i < 2 and 0 < i < n - 1:
            c = ps[i].H[:, axis] / ps[i].H[:, 2]
            if c.max() - c.min() <= single:
                alone, lo, hi, j = True, float(c.min()), float(c.max()), i + 1
        if (j - i >= 2 or alone) and hi > lo:
            mid = 0.5 * (lo + hi)
            band = 0.5 * (hi - lo)
            if alone:
                at = _turning_end(ps[i - 1], ps[i], ps[j], axis)
                if at is None:  # a short piece in a bend, not a pcurve turning on a line: as it is
                    i += 1
                    continue
                mid = float(at)
                band = hi - lo
            for p in ps[i:j]:
                p.H[:, axis] = mid * p.H[:, 2]
            if i > 0:
                ps[i - 1].H[-1, axis] = mid * ps[i - 1].H[-1, 2]
            if j < n:
                ps[j].H[0, axis] = mid * ps[j].H[0, 2]
            worst_band = max(worst_band, band)
        i = max(j, i + 1)
    return worst_band


def _turning_end(before: _Piece, p: _Piece, after: _Piece, axis: int) -> float | None:
    """The ``axis`` coordinate of the one end of ``p`` where the pcurve turns back (the piece beside
    it leaves that end on the same side as ``p`` does), or None if neither or both do."""
    def c(q: _Piece, k: int) -> float:
        return float(q.H[k, axis] / q.H[k, 2])

    a, b = c(p, 0), c(p, -1)
    turn_a = (c(before, 0) - a) * (b - a) > 0
    turn_b = (c(after, -1) - b) * (a - b) > 0
    if turn_a == turn_b:
        return None
    return a if turn_a else b


def _close_loops(chains: list[list[tuple[_Coedge, list[_Piece]]]], fixed: dict | None = None,
                 g: _FaceGeometry | None = None) -> float:
    """Make every loop exactly closed in uv: where one coedge ends and the next begins (in the loop's
    travel order), both end control points move to the midpoint, except in a coordinate that
    ``_flatten`` fixed on one of them, which wins. Real files leave uv gaps up to the vertex
    tolerance there. Returns the largest move: in uv units without ``g``; with it, the 3D bound
    of what the move does to the piece (|move| x the speed of the spans the piece's control
    polygon, before and after, meets: moving one control point moves the curve by at most that)."""
    fixed = fixed or {}
    worst = 0.0
    for chain in chains:
        ends = []
        for ce, ps in chain:
            first, last = (ps[0], 0), (ps[-1], -1)
            ends.append((last, first) if ce.reversed else (first, last))  # (travel start, travel end)
        for i in range(len(ends)):
            (pa, ra) = ends[i][1]
            (pb, rb) = ends[(i + 1) % len(ends)][0]
            a = pa.H[ra, :2] / pa.H[ra, 2]
            b = pb.H[rb, :2] / pb.H[rb, 2]
            mid = 0.5 * (a + b)
            fa = fixed.get(id(chain[i][0]), (None, None))
            fb = fixed.get(id(chain[(i + 1) % len(chain)][0]), (None, None))
            for axis in (0, 1):
                pins = [f[axis] for f in (fa, fb) if f[axis] is not None]
                if pins:
                    mid[axis] = sum(pins) / len(pins)
            before = [p.H[:, :2] / p.H[:, 2:3] for p in (pa, pb)]
            _set_point(pa.H, ra, mid)
            _set_point(pb.H, rb, mid)
            for p, old, end in ((pa, before[0], a), (pb, before[1], b)):
                d = np.abs(end - mid)
                if g is None:
                    worst = max(worst, float(np.linalg.norm(d)))
                elif d.any():  # per axis: a move in v costs only the v-speed
                    box = np.concatenate([old, p.H[:, :2] / p.H[:, 2:3]])
                    worst = max(worst, float(d @ g.speed_over(box)))
    return worst


def _face_pieces(face: Face, model: Model, plan: dict[int, np.ndarray], g: _FaceGeometry,
                 budget: float = 0.0, join_gap: float = 0.0) -> tuple[list[_Piece], float, float]:
    """The face's pcurve pieces, cut at the edge plan, near-iso coedges flattened (``_flatten``
    within ``budget``, model units) and the loops closed exactly; with 3D bounds of the moves made
    to close them (see ``_close_loops``) and to flatten."""
    chains: list[list[tuple[_Coedge, list[_Piece]]]] = [[] for _ in face.loops]
    for ce in _coedges(face, model):
        params = plan.get(ce.edge) if not ce.degenerate else np.array(_needs(ce, g.breaks, (g.ueps, g.veps)))
        params = np.array([]) if params is None else params
        params = params[(params > ce.first) & (params < ce.last)]
        ps = [_Piece(H.copy(), ce.edge, w0, w1, ce.degenerate, ce.curve)
              for w0, w1, H in _span_pieces(ce, params)]
        chains[ce.loop].append((ce, ps))
    fixed, flat = _flatten(chains, g, budget)
    move = _close_loops(chains, fixed, g)
    pieces = [q for chain in chains for _, ps in chain for p in ps for q in _monotone(p, (g.ueps, g.veps))]
    if join_gap > 0.0:
        pieces = _join_t_sides(face, model, pieces, g, join_gap)
    return pieces, move, flat


def _boundary_line(p: _Piece, face: Face, g: _FaceGeometry) -> tuple[int, int] | None:
    """(axis, end) of the side of the surface's domain rectangle that a piece runs along (axis 0:
    a v-iso line, v at its lower (end 0) or upper (1) knot; axis 1: a u-iso line), or None."""
    s = face.surface
    uv = p.H[:, :2] / p.H[:, 2:3]
    for axis, knots, eps in ((0, s.vknots, g.veps), (1, s.uknots, g.ueps)):
        c = uv[:, 1 - axis]
        for end, x in enumerate((knots[0], knots[-1])):
            if float(np.abs(c - x).max()) <= eps:
                return axis, end
    return None


def _join_t_sides(face: Face, model: Model, pieces: list[_Piece], g: _FaceGeometry,
                  join_gap: float) -> list[_Piece]:
    """An untrimmed face (one loop running along the sides of its surface's domain) whose side is
    made of several edges, as in this tool's own output where a T-vertex splits the longer side:
    consecutive pieces on one side of the domain become one iso piece without an edge, so the face
    is not cut at the T-vertex (a cut there would run across the patch and split its neighbour
    across the other side in turn: converting an output again would not be idempotent). Such a side
    keeps the face's own boundary, and stage 2 puts no shared curve into it; that is only right where
    the side lies within ``join_gap`` (model units, the watertight gap) of every edge's curve, which
    is checked on samples. Other faces, and sides that fail the check, are left as they are."""
    if len(face.loops) != 1 or len(pieces) < 5:
        return pieces
    lines = []
    for p in pieces:  # most faces have a piece off the domain's sides: stop at the first
        line = _boundary_line(p, face, g)
        if line is None:
            return pieces
        lines.append(line)
    # the loop's pieces in order; rotate so that a run on one side does not wrap around the start
    k0 = next((k for k in range(len(pieces)) if lines[k] != lines[k - 1]), None)
    if k0 is None:
        return pieces
    order = list(range(k0, len(pieces))) + list(range(k0))
    runs: list[list[int]] = []
    for k in order:
        if runs and lines[runs[-1][-1]] == lines[k]:
            runs[-1].append(k)
        else:
            runs.append([k])
    out: list[_Piece] = []
    for run in runs:
        ps = [pieces[k] for k in run]
        edges = {p.edge for p in ps}
        if len(edges) < 2 or any(p.degenerate for p in ps) or not all(
                _on_edge(p, face, model) <= join_gap and _vertices_on_face(p, face, model) <= join_gap
                for p in ps):
            out.extend(ps)
            continue
        axis = lines[run[0]][0]  # the coordinate that runs along the side
        ends = np.concatenate([p.H[[0, -1]] / p.H[[0, -1], 2:3] for p in ps])
        a, b = ends[np.argmin(ends[:, axis])], ends[np.argmax(ends[:, axis])]
        out.append(_Piece(np.array([a, b]), None, 0.0, 0.0, False, None))
    return out


def _vertices_on_face(p: _Piece, face: Face, model: Model) -> float:
    """Distance of the edge's vertices at the piece's ends (where it ends at one) from the face's
    surface there: stage 2 puts the neighbours' corners on the vertices, and a T-vertex off the
    joined side would open a gap beside it."""
    edge = model.edges[p.edge]
    worst = 0.0
    for w, v in ((edge.first, edge.vertices[0]), (edge.last, edge.vertices[1])):
        tol_w = 1e-9 * max(abs(edge.last - edge.first), 1e-300)
        if min(abs(p.w0 - w), abs(p.w1 - w)) <= tol_w:
            on_face = face.surface.evaluate(p.pcurve.evaluate(np.array([w])))[0]
            worst = max(worst, float(np.linalg.norm(model.vertices[v] - on_face)))
    return worst


def _on_edge(p: _Piece, face: Face, model: Model) -> float:
    """Sampled distance between a piece's edge curve and the face's surface along the piece."""
    curve = model.edges[p.edge].curve
    if curve is None or p.pcurve is None:
        return float("inf")
    w = p.w0 + np.linspace(0.0, 1.0, 9) * (p.w1 - p.w0)
    on_face = face.surface.evaluate(p.pcurve.evaluate(w))
    return float(np.linalg.norm(curve.evaluate(w) - on_face, axis=1).max())


def _monotone(p: _Piece, eps) -> list[_Piece]:
    """The piece cut at the u- and v-extrema inside it. The edge plan cut every pcurve at its
    extrema already; closing a loop moves an end control point, which can turn a short piece back
    near its end, so the closed pieces are checked again (face-local cuts)."""
    ts = sorted({r for a in (0, 1) for r in _extrema(p.H, a, eps[a])})
    out, rest, t0 = [], p, 0.0
    for t in ts:
        tl = (t - t0) / (1.0 - t0)
        if not 1e-9 < tl < 1.0 - 1e-9:
            continue
        left, rest = _split(rest, tl)
        out.append(left)
        t0 = t
    return out + [rest]


def untrim_face(face: Face, model: Model, plan: dict[int, np.ndarray], tol: Tolerances,
                g: _FaceGeometry | None = None, rung_cuts: str = "plan") -> FaceResult:
    t0 = time.perf_counter()
    fr = FaceResult(face.index)
    g = g or _FaceGeometry(face, model.diagonal, tol)
    fr.eps = (g.ueps_lines, g.veps)
    ctx = _FaceContext(face, g, tol.approx_rel * model.diagonal, tol.max_degree)
    pieces, move, flat = _face_pieces(face, model, plan, g, _FLATTEN * tol.approx_rel * model.diagonal,
                                      tol.watertight_rel * model.diagonal)
    fr.closure = move + flat
    fr.flattened = flat
    fr.approximated = bool(flat > g.snap)
    from .wrap import turned_patches, wrap_sites, wrapped

    sites = wrap_sites(face, model, g) if tol.wrap_tips else []
    pieces, wraps, wrap_ends = wrapped(face, pieces, sites, model, g)
    fr.wraps = len(wrap_ends) - len(wraps)  # a wrap of n turned cells ends n + 1 of them
    reparam = 0.0
    for ua, ubb, bot, top in _cells(face, pieces, g, fr, rung_cuts, plan, wrap_ends):
        t = time.perf_counter()
        fr.patches.extend(ctx.cell_patches(ua, ubb, bot, top, fr))
        reparam += time.perf_counter() - t
    t = time.perf_counter()
    fr.patches.extend(turned_patches(face, wraps, model, tol, fr))
    reparam += time.perf_counter() - t
    t = time.perf_counter()
    for p in fr.patches:
        # a sub-box is the surface's own span at its own degree: only composition writes degrees
        # above what a patch needs. Reducing a box anyway would lower this tool's own output (whose
        # patches may hold a short piece of an edge curve that is its degree within 1e-13 of its
        # size) on a second conversion
        if not p.box:
            p.ctrl = compact(p.ctrl, p.rational)
    reparam += time.perf_counter() - t
    fr.times = {"cells": time.perf_counter() - t0 - reparam, "reparam": reparam}
    if fr.snapped:
        fr.closure += g.snap
    approx = [p for p in fr.patches if p.approximated]
    fr.approximated = fr.approximated or bool(approx)
    fr.estimated = any(p.estimated for p in approx)
    fr.bound = max((p.bound for p in fr.patches), default=0.0) + face.approximation + fr.closure
    return fr


#: a turned face may have at most this many times the patches of the face as is plus one per rung
#: piece the turn lets take its edge's curve (``untrim``)
_TURN_GROWTH = 2.0
#: a face whose flattening (``FaceResult.flattened``) costs more than this many rung slides
#: (``RUNG_SLIDE`` of the tolerance) is decomposed turned as well, and kept turned when that
#: flattens less than half as much with no more patches and no more unshared rungs (``untrim``)
_TURN_REPAIRS = 1.0


def _face_or_problem(face: Face, model: Model, plan: dict[int, np.ndarray], tol: Tolerances,
                     g: _FaceGeometry) -> FaceResult:
    """The face's stage-1 result, or a result carrying the error as its problem. A face whose
    cells fold with the rung cuts at plan parameters (``_cells``) is made again with cuts at its
    vertices only, then without."""
    fr = None
    for rung_cuts in _RUNG_CUTS:
        try:
            this = untrim_face(face, model, plan, tol, g, rung_cuts)
        except UntrimError as exc:
            this = FaceResult(face.index)
            this.problems.append(str(exc))
        if fr is None or len(this.problems) < len(fr.problems):
            fr = this
        if not fr.problems:
            break
    return fr


def transpose_face(face: Face) -> Face:
    """The same face with u and v swapped: surface axes, pcurve coordinates and uv bounds. The
    surface normal S_u x S_v changes sign, so ``reversed`` flips and the face's outward side stays."""
    s = face.surface
    surf = BSplineSurface(s.vdegree, s.udegree, s.vknots, s.uknots,
                          np.ascontiguousarray(s.poles.transpose(1, 0, 2)),
                          None if s.weights is None else np.ascontiguousarray(s.weights.T))
    loops = tuple(Loop(tuple(ce if ce.pcurve is None else
                             replace(ce, pcurve=replace(ce.pcurve,
                                                        poles=np.ascontiguousarray(ce.pcurve.poles[:, ::-1])))
                             for ce in loop.coedges), loop.outer)
                  for loop in face.loops)
    u0, u1, v0, v1 = face.uv_bounds
    return replace(face, surface=surf, reversed=not face.reversed, loops=loops, uv_bounds=(v0, v1, u0, u1),
                   turned=not face.turned)


def untrim(model: Model, tol: Tolerances, progress=None) -> UntrimResult:
    """Stage 1 on a whole model. ``progress`` (optional) is called once per face.

    Turned faces: a face (without seams) whose cells leave rungs along its edges that
    cannot take the edge's curve (``_unshared_rungs``), or that has a problem, is also decomposed
    turned (``transpose_face``). The turned face is kept when its cells have no problem and leave
    fewer such rungs, with at most ``_TURN_GROWTH`` times the patches plus the rungs saved (a face
    whose u-iso edges are not affine in their parameter becomes one whose edges run along u: fusee's
    face 9 goes from 9 to 180 patches). It then replaces the face in ``model.faces``: the rest of
    the pipeline reads the face from the model, so it sees the same surface and pcurves as its
    patches."""
    t0 = time.perf_counter()
    geoms = [_FaceGeometry(face, model.diagonal, tol) for face in model.faces]
    plan = edge_plan(model, geoms, tol.sliver_rel * model.diagonal,
                     max(tol.thin_rel, tol.sliver_rel) * model.diagonal, tol.wrap_tips)
    slide = RUNG_SLIDE * tol.approx_rel * model.diagonal
    plan_time = time.perf_counter() - t0
    faces = []
    dropped: dict[int, dict[int, set[float]]] = {}  # per face, the plan cuts it leaves out beside strips
    for i, (face, g) in enumerate(zip(model.faces, geoms, strict=True)):
        fr = _face_or_problem(face, model, plan, tol, g)
        # faces with a seam keep their orientation; a pole turns with the face (it is a degenerate
        # piece on a slab line then, which the cells take as a collapsed rung): the wing's fuselage
        # face 13, whose edge 29 wiggles around u = 0 by 1e-4 over 180 spans, made 11359 thin
        # cells as is (119 rungs unshared, most of the wing's free edges) and 986 turned (none)
        fixed = any(model.edges[ce.edge].seam for lp in face.loops for ce in lp.coedges)
        left = 0 if fixed or fr.problems else _unshared_rungs(fr, slide)
        # a face whose flattening costs much as is (wiggly near-iso pcurves) is tried turned too:
        # fusee's face 6, whose two u-sides wiggle around u = 0 and u = 1 by 3e-5, spent 1.7e-4 on
        # flattening as is, in 163 cells along the wiggles whose rungs stage 2 could not all share
        # (kept as is, 7 free edges), and none turned, in 67. Loop closing costs the same both ways
        costly = fr.flattened > _TURN_REPAIRS * slide
        if not fixed and (fr.problems or left or costly):
            turned = transpose_face(face)
            gt = _FaceGeometry(turned, model.diagonal, tol)
            frt = _face_or_problem(turned, model, plan, tol, gt)
            if not frt.problems:
                left_t = _unshared_rungs(frt, slide)
                room = _TURN_GROWTH * (len(fr.patches) + left - left_t)
                # and never at the price of repairs: turned, a thin blend's short sides that wiggle
                # by 2e-5 in v were flattened onto iso-lines (a 7e-4 move), left unshared as rungs
                # at that distance from their edge (bug33398: a 1.35e-3 gap)
                repairs = frt.closure <= fr.closure + 0.1 * slide
                cheaper = (costly and left_t <= left and frt.flattened < 0.5 * fr.flattened
                           and len(frt.patches) <= len(fr.patches))
                if fr.problems or ((left_t < left or cheaper) and repairs and len(frt.patches) <= room):
                    model.faces[i], fr = turned, frt
                    geoms[i] = gt
        fr, drops = _without_strip_cuts(model.faces[i], model, plan, fr, tol, geoms[i], slide)
        if drops:
            dropped[i] = drops
        faces.append(fr)
        if progress is not None:
            progress(1)
    from .topology import JOIN_REL

    cusps = {i: cusp_tails(model, fr, JOIN_REL * model.diagonal, slide) for i, fr in enumerate(faces)}
    # a tail's edges keep every plan cut on every face: stage 2 moves the far end of a tail, and the
    # edge's curve with it, piecewise linearly between the cuts (``substitute._Curves._alias_move``),
    # so a side through a cut would not pass through its neighbour's corner there (fusee edge 253:
    # a T-vertex 2.1e-7 off a side of face 44)
    tails = {t[0] for i, fr in enumerate(faces) for c in (*fr.crossings, *cusps[i]) for t in c}
    redo = [i for i, drops in dropped.items() if set(drops) & tails]
    for i in redo:
        del dropped[i]
        faces[i] = _face_or_problem(model.faces[i], model, plan, tol, geoms[i])
    if redo:
        cusps = {i: cusp_tails(model, fr, JOIN_REL * model.diagonal, slide) for i, fr in enumerate(faces)}
    for i, tails_i in cusps.items():
        faces[i].crossings.extend(tails_i)
    own: dict[int, dict[int, set[float]]] = {i: {e: set(ws) for e, ws in d.items()}
                                             for i, d in dropped.items()}
    strip_cuts: dict[int, set[float]] = {}
    for d in dropped.values():
        for e, ws in d.items():
            strip_cuts.setdefault(e, set()).update(ws)
    for i in _crossing_cuts(model, plan, faces, tol.sliver_rel * model.diagonal, own):
        fr = _face_or_problem(model.faces[i], model, _plan_without(plan, own.get(i, {})), tol, geoms[i])
        fr.crossings.extend(cusps[i])  # the face made again keeps its cusps' tails
        fr.strip_cuts = faces[i].strip_cuts  # and leaves out the same plan cuts (``own``)
        if len(fr.problems) <= len(faces[i].problems):
            faces[i] = fr
    return UntrimResult(faces, plan, tol.approx_rel * model.diagonal, tol.max_degree, plan_time, own,
                        strip_cuts)


#: a cell whose rungs are both longer than this many times its bottom and top (in 3D, along their
#: control polygons) is a strip across its slab (``_without_strip_cuts``); the independent checker
#: counts patches more than 500 times longer than wide
_STRIP = 200.0
#: a cell with a collapsed rung (a loop's tip) whose other rung is longer than this many times its
#: width (its farthest point from that rung) is a needle cap (``_caps``)
_NEEDLE = 50.0


def _side_lengths(p: Patch) -> list[float]:
    """Control-polygon lengths of a patch's bottom, top, left and right sides (model units)."""
    c = p.ctrl[..., :3] / p.ctrl[..., 3:] if p.rational else p.ctrl
    rows = (c[:, 0], c[:, -1], c[0, :], c[-1, :])
    return [float(np.linalg.norm(np.diff(r, axis=0), axis=1).sum()) for r in rows]


def _long_thin(fr: FaceResult, sliver: float, across: tuple[int, int]) -> list[Patch]:
    """The face's patches whose sides ``across`` (indices into ``_side_lengths``) are wider than a
    sliver and more than ``_STRIP`` times shorter than the other two."""
    along = tuple(k for k in range(4) if k not in across)
    out = []
    for p in fr.patches:
        sides = _side_lengths(p)
        width = max(sides[k] for k in across)
        if width > sliver and min(sides[k] for k in along) > _STRIP * width:
            out.append(p)
    return out


def _strips(fr: FaceResult, sliver: float) -> list[Patch]:
    """The face's patches that are strips across their slab (``_STRIP``), wider than a sliver."""
    return _long_thin(fr, sliver, (0, 1))


def _bands(fr: FaceResult, sliver: float) -> list[Patch]:
    """The face's patches that are strips the other way: rungs wider than a sliver and more than
    ``_STRIP`` times shorter than bottom and top (two cuts close in v across the cell)."""
    return _long_thin(fr, sliver, (2, 3))


def _caps(fr: FaceResult, thin: float, ueps: float, veps: float) -> list[tuple[Patch, int]]:
    """The face's needle caps, each as (patch, end): a cell whose bottom and top are edge pieces that
    meet at its ``end`` (0: s = 0, -1: s = 1; the rung there is one point, the tip of a loop at its
    u-extremum), and that lies within ``thin`` of its other rung all over, or within ``1 / _NEEDLE``
    of that rung's length. A slab line a hair short of the tip makes one
    (occt__bug24595_281390.stp face 3: 0.051 long, 3.9e-4 wide, the line 1e-5 in u from the
    extremum, through two plan cuts of the cylinder beside it). The build remakes a cap as a quad
    with two flat corners, the tip and the middle of the rung (``core.triangle``), which here stood
    3.9e-4 apart: a bow-tie, and the mesher's triangles in it had two corners at one node."""
    from .topology import _grid_points, project, side_row

    out = []
    for p in fr.patches:
        if p.bottom.iso or p.top.iso or p.bottom.edge is None or p.top.edge is None:
            continue
        for end in (0, -1):
            b = p.bottom.H[end, :2] / p.bottom.H[end, 2]
            t = p.top.H[end, :2] / p.top.H[end, 2]
            if abs(b[0] - t[0]) > 2 * ueps or abs(b[1] - t[1]) > veps:
                continue
            rung = side_row(p.ctrl, p.rational, "left" if end == -1 else "right")
            width = project(rung, _grid_points(p.ctrl, p.rational, 9))[1].max()
            if width <= thin or _NEEDLE * width < _side_lengths(p)[2 if end == -1 else 3]:
                out.append((p, end))
            break
    return out


def _defects(fr: FaceResult, g: _FaceGeometry) -> int:
    """Strips, bands and needle caps among the face's cells: what ``_without_strip_cuts`` makes
    fewer."""
    caps = _caps(fr, g.thin, g.ueps_lines, g.veps)
    return len(_strips(fr, g.sliver)) + len(_bands(fr, g.sliver)) + len(caps)


def _drop_free_cut(drops: dict[int, set[float]], free: dict[int, set[float]], model: Model, e: int,
                   w: float) -> None:
    """Add to ``drops`` the plan cut of ``free`` on edge ``e`` at parameter ``w`` (to 1e-9 of the
    edge's range), if there is one."""
    ws = np.array(sorted(free[e]))
    edge = model.edges[e]
    k = int(np.argmin(np.abs(ws - w)))
    if abs(ws[k] - w) <= 1e-9 * max(edge.last - edge.first, 1e-300):
        drops.setdefault(e, set()).add(float(ws[k]))


def _band_cuts(drops: dict[int, set[float]], fr: FaceResult, bands: list[Patch], free: dict[int, set[float]],
               model: Model, veps: float, ueps: float) -> None:
    """Add to ``drops`` the plan cuts in ``free`` that end a band: an end of the band's bottom or top
    that is the end of an iso piece (a rung along an edge) at that plan parameter."""
    ends = [(float(q.H[k, 0] / q.H[k, 2]), float(q.H[k, 1] / q.H[k, 2]), q.edge, float(w))
            for q in fr.iso_pieces if q.edge is not None and q.edge in free
            for k, w in ((0, q.w0), (-1, q.w1))]
    if not ends:
        return
    E = np.array([e[:2] for e in ends])
    for p in bands:
        for side in (p.bottom, p.top):
            for k in (0, -1):
                x = side.H[k, :2] / side.H[k, 2]
                at = (np.abs(E[:, 0] - x[0]) <= 2 * ueps) & (np.abs(E[:, 1] - x[1]) <= veps)
                for h in np.flatnonzero(at):
                    _drop_free_cut(drops, free, model, ends[h][2], ends[h][3])


def _droppable_cuts(face: Face, model: Model, plan: dict[int, np.ndarray],
                    g: _FaceGeometry) -> dict[int, set[float]]:
    """Per edge of the face, the plan's parameters that only other faces need: not an end of the
    edge, not a break of its 3D curve, and not the plan point that stands for one of this face's
    own needs (``_needs``; the plan merged and thinned them, so the nearest plan point serves)."""
    out: dict[int, set[float]] = {}
    coedges = _coedges(face, model)
    uses = Counter(ce.edge for ce in coedges)
    for ce in coedges:
        edge = model.edges[ce.edge]
        P = plan.get(ce.edge, np.zeros(0))
        # an edge twice on the face (a seam) keeps every cut: each coedge may need what the other does not
        if ce.degenerate or edge.curve is None or not len(P) or uses[ce.edge] > 1:
            continue
        anchors = np.concatenate([[edge.first], P, [edge.last]])
        needs = _needs(ce, g.breaks, (g.ueps, g.veps), g.flat) + list(_interior_breaks(edge.curve.knots,
                                                                                edge.curve.degree))
        served = {int(np.argmin(np.abs(anchors - w))) for w in needs}
        free = {float(w) for k, w in enumerate(P, start=1) if k not in served}
        if free:
            out[ce.edge] = free
    return out


def _without_strip_cuts(face: Face, model: Model, plan: dict[int, np.ndarray], fr: FaceResult,
                        tol: Tolerances, g: _FaceGeometry,
                        slide: float) -> tuple[FaceResult, dict[int, set[float]]]:
    """The face made again without the plan cuts that end strips across its slabs, where that
    leaves fewer strips and nothing worse, and those cuts (edge -> parameters; none: ``fr`` kept).

    A plan cut that only a neighbour needs (its knot line, its extremum) puts a slab line across
    this face; where that line stands close in u to another (a knot line, a vertex), the cells
    between are strips many times longer than wide (bspline_boolean face 0: 19 of 176 patches more
    than 500 times, 0.04 x 75 beside its knot line u = 0.25). Without the cut the face's side runs
    through the parameter; the neighbour's corner there is a T-vertex on that side, which stage 2
    makes a subdivision point of the shared curve (the side takes the edge's curve over both plan
    pieces: no break of the curve lies between them). The cuts at the far rung of a needle cap
    (``_caps``) are left out in the same way, so the cap reaches the next slab line."""
    if fr.problems:
        return fr, {}
    strips = _strips(fr, g.sliver)
    bands = _bands(fr, g.sliver)
    caps = _caps(fr, g.thin, g.ueps_lines, g.veps)
    if not strips and not bands and not caps:
        return fr, {}
    try:
        free = _droppable_cuts(face, model, plan, g)
    except UntrimError:
        return fr, {}
    drops: dict[int, set[float]] = {}
    _band_cuts(drops, fr, bands, free, model, g.veps, g.ueps_lines)
    for p in strips:
        for side in (p.bottom, p.top):
            if side.iso or side.edge is None or side.edge not in free:
                continue
            for w in (side.w0, side.w1):
                _drop_free_cut(drops, free, model, side.edge, w)
    for p, end in caps:  # the cuts at the rung away from the tip
        for side in (p.bottom, p.top):
            if side.edge in free:
                _drop_free_cut(drops, free, model, side.edge, side.w1 if end == 0 else side.w0)
    if not drops:
        return fr, {}
    again = _face_or_problem(face, model, _plan_without(plan, drops), tol, g)
    fewer = _defects(again, g) < len(strips) + len(bands) + len(caps)
    if (again.problems or not fewer or len(again.patches) > len(fr.patches)
            or _unshared_rungs(again, slide) > _unshared_rungs(fr, slide)):
        return fr, {}
    again.strip_cuts = sum(len(ws) for ws in drops.values())
    return again, drops


def _plan_without(plan: dict[int, np.ndarray], cuts: dict[int, set[float]]) -> dict[int, np.ndarray]:
    if not cuts:
        return plan
    out = dict(plan)
    for e, ws in cuts.items():
        out[e] = np.array([w for w in plan[e] if float(w) not in ws])
    return out


def _tail_vertex(model: Model, e: int, w: float) -> int | None:
    """The vertex at edge ``e``'s end when ``w`` is that end's parameter, else None."""
    edge = model.edges[e]
    if edge.degenerate or edge.curve is None:
        return None
    eps = 1e-9 * max(edge.last - edge.first, 1e-300)
    if abs(w - edge.first) <= eps:
        return edge.vertices[0]
    if abs(w - edge.last) <= eps:
        return edge.vertices[1]
    return None


def crossing_tails(model: Model, fr: FaceResult) -> list[tuple[tuple[int, float, float], ...]]:
    """The face's crossings whose two tails run on two edges to one vertex, each as
    ((edge a, w at the crossing, w at the vertex), (edge b, ...)) with a < b: those stage 2 joins
    (``substitute._Tails``). A crossing whose tails end elsewhere (on a slab line) is left alone."""
    out = []
    for tail in fr.crossings:
        (ea, xa, fa), (eb, xb, fb) = sorted(tail)
        va, vb = _tail_vertex(model, ea, fa), _tail_vertex(model, eb, fb)
        if ea != eb and va is not None and va == vb and xa != fa and xb != fb:
            out.append(((ea, xa, fa), (eb, xb, fb)))
    return out


def cusp_tails(model: Model, fr: FaceResult, eps: float, slide: float) -> list:
    """The face's cusps as tails (the form of ``FaceResult.crossings``): where two of its edges a < b
    leave a vertex V tangentially and stay within ``eps`` (the B-rep's joining distance) of each
    other, the face between them is a sliver the B-rep cannot keep (its cells are dropped as
    flat), so the faces beyond a and beyond b meet each other there. Given each its own edge's
    curve, they stood as far apart as the sliver is wide (gmsh__U_Joint_2.stp: 2.6e-9 beside its
    cusps, fusee: 1.7e-7). As for a crossing, the edge plan then cuts both edges at the tail's far
    end and stage 2 gives the two tails a's curve (``substitute._Tails``). The tail runs from V to
    the farthest pair of the face's corners, one on a and one on b, within ``eps`` of each other,
    with a and b over the stretch to them within ``eps`` (b's parameter mapped affinely onto
    a's, as stage 2 maps it); one shorter than 10 ``eps`` is left alone."""
    if fr.problems or not fr.patches:
        return []
    at: dict[int, list[tuple[int, float]]] = {}
    for e in {ce.edge for lp in model.faces[fr.face].loops for ce in lp.coedges}:
        edge = model.edges[e]
        if edge.curve is None or edge.degenerate or edge.seam:
            continue
        for v, w in ((edge.vertices[0], edge.first), (edge.vertices[1], edge.last)):
            at.setdefault(v, []).append((e, w))
    pairs = []
    for v, ends in at.items():
        if len(ends) == 2 and ends[0][0] != ends[1][0]:
            (ea, fa), (eb, fb) = sorted(ends)
            if _tangent(model, ea, fa, eb, fb):
                pairs.append((v, ea, fa, eb, fb))
    if not pairs:
        return []
    from .substitute import IsoPieces, _refs  # here: substitute imports this module

    iso = IsoPieces(fr.iso_pieces)
    params: dict[int, set[float]] = {}
    for p in fr.patches:
        for ref in _refs(p, iso, fr.eps if fr.eps is not None else (0.0, 0.0), slide)[0].values():
            if ref is not None and not ref.pole and ref.along is None:
                params.setdefault(ref.edge, set()).update((float(ref.wa), float(ref.wb)))
    out = []
    for v, ea, fa, eb, fb in pairs:
        tail = _cusp(model, v, (ea, fa, params.get(ea, set())), (eb, fb, params.get(eb, set())), eps)
        if tail is not None:
            out.append(tail)
    return out


#: two edges leaving a vertex at less than this angle (radians) are looked at as a cusp
_CUSP_ANGLE = 0.01


def _tangent(model: Model, ea: int, fa: float, eb: int, fb: float) -> bool:
    """Whether edges a and b leave their common vertex (at parameters fa and fb) in one direction."""
    dirs = []
    for e, f in ((ea, fa), (eb, fb)):
        edge = model.edges[e]
        h = 1e-6 * (edge.last - edge.first) * (1.0 if f == edge.first else -1.0)
        d = np.diff(edge.curve.evaluate(np.array([f, f + h])), axis=0)[0]
        n = float(np.linalg.norm(d))
        if n == 0.0:
            return False
        dirs.append(d / n)
    return float(np.dot(dirs[0], dirs[1])) > np.cos(_CUSP_ANGLE)


def _cusp(model: Model, v: int, a: tuple, b: tuple, eps: float):
    """The tail of the cusp at vertex v between edges a and b, each (edge, parameter at v, the
    face's corner parameters on it), or None (``cusp_tails``). Going out from v over the corners
    on a: the farthest one with a corner on b within ``eps`` of it, where a and b over the stretch
    to them stay within ``eps`` of each other at affinely mapped parameters."""
    (ea, fa, wa), (eb, fb, wb) = a, b
    ca, cb = model.edges[ea].curve, model.edges[eb].curve
    xa = np.array(sorted((w for w in wa if w != fa), key=lambda w: abs(w - fa)))
    xb = np.array(sorted((w for w in wb if w != fb), key=lambda w: abs(w - fb)))
    if not len(xa) or not len(xb):
        return None
    pa, pb = ca.evaluate(xa), cb.evaluate(xb)
    g = np.linspace(0.0, 1.0, 33)
    best = None
    for i in range(len(xa)):
        d = np.linalg.norm(pb - pa[i], axis=1)
        j = int(np.argmin(d))
        if d[j] > eps:
            continue
        apart = ca.evaluate(fa + g * (xa[i] - fa)) - cb.evaluate(fb + g * (xb[j] - fb))
        if np.linalg.norm(apart, axis=1).max() > eps:
            break
        best = (i, (ea, float(xa[i]), fa), (eb, float(xb[j]), fb))
    if best is None or np.linalg.norm(pa[best[0]] - model.vertices[v]) < 10.0 * eps:
        return None
    return best[1:]


def _crossing_cuts(model: Model, plan: dict[int, np.ndarray], faces: list[FaceResult],
                   sliver: float, own: dict[int, dict[int, set[float]]]) -> list[int]:
    """Put the faces' crossings (``crossing_tails``) into the edge plan: the edge parameter at each
    crossing becomes a cut of its edge, so the neighbour on that edge ends a side there too.
    Beyond the crossing the face has no area, and its two neighbours meet each other along the two
    tails (stage 2 gives the tails one curve). A cut within a sliver of a cut the edge has (or of
    its ends) is not added. ``own`` receives, per face, the cuts its own crossings made. Returns
    the faces to decompose again: those with an edge that got a cut from another face's crossing
    (a face ends its cell at its own crossing already)."""
    for fr in faces:
        for tail in crossing_tails(model, fr):
            for e, w, _ in tail:
                edge = model.edges[e]
                have = np.concatenate([[edge.first, edge.last], plan.get(e, np.zeros(0))])
                pts = edge.curve.evaluate(np.append(have, w))
                if np.linalg.norm(pts[:-1] - pts[-1], axis=1).min() <= sliver:
                    continue
                plan[e] = np.sort(np.append(plan.get(e, np.zeros(0)), w))
                own.setdefault(fr.face, {}).setdefault(e, set()).add(float(w))
    redo = []
    for i, face in enumerate(model.faces):
        others = {e for f, cuts in own.items() if f != face.index for e in cuts}
        if others & {ce.edge for lp in face.loops for ce in lp.coedges}:
            redo.append(i)
    return redo


def _unshared_rungs(fr: FaceResult, slide: float) -> int:
    """Rungs of the face's cells that run along one of its edges but cannot take the edge's curve
    in stage 2 (by stage 2's own test, ``substitute._rung_ref``: the rung spans more than one plan
    piece, or the edge's parameter is too far from affine along it)."""
    from .substitute import IsoPieces, _rung_ref, _side_length  # here: substitute imports this module

    iso = [q for q in fr.iso_pieces if not q.degenerate and q.edge is not None]
    if not iso or fr.eps is None:
        return 0
    ends = np.array([q.H[[0, -1], :2] / q.H[[0, -1], 2:3] for q in iso])  # (k, 2, 2)
    qu, qlo, qhi = ends[:, 0, 0], ends[:, :, 1].min(axis=1), ends[:, :, 1].max(axis=1)
    eu, ev = fr.eps
    table = IsoPieces(fr.iso_pieces)
    n = 0
    for p in fr.patches:
        cm = cell_map(p, np.array([0.0, 1.0]), np.array([0.0, 1.0]))
        for k, (a, b) in enumerate(cm):
            lo, hi = min(a[1], b[1]) + ev, max(a[1], b[1]) - ev
            if np.any((np.abs(qu - a[0]) <= 2 * eu) & (qlo < hi) & (qhi > lo)):  # along an edge
                n += _rung_ref(table, a, b, fr.eps, _side_length(p, k), slide) is None
    return n


# ------------------------------------------------------------------------------------ evaluation


def patch_points(patch: Patch, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points of a patch on the grid s x t -> (len(s), len(t), 3)."""
    C = patch.ctrl
    m1, n1, d = C.shape
    h = basis(n1 - 1, t)[None] @ (basis(m1 - 1, s) @ C.reshape(m1, n1 * d)).reshape(-1, n1, d)
    return h[..., :3] / h[..., 3:4] if patch.rational else h


def cell_map(patch: Patch, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The exact cell map phi(s, t) in the face's global uv on the grid s x t -> (len(s), len(t), 2)."""
    if patch.box:
        # a sub-box: u runs linearly between the rungs on both sides (whatever the pieces' own parameter)
        lin = lambda H: np.outer(1 - s, H[0, :2] / H[0, 2]) + np.outer(s, H[-1, :2] / H[-1, 2])  # noqa: E731
        b, tp = lin(patch.bottom.H), lin(patch.top.H)
    else:
        b, tp = _eval(patch.bottom.H, s), _eval(patch.top.H, s)
    return (1 - t)[None, :, None] * b[:, None, :] + t[None, :, None] * tp[:, None, :]
