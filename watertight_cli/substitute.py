"""Stage 2: one shared curve per boundary, substituted into the patches' boundary rows.

Stage 1 leaves every boundary patch with a side S_f(pc_f(w)) on its face's surface; the two faces
of an edge (and the edge's 3D curve C) are three different curves. Here every patch side that lies
on an edge gets the edge's shared curve K instead:

- K is the edge's 3D curve C restricted to the side's parameter interval [wa, wb] (the paper's
  choice). The edge plan put C's knots among every face's cuts, so a side lies inside one Bezier
  span of C and K is an exact sub-curve of it. Every K is computed once per (edge, interval) and
  cached, with the interval in increasing order, so two faces get the same bits.
- A side collapsed to a pole gets the pole's vertex.
- Corners on an edge move to one value shared by every patch that touches them: the model vertex
  at the edge's ends, C(w) inside the edge.
- The rung of a cell that lies on a u-iso piece of the boundary is a boundary side too; its edge
  parameters come from the piece (the rung is linear in v, so a pcurve whose parameter is not
  affine in v gives K a different speed along the side; the change is measured like any other).
- Inner sides that two patches of a face share get the first patch's row in both, at a common
  degree, so they are bitwise equal; inner sides with no partner end on a T-vertex and are counted.
- Rational K are put in standard form (end weights 1, by a Moebius change of parameter that keeps
  the shape), so corners where two K meet agree on their weight.

The change of each patch against its stage-1 patch is bounded by the largest control-point move
when the weights did not change (convex hull property); where weights changed it is sampled, and
the face's figure is marked as an estimate. Numpy only; the B-rep is built in ``occ.assemble``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .core.approx import fit_curve, fit_points
from .core.bernstein import basis, product
from .core.bezier import (
    curve_eval,
    curve_segment,
    elevate_curve,
    elevate_surface,
    rational_curve_eval,
    rational_surface_eval_grid,
    surface_eval_grid,
)
from .core.bspline import to_bezier
from .core.reduce import reduce_curve
from .gaps import vertex_corners
from .model import Model
from .tolerances import Tolerances
from .topology import JOIN_REL, MERGE_REL, project
from .untrim import RUNG_SLIDE, Patch, UntrimResult, _deriv_h, _eval, _t_at_u, cell_map, crossing_tails
from .verify import side_deviations

__all__ = ["substitute", "Substitution", "FaceSubstitution", "SIDES"]

#: side name -> (index into ctrl selecting its row, direction "s" or "t", corners at its start and end)
SIDES = {
    "bottom": ((slice(None), 0), "s", ((0, 0), (1, 0))),
    "top": ((slice(None), -1), "s", ((0, 1), (1, 1))),
    "left": ((0, slice(None)), "t", ((0, 0), (0, 1))),
    "right": ((-1, slice(None)), "t", ((1, 0), (1, 1))),
}
_DIVIDE_REL = 1e-9  # relative residual of a weight division that counts as exact
_POLY_REL = 0.01  # share of the tolerance a polynomial K may differ from a rational C
#: share of the watertight gap (``Tolerances.watertight_rel``) by which an edge curve may
#: move when lowered to its rows' degree (``_Curves.lower``). A STEP file's 13 significant digits
#: round a pole 50 from the origin by 5e-12, and the certified bound of a degree-25 curve so rounded
#: is about twice that (loft_minus_cylinder's output, diagonal 81: 8e-12 for a piece 0.005 long);
#: a move below I2's goal is no change that any check here can see. The same share bounds the end
#: moves that a rational curve makes by its end poles instead of its affine correction (``exact``)
_LOWER_REL = 1.0
#: a reduction in ``_Curves.lower`` stops where its bound grows past this x the first one (or
#: past this x ``_LOWER_FLOOR`` x the limit): there the curve's true degree is passed
_LOWER_JUMP = 10.0
_LOWER_FLOOR = 1e-3
_BEND_REL = 1e-13  # T-vertices this close to the long side (x diagonal) need no bend (``_through``)
_RUNG_FIT_REL = 0.1  # a rung's fit of K at its own parameter: within this x watertight_rel x diagonal
_BUMP_PEAK = 1.1  # a long side bent through its T-vertices moves elsewhere by at most this x their move
_BUMP_CAP = 2.0  # ... and is not bent at all where no degree in the budget keeps it within this,
_BUMP_SLACK = 0.1  # unless the bulge stays within this x the tolerance (tiny moves near an end)
_RUNG_SLIDE_MAX = 0.5  # past the fit's budget a rung may slide along K by this x the tolerance
_T_MERGE = 1e-6  # T-vertex parameters on a long side this close, at one 3D point, are one vertex
_REFIT_GROWTH = 4.0  # a refitted net spanning more than this times the old one is refused
_ELEVATE = 25  # elevation used to tighten control-net bounds of a patch's change
_SAMPLES = 17  # grid per direction for the sampled change of patches whose weights changed


@dataclass
class FaceSubstitution:
    face: int
    moved: float = 0.0  # largest change of a patch against its stage-1 patch (model units)
    estimated: bool = False  # some patch's change was sampled (its weights changed)
    boundary_sides: int = 0
    inner_shared: int = 0  # inner sides made bitwise equal with their partner
    inner_unpaired: int = 0  # inner sides without a partner of the same extent (T-junctions)
    inner_reparam: int = 0  # shared inner sides left as they are: same line, other parameterization
    inner_t: int = 0  # inner sides made subdivisions of a neighbour's longer side (T-vertices)
    t_guided: int = 0  # such long sides bent onto the shared curve beside them too (``_through_guided``)
    inner_mismatch: int = 0  # sides paired by their corners but further apart than a copy may move
    rungs_fitted: int = 0  # rungs on an edge that took its curve at their own parameter (a fit)
    rungs_slid: int = 0  # such rungs whose fit needed more than the degree budget: K taken as it is
    rungs_unshared: int = 0  # such rungs that would also slide too far (left as they are)
    # largest distance of a patch from its stage-1 patch at the same (s, t), sampled on a grid (the
    # measured counterpart of ``moved``, which sums certified bounds of the successive steps)
    moved_sampled: float = 0.0
    # per patch, the sampled move plus the stage-1 patch's deviation from the input face (its bound,
    # or where the loop closure moved a trimming side, that side's sampled distance from S(pcurve)
    # when it is larger, within bound + closure); the largest
    deviation_sampled: float = 0.0
    elevated: int = 0  # patches whose degree was raised to take a shared curve
    corners_moved: int = 0  # corners moved onto a shared curve in patches with no side there
    problems: list[str] = field(default_factory=list)


@dataclass
class Substitution:
    faces: list[FaceSubstitution]
    curves: dict[int, str]  # edge -> which shared curve it got ("3d curve", "3d curve, polynomial
    # fit", "midway between the faces" or "pole")
    t_vertices: int = 0  # corners on an edge that only some of the edge's faces have
    straddles: int = 0  # sides whose interval crosses a knot of the edge's curve (should be 0)

    @property
    def moved(self) -> float:
        return max((f.moved for f in self.faces), default=0.0)


@dataclass
class _Ref:
    """What a patch side lies on: an edge interval (w at the side's start and end), or a pole."""

    edge: int
    wa: float
    wb: float
    pole: bool = False
    # a rung along an iso piece whose edge parameter is not affine along the rung: (piece H, w0,
    # w1, v at the rung's start, v at its end), or for two pieces (((H, w0, w1), ...), wa, wb, v at
    # the start, v at the end); the rung then takes K at that parameter (``_rung_row``)
    along: tuple | None = None


class _Curves:
    """Shared curves and corner points of a model, each computed once.

    A segment of a polynomial 3D curve is K itself. A segment of a rational one is decided once
    from all the patch rows that will take it (``decide``): it stays rational (exact) when some
    rational row has the same weights up to a scale and a Moebius change of parameter (the row
    then takes it exactly); otherwise the lowest-degree polynomial within ``poly_tol`` replaces it,
    so polynomial patches stay polynomial (its sampled distance from C is recorded).
    """

    def __init__(self, model: Model, poly_tol: float, max_degree: int, vertices: np.ndarray,
                 still: float = 0.0):
        self.model = model
        self.still = still  # end moves up to this (model units) are made by the end poles (``exact``)
        self._pins: dict[int, list[np.ndarray]] = {}
        self.vertices = vertices  # the corner point of each vertex (``gaps.vertex_corners``)
        self.poly_tol = poly_tol
        self.max_degree = max_degree
        self._spans: dict[int, tuple[np.ndarray, np.ndarray, bool]] = {}
        self._k: dict[tuple[int, float, float], np.ndarray] = {}
        self.fit_error: dict[int, float] = {}
        self._moves: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._fits: dict[int, list] = {}  # edge -> per span (polynomial net, sampled error)
        self._corners: dict[tuple, np.ndarray] = {}
        self.straddles = 0
        # edges whose shared curve is the one midway between their two faces' boundaries:
        # edge -> (breaks, per-piece polynomial nets), and the largest fit error per edge
        self._mid: dict[int, tuple[np.ndarray, list[np.ndarray]]] = {}
        self.mid_error: dict[int, float] = {}
        # a crossing's point on the second edge is the first edge's point there (``_Tails``):
        # edge -> [(w on it, other edge, w on that)]
        self.corner_alias: dict[int, list[tuple[float, int, float]]] = {}
        self._alias_moves: dict[int, tuple[np.ndarray, np.ndarray] | None] = {}

    def spans(self, e: int):
        if e not in self._spans:
            c = self.model.edges[e].curve
            br, sp = to_bezier(c.knots, c.degree, c.homogeneous())
            self._spans[e] = (br, list(sp), c.rational)
        return self._spans[e]

    def rational(self, e: int) -> bool:
        return self.spans(e)[2]

    @staticmethod
    def key(e: int, wa: float, wb: float) -> tuple[int, float, float]:
        return (e, wa, wb) if wa <= wb else (e, wb, wa)

    def corner_key(self, e: int, w: float):
        edge = self.model.edges[e]
        eps = 1e-11 * max(edge.last - edge.first, 1e-300)
        for x, e1, x1 in self.corner_alias.get(e, ()):
            if abs(w - x) <= eps:
                return self.corner_key(e1, x1)
        if abs(w - edge.first) <= eps:
            return ("v", edge.vertices[0])
        if abs(w - edge.last) <= eps:
            return ("v", edge.vertices[1])
        return ("e", e, float(w))

    def corner(self, key) -> np.ndarray:
        if key[0] == "v":
            return self.vertices[key[1]]
        if key not in self._corners:
            # the point of the curve the segments are cut from: C', or its per-span fit
            h = self._piece(key[1], key[2], key[2])[0]
            self._corners[key] = h[:3] / h[3] if h.shape[0] == 4 else h
        return self._corners[key]

    def exact(self, e: int, lo: float, hi: float) -> np.ndarray:
        """C' on [lo, hi] (lo <= hi), homogeneous when rational: C plus the affine-in-w correction
        that takes its ends onto the model's vertices. Every segment and corner of the edge is
        taken from this one curve, so a side split at a T-vertex still matches its neighbours."""
        br, sp, rat = self.spans(e)
        j = int(np.clip(np.searchsorted(br, 0.5 * (lo + hi), side="right") - 1, 0, len(sp) - 1))
        x0, x1 = br[j], br[j + 1]
        eps = 1e-9 * (x1 - x0)
        if lo < x0 - eps or hi > x1 + eps:
            self.straddles += 1  # the interval crosses a knot of C: K extends the span's polynomial
        d0, d1 = self.end_moves(e)
        if rat and max(float(np.linalg.norm(d0)), float(np.linalg.norm(d1))) <= self.still:
            # a rational curve a hair off its vertices (this tool's own output: the vertex and
            # the curve's end are rounded to the file's digits apart) takes them by its end poles,
            # which moves no point by more than the move and keeps its degree; the affine
            # correction below raises the degree by one, and a second conversion raised every
            # rational patch on such an edge (filleted_freeform's fillet patches)
            sp = self._pinned(e, d0, d1)
            return curve_segment(sp[j], (lo - x0) / (x1 - x0), (hi - x0) / (x1 - x0))
        K = curve_segment(sp[j], (lo - x0) / (x1 - x0), (hi - x0) / (x1 - x0))
        if not (d0.any() or d1.any()):
            return K
        edge = self.model.edges[e]
        lam = (np.array([lo, hi]) - edge.first) / (edge.last - edge.first)
        D = np.outer(1.0 - lam, d0) + np.outer(lam, d1)  # degree 1 in w
        if not rat:
            return K + (elevate_curve(D, K.shape[0] - 2) if K.shape[0] > 2 else D)
        Dw = product(D, K[:, 3])  # kappa * D, degree k + 1
        return np.concatenate([elevate_curve(K, 1)[:, :3] + Dw, elevate_curve(K[:, 3:], 1)], axis=1)

    def _pinned(self, e: int, d0: np.ndarray, d1: np.ndarray) -> list[np.ndarray]:
        """The rational curve's spans with its first and last pole moved by d0 and d1 (homogeneous:
        the weight stays), so that it ends on its vertices."""
        if e not in self._pins:
            sp = [x.copy() for x in self.spans(e)[1]]
            sp[0][0, :3] += d0 * sp[0][0, 3]
            sp[-1][-1, :3] += d1 * sp[-1][-1, 3]
            self._pins[e] = sp
        return self._pins[e]

    def end_moves(self, e: int) -> tuple[np.ndarray, np.ndarray]:
        if e not in self._moves:
            edge = self.model.edges[e]
            ends = edge.curve.evaluate(np.array([edge.first, edge.last]))
            v = self.vertices[list(edge.vertices)]
            self._moves[e] = (v[0] - ends[0], v[1] - ends[1])
        return self._moves[e]

    def lower(self, e: int, uses: list[tuple[float, float, np.ndarray, float]], limit: float) -> float:
        """Lower each span of an edge curve towards the lowest degree of the rows that take a
        segment of it: a degree reduction of the span (ends held), or a row that takes the whole
        span, whichever is of the lowest degree and within ``limit`` of the span at the same
        parameters (model units, certified). This tool's output writes an edge's curve as the
        side of its highest-degree patch: an elevated form, which rounding to the file's 13 digits
        leaves a hair off its true degree (certified 7e-13 on a side 4 long, 8e-12 on one 0.005
        long and 50 from the origin), or for a rational patch that took a curve's weight function
        the curve times a common polynomial factor, which no reduction finds. Taken as it is, it
        would raise every lower-degree patch on the edge to that degree when the output is
        converted again. A rational span that a polynomial row holds becomes that row, at its own
        true degree; an edge whose spans all have equal weights then is polynomial. Returns the
        largest bound of a change made (0.0 when none)."""
        br, sp, rational = self.spans(e)
        worst = 0.0
        for j, (x0, x1) in enumerate(zip(br[:-1], br[1:], strict=True)):
            eps = 1e-9 * (x1 - x0)
            inside = [(lo, hi, r) for lo, hi, r, _ in uses if lo >= x0 - eps and hi <= x1 + eps]
            if not inside:
                continue
            whole = [r for lo, hi, r in inside if lo <= x0 + eps and hi >= x1 - eps]
            d = sp[j].shape[0] - 1
            cols = sp[j].shape[1]
            low = max(min(r.shape[0] - 1 for *_, r in inside), 1)
            # a polynomial row may hold a rational span, at any degree: a rational patch that took
            # a polynomial curve K keeps its own weights W, N = K W, and its side, written as the
            # edge's curve, is K W over W (filleted_freeform's output: a degree-5 side written at 23)
            held = None
            if cols == 4:
                for c in sorted((r for r in whole if r.shape[1] == 3), key=len):
                    bound = _curve_distance(sp[j], _homog(c), True)
                    if bound <= limit:
                        held = (_homog(np.array(c, dtype=float)), bound)
                        break
            if held is None and low >= d:
                continue
            base = held[0] if held is not None else sp[j]
            best = held
            # (a held span keeps its polynomial row: the lowest-degree one within the limit)
            for c in sorted((r for r in whole if held is None and r.shape[1] == cols
                             and r.shape[0] - 1 < d), key=len):
                bound = _curve_distance(sp[j], c, rational)
                if bound <= limit:
                    best = (np.array(c, dtype=float), bound)
                    break
            # reductions from the rows' lowest degree down to the span's true degree: a rational
            # row with weights of true degree w takes a polynomial curve of degree k without a raise
            # only when k + w is at most its degree (``_common_weights``), so the curve goes to its
            # own true degree (filleted_freeform: a degree-9 row with linear weights holding a
            # degree-8 curve written at degree 25). Past the true degree the bound stops being the
            # rounding's and grows (a degree-10 curve written at 25: 1.1e-13 at 10, 1.3e-12 at 9,
            # 3.1e-11 at 8); a reduction there moved the curve on every conversion
            r = min(low, base.shape[0] - 1)
            ref = None
            while r >= 1 and (best is None or r < best[0].shape[0] - 1):
                # a held row is reduced as the polynomial it is, its weights kept exactly 1
                red = (_homog(reduce_curve(base[:, :3], r, fix_ends=1)[0]) if held is not None
                       else reduce_curve(base, r, fix_ends=1)[0])
                bound = _curve_distance(sp[j], red, rational)
                ref = max(bound, _LOWER_FLOOR * limit) if ref is None else ref
                if bound > limit or bound > _LOWER_JUMP * ref:
                    break
                best = (red, bound)
                r -= 1
            if best is not None:
                sp[j] = best[0]
                worst = max(worst, best[1])
        if rational and all(np.all(x[:, 3] == x[0, 3]) for x in sp):
            self._spans[e] = (br, [x[:, :3] / x[:, 3:] for x in sp], False)
        self._alias_moves.clear()
        return worst

    def decide(self, e: int, uses: list[tuple[float, float, np.ndarray, float]]) -> None:
        """Choose the shared curve of a rational edge from the (lo, hi, row, patch size) uses: C'
        itself, or a polynomial fit of each of its spans, whichever is predicted to move the
        patches less (a weight mismatch of relative size r moves a patch by about r times its
        size). The choice is per edge and the fit per span, so the sides that meet at a T-vertex
        are subdivisions of one curve."""
        if not self.rational(e):
            return
        exact = max((_mismatch(r, self.exact(e, lo, hi), self.max_degree) * size
                     for lo, hi, r, size in uses), default=0.0)
        if exact == 0.0:
            return
        br, sp, _ = self.spans(e)
        fits = []
        for x0, x1 in zip(br[:-1], br[1:], strict=True):
            fit = self._polynomial(self.exact(e, float(x0), float(x1)))
            if fit is None:
                return
            fits.append(fit)
        self._fits[e] = fits
        cost = max(f[1] for f in fits) + max(
            (_mismatch(r, _homog(self.segment(e, lo, hi)), self.max_degree) * size
             for lo, hi, r, size in uses if r.shape[1] == 4), default=0.0)
        for key in [k for k in self._k if k[0] == e]:  # segments cut from the fits while costing
            del self._k[key]
        for key in [k for k in self._corners if k[0] == "e" and k[1] == e]:  # and their corners
            del self._corners[key]
        if cost < exact:
            self.fit_error[e] = max(f[1] for f in fits)
        else:
            del self._fits[e]
        self._alias_moves.clear()

    def decide_midway(self, e: int, cuts: np.ndarray) -> bool:
        """Use the curve midway between the two faces' boundaries S_f(pc_f(w)) on edge ``e`` when its
        3D curve lies farther from both faces than the faces lie from each other (sampled at nine
        points of every piece of the edge plan). The midway curve is fitted per plan piece
        (``cuts`` are the plan's inner parameters) by the lowest-degree polynomial within
        ``poly_tol``, then corrected affinely in w onto the model's vertices like C; every segment
        and corner of the edge is cut from these fits. Returns whether it was chosen."""
        edge = self.model.edges[e]
        if edge.curve is None or edge.seam or edge.degenerate or len(edge.faces) != 2:
            return False
        tracks = []
        for f in edge.faces:
            pcs = [ce for loop in self.model.faces[f].loops for ce in loop.coedges
                   if ce.edge == e and ce.pcurve is not None]
            if len(pcs) != 1:
                return False
            tracks.append((self.model.faces[f].surface, pcs[0].pcurve))
        breaks = np.concatenate([[edge.first], np.asarray(cuts, dtype=float), [edge.last]])

        def boundary(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            a, b = (srf.evaluate(pc.evaluate(w)) for srf, pc in tracks)
            return a, b

        w = np.concatenate([np.linspace(x0, x1, 9) for x0, x1 in zip(breaks[:-1], breaks[1:], strict=True)])
        a, b = boundary(w)
        c = edge.curve.evaluate(w)
        d_ab = float(np.linalg.norm(a - b, axis=1).max())
        d_c = min(float(np.linalg.norm(c - a, axis=1).max()), float(np.linalg.norm(c - b, axis=1).max()))
        # only where it pays: C at least twice as far from the nearer face as the faces are apart,
        # and farther than ten fit tolerances (exact models keep their exact C)
        if not (d_c > 2.0 * d_ab and d_c > 10.0 * self.poly_tol):
            return False
        nets, err = [], 0.0
        # per piece: the midway points at Chebyshev-Lobatto nodes (fit) and on a uniform grid
        # (check), evaluated once; then the lowest degree whose least-squares fit with the ends
        # held is within poly_tol on the check grid
        n = 8 * (self.max_degree + 1)
        tc = 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / (n - 1))
        te = np.linspace(0.0, 1.0, 401)
        for x0, x1 in zip(breaks[:-1], breaks[1:], strict=True):
            pa, pb = boundary(x0 + np.concatenate([tc, te]) * (x1 - x0))
            mid = 0.5 * (pa + pb)
            xc, xe = mid[:n], mid[n:]
            fit = None
            for q in range(1, self.max_degree + 1):
                ctrl = fit_points(tc, xc, q)
                dev = float(np.linalg.norm(basis(q, te) @ ctrl - xe, axis=1).max())
                if dev <= self.poly_tol:
                    fit = (ctrl, dev)
                    break
            if fit is None:
                return False
            nets.append(fit[0])
            err = max(err, fit[1])
        # onto the model's vertices, affinely in w (as ``exact`` does for C)
        v = self.vertices[list(edge.vertices)]
        d0, d1 = v[0] - nets[0][0], v[1] - nets[-1][-1]
        span = edge.last - edge.first
        for i, (x0, x1) in enumerate(zip(breaks[:-1], breaks[1:], strict=True)):
            lam = (np.array([x0, x1]) - edge.first) / span
            D = np.outer(1.0 - lam, d0) + np.outer(lam, d1)
            K = nets[i]
            nets[i] = K + (elevate_curve(D, K.shape[0] - 2) if K.shape[0] > 2 else D)
        self._mid[e] = (breaks, nets)
        self._alias_moves.clear()
        self.mid_error[e] = err + max(float(np.linalg.norm(d0)), float(np.linalg.norm(d1)))
        return True

    def _polynomial(self, K: np.ndarray):
        xyz = lambda t: rational_curve_eval(K, t)  # noqa: E731
        for q in range(max(1, K.shape[0] - 1), self.max_degree + 1):
            fit = fit_curve(xyz, q, self.poly_tol)
            if fit is not None:
                return fit
        return None

    def segment(self, e: int, wa: float, wb: float) -> np.ndarray:
        """The shared curve on [wa, wb] (reversed when wa > wb): (k+1, 3), or (k+1, 4) homogeneous.
        Its ends are exactly the corner points there (``corner``): a piece that crosses a knot of
        C, or is cut from another span than the corner, ends a hair off it, and setting the corner
        afterwards would bend each patch's row differently at its own degree. The ends are moved
        by a straight blend instead (in the homogeneous numerator for a rational K), once for
        every patch that takes the piece."""
        key = self.key(e, wa, wb)
        K = self._k.get(key)
        if K is None:
            lo, hi = key[1], key[2]
            K = self._piece(e, lo, hi)
            if K.shape[0] > 1:
                ends = K[[0, -1], :3] / K[[0, -1], 3:4] if K.shape[1] == 4 else K[[0, -1]]
                want = np.array([self.corner(self.corner_key(e, w)) for w in (lo, hi)])
                delta = want - ends
                if delta.any():
                    lam = np.linspace(0.0, 1.0, K.shape[0])[:, None]
                    blend = (1.0 - lam) * delta[0] + lam * delta[1]
                    K = K.copy()
                    if K.shape[1] == 4:
                        K[:, :3] += blend * K[:, 3:4]
                        K[[0, -1], :3] = want * K[[0, -1], 3:4]
                    else:
                        K += blend
                        K[[0, -1]] = want
            self._k[key] = K
        return K if wa <= wb else K[::-1]

    def between(self, ka, kb, face: int) -> list[np.ndarray]:
        """The shared curves from corner ``ka`` to corner ``kb`` (``corner_key`` values): the
        segments, each within one piece of its edge's curve, of the edges of ``face`` that run
        between the two (both on one edge, or a vertex and a point of an edge that ends there,
        or two vertices of an edge). Oriented from ka to kb."""
        if ka is None or kb is None or ka == kb:
            return []
        found = []
        for ce in (ce for loop in self.model.faces[face].loops for ce in loop.coedges):
            edge = self.model.edges[ce.edge]
            if edge.curve is None or edge.degenerate or ce.edge in {x[1] for x in found}:
                continue
            at = []
            for k in (ka, kb):
                if k[0] == "e":
                    at.append([k[2]] if k[1] == ce.edge else [])
                else:
                    at.append([w for w, v in ((edge.first, edge.vertices[0]), (edge.last, edge.vertices[1]))
                               if v == k[1]])
            for wa in at[0]:
                for wb in at[1]:
                    if wa != wb and self._one_piece(ce.edge, min(wa, wb), max(wa, wb)):
                        found.append((self.segment(ce.edge, wa, wb), ce.edge))
        return [K for K, _ in found]

    def _one_piece(self, e: int, lo: float, hi: float) -> bool:
        """Whether [lo, hi] lies within one piece of what ``_piece`` cuts from (a span of C or of
        its fit, a plan piece of the midway curve): a segment across a break is not the curve."""
        br = self._mid[e][0] if e in self._mid else self.spans(e)[0]
        inner = br[1:-1]
        eps = 1e-9 * max(float(br[-1] - br[0]), 1e-300)
        return not np.any((inner > lo + eps) & (inner < hi - eps))

    def _piece(self, e: int, lo: float, hi: float) -> np.ndarray:
        """The shared curve on [lo, hi]: ``_cut`` plus the aliased corners' move (``_alias_move``)."""
        K = self._cut(e, lo, hi)
        move = self._alias_move(e)
        if move is None:
            return K
        ws, d = move
        D = np.stack([np.interp([lo, hi], ws, d[:, k]) for k in range(3)], axis=1)  # affine in w here
        if not D.any():
            return K
        if K.shape[1] == 3:
            return K + (elevate_curve(D, K.shape[0] - 2) if K.shape[0] > 2 else D)
        Dw = product(D, K[:, 3])
        return np.concatenate([elevate_curve(K, 1)[:, :3] + Dw, elevate_curve(K[:, 3:], 1)], axis=1)

    def _alias_move(self, e: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Where a corner of edge e is another edge's corner (``corner_alias``: the far end of a
        tail, ``_Tails``), the edge's curve moves there by the distance between the two, and the
        move fades linearly in w to nothing at the next such corner or the edge's end: (knots w,
        moves). One function of w for the whole edge, so every segment cut from it is a piece of
        one curve. Moving each segment's end by a straight blend of its own (``segment``) bent a
        long side and the short ones beside it differently: at fusee's cusp a neighbour's corner
        stood 1.7e-7 off a side that ended at the moved corner. None when no corner moves."""
        if e not in self._alias_moves:
            self._alias_moves[e] = None  # while it is computed (an alias of an alias stays still)
            alias = self.corner_alias.get(e, ())
            if alias:
                edge = self.model.edges[e]
                knots = {edge.first: np.zeros(3), edge.last: np.zeros(3)}
                for x, e1, x1 in alias:
                    h = self._cut(e, x, x)[0]
                    here = h[:3] / h[3] if h.shape[0] == 4 else h
                    knots[float(x)] = self.corner(self.corner_key(e1, x1)) - here
                ws = np.array(sorted(knots))
                self._alias_moves[e] = (ws, np.array([knots[w] for w in ws]))
        return self._alias_moves[e]

    def _cut(self, e: int, lo: float, hi: float) -> np.ndarray:
        """The shared curve on [lo, hi] as cut from C', its fits or the midway curve."""
        if e in self._mid:
            br, nets = self._mid[e]
            j = int(np.clip(np.searchsorted(br, 0.5 * (lo + hi), side="right") - 1, 0, len(nets) - 1))
            x0, x1 = br[j], br[j + 1]
            if lo < x0 - 1e-9 * (x1 - x0) or hi > x1 + 1e-9 * (x1 - x0):
                self.straddles += 1
            K = curve_segment(nets[j], (lo - x0) / (x1 - x0), (hi - x0) / (x1 - x0))
        elif e in self._fits:
            br = self.spans(e)[0]
            j = int(np.clip(np.searchsorted(br, 0.5 * (lo + hi), side="right") - 1, 0, len(br) - 2))
            x0, x1 = br[j], br[j + 1]
            K = curve_segment(self._fits[e][j][0], (lo - x0) / (x1 - x0), (hi - x0) / (x1 - x0))
        else:
            K = self.exact(e, lo, hi)
        return K


class _Tails:
    """The tails beyond the faces' crossings (``untrim.crossing_tails``), taken as one boundary.

    Where a face's two pcurves (edges a and b) cross a hair before the vertex V they meet at, the
    face ends at the crossing and its neighbours across a and across b meet each other from there
    to V: a's tail [xa, V] and b's tail [xb, V] are one boundary, and the crossing is one corner.
    The edge plan cut both edges at the crossing (``untrim._crossing_cuts``); here the sides on
    b's tail take a's tail (b's parameter mapped affinely onto a's), so the two neighbours get the
    same curve, and a corner at b's crossing parameter is a's corner there. The edge with the lower
    index keeps its own curve."""

    def __init__(self, model: Model, result: UntrimResult):
        self.maps: dict[int, list[tuple[float, float, int, float, float]]] = {}
        seen = set()
        for fr in result.faces:
            for (ea, xa, fa), (eb, xb, fb) in crossing_tails(model, fr):
                if (eb, xb) not in seen:
                    seen.add((eb, xb))
                    self.maps.setdefault(eb, []).append((xb, fb, ea, xa, fa))

    def rewrite(self, ref: _Ref | None) -> None:
        """Put a side on b's tail onto a's tail, in place."""
        if ref is None or ref.pole or ref.along is not None:
            return
        for xb, fb, ea, xa, fa in self.maps.get(ref.edge, ()):
            lo, hi = min(xb, fb), max(xb, fb)
            eps = 1e-9 * (hi - lo)
            if all(lo - eps <= w <= hi + eps for w in (ref.wa, ref.wb)):
                f = (fa - xa) / (fb - xb)
                ref.edge = ea
                ref.wa, ref.wb = (fa if w == fb else xa + (w - xb) * f for w in (ref.wa, ref.wb))
                return

    def corners(self) -> dict[int, list[tuple[float, int, float]]]:
        """b -> [(xb, a, xa)]: the crossing's corner on b is a's (``_Curves.corner_alias``)."""
        return {eb: [(xb, ea, xa) for xb, _, ea, xa, _ in maps] for eb, maps in self.maps.items()}


def _weight_factor(kappa: np.ndarray, budget: int) -> np.ndarray:
    """K's weight function kappa (normalized to kappa[0] = 1), or its least-squares reduction to the
    degree ``budget`` that a polynomial patch can still take (ends kept)."""
    kappa = kappa / kappa[0]
    k = len(kappa) - 1
    if k <= budget:
        return kappa
    if budget < 1:
        return np.ones(1)
    return reduce_curve(kappa[:, None], budget, fix_ends=1)[0][:, 0]


def _divide(omega: np.ndarray, kappa: np.ndarray) -> np.ndarray | None:
    """g with kappa * g = omega (Bernstein coefficients, degree len(omega) - len(kappa)), or None when
    omega has no such factor. A row S(pc(w)) of a rational patch and a segment of a 3D curve that
    is the same rational curve in the same parameter differ by such a common factor; the row then
    takes K * g. The factor is fitted with its end values fixed (kappa * g has omega's end weights,
    so the corners and the sides through them keep theirs); the division counts when the rest
    matches within ``_DIVIDE_REL``."""
    d, k = len(omega) - 1, len(kappa) - 1
    if d < k:
        return None
    A = product(kappa, np.eye(d - k + 1))  # column j: kappa times the j-th Bernstein basis polynomial
    if d == k:
        g = np.array([omega[0] / kappa[0]])
    else:
        g = np.zeros(d - k + 1)
        g[0], g[-1] = omega[0] / kappa[0], omega[-1] / kappa[-1]
        if d - k > 1:
            g[1:-1], *_ = np.linalg.lstsq(A[:, 1:-1], omega - A[:, 0] * g[0] - A[:, -1] * g[-1], rcond=None)
    if np.abs(A @ g - omega).max() > _DIVIDE_REL * np.abs(omega).max():
        return None
    return g


def _mismatch(row: np.ndarray, K: np.ndarray, max_degree: int) -> float:
    """Relative weight mismatch left when ``row`` takes K after the best scale and Moebius change of
    parameter (0 when the weights agree). A polynomial row is first multiplied by K's weight
    function, reduced to the degree budget (see ``_weight_factor``)."""
    d, k = row.shape[0] - 1, K.shape[0] - 1
    if row.shape[1] == 3:
        if K.shape[1] == 3:
            return 0.0
        w_row = _weight_factor(K[:, 3], max_degree - max(d, k))
    else:
        w_row = row[:, 3]
        if _divisible(w_row, K[:, 3] if K.shape[1] == 4 else np.ones(k + 1)) or d + k <= max_degree:
            return 0.0  # divides, or the patch takes K's weights as a factor (``_common_weights``)
    n = max(len(w_row) - 1, k)
    w_row = elevate_curve(w_row[:, None], n - len(w_row) + 1)[:, 0]
    w = K[:, 3] if K.shape[1] == 4 else np.ones(k + 1)
    w = elevate_curve(w[:, None], n - k)[:, 0] if n > k else w
    r = np.log(w_row / w)
    line = r[0] + (r[-1] - r[0]) * np.arange(n + 1) / max(n, 1)
    return float(np.abs(r - line).max())


class IsoPieces:
    """A face's u-iso boundary pieces (``FaceResult.iso_pieces``) with their ends' u and v-range as
    arrays, so that ``_rung_ref`` finds a rung's piece by one vectorized test instead of a loop over
    every piece for every rung (gmsh__wing_fuselage.step: 45 s of the substitution's 84 s, its face
    13 having thousands of both). Pieces that are several edges (``edge`` None) are left out."""

    def __init__(self, pieces):
        self.pieces = [p for p in pieces if p.edge is not None]
        uv = np.array([p.H[[0, -1], :2] / p.H[[0, -1], 2:3] for p in self.pieces]).reshape(-1, 2, 2)
        self.uv = uv
        self.u0, self.u1 = uv[:, 0, 0], uv[:, 1, 0]
        self.vlo, self.vhi = uv[:, :, 1].min(axis=1), uv[:, :, 1].max(axis=1)

    def first(self, a: np.ndarray, b: np.ndarray, eps: tuple[float, float]) -> int | None:
        """The first piece (in the face's order) on whose u-iso line, and within whose v-range, the
        rung from ``a`` to ``b`` lies."""
        if not self.pieces:
            return None
        du = np.maximum(np.maximum(np.abs(a[0] - self.u0), np.abs(b[0] - self.u0)), np.abs(a[0] - self.u1))
        ok = ((du <= 2 * eps[0]) & (min(a[1], b[1]) >= self.vlo - eps[1])
              & (max(a[1], b[1]) <= self.vhi + eps[1]))
        k = int(np.argmax(ok))
        return k if ok[k] else None

    def pair(self, a: np.ndarray, b: np.ndarray, eps: tuple[float, float]) -> tuple[int, int] | None:
        """Two pieces of one edge that meet end to end on the u-iso line of the rung from ``a`` to
        ``b``, the first holding ``a`` and the second ``b`` (when no one piece holds it): stage 1
        dropped a plan cut a sliver beside a knot line (``untrim._sliver_cuts_dropped``), so the
        rung ends at the knot line, a hair past the piece that ends at the plan's parameter."""
        if not self.pieces:
            return None
        du = np.maximum(np.maximum(np.abs(a[0] - self.u0), np.abs(b[0] - self.u0)), np.abs(a[0] - self.u1))
        line = du <= 2 * eps[0]
        if not line.any():
            return None
        has = [np.flatnonzero(line & (x[1] >= self.vlo - eps[1]) & (x[1] <= self.vhi + eps[1]))
               for x in (a, b)]
        for i in has[0]:
            for j in has[1]:
                if i != j and self.pieces[i].edge == self.pieces[j].edge and (
                        np.abs(self.uv[i, 1] - self.uv[j, 0]).max() <= 0.0
                        or np.abs(self.uv[i, 0] - self.uv[j, 1]).max() <= 0.0):
                    return int(i), int(j)
        return None


def _rung_ref(pieces, a: np.ndarray, b: np.ndarray, eps: tuple[float, float], length: float = 0.0,
              slide: float = 0.0) -> _Ref | None:
    """The edge interval of a rung from uv ``a`` to ``b`` when it lies on a u-iso boundary piece
    (``pieces``: the face's iso pieces, as a list or, for many rungs, as one ``IsoPieces``).

    The rung runs linearly in v; the edge's parameter may not. Taking the curve then slides each
    point of the row along the side by up to 2 x (v's departure from affine on the piece) x the
    side's speed (``length`` / its v extent, model units); that is allowed up to ``slide`` (the
    move is measured and bounded like any other). Beyond it the reference carries the piece
    (``_Ref.along``), and the rung takes the curve at its own parameter (``_rung_row``)."""
    table = pieces if isinstance(pieces, IsoPieces) else IsoPieces(pieces)
    k = table.first(a, b, eps)
    if k is None:
        two = table.pair(a, b, eps)
        if two is None:
            return None
        ws, bent = [], False
        for x, m in zip((a, b), two, strict=True):
            p = table.pieces[m]
            if p.degenerate:
                return None
            bent = bent or (p.H.shape[0] > 2
                            and not _affine_enough(p.H, abs(b[1] - a[1]), eps[1], length, slide))
            ws.append(p.w0 + _t_at_u(p.H, float(x[1]), axis=1) * (p.w1 - p.w0))
        # the rung then takes K at its own parameter over both pieces, as over one bent piece
        # (trj8: a rung over a piece 0.18 long that is not affine and one 1e-6 long beside it,
        # where stage 1 dropped the cut at the pcurve's knot, ``untrim._knot_cuts_dropped``)
        along = None
        if bent:
            along = (tuple((table.pieces[m].H, table.pieces[m].w0, table.pieces[m].w1) for m in two),
                     ws[0], ws[1], float(a[1]), float(b[1]))
        return _Ref(table.pieces[two[0]].edge, ws[0], ws[1], along=along)
    p, uv = table.pieces[k], table.uv[k]
    if p.degenerate:
        return _Ref(p.edge, p.w0, p.w1, pole=True)
    along = None
    if p.H.shape[0] > 2 and not _affine_enough(p.H, abs(b[1] - a[1]), eps[1], length, slide):
        along = (p.H, p.w0, p.w1, float(a[1]), float(b[1]))
    ws = [p.w0 + _t_at_u(p.H, float(x[1]), axis=1) * (p.w1 - p.w0) for x in (a, b)]
    # snap to the piece's ends, so corners at plan parameters get the plan's floats
    ws = [p.w0 if abs(x[1] - uv[0, 1]) <= eps[1] else p.w1 if abs(x[1] - uv[1, 1]) <= eps[1] else w
          for x, w in zip((a, b), ws, strict=True)]
    return _Ref(p.edge, ws[0], ws[1], along=along)


def _piece_t_at_v(H: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Parameters of a homogeneous uv piece monotone in v where it reaches the values ``v``: the
    vectorized counterpart of ``untrim._t_at_u`` (a dense table, then Newton steps on v(t))."""
    grid = np.linspace(0.0, 1.0, 257)
    table = _eval(H, grid)[:, 1]
    order = np.argsort(table)
    t = np.interp(v, table[order], grid[order])
    D = _deriv_h(H)
    for _ in range(4):
        h, dh = basis(H.shape[0] - 1, t) @ H, basis(D.shape[0] - 1, t) @ D
        dv = (dh[:, 1] * h[:, 2] - h[:, 1] * dh[:, 2]) / h[:, 2] ** 2  # (y / w)'
        step = np.divide(h[:, 1] / h[:, 2] - v, dv, out=np.zeros_like(t), where=dv != 0.0)
        t = np.clip(t - step, 0.0, 1.0)
    return t


def _edge_w_at_v(along: tuple, v: np.ndarray) -> np.ndarray:
    """The edge parameter where a rung's iso piece reaches the values ``v`` (``_Ref.along``: its
    first three entries are the piece's H, w0 and w1, or, for two pieces of one edge end to end,
    a tuple of (H, w0, w1) per piece, each then taking the v within its own range)."""
    if isinstance(along[0], np.ndarray):
        H, w0, w1 = along[:3]
        return w0 + _piece_t_at_v(H, v) * (w1 - w0)
    w = np.empty_like(v)
    done = np.zeros(v.shape, dtype=bool)
    for k, (H, w0, w1) in enumerate(along[0]):
        ends = H[[0, -1], 1] / H[[0, -1], 2]
        mine = ~done & ((v >= ends.min()) & (v <= ends.max()) if k < len(along[0]) - 1 else True)
        if mine.any():
            w[mine] = w0 + _piece_t_at_v(H, v[mine]) * (w1 - w0)
            done |= mine
    return w


def _rung_samples(K: np.ndarray, along: tuple, max_degree: int):
    """K at a rung's own parameter, K(a(t)), sampled at Chebyshev points ``tc`` (for a fit) and at
    even points ``te`` (to measure it): (tc, K(a(tc)), te, K(a(te))); None where a is constant."""
    va, vb = along[3], along[4]
    n = 8 * (max_degree + 1)
    tc = 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / (n - 1))
    te = np.linspace(0.0, 1.0, 201)
    t = np.concatenate([tc, te])
    w = _edge_w_at_v(along, va + t * (vb - va))
    if w[n - 1] == w[0]:
        return None
    a = np.clip((w - w[0]) / (w[n - 1] - w[0]), 0.0, 1.0)
    pts = rational_curve_eval(_homog(K), a)
    return tc, pts[:n], te, pts[n:]


def _rung_row(K: np.ndarray, along: tuple, max_degree: int, target: float,
              samples: tuple | None = None) -> np.ndarray | None:
    """The row of a rung that lies on an iso piece of an edge whose parameter is not affine along
    the rung: K at the rung's own parameter, K(a(t)) with a(t) the edge parameter where the rung
    (linear in v) reaches v(t), normalized to [0, 1]. A polynomial of the lowest degree (up to
    ``max_degree``) whose least-squares fit with the ends held is within ``target`` of it; None
    past the budget. The rung then lies on the shared curve to the fit's error instead of staying
    on the face's own boundary (the input's gap away) or sliding along it. ``samples``: those of
    ``_rung_samples``, when the caller has them."""
    samples = samples or _rung_samples(K, along, max_degree)
    if samples is None:
        return None
    tc, pc, te, pe = samples
    for q in range(max(1, K.shape[0] - 1), max_degree + 1):
        F = fit_points(tc, pc, q)
        if float(np.linalg.norm(basis(q, te) @ F - pe, axis=1).max()) <= target:
            return F
    return None


def _rung_slide(K: np.ndarray, along: tuple, max_degree: int, samples: tuple | None = None) -> float:
    """How far K in its own parameter (the row a rung takes when its fit fails) lies from K at the
    rung's parameter: the patch's interior slides along the rung by this much."""
    samples = samples or _rung_samples(K, along, max_degree)
    if samples is None:
        return float("inf")
    _, _, te, pe = samples
    return float(np.linalg.norm(rational_curve_eval(_homog(K), te) - pe, axis=1).max())


def _affine_enough(H: np.ndarray, dv: float, veps: float, length: float, slide: float) -> bool:
    """Whether a piece's v is affine in its parameter within ``veps``, or close enough that a rung
    of v extent ``dv`` and 3D ``length`` slides by at most ``slide`` taking the edge's curve."""
    if np.allclose(H[:, 2], H[0, 2]):
        v = H[:, 1] / H[:, 2]
        even = v[0] + (v[-1] - v[0]) * np.arange(len(v)) / (len(v) - 1)
        dev = float(np.abs(v - even).max())  # convex hull: bounds v(w) - affine
    else:
        t = np.linspace(0.0, 1.0, 33)
        v = _eval(H, t)[:, 1]
        dev = float(np.abs(v - (v[0] + t * (v[-1] - v[0]))).max())
    if dev <= veps:
        return True
    return dv > 0 and 2.0 * dev * length / dv <= slide


def _refs(patch: Patch, fr_pieces, eps, slide: float = 0.0) -> tuple[dict[str, _Ref | None], np.ndarray]:
    """Each side's edge reference (None for inner sides) and the patch's corner uv (2, 2, 2);
    ``slide`` as in ``_rung_ref``."""
    cm = cell_map(patch, np.array([0.0, 1.0]), np.array([0.0, 1.0]))
    out: dict[str, _Ref | None] = {}
    for name, side in (("bottom", patch.bottom), ("top", patch.top)):
        if side.edge is None:
            out[name] = None
        else:
            out[name] = _Ref(side.edge, side.w0, side.w1, pole=side.degenerate)
    for k, name in enumerate(("left", "right")):
        out[name] = _rung_ref(fr_pieces, cm[k, 0], cm[k, 1], eps, _side_length(patch, k), slide)
    return out, cm


def _side_length(patch: Patch, k: int) -> float:
    """The control polygon's length (a bound of the side's length) of the left (``k`` 0) or right
    (1) side of a patch."""
    row = patch.ctrl[0 if k == 0 else -1]
    xyz = row[:, :3] / row[:, 3:4] if patch.rational else row
    return float(np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum())


def _cartesian(H: np.ndarray, rational: bool) -> np.ndarray:
    return H[..., :3] / H[..., 3:4] if rational else H


def _elevation_for(net: np.ndarray, axis: int) -> int:
    """How far to elevate a net along ``axis``: to twice its degree, within OCCT's limit."""
    return max(1, min(net.shape[axis] - 1, 25))


def _elevated_bound(diff: np.ndarray) -> float:
    """max |D(s, t)| of a Bezier difference net, bounded on the net elevated to about twice its
    degrees (the control points of an elevated net converge to the values; the convex hull keeps
    it a bound)."""
    hull = float(np.linalg.norm(diff, axis=-1).max())
    if hull == 0.0:
        return 0.0
    up = elevate_surface(diff, min(_ELEVATE, _elevation_for(diff, 0)), min(_ELEVATE, _elevation_for(diff, 1)))
    return min(hull, float(np.linalg.norm(up, axis=-1).max()))


def _change(old: np.ndarray, new: np.ndarray, rational: bool) -> tuple[float, bool]:
    """Bound of max |new - old| over the patch (both the same surface type and degree): the largest
    control-point move when the weights are equal (convex hull), else sampled and flagged."""
    if not rational:
        return _elevated_bound(new - old), False
    if np.allclose(old[..., 3], new[..., 3], rtol=1e-12, atol=0.0):
        hull = float(np.linalg.norm(_cartesian(new, True) - _cartesian(old, True), axis=-1).max())
        # N / W with N = sum w dP B and W = sum w B: |N| and W bounded on elevated nets
        w = new[..., 3]
        num = (_cartesian(new, True) - _cartesian(old, True)) * w[..., None]
        ru, rv = min(_ELEVATE, _elevation_for(w, 0)), min(_ELEVATE, _elevation_for(w, 1))
        wmin = float(elevate_surface(w[..., None], ru, rv).min())
        tight = _elevated_bound(num) / wmin if wmin > 0 else np.inf
        return min(hull, tight), False
    s = np.linspace(0.0, 1.0, _SAMPLES)
    s = np.unique(np.concatenate([s, s[:3] * 0.1, 1 - s[:3] * 0.1]))

    def pts(H):
        m1, n1, d = H.shape
        h = basis(n1 - 1, s)[None] @ (basis(m1 - 1, s) @ H.reshape(m1, n1 * d)).reshape(-1, n1, d)
        return h[..., :3] / h[..., 3:4]

    return float(np.linalg.norm(pts(new) - pts(old), axis=-1).max()), True


def _refit(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """A rational patch whose weights changed (a row took a K with other weights): refit its inner
    control points (all but the four sides, which neighbours share) so the surface stays on the
    stage-1 patch, moved as its rows and corners moved. With the new weights fixed the fit is
    linear: sum_ij B_i B_j w_ij P_ij = D(s, t) S(s, t), solved by least squares on a Chebyshev
    grid. In the unknowns Q_ij = w_ij P_ij the system is the Kronecker product of the two inner
    basis matrices, so its least-squares solution is pinv(Bs) R pinv(Bt)^T: two small
    pseudo-inverses instead of one dense solve (which took most of the conversion time of models
    refit at degree 24)."""
    m1, n1 = new.shape[:2]
    if m1 < 3 or n1 < 3:
        return new
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, 2 * m1 + 1))
    t = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, 2 * n1 + 1))
    bs, bt = basis(m1 - 1, s), basis(n1 - 1, t)
    target = np.einsum("ai,bj,ijd->abd", bs, bt, old)
    # the old surface plus the move of the net (rows, corners) blended as in a polynomial patch:
    # fitting the old surface itself would ask the inside to bend back from moved rows within
    # the patch, which a high-degree net can only do with huge control points
    move = _cartesian(new, True) - _cartesian(old, True)
    S = target[..., :3] / target[..., 3:4] + np.einsum("ai,bj,ijd->abd", bs, bt, move)
    w = new[..., 3]
    D = bs @ w @ bt.T
    fixed = new[..., :3].copy()
    fixed[1:-1, 1:-1] = 0.0
    rhs = D[..., None] * S - np.einsum("ai,bj,ijd->abd", bs, bt, fixed)
    ps, pt = np.linalg.pinv(bs[:, 1:-1]), np.linalg.pinv(bt[:, 1:-1])
    out = new.copy()
    out[1:-1, 1:-1, :3] = np.einsum("ia,abd,jb->ijd", ps, rhs, pt)
    return out


def _row(H: np.ndarray, name: str) -> np.ndarray:
    return H[SIDES[name][0]]


def _degrees_for(H: np.ndarray, rows: dict[str, np.ndarray]) -> tuple[int, int]:
    ds, dt = H.shape[0] - 1, H.shape[1] - 1
    for name, K in rows.items():
        if SIDES[name][1] == "s":
            ds = max(ds, K.shape[0] - 1)
        else:
            dt = max(dt, K.shape[0] - 1)
    return ds, dt


def _put(H: np.ndarray, name: str, K: np.ndarray) -> None:
    """Write K into the row ``name`` of H at H's degree (in place).

    In a rational H the row keeps its weights where they are K's times a common factor (see
    ``_divide``); otherwise K's weights are matched to the row's corner weights by a scale and a
    Moebius change of parameter (both keep K's shape), so the corners, which two rows share, keep
    their weights, and the caller refits the inner control points."""
    idx, axis, _ = SIDES[name]
    d = (H.shape[0] if axis == "s" else H.shape[1]) - 1
    if H.shape[-1] == 4 and d > 0:
        row = H[idx]
        g = _divide(row[:, 3], K[:, 3])
        if g is not None:  # K itself, written with (nearly) the row's weights
            H[idx] = product(K, g) if len(g) > 1 else K * g[0]
            return
    if K.shape[0] - 1 < d:
        K = elevate_curve(K, d - (K.shape[0] - 1))
    if H.shape[-1] == 4 and d > 0:
        K = _match_ends(K, H[idx])
    H[idx] = K


def _match_ends(K: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Homogeneous K (same degree as ``row``) with the end weights of ``row``, by a scale and a
    Moebius change of parameter (neither changes K's shape): the corners, which the rows through
    them share, keep their weights, so those rows keep their shapes."""
    d = K.shape[0] - 1
    rho = ((row[-1, 3] / row[0, 3]) * (K[0, 3] / K[-1, 3])) ** (1.0 / d)
    K = K * (rho ** np.arange(d + 1))[:, None]
    return K * (row[0, 3] / K[0, 3])


def _divisible(omega: np.ndarray, kappa: np.ndarray) -> bool:
    """omega (a row's weights) is kappa times a polynomial, at omega's degree or K's."""
    if len(omega) < len(kappa):
        omega = elevate_curve(omega[:, None], len(kappa) - len(omega))[:, 0]
    return _divide(omega, kappa) is not None


def _common_weights(H: np.ndarray, rows: dict[str, np.ndarray], max_degree: int,
                    added: list | None = None) -> np.ndarray:
    """A rational net made ready to take its rows exactly, in K's own parameter: along each axis, H
    is multiplied by the weight function kappa of every K whose row weights omega it does not
    divide (a polynomial K counts as kappa = 1 at K's degree, which elevates H by that degree).
    The surface is unchanged, and each row's weights become omega times kappa times the other
    factors, so ``_put`` divides them exactly. Left as it is past ``max_degree`` (``_put`` then
    matches corner weights and the caller refits). The factors used go into ``added``."""
    for axis, names in ((0, ("bottom", "top")), (1, ("left", "right"))):
        needing = [n for n in names if n in rows and not _divisible(_row(H, n)[:, 3], rows[n][:, 3])]
        factors = [rows[n][:, 3] for n in needing]
        if factors and all(np.all(f == f[0]) for f in factors):
            H = _elevated_to_divide(H, axis, {n: rows[n] for n in needing}, max_degree)
            continue
        if not factors or H.shape[axis] - 1 + sum(len(f) - 1 for f in factors) > max_degree:
            continue
        for f in factors:
            H = _times(H, axis, f / f[0], added)
    return H


def _elevated_to_divide(H: np.ndarray, axis: int, rows: dict[str, np.ndarray], max_degree: int) -> np.ndarray:
    """H elevated along ``axis`` by the fewest degrees (within ``max_degree``) at which each row's
    weights omega hold a polynomial K (kappa = 1 at K's degree k): omega times 1 at degree k must
    reach k + omega's own degree. Multiplying by kappa = 1 at degree k elevates by all of k, which
    went past the budget where a few degrees do (filleted_freeform: rows of degree 14 with weights
    of degree 7 taking a degree-14 K need 21, not 28; matched by a Moebius change instead, their
    sides slid 6.9e-5 along the edge, which a second conversion took as a move). Left as it is
    when no degree within the budget does."""
    # a row of the net elevated along its own axis is the row elevated: only the weights are
    # elevated while the degree is sought, the net once it is found
    weights = {n: _row(H, n)[:, 3:4] for n in rows}
    for m in range(1, max_degree - (H.shape[axis] - 1) + 1):
        if all(_divisible(elevate_curve(weights[n], m)[:, 0], K[:, 3]) for n, K in rows.items()):
            return elevate_surface(H, m, 0) if axis == 0 else elevate_surface(H, 0, m)
    return H


def _times(H: np.ndarray, axis: int, f: np.ndarray, added: list | None = None) -> np.ndarray:
    """The same rational surface with its homogeneous net times the weight function ``f`` (Bernstein
    coefficients) along ``axis``; the factor is recorded in ``added``."""
    if added is not None:
        added.append((axis, f))
    return np.swapaxes(product(np.swapaxes(H, 0, axis), f, axis=0), 0, axis)


def _missing_factors(H: np.ndarray, own: list, partner: list, axis: int, max_degree: int,
                     added: list) -> np.ndarray:
    """An inner side shared by two rational patches that each took other curves' weight functions
    (a cell cut under another, one below taking its bottom's K, one above its top's): the row's
    weights are w x kappa_1 against w x kappa_2. Multiplying this net by the partner's factors
    along the side that it lacks makes its weights a multiple of the partner's at the degree the
    uncut cell had; multiplying by the partner's whole row weights (as ``_common_weights`` would)
    doubles the degree (44 for bug33398's blends)."""
    missing = [f for ax, f in partner if ax == axis
               and not any(a2 == ax and len(g) == len(f) and np.allclose(g, f, rtol=1e-12, atol=0.0)
                           for a2, g in own)]
    if not missing or H.shape[axis] - 1 + sum(len(f) - 1 for f in missing) > max_degree:
        return H
    for f in missing:
        H = _times(H, axis, f, added)
    return H


def _curve_distance(a: np.ndarray, b: np.ndarray, rational: bool) -> float:
    """A certified bound of max_t |a(t) - b(t)| for two Bezier curves of any degrees (homogeneous
    when ``rational``): the convex hull of their difference at the higher of the two degrees; for
    rational ones the largest ratio |n_i| / d_i of the coefficients of N = N_b W_a - N_a W_b and
    D = W_a W_b (D > 0), which bounds |N(t)| / D(t) since both are the same Bernstein blend. Each
    is taken on the polynomials elevated by their own degree, where control points lie closer to
    the values (a rounded degree-3 curve against its reduction: 1.9e-10 on the net, 4.8e-11
    elevated, 6.8e-12 sampled; a rounded rational line written at degree 4, weights 0.58 to 1.87,
    against its reduction: 1.8e-10 as max |n_i| over min d_i, 2.8e-11 as the ratio, 1.6e-11
    sampled)."""
    if not rational:
        k = max(len(a), len(b)) - 1
        up = lambda c: elevate_curve(c, k - (len(c) - 1))  # noqa: E731
        diff = up(a) - up(b)
        return float(np.linalg.norm(elevate_curve(diff, max(k, 1)), axis=1).max())
    num = product(b[:, :3], a[:, 3]) - product(a[:, :3], b[:, 3])
    den = product(a[:, 3:], b[:, 3:])
    d = max(len(num) - 1, 1)
    den = elevate_curve(den, d)[:, 0]
    if den.min() <= 0.0:
        return float("inf")
    return float((np.linalg.norm(elevate_curve(num, d), axis=1) / den).max())


def _homog(K: np.ndarray) -> np.ndarray:
    return K if K.shape[1] == 4 else np.concatenate([K, np.ones((K.shape[0], 1))], axis=1)


def substitute(model: Model, result: UntrimResult, tol: Tolerances, progress=None,
               near: list[np.ndarray] | None = None) -> Substitution:
    """Put the shared curves into every patch of ``result`` (in place); returns what changed.
    ``near``: per face of ``result``, the verify step's ``side_per_patch`` (measured here when
    None)."""
    curves = _Curves(model, _POLY_REL * tol.approx_rel * model.diagonal, tol.max_degree,
                     vertex_corners(model, tol.approx_rel * model.diagonal)[0],
                     _LOWER_REL * tol.watertight_rel * model.diagonal)
    tails = _Tails(model, result)
    curves.corner_alias = tails.corners()
    infos = []
    users: dict[tuple, list[np.ndarray]] = {}
    corner_uses: dict[tuple, int] = {}
    used: dict[int, str] = {}
    merges: dict[int, list[tuple[float, float]]] = {}
    for fr in result.faces:  # pass 1: what every side lies on, and the rows each segment goes into
        eps = fr.eps if fr.eps is not None else (0.0, 0.0)
        info = []
        iso = IsoPieces(fr.iso_pieces)
        for p in fr.patches:
            refs, cm = _refs(p, iso, eps, RUNG_SLIDE * tol.approx_rel * model.diagonal)
            for ref in refs.values():
                tails.rewrite(ref)
            info.append((refs, cm))
            for name, ref in refs.items():
                if ref is None or ref.pole:
                    continue
                row = _row(p.ctrl, name)
                if ref.wa > ref.wb:
                    row = row[::-1]
                size = float(np.ptp(_cartesian(p.ctrl, p.rational).reshape(-1, 3), axis=0).max())
                lo, hi = sorted((ref.wa, ref.wb))
                users.setdefault(ref.edge, []).append((lo, hi, row, size))
        infos.append(info)
        _corner_merges(fr, info, merges, model, MERGE_REL * model.diagonal)
    snap = _snap_params(model, users, result.plan, tol, merges)
    for info in infos:
        for refs, _ in info:
            for ref in refs.values():
                if ref is not None and not ref.pole:
                    ref.wa, ref.wb = snap[ref.edge].get(ref.wa, ref.wa), snap[ref.edge].get(ref.wb, ref.wb)
    users = {e: [(snap[e].get(lo, lo), snap[e].get(hi, hi), r, size) for lo, hi, r, size in uses]
             for e, uses in users.items()}
    for e, uses in users.items():
        if not curves.decide_midway(e, result.shared_cuts(e)):
            curves.lower(e, uses, _LOWER_REL * tol.watertight_rel * model.diagonal)
            curves.decide(e, uses)
    faces: list[FaceSubstitution] = []
    # each stage-1 patch as it is (copies: the substitution writes into the nets it keeps) and its
    # deviation from the input face: its bound, and where its trimming sides were moved by the loop
    # closure, their measured distance from S(pcurve), within bound + closure
    if near is None:
        near = [side_deviations(fr, model) for fr in result.faces]
    stage1 = [[(p.ctrl.copy(), p.rational, max(p.bound, min(float(d), p.bound + fr.closure)))
               for p, d in zip(fr.patches, sides, strict=True)]
              for fr, sides in zip(result.faces, near, strict=True)]
    for fr, info in zip(result.faces, infos, strict=True):  # pass 2: substitute
        fs = FaceSubstitution(fr.face)
        faces.append(fs)
        moved: dict[tuple[int, tuple[int, int]], np.ndarray] = {}
        keyed: dict[tuple[int, tuple[int, int]], tuple] = {}  # the same corners' ``corner_key``
        for pi, (p, (refs, _)) in enumerate(zip(fr.patches, info, strict=True)):
            rows: dict[str, np.ndarray] = {}
            corners: dict[tuple[int, int], tuple] = {}
            for name, ref in refs.items():
                if ref is None:
                    continue
                fs.boundary_sides += 1
                c0, c1 = SIDES[name][2]
                if ref.pole:
                    corners[c0] = corners[c1] = ("v", model.edges[ref.edge].vertices[0])
                    used[ref.edge] = "pole"
                    continue
                K = curves.segment(ref.edge, ref.wa, ref.wb)
                if ref.along is not None:
                    fit_tol = _RUNG_FIT_REL * tol.watertight_rel * model.diagonal
                    samples = _rung_samples(K, ref.along, tol.max_degree)
                    row = _rung_row(K, ref.along, tol.max_degree, fit_tol, samples)
                    if row is not None:
                        K = row
                        fs.rungs_fitted += 1
                    elif (_rung_slide(K, ref.along, tol.max_degree, samples)
                          <= _RUNG_SLIDE_MAX * tol.approx_rel * model.diagonal):
                        # past the degree budget (a(t) not smooth enough for a fit to 1e-13): the
                        # rung takes K in its own parameter, exact on the edge, and the interior
                        # slides along it (the move, measured, goes into the patch's bound); left
                        # unshared, the rung was 1.6e-6 from its neighbour, so trj8 had free edges
                        fs.rungs_slid += 1
                    else:
                        fs.rungs_unshared += 1
                        continue
                ka, kb = curves.corner_key(ref.edge, ref.wa), curves.corner_key(ref.edge, ref.wb)
                for k in (ka, kb):
                    if k[0] == "e":
                        corner_uses[k] = corner_uses.get(k, 0) + 1
                rows[name] = K
                corners[c0], corners[c1] = ka, kb
                used[ref.edge] = ("midway between the faces" if ref.edge in curves.mid_error
                                  else "3d curve, polynomial fit" if ref.edge in curves.fit_error
                                  else "3d curve")
                fs.moved = max(fs.moved, curves.fit_error.get(ref.edge, 0.0))
            if corners:
                _apply(p, rows, corners, curves, fs, tol)
                for c, key in corners.items():
                    moved[(pi, c)] = curves.corner(key)
                    keyed[(pi, c)] = key
        labels = _unify_corners(fr, info, moved, fs, MERGE_REL * model.diagonal)
        at: dict[int, tuple] = {}
        for pc, key in keyed.items():
            at.setdefault(labels[pc], key)
        _share_inner(fr, info, labels, fs, tol, model.diagonal,
                     lambda la, lb, face=fr.face, at=at: curves.between(at.get(la), at.get(lb), face))
        if progress is not None:
            progress(1)
    for fr, fs, before in zip(result.faces, faces, stage1, strict=True):
        for p, (ctrl, rational, bound) in zip(fr.patches, before, strict=True):
            move = _sampled_move(ctrl, rational, p.ctrl, p.rational)
            fs.moved_sampled = max(fs.moved_sampled, move)
            fs.deviation_sampled = max(fs.deviation_sampled, move + bound)
    uses_per_edge = {e.index: e.uses for e in model.edges}
    t_vertices = sum(1 for k, n in corner_uses.items() if n < 2 * uses_per_edge[k[1]])
    return Substitution(faces, used, t_vertices, curves.straddles)


_MOVE_GRID = np.linspace(0.0, 1.0, 17)


def _sampled_move(a: np.ndarray, a_rational: bool, b: np.ndarray, b_rational: bool) -> float:
    """max |A(s, t) - B(s, t)| over a 17 x 17 grid (sides included) of two patch nets."""
    g = _MOVE_GRID
    pa = (rational_surface_eval_grid if a_rational else surface_eval_grid)(a, g, g)
    pb = (rational_surface_eval_grid if b_rational else surface_eval_grid)(b, g, g)
    return float(np.linalg.norm(pa - pb, axis=-1).max())


def _snap_params(model: Model, users: dict, plan: dict, tol: Tolerances,
                 merges: dict | None = None) -> dict[int, dict[float, float]]:
    """Per edge, side-end parameters that stand less than a sliver apart (in 3D, through the curve's
    speed), or that a face's corner cluster joins (``merges``, see ``_corner_merges``), mapped onto
    one value: the edge's end (its vertex), else the plan's, where one is among them. Stage 1 can end two
    neighbouring cells' sides a sliver apart on the same edge (a plan cut next to a slab line);
    one parameter makes them one corner."""
    out: dict[int, dict[float, float]] = {}
    sliver = tol.sliver_rel * model.diagonal
    merges = merges or {}
    for e, uses in users.items():
        edge = model.edges[e]
        anchors = set(float(x) for x in plan.get(e, ())) | {float(edge.first), float(edge.last)}
        # cluster pairs join a hair apart along the edge, never across it (the two ends of a
        # closed edge are one point in 3D and in uv but not one parameter)
        pairs = [(a, b) for a, b in merges.get(e, []) if abs(a - b) < 0.25 * (edge.last - edge.first)]
        if pairs:
            ab = edge.curve.evaluate(np.array(pairs, dtype=float).reshape(-1))
            near = np.linalg.norm(ab[0::2] - ab[1::2], axis=1) <= tol.approx_rel * model.diagonal
            pairs = [pair for pair, ok in zip(pairs, near, strict=True) if ok]
        vals = np.array(sorted({float(w) for lo, hi, _, _ in uses for w in (lo, hi)} | anchors
                               | {float(w) for pair in pairs for w in pair}))
        pts = edge.curve.evaluate(vals)
        close = np.flatnonzero(np.linalg.norm(np.diff(pts, axis=0), axis=1) <= sliver)
        where = {float(w): n for n, w in enumerate(vals)}
        rows = np.concatenate([close, [where[float(a)] for a, _ in pairs]]).astype(int)
        cols = np.concatenate([close + 1, [where[float(b)] for _, b in pairs]]).astype(int)
        graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(vals), len(vals)))
        _, label = connected_components(graph, directed=False)
        rep: dict[int, float] = {}
        ends = {float(edge.first), float(edge.last)}
        rank = {float(w): 0 if float(w) in ends else 1 if float(w) in anchors else 2 for w in vals}
        for w, lab in zip(vals, label, strict=True):  # increasing: an end (its vertex), a plan
            w = float(w)  # parameter, else the smallest
            if lab not in rep or rank[w] < rank[rep[lab]]:
                rep[lab] = w
        out[e] = {float(w): rep[lab] for w, lab in zip(vals, label, strict=True)}
    return out


def _apply(p: Patch, rows: dict[str, np.ndarray], corners: dict, curves: _Curves,
           fs: FaceSubstitution, tol: Tolerances) -> None:
    """Substitute the rows and the moved corners of one patch, elevating it where needed.

    A polynomial patch that takes a rational K is first written as the same surface with K's weight
    function (its homogeneous net times kappa(s), exact), so its row takes K with equal weights.
    A K whose weights are all equal is polynomial (``_Curves.lower`` gives a rational edge the
    polynomial row that holds it): taken as rational, it made its polynomial patch rational and
    raised it by K's degree."""
    rows = {k: (K[:, :3] / K[:, 3:] if K.shape[1] == 4 and np.all(K[:, 3] == K[0, 3]) else K)
            for k, K in rows.items()}
    was_rational = p.rational
    rational = p.rational or any(K.shape[1] == 4 for K in rows.values())
    H = p.ctrl
    added: list = []
    if rational and not was_rational:
        H = np.concatenate([H, np.ones(H.shape[:2] + (1,))], axis=-1)
        for axis, names in ((0, ("bottom", "top")), (1, ("left", "right"))):
            ks = [rows[n] for n in names if n in rows and rows[n].shape[1] == 4]
            if ks:
                d = max(H.shape[axis] - 1, ks[0].shape[0] - 1)
                f = _weight_factor(ks[0][:, 3], tol.max_degree - d)
                if len(f) > 1:  # the factor runs along ``axis``
                    H = _times(H, axis, f / f[0], added)
        rows = {k: _homog(K) for k, K in rows.items()}
    elif rational:
        rows = {k: _homog(K) for k, K in rows.items()}
    if rational:
        H = _common_weights(H, rows, tol.max_degree, added)
    ds, dt = _degrees_for(H, rows)
    if max(ds, dt) > tol.max_degree:
        fs.problems.append(f"face {p.face}: a shared curve needs degree {max(ds, dt)} "
                           f"> {tol.max_degree} in a patch")
        return
    ru, rv = ds - (H.shape[0] - 1), dt - (H.shape[1] - 1)
    if ru or rv:
        H = elevate_surface(H, ru, rv)
    if H.shape != p.ctrl.shape[:2] + (H.shape[2],):
        fs.elevated += 1
    old = H.copy()
    ii = {0: 0, 1: -1}
    # corners move by a bilinear displacement of the whole net: a side between two moved corners
    # then changes by the same straight blend in every patch that has it, whatever its degree
    _displace(H, {c: curves.corner(key) - _corner_xyz(H, c, rational) for c, key in corners.items()},
              rational)
    for name, K in rows.items():
        _put(H, name, K)
    for (s, t), key in corners.items():
        x = curves.corner(key)
        if rational:
            H[ii[s], ii[t]] = np.append(x * H[ii[s], ii[t], 3], H[ii[s], ii[t], 3])
        else:
            H[ii[s], ii[t]] = x
    # a side whose two corners are one point (a pole, a collapsed rung) stays one point; a rational
    # side keeps its weights (they shape the surface beside the pole and the sides through its
    # ends: copying the corner's weight along it moved marsCapsule's rungs by 0.013)
    for name, (idx, _, (c0, c1)) in SIDES.items():
        if c0 in corners and corners.get(c1) == corners[c0] and name not in rows:
            if rational:
                x = curves.corner(corners[c0])
                H[idx + (slice(0, 3),)] = x * H[idx + (slice(3, 4),)]
            else:
                H[idx] = H[ii[c0[0]], ii[c0[1]]]
    if rational:
        refit = _refit_checked(old, H)
        if refit is None:
            # an ill-conditioned refit (marsCapsule: nets of a 13 mm part out to 36000): the patch
            # keeps its stage-1 net and the gap there, which the read-back measures
            fs.problems.append(f"face {p.face}: a patch could not take its shared curves (the refit of "
                               "its weights was ill-conditioned); left as in stage 1")
            return
        H = refit
    moved, est = _change(old, H, rational)
    fs.moved = max(fs.moved, moved)
    fs.estimated = fs.estimated or est
    p.ctrl, p.rational = H, rational
    p.factors = p.factors + added
    p.bound += moved


def _refit_checked(old: np.ndarray, H: np.ndarray) -> np.ndarray | None:
    """A rational net whose weights changed, with its inner control points refitted (``_refit``);
    None where the refit is ill-conditioned (its net spans more than ``_REFIT_GROWTH`` x the old)."""
    if np.allclose(old[..., 3], H[..., 3], rtol=1e-12, atol=0.0):
        return H
    H = _refit(old, H)
    size = float(np.ptp(_cartesian(old, True).reshape(-1, 3), axis=0).max())
    if float(np.ptp(_cartesian(H, True).reshape(-1, 3), axis=0).max()) > _REFIT_GROWTH * size:
        return None
    return H


def _corner_clusters(fr, info, eps3: float = 0.0, fixed: dict | None = None
                     ) -> tuple[list[tuple[int, tuple[int, int]]], np.ndarray]:
    """The face's patch corners (patch, corner) and, per corner, the index of its cluster's
    representative: corners closer in uv than the face's line thresholds (``FaceResult.eps``,
    where stage 1 merged slab lines) are one corner; greedy clusters around representatives (no
    chaining: a run of close corners along a line must not merge corners that are far apart).
    With ``eps3``, corners closer than that in 3D join too, closest first (the callers pass the
    distance at which the B-rep's vertices merge, ``topology.MERGE_REL``): a cell thinner than the
    joining tolerance is dropped as flat when the B-rep is built, so the sides on both sides of it
    must be one row. Two clusters
    that hold corners ``fixed`` at different points (on shared curves) stay apart: moving either
    would take its row off its curve (fusee: a wedge cell whose short side is 9e-8 long)."""
    keys = [(i, c) for i in range(len(fr.patches)) for c in ((0, 0), (1, 0), (0, 1), (1, 1))]
    if not keys:
        return keys, np.zeros(0, dtype=int)
    uv = np.array([info[i][1][c] for i, c in keys])
    ueps, veps = fr.eps if fr.eps is not None else (0.0, 0.0)
    scale = np.array([max(ueps, 1e-12 * max(np.ptp(uv[:, 0]), 1e-300)),
                      max(veps, 1e-12 * max(np.ptp(uv[:, 1]), 1e-300))])
    pts = uv / scale
    near = cKDTree(pts).query_ball_point(pts, 2.0, p=np.inf)  # all at once: one call, not one per corner
    rep = [-1] * len(keys)
    for n in range(len(keys)):
        if rep[n] >= 0:
            continue
        rep[n] = n
        for j in near[n]:
            if rep[j] < 0:
                rep[j] = n
    rep = np.array(rep)
    if eps3 <= 0.0:
        return keys, rep
    xyz = np.array([_corner_xyz(fr.patches[i].ctrl, c, fr.patches[i].rational) for i, c in keys])
    pairs = cKDTree(xyz).query_pairs(eps3, output_type="ndarray")
    if not len(pairs):
        return keys, rep
    parent = rep.copy()

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = int(parent[x])
        return x

    value: dict[int, np.ndarray] = {}
    for n, k in enumerate(keys):
        if fixed and k in fixed:
            value.setdefault(find(n), fixed[k])
    order = np.argsort(np.linalg.norm(xyz[pairs[:, 0]] - xyz[pairs[:, 1]], axis=1), kind="stable")
    for a, b in pairs[order]:
        ra, rb = find(int(a)), find(int(b))
        if ra == rb:
            continue
        va, vb = value.get(ra), value.get(rb)
        if va is not None and vb is not None and not np.array_equal(va, vb):
            continue
        lo, hi = min(ra, rb), max(ra, rb)
        parent[hi] = lo
        if va is not None or vb is not None:
            value[lo] = va if va is not None else vb
    return keys, np.array([find(n) for n in range(len(keys))])


def _corner_merges(fr, info, merges: dict[int, list[tuple[float, float]]], model: Model,
                   eps3: float = 0.0) -> None:
    """Edge parameters that one corner cluster of the face puts on the same edge (sides of cells a
    sliver apart in uv, ending on the edge a hair apart), or a parameter near an edge's end whose
    cluster also holds that end's vertex: recorded in ``merges`` as pairs, so ``_snap_params``
    makes them one parameter and every patch there takes the same corner point. Otherwise
    ``_unify_corners`` moves all but one onto that point and their rows leave the shared curve
    (1.1e-6 on gmsh__Block.stp, 1.8e-6 on trj8: more than a sliver in 3D)."""
    keys, rep = _corner_clusters(fr, info, eps3)
    pos = {k: n for n, k in enumerate(keys)}
    ends = []  # (cluster, edge, w)
    vertices: dict[int, set[int]] = {}
    for i, (refs, _) in enumerate(info):
        for name, ref in refs.items():
            if ref is None or ref.pole:
                continue
            edge = model.edges[ref.edge]
            near = 1e-11 * max(edge.last - edge.first, 1e-300)
            for w, c in zip((ref.wa, ref.wb), SIDES[name][2], strict=True):
                root = int(rep[pos[(i, c)]])
                ends.append((root, ref.edge, w))
                if abs(w - edge.first) <= near:
                    vertices.setdefault(root, set()).add(edge.vertices[0])
                elif abs(w - edge.last) <= near:
                    vertices.setdefault(root, set()).add(edge.vertices[1])
    first: dict[tuple[int, int], float] = {}
    for root, e, w in ends:
        edge = model.edges[e]
        at = [x for x, v in ((edge.first, edge.vertices[0]), (edge.last, edge.vertices[1]))
              if v in vertices.get(root, ())]
        if at:  # the cluster holds a vertex of this edge: the nearer end of the edge
            w0 = min(at, key=lambda x: abs(x - w))
            first.setdefault((root, e), w0)
        w0 = first.setdefault((root, e), w)
        if w0 != w:
            merges.setdefault(e, []).append((w0, w))


def _unify_corners(fr, info, moved: dict, fs: FaceSubstitution, eps3: float = 0.0) -> dict:
    """One point per corner of the face's decomposition (``_corner_clusters``). Its value is the
    shared curve's point where some patch put one there (the boundary), else the first patch's.
    Every patch gets that value at that corner, except corners that a patch put on a shared curve
    (they keep theirs); returns (patch, corner) -> corner id."""
    keys, rep = _corner_clusters(fr, info, eps3, moved)
    if not keys:
        return {}

    def find(x):
        return int(rep[x])

    value: dict[int, np.ndarray] = {}
    for n, k in enumerate(keys):
        if k in moved:
            value.setdefault(find(n), moved[k])
    labels = {}
    moves: dict[int, dict] = {}
    for n, (i, c) in enumerate(keys):
        root = find(n)
        labels[(i, c)] = root
        p = fr.patches[i]
        cur = _corner_xyz(p.ctrl, c, p.rational)
        # a corner put on a shared curve stays there, also where its cluster holds another such
        # corner (two boundary curves a hair apart: a wedge cell whose short side is 9e-8 long)
        x = moved[(i, c)] if (i, c) in moved else value.setdefault(root, cur.copy())
        if not np.array_equal(cur, x):
            moves.setdefault(i, {})[c] = x - cur
    for i, mv in moves.items():
        p = fr.patches[i]
        H = p.ctrl.copy()
        _displace(H, mv, p.rational)
        move, _ = _change(p.ctrl, H, p.rational)
        p.ctrl = H
        p.bound += move
        fs.moved = max(fs.moved, move)
        fs.corners_moved += len(mv)
    return labels


def _corner_xyz(H: np.ndarray, c: tuple[int, int], rational: bool) -> np.ndarray:
    x = H[(0, -1)[c[0]], (0, -1)[c[1]]]
    return x[:3] / x[3] if rational else x.copy()


def _displace(H: np.ndarray, moves: dict, rational: bool) -> None:
    """Move corners (s, t) of the net H by ``moves[(s, t)]`` (3D) with the bilinear blend of the four
    corner moves, written at H's degrees (in place; a rational net keeps its weights). A rational
    net gets the blend of the moves times the corner weights in its homogeneous numerator: each
    side then changes by (blend of w delta) / W(s), the same function at any degree of the side,
    so two patches that share a side and move its corners alike still share it."""
    if not moves:
        return
    ls = np.linspace(0.0, 1.0, H.shape[0])
    lt = np.linspace(0.0, 1.0, H.shape[1])
    d = np.zeros(H.shape[:2] + (3,))
    for (s, t), delta in moves.items():
        ws = ls if s == 1 else 1.0 - ls
        wt = lt if t == 1 else 1.0 - lt
        scale = H[(0, -1)[s], (0, -1)[t], 3] if rational else 1.0
        d += np.outer(ws, wt)[..., None] * (delta * scale)
    if rational:
        H[..., :3] += d
    else:
        H += d


def _share_inner(fr, info, labels: dict, fs: FaceSubstitution, tol: Tolerances, diagonal: float,
                 guide=None) -> None:
    """Make inner sides that two patches share bitwise equal (the lowest-degree row wins): two
    sides are shared when they join the same two corners (see ``_unify_corners``). ``guide``
    (two corner ids -> the shared curves between them) is for ``_share_t_sides``."""
    items = []  # (patch index, side name, start uv, end uv)
    ends = []
    on_edge: dict[tuple[int, int], tuple[int, str, tuple[int, int]]] = {}  # corner ids -> a side on an edge
    for i, (refs, cm) in enumerate(info):
        for name, (_, _, (c0, c1)) in SIDES.items():
            if refs[name] is None:
                items.append((i, name, cm[c0], cm[c1]))
                ends.append((labels[(i, c0)], labels[(i, c1)]))
            elif not refs[name].pole:
                la, lb = labels[(i, c0)], labels[(i, c1)]
                if la != lb:
                    on_edge.setdefault((min(la, lb), max(la, lb)), (i, name, (la, lb)))
    if not items:
        return
    pts = np.array([[*a, *b] for _, _, a, b in items])
    span = np.ptp(pts.reshape(-1, 2), axis=0)
    span[span == 0] = 1.0
    fwd = pts * np.tile(1.0 / span, 2)
    by_ends: dict[tuple[int, int], list[int]] = {}
    for k, (a, b) in enumerate(ends):
        if a != b:  # a collapsed side has nothing to share
            by_ends.setdefault((min(a, b), max(a, b)), []).append(k)
    patches = fr.patches
    lonely = []
    partners: dict[int, list[tuple[int, bool]]] = {}  # item -> the others with its two corners
    copies: list[tuple[int, int, bool]] = []  # (winner, side that took its row, reversed)
    for key, ks in by_ends.items():
        if key in on_edge and _onto_edge_side(fr, items, ends, ks, on_edge[key], fs, tol, diagonal):
            continue
        owners = {items[k][0] for k in ks}
        if len(owners) < 2:
            lonely.extend(ks)  # a side with a T-vertex on it, or one of the sides that meet there
            continue
        for k in ks:
            partners[k] = [(j, ends[j] != ends[k]) for j in ks if j != k]
        # the lowest-degree row wins: both rows are the same curve (S along one uv line), and a
        # row of a patch whose interior needs a higher degree would raise its neighbour to it
        # (loft_minus_cylinder: 213 patches one or two degrees above their own, which a second
        # conversion gave back)
        m = min(ks, key=lambda k: _row(patches[items[k][0]].ctrl, items[k][1]).shape[0])
        src = patches[items[m][0]]
        for k in ks:
            if items[k][0] == items[m][0]:
                continue
            flip = ends[k] != ends[m]
            if not _same_parameter(src, items[m][1], patches[items[k][0]], items[k][1], flip, fr.eps,
                                   JOIN_REL * diagonal):
                # the same line in another parameterization (a side that follows an edge's
                # parameter): copying would slide the patch along it; both stay on the line
                fs.inner_reparam += 1
                continue
            _copy_shared(patches, items, m, k, flip, fs, tol, diagonal)
            copies.append((m, k, flip))
            fs.inner_shared += 1
    touched = _share_t_sides(fr, items, lonely, fwd, fs, tol, diagonal, partners, ends, guide)
    # a T-side copy moves its patch's corners onto the long side, and the patch's other sides with
    # them, each by the blend its own degree and weights give: a side shared before with a patch of
    # other weights no longer matches its partner (fusee face 184 with wrapped tips: a ladder
    # cell's top, degree 1, against the degree-5 rational bottom of the cell above, 4.6e-8 apart
    # after both took the same T-vertex). The partner takes the winner's row again.
    for m, k, flip in copies:
        if items[m][0] in touched or items[k][0] in touched:
            _copy_shared(patches, items, m, k, flip, fs, tol, diagonal)


def _copy_shared(patches, items, m: int, k: int, flip: bool, fs: FaceSubstitution, tol: Tolerances,
                 diagonal: float) -> None:
    """Side ``k`` takes the row of side ``m`` (items of ``_share_inner``), reversed when ``flip``."""
    src = patches[items[m][0]]
    row = _row(src.ctrl, items[m][1])
    _copy_row(patches[items[k][0]], items[k][1], row[::-1] if flip else row, src.rational, fs, tol, diagonal,
              src.factors)


def _onto_edge_side(fr, items, ends, ks: list[int], edge_side: tuple, fs: FaceSubstitution, tol: Tolerances,
                    diagonal: float) -> bool:
    """Inner sides ``ks`` that join the same two corners as a side on an edge (``edge_side``: patch,
    side name, its corner ids) bound a cell between them that is thinner than the joining
    tolerance (its other two sides collapsed when the corners were unified): the B-rep drops it as
    a fold, and the patches beyond its inner side then meet the neighbours across the edge
    directly. So every such side takes the edge side's row, the shared curve, where each lies
    within the joining tolerance of it at the same parameter (copying moves the patch by no
    more); returns whether they did. Each sharing the lowest-degree row among themselves instead,
    they kept the cell's width: ec_turbine face 19, a lens 4.3e-8 wide on the edge with face 12,
    which was the gap between the faces beyond it."""
    i, name, (la, lb) = edge_side
    src = fr.patches[i]
    eps3 = JOIN_REL * diagonal
    flips = [ends[k] != (la, lb) for k in ks]
    if not all(_same_parameter(src, name, fr.patches[items[k][0]], items[k][1], f, None, eps3)
               for k, f in zip(ks, flips, strict=True)):
        return False
    for k, flip in zip(ks, flips, strict=True):
        row = _row(src.ctrl, name)
        _copy_row(fr.patches[items[k][0]], items[k][1], row[::-1] if flip else row, src.rational, fs, tol,
                  diagonal, src.factors)
        fs.inner_shared += 1
    return True


def _side_uv(p: Patch, name: str, g: np.ndarray) -> np.ndarray:
    if name in ("bottom", "top"):
        return cell_map(p, g, np.array([0.0 if name == "bottom" else 1.0]))[:, 0]
    return cell_map(p, np.array([0.0 if name == "left" else 1.0]), g)[0]


def _same_parameter(a: Patch, an: str, b: Patch, bn: str, flip: bool, eps, eps3: float = 0.0) -> bool:
    """Two sides on one uv line run through it at the same parameter (so copying a row moves the
    patch only by the rows' difference, not along the line); or, with ``eps3``, two sides whose
    points at the same parameter are that close in 3D (the two sides of a cell thinner than the
    joining tolerance, which the B-rep drops)."""
    g = np.linspace(0.0, 1.0, 7)
    ua, ub = _side_uv(a, an, g), _side_uv(b, bn, g)
    if flip:
        ub = ub[::-1]
    e = np.array(eps if eps is not None else (0.0, 0.0)) * 4.0 + 1e-12
    if np.all(np.abs(ua - ub) <= e):
        return True
    if eps3 <= 0.0:
        return False
    pa, pb = (rational_curve_eval(_homog(_row(p.ctrl, n)), g) for p, n in ((a, an), (b, bn)))
    if flip:
        pb = pb[::-1]
    return bool(np.linalg.norm(pa - pb, axis=1).max() <= eps3)


def _share_t_sides(fr, items, lonely: list[int], fwd: np.ndarray, fs: FaceSubstitution, tol: Tolerances,
                   diagonal: float, partners: dict, ends: list, guide=None) -> set[int]:
    """Sides that meet a longer side of a neighbour at a T-vertex become subdivisions of that side,
    so the two stay on one curve (its corners at the T-vertex are computed once). The long side
    is a lonely one where there is one; else a side shared whole (``partners``: across a cell
    thinner than the joining tolerance, whose two sides were made one row), whose partners then
    take the long side's row too when it is bent. ``ends``: per side, the corner ids at its ends
    (``_unify_corners``); a short side's end that is the long side's end corner is cut there,
    not at its uv, which may lie a sliver before it. ``guide`` (two corner ids -> the shared
    curves between them): a piece of the long side that no short side here takes, from corner to
    corner of an edge of the face, lies beside the neighbour across that edge, whose side is the
    edge's shared curve; the bend then also takes the long side onto that curve there
    (``_through_guided``). Returns the patches whose rows it changed."""
    touched: set[int] = set()
    if not lonely:
        return touched
    # shorts: the lonely sides; containers: lonely ones first, else sides shared whole (across a
    # cell thinner than the joining tolerance whose two sides were joined: ec_turbine)
    a, b = fwd[:, :2], fwd[:, 2:]
    length = np.linalg.norm(b - a, axis=1)
    owner = np.array([it[0] for it in items])
    pools = [np.array(lonely), np.array(sorted(partners))]
    eps = 1e-7

    def container(k: int, pool: np.ndarray) -> int | None:
        """The longest side in ``pool`` of another patch whose segment holds both ends of k."""
        if not len(pool):
            return None
        pa, d = a[pool], b[pool] - a[pool]
        with np.errstate(invalid="ignore", divide="ignore"):
            ta = np.einsum("ij,ij->i", a[k] - pa, d) / np.maximum(length[pool] ** 2, 1e-300)
            tb = np.einsum("ij,ij->i", b[k] - pa, d) / np.maximum(length[pool] ** 2, 1e-300)
        da = np.linalg.norm(pa + ta[:, None] * d - a[k], axis=1)
        db = np.linalg.norm(pa + tb[:, None] * d - b[k], axis=1)
        ok = ((length[pool] > length[k] * (1 + 1e-12)) & (da <= eps) & (db <= eps)
              & (np.minimum(ta, tb) >= -eps) & (np.maximum(ta, tb) <= 1 + eps) & (owner[pool] != owner[k]))
        cands = pool[ok]
        return int(cands[np.argmax(length[cands])]) if len(cands) else None

    used = set()
    groups: dict[int, list] = {}
    for k in lonely:
        j = container(k, pools[0])
        if j is None:
            j = container(k, pools[1])
        if j is None:
            continue
        li, lname = items[j][0], items[j][1]
        long_p = fr.patches[li]
        ua, ub = _side_param(long_p, lname, items[k][2]), _side_param(long_p, lname, items[k][3])
        # an end in the long side's end corner is that end: cut at its uv, a sliver before it
        # (a cell thinner than the merge distance, its corners one), the short side ended 1.2e-7
        # short of the corner it shares (ec_turbine: I1, and a 7.4e-8 gap there)
        at = {ends[j][0]: 0.0, ends[j][1]: 1.0}
        ua, ub = at.get(ends[k][0], ua), at.get(ends[k][1], ub)
        groups.setdefault(j, []).append((k, ua, ub))
        used.update((k, j))
    for j, shorts in groups.items():
        li, lname = items[j][0], items[j][1]
        long_p = fr.patches[li]
        row = _row(long_p.ctrl, lname)
        # T-vertices inside the long side: the short sides' corners there (moved onto an edge's
        # curve where the T-vertex is on the face boundary) -- the long side is bent through them
        # corners of two short sides at one point (the same corner) that stand a hair apart along
        # the long side are one T-vertex: bending through both would need a stationary point
        ts, targets = [], []
        cuts = []
        for k, ua, ub in shorts:
            sp = fr.patches[items[k][0]]
            tips = _cartesian(_row(sp.ctrl, items[k][1]), sp.rational)[[0, -1]]
            cut = []
            for tau, x in ((ua, tips[0]), (ub, tips[1])):
                same = [n for n, t0 in enumerate(ts) if abs(tau - t0) <= _T_MERGE
                        and np.linalg.norm(x - targets[n]) <= 1e-12 * diagonal]
                if same:
                    tau = ts[same[0]]
                elif 1e-12 < tau < 1 - 1e-12:
                    ts.append(tau)
                    targets.append(x)
                cut.append(tau)
            cuts.append((k, *cut))
        shorts = cuts
        guides = [] if guide is None or long_p.rational else _guides(row, shorts, ends, j, guide,
                                                                     tol.approx_rel * diagonal)
        if ts or guides:
            ts_, targets_ = np.array(ts).reshape(-1), np.array(targets).reshape(-1, 3)
            atol, slack = _BEND_REL * diagonal, _BUMP_SLACK * tol.approx_rel * diagonal
            bent = _through(row, long_p.rational, ts_, targets_, atol, tol.max_degree, slack) if ts else None
            near = _guide_gap(row if bent is None else bent, guides) if guides else 0.0
            if near > atol:  # the plain bend (or the row) leaves a guided piece off its curve
                fit = _through_guided(row, ts_, targets_, guides, atol, tol.max_degree, slack)
                if fit is not None and fit[1] < near:
                    bent = fit[0]
                    fs.t_guided += 1
            if bent is not None:
                _copy_row(long_p, lname, bent, long_p.rational, fs, tol, diagonal, long_p.factors)
                row = _row(long_p.ctrl, lname)
                touched.add(li)
                for o, flip in partners.get(j, ()):
                    _copy_row(fr.patches[items[o][0]], items[o][1], row[::-1] if flip else row,
                              long_p.rational, fs, tol, diagonal, long_p.factors)
                    touched.add(items[o][0])
        for k, ua, ub in shorts:
            _copy_row(fr.patches[items[k][0]], items[k][1], curve_segment(row, ua, ub), long_p.rational,
                      fs, tol, diagonal, long_p.factors)
            touched.add(items[k][0])
            fs.inner_t += 1
    fs.inner_unpaired += len(set(lonely) - used)
    return touched


def _guides(row: np.ndarray, shorts: list, ends: list, j: int, guide, near: float) -> list:
    """The pieces (a, b, K) of long side ``j`` (row, polynomial) that none of ``shorts`` ((side,
    parameter of its start on the long side, of its end)) takes and that run along a shared curve K
    from corner to corner (``guide`` of the corner ids at a and b): the nearest such curve, when
    the piece lies within ``near`` of it."""
    cover = sorted((ua, ub, *ends[k]) if ua <= ub else (ub, ua, *ends[k][::-1]) for k, ua, ub in shorts)
    pos, at, gaps = 0.0, ends[j][0], []
    for lo, hi, la, lb in cover:
        if lo > pos + _T_MERGE:
            gaps.append((pos, lo, at, la))
        if hi > pos:
            pos, at = hi, lb
    if pos < 1.0 - _T_MERGE:
        gaps.append((pos, 1.0, at, ends[j][1]))
    out = []
    for a, b, la, lb in gaps:
        pts = curve_eval(row, a + (b - a) * np.array([0.25, 0.5, 0.75]))
        best = min(((float(project(_homog(K), pts)[1].max()), i, K) for i, K in enumerate(guide(la, lb))),
                   default=None)
        if best is not None and best[0] <= near:
            out.append((a, b, best[2]))
    return out


_GUIDE_GRID = np.linspace(0.0, 1.0, 65)


def _guide_points(K: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points of a guide curve, polynomial (k, 3) or homogeneous (k, 4), at parameters ``s``."""
    return rational_curve_eval(K, s) if K.shape[1] == 4 else curve_eval(K, s)


def _guide_feet(row: np.ndarray, guides: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The row's samples on its guided pieces: parameters, points, and their feet on the guides
    (which may be rational: fusee's guide edge was, and its homogeneous points met the row's)."""
    tau = np.concatenate([a + (b - a) * _GUIDE_GRID for a, b, _ in guides])
    pts = curve_eval(row, tau)
    feet = []
    for (_, _, K), chunk in zip(guides, np.split(pts, len(guides)), strict=True):
        s, _ = project(_homog(K), chunk)
        feet.append(_guide_points(K, s))
    return tau, pts, np.concatenate(feet)


def _guide_gap(row: np.ndarray, guides: list) -> float:
    """Largest distance of the row's guided pieces from their guides (sampled)."""
    _, pts, feet = _guide_feet(row, guides)
    return float(np.linalg.norm(pts - feet, axis=1).max())


def _through_guided(row: np.ndarray, ts: np.ndarray, targets: np.ndarray, guides: list, atol: float,
                    max_degree: int = 25, slack: float = 0.0) -> tuple[np.ndarray, float] | None:
    """A polynomial row plus a correction D, zero at both ends, that passes through ``targets`` at
    ``ts`` exactly and takes each guided piece (a, b, K) onto its curve K (least squares on the
    feet of the row's samples), of the lowest degree (from the row's own) that is within ``atol``
    there and does not bulge past _BUMP_CAP x the largest move (or past ``slack``); else the
    closest one that does not bulge. Returns the row and its sampled distance from the guides,
    or None when nothing needs to move or no degree keeps the bulge within bounds.

    A long side that only partly borders the patches of its face (the rest runs along an edge of
    the face, and a face beyond takes the edge's shared curve there) cannot follow both with the
    local bump of ``_through``: Block's side ran 6.2e-10 off its neighbour's straight edge, its
    bump peaking past the T-vertex."""
    n = row.shape[0] - 1
    tau, pts, feet = _guide_feet(row, guides)
    # the guides' points at the row's parameter mapped affinely (a piece cut from the same curve
    # as the guide keeps its parameter), and the feet of the row's points on them (any other
    # parameter); whichever fit comes closer is kept
    along = np.concatenate([_guide_points(K, _GUIDE_GRID) for _, _, K in guides])
    delta = targets - curve_eval(row, ts) if len(ts) else np.zeros((0, 3))
    scale = max(float(np.linalg.norm(feet - pts, axis=1).max()),
                float(np.linalg.norm(delta, axis=1).max()) if len(ts) else 0.0)
    if scale <= atol:
        return None
    x = np.linspace(0.0, 1.0, 129)
    best = None
    for E in (along - pts, feet - pts):
        for m in range(max(n, len(ts) + 1, 2), max(max_degree, 2) + 1):
            Bs = basis(m, tau)[:, 1:-1]
            if len(ts):
                Bt = basis(m, ts)[:, 1:-1]
                c0 = np.linalg.lstsq(Bt, delta, rcond=None)[0]
                if np.abs(Bt @ c0 - delta).max() > 1e-9 * scale:
                    continue
                _, sv, vt = np.linalg.svd(Bt)
                N = vt[int(np.sum(sv > 1e-12 * sv[0])):].T
            else:
                c0, N = np.zeros((m - 1, 3)), np.eye(m - 1)
            c = c0 + N @ np.linalg.lstsq(Bs @ N, E - Bs @ c0, rcond=None)[0] if N.shape[1] else c0
            peak = float(np.linalg.norm(basis(m, x)[:, 1:-1] @ c, axis=1).max()) / scale
            if peak > _BUMP_CAP and peak * scale > slack:
                continue
            D = np.zeros((m + 1, 3))
            D[1:-1] = c
            out = (elevate_curve(row, m - n) if m > n else row) + D
            miss = np.linalg.norm(curve_eval(out, ts) - targets, axis=1).max() if len(ts) else 0.0
            if miss > max(1e-9 * scale, atol):
                continue
            gap = _guide_gap(out, guides)
            if best is None or gap < best[1]:
                best = (out, gap)
            if gap <= atol:
                break
        if best is not None and best[1] <= atol:
            break
    return best


def _through(row: np.ndarray, rational: bool, ts: np.ndarray, targets: np.ndarray, atol: float = 0.0,
             max_degree: int = 25, slack: float = 0.0) -> np.ndarray | None:
    """The row plus a polynomial correction, zero at both ends, that makes it pass through
    ``targets`` at ``ts``: a Bernstein bump that peaks near one T-vertex (``_bump``), a least-norm
    one through several (``_spread``), each of the lowest degree that keeps it local. None when
    it already does within ``atol`` (the stacked cells beside a rung that plan cuts made put 40
    T-vertices on one side, a hair off it by the rounding of their compositions: bending through
    them all would take degree 44), or when the correction would need more than ``max_degree``
    (the T-vertices then stay where they are; the read-back measures what that leaves), or when
    the correction would bulge past _BUMP_CAP x the move and past ``slack``."""
    h = basis(row.shape[0] - 1, ts) @ row
    pts = h[:, :3] / h[:, 3:4] if rational else h
    delta = targets - pts
    scale = float(np.abs(_cartesian(row, rational)).max()) or 1.0
    n = len(ts)
    if np.abs(delta).max() <= max(1e-15 * scale, atol) or n + 1 > max_degree:
        return None
    # the correction N (zero at both ends) takes the value delta at the ts. A rational row is bent
    # in its homogeneous coordinates: adding N to the numerator moves the curve by N / W, so N
    # takes delta W there (exact at the ts)
    if rational:
        delta = delta * h[:, 3:4]
    D = (_bump(float(ts[0]), delta[0], max_degree, slack) if n == 1
         else _spread(ts, delta, max_degree, slack))
    if D is None:
        return None
    deg = max(row.shape[0] - 1, D.shape[0] - 1)
    base = elevate_curve(row, deg - (row.shape[0] - 1)) if deg > row.shape[0] - 1 else row.copy()
    D = elevate_curve(D, deg - (D.shape[0] - 1)) if deg > D.shape[0] - 1 else D
    if rational:
        base[:, :3] += D
    else:
        base += D
    return base


def _bump(tau: float, delta: np.ndarray, max_degree: int, slack: float = 0.0) -> np.ndarray | None:
    """The correction that moves a curve by ``delta`` at ``tau`` and keeps its ends: one Bernstein
    polynomial B_i^m scaled to ``delta`` at tau, of the lowest degree m (up to the budget) whose
    largest value stays within _BUMP_PEAK x delta, else the one that comes closest (None past
    _BUMP_CAP: a T-vertex a hair from an end, where any bump would bulge). The quadratic
    x (1 - x) peaks in the middle: at tau = 0.96 it moved the middle of the side 7 x as far as the
    T-vertex (bug24595: 0.087 for 0.012)."""
    best = None
    for m in range(2, max(max_degree, 2) + 1):
        i = min(max(int(round(tau * m)), 1), m - 1)
        at = float(basis(m, np.array([tau]))[0, i])
        peak = float(basis(m, np.array([i / m]))[0, i]) / at
        if best is None or peak < best[0]:
            best = (peak, m, i, at)
        if peak <= _BUMP_PEAK:
            break
    if best[0] > _BUMP_CAP and best[0] * float(np.linalg.norm(delta)) > slack:
        return None  # a T-vertex a hair from an end: no polynomial of the budget is local
    _, m, i, at = best
    D = np.zeros((m + 1, len(delta)))
    D[i] = delta / at
    return D


def _spread(ts: np.ndarray, delta: np.ndarray, max_degree: int, slack: float = 0.0) -> np.ndarray | None:
    """The correction through several T-vertices: Bernstein coefficients of degree m, zero at both
    ends, equal to ``delta`` at ``ts``, of least norm; the lowest m (from the interpolating one,
    len(ts) + 1, up to the budget) whose largest value (sampled) stays within _BUMP_PEAK x the
    largest move, else the one that comes closest. The interpolant alone bulges between T-vertices near an
    end (fusee: 0.009 against a move of 0.003; the bend was refused and the short sides moved their
    corners off their neighbours' rows). None when no degree in the budget interpolates them."""
    n = len(ts)
    scale = float(np.linalg.norm(delta, axis=1).max())
    x = np.linspace(0.0, 1.0, 129)
    best = None
    for m in range(n + 1, max(max_degree, n + 1) + 1):
        A = basis(m, ts)[:, 1:-1]
        c = np.linalg.lstsq(A, delta, rcond=None)[0]  # least norm; T-vertices a hair apart are
        if np.abs(A @ c - delta).max() > 1e-9 * scale:  # near-singular: it must still interpolate
            continue
        peak = float(np.linalg.norm(basis(m, x)[:, 1:-1] @ c, axis=1).max()) / scale
        if best is None or peak < best[0]:
            best = (peak, m, c)
        if peak <= _BUMP_PEAK:
            break
    if best is None or best[0] > _BUMP_CAP and best[0] * scale > slack:
        return None
    _, m, c = best
    D = np.zeros((m + 1, delta.shape[1]))
    D[1:-1] = c
    return D


def _side_param(p: Patch, name: str, uv: np.ndarray) -> float:
    """The parameter of a patch side at a point of the face's uv domain that lies on it."""
    if name in ("left", "right"):  # rungs: straight in uv, linear in t
        cm = cell_map(p, np.array([0.0 if name == "left" else 1.0]), np.array([0.0, 1.0]))[0]
        d = cm[1] - cm[0]
        return float(np.clip(np.dot(uv - cm[0], d) / max(np.dot(d, d), 1e-300), 0.0, 1.0))
    side = p.bottom if name == "bottom" else p.top
    ends = side.H[[0, -1], :2] / side.H[[0, -1], 2:3]
    axis = 0 if abs(ends[1, 0] - ends[0, 0]) >= abs(ends[1, 1] - ends[0, 1]) else 1
    if p.box:
        return float(np.clip((uv[axis] - ends[0, axis]) / (ends[1, axis] - ends[0, axis]), 0.0, 1.0))
    return _t_at_u(side.H, float(uv[axis]), axis=axis)


def _row_gap(a: np.ndarray, b: np.ndarray, rational: bool) -> float:
    """Largest distance between two rows (of one degree) at the same parameter, sampled."""
    g = np.linspace(0.0, 1.0, 33)
    if rational:
        return float(np.linalg.norm(rational_curve_eval(a, g) - rational_curve_eval(b, g), axis=1).max())
    return float(np.linalg.norm(curve_eval(a, g) - curve_eval(b, g), axis=1).max())


def _copy_row(p: Patch, name: str, row: np.ndarray, row_rational: bool, fs: FaceSubstitution,
              tol: Tolerances, diagonal: float, factors: list = ()) -> None:
    """Copy a partner patch's row (the partner multiplied by the weight ``factors``) into side ``name``."""
    was_rational = p.rational
    rational = p.rational or row_rational
    H = p.ctrl
    if rational and not was_rational:
        H = np.concatenate([H, np.ones(H.shape[:2] + (1,))], axis=-1)
    if rational and not row_rational:
        row = _homog(row)
    added: list = []
    if rational:  # the neighbour's row may carry weights this net does not have (``_common_weights``)
        H = _missing_factors(H, p.factors, list(factors), 0 if name in ("bottom", "top") else 1,
                             tol.max_degree, added)
        H = _common_weights(H, {name: row}, tol.max_degree, added)
    ds, dt = _degrees_for(H, {name: row})
    if max(ds, dt) > tol.max_degree:
        fs.problems.append(f"face {p.face}: a shared inner side needs degree {max(ds, dt)}")
        return
    ru, rv = ds - (H.shape[0] - 1), dt - (H.shape[1] - 1)
    if ru or rv:
        H = elevate_surface(H, ru, rv)
    if H.shape[:2] != p.ctrl.shape[:2]:
        fs.elevated += 1
    old = H.copy()
    own = _row(H, name)
    d = own.shape[0] - 1
    g = None
    if rational:
        g = _divide(own[:, 3], row[:, 3])
        if g is not None:  # the same curve in the same parameter, written with (nearly) this net's weights
            row = product(row, g) if len(g) > 1 else row * g[0]
    if row.shape[0] - 1 < d:
        row = elevate_curve(row, d - (row.shape[0] - 1))
    if rational and g is None and d > 0:
        # other weights than this net's (the partner carries a weight function this one lacks):
        # the row keeps this net's corner weights, as a K does (``_put``); with the partner's end
        # weights the rows through the corners changed shape (ec_turbine face 11: an edge's side
        # moved 1.1e-5 off the edge, and the patch 2.4e-4)
        row = _match_ends(row, own)
    if np.array_equal(own, row):
        p.ctrl, p.rational = H, rational
        p.factors = p.factors + added
        return
    xyz = _cartesian(own, rational), _cartesian(row, rational)
    limit = tol.approx_rel * diagonal + 2.0 * fs.moved
    if (np.linalg.norm(xyz[0] - xyz[1], axis=1).max() > limit
            and _row_gap(own, row, rational) > limit):
        # more apart than the tolerance and the corner moves explain: not one side (left as it is,
        # counted; the read-back check measures what it leaves). The control points tell first;
        # the curves decide: a long side bent through a T-vertex near its end (bug24595, 0.012 at
        # t = 0.96) has control points 28 x further apart than its points
        fs.inner_mismatch += 1
        return
    H = H.copy()
    # the row's ends may differ from this net's corners (a T-side takes a piece of the bent long
    # side): move them by the bilinear blend first, so the two sides through each corner change by
    # a straight blend whatever their degrees, as in the neighbour that has the same corner
    idx, _, corner_ids = SIDES[name]
    ends = xyz[1][[0, -1]]
    _displace(H, {c: x - _corner_xyz(H, c, rational) for c, x in zip(corner_ids, ends, strict=True)},
              rational)
    H[idx] = row
    if rational:
        # the inside follows the new row (its weights changed); where that refit is ill-conditioned
        # (bug33398 face 267) the net keeps its inner points, and the move is measured as it is
        refit = _refit_checked(old, H)
        H = H if refit is None else refit
    moved, est = _change(old, H, rational)
    fs.moved = max(fs.moved, moved)
    fs.estimated = fs.estimated or est
    p.ctrl, p.rational = H, rational
    p.factors = p.factors + added
    p.bound += moved
