"""Where to split the long sides of long, narrow patches (arrays in, arrays out).

Stage 1 can only cut a face along its slab lines, rungs and knot lines, and where two of those run
close together it leaves a strip thousands of times longer than it is wide (bspline_boolean face 0:
knots 4e-4 apart, a strip 0.001 wide and 28 long). Such a patch is exact, but anything that samples
boundaries at a fixed count per edge sees its neighbours' samples farther apart than the strip is
wide, and takes the far side of the strip for the near one.

The patch stays whole; its two long sides get vertices at stations along them, so that no edge
of them is more than ``ratio`` times longer than the strip is wide where it runs. A station on
side 1 is the nearest point of side 1 to its station on side 0 (the two sides are split opposite
each other, also where the strip ends on a rung that crosses it at a shallow angle). Stations
snap to known vertices nearby, so that two strips that share a long side split it at the same
points. ``topology.split`` puts the points into the edges, which splits the neighbours' sides too.

These stations were first used to cut strips across into pieces (each the patch composed with a
bilinear map and reduced again): with the same stations, the independent checker found the same
boundary figures on the fixtures, at 2 to 2.5 times the patches.
"""

from __future__ import annotations

import numpy as np

from .bernstein import basis
from .bezier import curve_eval, dehomogenize

__all__ = ["SlenderSplit", "slender_axes", "slender_axis", "split_along", "split_points", "strip_measures"]

_COARSE = 17  # samples per side for the first look; most patches stop there
_FINE_MAX = 4097  # most samples per side for placing the stations
_PIECES_MAX = 1024  # most pieces one long side is split into
_STEP = 8  # fine samples per piece at least, so that the pieces' lengths follow the widths
_SIDES = 0.5  # a strip's two long sides are within this factor of each other's length
_BRUTE = 1 << 16  # point-segment pairs up to which ``_to_polyline`` measures them all


class SlenderSplit:
    """Where a slender patch's long sides are split: ``axis`` is the patch's long axis; side 0 (at
    the start of the other axis) at parameters ``a``, side 1 (at its end) at ``b``, both increasing
    inside (0, 1); ``points`` (len(a) + len(b), 3) are those points, side 0's first (Cartesian)."""

    __slots__ = ("axis", "a", "b", "points")

    def __init__(self, axis: int, a: np.ndarray, b: np.ndarray, points: np.ndarray):
        self.axis, self.a, self.b, self.points = axis, a, b, points


def _cartesian(pts: np.ndarray, rational: bool) -> np.ndarray:
    return dehomogenize(pts) if rational else pts


def _to_polyline(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each point of ``a`` (k, 3) to the polyline through ``b`` (m, 3), and the
    polyline parameter of the foot (segment index + fraction): (k,), (k,). Long polylines go
    through a k-d tree of their points (``_to_polyline_near``)."""
    if len(a) * len(b) > _BRUTE and len(b) > 2:
        return _to_polyline_near(a, b)
    dist, where = np.empty(len(a)), np.empty(len(a))
    for i0 in range(0, len(a), 256):  # chunks keep the (chunk, m, 3) temporaries small
        c = slice(i0, i0 + 256)
        dist[c], where[c] = (x[0] for x in _to_polylines(a[None, c], b[None]))
    return dist, where


def _to_polylines(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``_to_polyline`` for a stack, every point against every segment: a (P, k, 3) to the
    polylines b (P, m, 3); distances and feet (segment index + fraction), (P, k) each."""
    p, d = b[:, :-1], np.diff(b, axis=1)
    dd = np.maximum(np.einsum("pij,pij->pi", d, d), 1e-300)
    x = a[:, :, None, :] - p[:, None]
    t = np.clip(np.einsum("pkij,pij->pki", x, d) / dd[:, None], 0.0, 1.0)
    r = np.linalg.norm(x - t[..., None] * d[:, None], axis=-1)
    j = r.argmin(axis=2)
    return np.take_along_axis(r, j[..., None], 2)[..., 0], j + np.take_along_axis(t, j[..., None], 2)[..., 0]


def _to_polyline_near(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``_to_polyline`` by the segments near each point alone: a point's foot lies within half a
    segment of one of that segment's ends, so it lies on a segment with an end within
    (distance to the nearest point of ``b``) + (longest segment) / 2 of the point; only those are
    measured. The same distances as measuring every segment (the foot may differ where two
    segments are equally near)."""
    from scipy.spatial import cKDTree

    p, d = b[:-1], np.diff(b, axis=0)
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    tree = cKDTree(b)
    near, _ = tree.query(a)
    reach = near + 0.5 * float(np.sqrt(dd.max())) * (1.0 + 1e-9) + 1e-300
    found = tree.query_ball_point(a, reach)
    counts = np.fromiter((len(f) for f in found), dtype=int, count=len(a))
    verts = np.fromiter((v for f in found for v in f), dtype=int, count=int(counts.sum()))
    pt = np.repeat(np.arange(len(a)), counts)
    # each vertex found stands for the segments on both sides of it
    seg = np.concatenate([verts - 1, verts])
    pt = np.concatenate([pt, pt])
    ok = (seg >= 0) & (seg < len(p))
    seg, pt = seg[ok], pt[ok]
    x = a[pt] - p[seg]
    t = np.clip(np.einsum("ij,ij->i", x, d[seg]) / dd[seg], 0.0, 1.0)
    r = np.linalg.norm(x - t[:, None] * d[seg], axis=1)
    order = np.lexsort((seg, r, pt))  # per point: nearest first, the lower segment on a tie
    first = order[np.concatenate([[True], np.diff(pt[order]) > 0])]
    return r[first], seg[first] + t[first]


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


def strip_measures(ctrls: np.ndarray, rational: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first look at a stack of nets of one shape, ctrls (P, m+1, n+1, d), in one pass of array
    operations, per patch and axis (P, 2): the narrowest width between the two sides that run
    along that axis, the longer of them, and whether neither is less than ``_SIDES`` of the other
    (a strip, not a triangle or a wedge). ``slender_axes`` reads them."""
    ctrls = np.asarray(ctrls, dtype=float)
    P = len(ctrls)
    narrow, longest, balanced = np.zeros((P, 2)), np.zeros((P, 2)), np.zeros((P, 2), dtype=bool)
    s = np.linspace(0.0, 1.0, _COARSE)
    for axis in (0, 1):
        net = ctrls if axis == 1 else np.swapaxes(ctrls, 1, 2)
        rows = net[:, [0, -1]]  # (P, 2, n+1, d): the sides along axis 1
        pts = np.einsum("kj,pijd->pikd", basis(rows.shape[2] - 1, s), rows)
        pts = _cartesian(pts, rational)
        lo, hi = pts[:, 0], pts[:, 1]
        width = np.empty((P, _COARSE))
        for i0 in range(0, P, 512):  # chunks keep the (chunk, k, k, 3) temporaries small
            c = slice(i0, i0 + 512)
            width[c] = np.minimum(_to_polylines(lo[c], hi[c])[0], _to_polylines(hi[c], lo[c])[0])
        narrow[:, axis] = width.min(axis=1)
        lengths = np.linalg.norm(np.diff(pts, axis=2), axis=3).sum(axis=2)  # (P, 2)
        longest[:, axis] = lengths.max(axis=1)
        balanced[:, axis] = lengths.min(axis=1) >= _SIDES * lengths.max(axis=1)
    return narrow, longest, balanced


def slender_axes(ctrls, rational: bool, ratio: float, floor: float, measures=None) -> np.ndarray:
    """``slender_axis`` for a stack of nets of one shape, ctrls (P, m+1, n+1, d): (P,) ints, the
    axis, or -1 where the patch is not slender. ``measures``: the stack's ``strip_measures``, when
    the caller has them already (asking with another ratio and floor costs no second look)."""
    narrow, longest, balanced = strip_measures(ctrls, rational) if measures is None else measures
    out = np.full(len(narrow), -1)
    best = np.zeros(len(narrow))
    for axis in (0, 1):
        strip = (narrow[:, axis] > floor) & balanced[:, axis]
        aspect = np.where(strip, longest[:, axis] / np.where(strip, narrow[:, axis], 1.0), 0.0)
        take = strip & (aspect > ratio) & ((out < 0) | (aspect > best))
        out[take], best[take] = axis, aspect[take]
    return out


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
    that share a long side are split at the same points, not at points a rounding apart."""
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
    # the stations run the same way along both sides
    ok = np.concatenate([[True], (np.diff(a) > 0) & (np.diff(b) > 0)])
    while not ok.all():
        a, b = a[ok], b[ok]
        ok = np.concatenate([[True], (np.diff(a) > 0) & (np.diff(b) > 0)])
    return (a, b) if len(a) else None


def split_points(ctrl: np.ndarray, rational: bool, ratio: float, floor: float, snap=None,
                 on: float = 0.0) -> SlenderSplit | None:
    """Where to split the long sides of a patch more than ``ratio`` times longer than wide
    (``slender_axis``) so that every piece of them is at most ``ratio`` times longer than the strip
    is wide there, or None when it is not slender (or too narrow somewhere to measure: ``floor``).

    ctrl : (m+1, n+1, d) net, homogeneous when ``rational``. ``snap(points (k, 3), radii (k,))``,
    when given, returns for each point a known vertex within its radius, or NaNs: a station that
    would land near a vertex that lies on the side (within ``on``) goes to it instead."""
    axis = slender_axis(ctrl, rational, ratio, floor)
    return None if axis is None else split_along(ctrl, rational, axis, ratio, floor, snap, on)


def split_along(ctrl: np.ndarray, rational: bool, axis: int, ratio: float, floor: float, snap=None,
                on: float = 0.0) -> SlenderSplit | None:
    """``split_points`` for a patch already known to be slender along ``axis`` (``slender_axes``)."""
    net = np.asarray(ctrl, dtype=float)
    if axis == 0:
        net = np.swapaxes(net, 0, 1)
    stations = _stations(net, rational, ratio, floor, snap, on)
    if stations is None:
        return None
    a, b = stations
    pts = np.concatenate([_cartesian(curve_eval(net[0], a), rational),
                          _cartesian(curve_eval(net[-1], b), rational)])
    return SlenderSplit(axis, a, b, pts)
