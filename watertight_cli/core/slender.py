"""Long, narrow patches cut across into shorter ones (arrays in, arrays out).

Stage 1 can only cut a face along its slab lines, rungs and knot lines, and where two of those run
close together it leaves a strip thousands of times longer than it is wide (bspline_boolean face 0:
knots 4e-4 apart, a strip 0.001 wide and 28 long). Such a patch is exact, but anything that samples
boundaries at a fixed count per edge sees its neighbours' samples farther apart than the strip is
wide, and a mesher makes needles of it.

A strip is cut across by straight lines of its own parameter square: from a point of one long side
to the nearest point of the other. An iso-line would be simpler, but where the strip ends on a rung
that crosses it at a shallow angle, every iso-line across is a long diagonal (0.18 long across that
strip 0.001 wide), and pieces between diagonals are as slender as the whole. A piece between two
straight cuts is the patch composed with a bilinear map, exact at bidegree (m + n, n)
(``core.compose``), and brought back to the patch's own bidegree by constrained least squares
(``core.reduce``) with a certified bound: across a strip the patch barely varies, so the bound is
rounding (1e-13 on that strip). Each cut is made once and given to both pieces beside it, and the
long sides' pieces are the long sides' own sub-curves, so the neighbours see their sides unchanged
and the cuts' ends as T-vertices on them.
"""

from __future__ import annotations

import numpy as np

from .bezier import curve_eval, curve_segment, dehomogenize
from .compose import compose
from .reduce import reduce_curve, reduce_surface

__all__ = ["SlenderCut", "cut_slender", "slender_axis"]

_COARSE = 17  # samples per side for the first look; most patches stop there
_FINE_MAX = 4097  # most samples per side for placing the cuts
_PIECES_MAX = 1024  # most pieces one patch is cut into
_STEP = 8  # fine samples per piece at least, so that the pieces' lengths follow the widths
_SIDES = 0.5  # a strip's two long sides are within this factor of each other's length


class SlenderCut:
    """The pieces of one patch (nets in order along its length), the certified bound of their
    deviation from it (homogeneous bound over the smallest weight for rational nets), whether
    they took the composed degree, and where the cuts run: ``axis`` is the patch's long axis, and
    cut k goes straight from parameter a[k] on its side at the start of the other axis to b[k]
    on the side at the end (piece k covers the patch between cuts k - 1 and k)."""

    __slots__ = ("pieces", "bound", "degree_raised", "axis", "a", "b")

    def __init__(self, pieces: list[np.ndarray], bound: float, degree_raised: bool, axis: int,
                 a: np.ndarray, b: np.ndarray):
        self.pieces = pieces
        self.bound = bound
        self.degree_raised = degree_raised
        self.axis, self.a, self.b = axis, a, b


def _cartesian(pts: np.ndarray, rational: bool) -> np.ndarray:
    return dehomogenize(pts) if rational else pts


def _to_polyline(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each point of ``a`` (k, 3) to the polyline through ``b`` (m, 3), and the
    polyline parameter of the foot (segment index + fraction): (k,), (k,)."""
    p, d = b[:-1], np.diff(b, axis=0)
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    dist, where = np.empty(len(a)), np.empty(len(a))
    for i0 in range(0, len(a), 256):  # chunks keep the (chunk, m, 3) temporaries small
        x = a[i0:i0 + 256, None, :] - p[None]
        t = np.clip(np.einsum("kij,ij->ki", x, d) / dd, 0.0, 1.0)
        r = np.linalg.norm(x - t[..., None] * d[None], axis=-1)
        j = r.argmin(axis=1)
        dist[i0:i0 + 256] = r[np.arange(len(j)), j]
        where[i0:i0 + 256] = j + t[np.arange(len(j)), j]
    return dist, where


def _long_sides(net: np.ndarray, rational: bool, n: int):
    """The sides at the start and the end of axis 0 (they run along axis 1), sampled at n
    parameters: (s, side 0 points, side 1 points)."""
    s = np.linspace(0.0, 1.0, n)
    pts = _cartesian(curve_eval(np.moveaxis(net[[0, -1]], 1, 0), s), rational)  # (n, 2, 3)
    return s, pts[:, 0], pts[:, 1]


def slender_axis(ctrl: np.ndarray, rational: bool, ratio: float, floor: float) -> int | None:
    """The axis along which the patch is a strip more than ``ratio`` times longer than it is wide
    (its two sides that run along it stand that close, and neither is less than half the other
    long), or None. A patch narrower than ``floor`` somewhere (a collapsed side: a triangle or a
    pole wedge) counts as not slender: it has no width to measure pieces by; nor does a triangle
    made four-sided (``core.triangle``), whose side at the tip is short and near the long one."""
    best = None
    for axis in (0, 1):
        net = ctrl if axis == 1 else np.swapaxes(ctrl, 0, 1)
        _, lo, hi = _long_sides(net, rational, _COARSE)
        width = np.minimum(_to_polyline(lo, hi)[0], _to_polyline(hi, lo)[0])
        if float(width.min()) <= floor:
            continue
        lengths = [np.linalg.norm(np.diff(side, axis=0), axis=1).sum() for side in (lo, hi)]
        if min(lengths) < _SIDES * max(lengths):  # a triangle or a wedge, not a strip
            continue
        aspect = max(lengths) / float(width.min())
        if aspect > ratio and (best is None or aspect > best[1]):
            best = (axis, aspect)
    return None if best is None else best[0]


def _foot(net_side: np.ndarray, rational: bool, pts: np.ndarray, s0: np.ndarray) -> np.ndarray:
    """Parameters of the side curve nearest to ``pts`` (k, 3), refined from ``s0`` by Gauss-Newton
    (the points lie on the curve, where it converges fast)."""
    from .bezier import curve_derivative

    s = np.clip(np.asarray(s0, dtype=float).copy(), 0.0, 1.0)
    d1 = curve_derivative(net_side)
    for _ in range(8):
        h, dh = curve_eval(net_side, s), curve_eval(d1, s)
        if rational:
            c = h[:, :-1] / h[:, -1:]
            dc = (dh[:, :-1] - c * dh[:, -1:]) / h[:, -1:]
        else:
            c, dc = h, dh
        step = np.einsum("ij,ij->i", dc, c - pts) / np.maximum(np.einsum("ij,ij->i", dc, dc), 1e-300)
        s = np.clip(s - step, 0.0, 1.0)
        if np.abs(step).max() <= 1e-15:
            break
    return s


def _snapped(net_side, rational, t, snap, on: float):
    """``t`` (parameters of the side at the samples ``s``) moved onto existing vertices that lie on
    the side within ``on`` and within a quarter of the distance to the next station: two strips
    that share a long side are cut at the same points, not at points a rounding apart."""
    if snap is None or not len(t):
        return t
    pts = _cartesian(curve_eval(net_side, t), rational)
    ends = np.concatenate([[0.0], t, [1.0]])
    ends_pts = _cartesian(curve_eval(net_side, ends), rational)
    gaps = np.linalg.norm(np.diff(ends_pts, axis=0), axis=1)
    radius = 0.25 * np.minimum(gaps[:-1], gaps[1:])
    hits = snap(pts, radius)
    found = ~np.isnan(hits[:, 0])
    if not found.any():
        return t
    t = t.copy()
    tf = _foot(net_side, rational, hits[found], t[found])
    on_side = np.linalg.norm(_cartesian(curve_eval(net_side, tf), rational) - hits[found], axis=1) <= on
    idx = np.flatnonzero(found)[on_side]
    t[idx] = tf[on_side]
    return t


def _stations(net: np.ndarray, rational: bool, ratio: float, floor: float, snap, on: float):
    """Cut stations along a strip whose long direction is axis 1: parameters a on side 0 and b on
    side 1 (the nearest point of side 1 to side 0 at a), both increasing inside (0, 1), chosen so
    that each piece is at most ``ratio`` times longer than its narrowest width; snapped to the
    vertices that ``snap`` knows (see ``_snapped``)."""
    _, lo, hi = _long_sides(net, rational, _COARSE)
    aspect = np.linalg.norm(np.diff(lo, axis=0), axis=1).sum() / max(_to_polyline(lo, hi)[0].min(), floor)
    n = int(min(_FINE_MAX, _STEP * np.ceil(aspect / ratio) + _COARSE))
    while True:
        s, lo, hi = _long_sides(net, rational, n)
        width, foot = _to_polyline(lo, hi)
        if float(width.min()) <= floor:
            return None
        # where the strip narrows between the coarse samples (a pinch), one fine step may be
        # near as long as a piece there may be: sample finer, up to the cap
        step = np.linalg.norm(np.diff(lo, axis=0), axis=1)
        short = step / (ratio * np.minimum(width[:-1], width[1:]))
        want = int(min(_FINE_MAX, np.ceil((n - 1) * _STEP * float(short.max())) + 1))
        if float(short.max()) <= 0.5 or want <= n:
            break
        n = want
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(lo, axis=0), axis=1))])
    # side 1 measured too, at the feet of side 0's samples: where the strip ends slanted, side 1's
    # first and last pieces are longer than side 0's by the slant
    length1 = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(hi, axis=0), axis=1))])
    along1 = np.interp(foot, np.arange(n), length1)
    along1[-1] = length1[-1]
    cuts, i = [], 0
    while len(cuts) < _PIECES_MAX - 1:
        run = np.minimum.accumulate(width[i:])
        start1 = along1[i] if i else 0.0
        fits = np.maximum(length[i:] - length[i], along1[i:] - start1) <= ratio * run
        if fits.all():
            break
        j = i + max(int(np.argmin(fits)) - 1, 1)
        if j >= n - 1:
            break
        cuts.append(j)
        i = j
    if not cuts:
        return None
    k = len(cuts) + 1  # the same number of cuts at equal length leaves no stub, where it fits
    even = np.clip(np.searchsorted(length, length[-1] * np.arange(1, k) / k), 1, n - 2)
    ends = np.concatenate([[0], even, [n - 1]])
    starts1 = np.concatenate([[0.0], along1[ends[1:-1]]])
    if len(np.unique(even)) == k - 1 and all(
            max(length[b] - length[a], along1[b] - s1) <= ratio * float(width[a:b + 1].min())
            for a, b, s1 in zip(ends[:-1], ends[1:], starts1, strict=True)):
        cuts = list(even)
    a = _snapped(net[0], rational, s[cuts], snap, on)
    # side 1's nearest point to each station of side 0: the polyline's foot, then refined
    pts = _cartesian(curve_eval(net[0], a), rational)
    _, f = _to_polyline(pts, hi)
    b = _foot(net[-1], rational, pts, np.interp(f, np.arange(n), s))
    b = _snapped(net[-1], rational, b, snap, on)
    keep = (a > 0.0) & (a < 1.0) & (b > 0.0) & (b < 1.0)
    a, b = a[keep], b[keep]
    ok = np.concatenate([[True], (np.diff(a) > 0) & (np.diff(b) > 0)])  # straight cuts must not cross
    while not ok.all():
        a, b = a[ok], b[ok]
        ok = np.concatenate([[True], (np.diff(a) > 0) & (np.diff(b) > 0)])
    return (a, b) if len(a) else None


def _cut_curve(net: np.ndarray, a: float, b: float, target: int) -> tuple[np.ndarray, float]:
    """The patch along the straight line from (0, a) to (1, b) of its square, at degree target."""
    exact = compose(net, np.array([[0.0], [1.0]]), np.array([[a], [b]]))[:, 0]
    return reduce_curve(exact, target, fix_ends=1)


def cut_slender(ctrl: np.ndarray, rational: bool, ratio: float, floor: float, budget: float,
                max_degree: int, snap=None, on: float = 0.0) -> SlenderCut | None:
    """Cut a patch more than ``ratio`` times longer than wide (``slender_axis``) into pieces that
    are not, by straight cuts across (see the module doc), or None when it is not slender or no
    cut fits. The pieces keep the patch's bidegree when that holds them within ``budget``, else
    they take the exact composed bidegree if it is within ``max_degree``, else None.

    ctrl : (m+1, n+1, d) net, homogeneous when ``rational``. ``snap(points (k, 3), radii (k,))``,
    when given, returns for each point a known vertex within its radius, or NaNs: a cut whose end
    would land near a vertex that lies on the side (within ``on``) goes through it instead.
    Returns the pieces in order along the patch's length; the first starts with the patch's own
    side there and the last ends with it."""
    axis = slender_axis(ctrl, rational, ratio, floor)
    if axis is None:
        return None
    net = np.asarray(ctrl, dtype=float)
    if axis == 0:
        net = np.swapaxes(net, 0, 1)
    stations = _stations(net, rational, ratio, floor, snap, on)
    if stations is None:
        return None
    a, b = stations
    m, n = net.shape[0] - 1, net.shape[1] - 1
    weight = float(net[..., -1].min()) if rational else 1.0
    if weight <= 0:
        return None
    for target, raised in ((m, False), (min(m + n, max_degree), True)):
        if raised and target == m:
            break
        made = _pieces(net, a, b, target)
        if made is None:
            continue
        pieces, bound = made
        bound /= weight
        if bound <= budget:
            if axis == 0:
                pieces = [np.ascontiguousarray(np.swapaxes(p, 0, 1)) for p in pieces]
            return SlenderCut(pieces, bound, raised, axis, a, b)
    return None


def _pieces(net: np.ndarray, a: np.ndarray, b: np.ndarray, target: int):
    """The pieces between consecutive cuts at degree ``target`` across, and their largest bound."""
    m, n = net.shape[0] - 1, net.shape[1] - 1
    from .bezier import elevate_curve

    ends_a = np.concatenate([[0.0], a, [1.0]])
    ends_b = np.concatenate([[0.0], b, [1.0]])
    side0 = [curve_segment(net[0], x, y) for x, y in zip(ends_a[:-1], ends_a[1:], strict=True)]
    side1 = [curve_segment(net[-1], x, y) for x, y in zip(ends_b[:-1], ends_b[1:], strict=True)]
    side0[0][0], side0[-1][-1] = net[0, 0], net[0, -1]
    side1[0][0], side1[-1][-1] = net[-1, 0], net[-1, -1]
    cuts, bound = [elevate_curve(net[:, 0], target - m)], 0.0
    for x, y in zip(a, b, strict=True):
        c, e = _cut_curve(net, x, y, target)
        bound = max(bound, e)
        cuts.append(c)
    cuts.append(elevate_curve(net[:, -1], target - m))
    for k, c in enumerate(cuts):  # the corners are the long sides' own points
        if k > 0:
            c[0], c[-1] = side0[k - 1][-1], side1[k - 1][-1]
        else:
            c[0], c[-1] = side0[0][0], side1[0][0]
    pieces = []
    for k in range(len(ends_a) - 1):
        V = np.array([[ends_a[k], ends_a[k + 1]], [ends_b[k], ends_b[k + 1]]])
        exact = compose(net, np.array([[0.0], [1.0]]), V)
        q, e = reduce_surface(exact, target, n, boundaries=(side0[k], side1[k], cuts[k], cuts[k + 1]))
        bound = max(bound, e)
        pieces.append(q)
    return pieces, bound
