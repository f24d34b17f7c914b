"""B-spline (and NURBS, homogeneous) curves and surfaces: knot insertion and Bezier extraction.

Conventions
-----------
- ``knots`` is the full (OCCT "flat") knot vector, length n+p+2 for n+1 control points of degree p.
  It need not be clamped: the valid parameter range is [knots[p], knots[n+1]] (as in scipy's BSpline).
- ``ctrl : (n+1, ...)`` with any trailing axes; a surface direction is handled by moving that axis first.
- NURBS are passed homogeneous (w*x, w*y, w*z, w); every routine here is linear in ``ctrl``.
"""

from __future__ import annotations

import numpy as np

from .bezier import curve_segment

__all__ = [
    "check_knots",
    "find_span",
    "multiplicity",
    "insert_knot",
    "to_bezier",
    "surface_to_bezier",
    "split_curve_at",
    "bspline_eval",
    "merge_removable_spans",
]


def check_knots(knots, degree: int, n_ctrl: int) -> np.ndarray:
    """Validate a knot vector against a degree and a control-point count; return it as float array.

    Raises ValueError on: negative degree, too few control points, wrong length, decreasing knots, or an
    empty valid range.
    """
    knots = np.asarray(knots, dtype=float)
    if degree < 0:
        raise ValueError(f"degree must be >= 0, got {degree}")
    if knots.ndim != 1:
        raise ValueError(f"knots must be 1-D, got shape {knots.shape}")
    if n_ctrl < degree + 1:
        raise ValueError(f"need at least degree+1 = {degree + 1} control points, got {n_ctrl}")
    if knots.shape[0] != n_ctrl + degree + 1:
        raise ValueError(
            f"knot vector length {knots.shape[0]} != n_ctrl + degree + 1 = {n_ctrl + degree + 1}"
        )
    if np.any(np.diff(knots) < 0):
        raise ValueError("knot vector must be non-decreasing")
    if not knots[n_ctrl] > knots[degree]:
        raise ValueError(f"empty parameter range [{knots[degree]}, {knots[n_ctrl]}]")
    return knots


def find_span(knots, degree: int, u):
    """Knot span index k with knots[k] <= u < knots[k+1], clipped to [degree, n] (NURBS Book A2.1).

    u = knots[n+1] (the end of the range) returns n, the last non-empty span. Vectorized.

    knots : (n+p+2,) float; u : float or (k,) float. Returns int or (k,) int.
    """
    knots = np.asarray(knots, dtype=float)
    n = knots.shape[0] - degree - 2
    k = np.searchsorted(knots, u, side="right") - 1
    k = np.clip(k, degree, n)
    # At u == knots[n+1] with repeated end knots, clip already gives n; step back over empty spans.
    if np.ndim(k) == 0:
        k = int(k)
        while k > degree and knots[k] == knots[k + 1]:
            k -= 1
        return k
    kk = k.copy()
    for _ in range(degree + 1):
        empty = (kk > degree) & (knots[kk] == knots[kk + 1])
        if not empty.any():
            break
        kk[empty] -= 1
    return kk


def multiplicity(knots, u: float) -> int:
    """Number of knots exactly equal to u."""
    return int(np.count_nonzero(np.asarray(knots) == u))


def insert_knot(knots, degree: int, ctrl, u: float, r: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Insert the knot u r times (NURBS Book A5.1, Boehm's algorithm).

    knots : (n+p+2,) float; ctrl : (n+1, ...) float (any trailing axes); u : float inside the valid range
    [knots[p], knots[n+1]]; r : int >= 0 with r + multiplicity(u) <= degree (ValueError otherwise).

    Returns (new_knots : (n+p+2+r,), new_ctrl : (n+1+r, ...)). The curve is unchanged.
    """
    knots = np.asarray(knots, dtype=float)
    ctrl = np.asarray(ctrl, dtype=float)
    p = int(degree)
    r = int(r)
    n = ctrl.shape[0] - 1
    if knots.shape[0] != n + p + 2:
        raise ValueError(f"knot vector length {knots.shape[0]} != n_ctrl + degree + 1 = {n + p + 2}")
    if r < 0:
        raise ValueError(f"insert_knot: r must be >= 0, got {r}")
    if r == 0:
        return knots.copy(), ctrl.copy()
    if not knots[p] <= u <= knots[n + 1]:
        raise ValueError(f"insert_knot: u={u} outside the valid range [{knots[p]}, {knots[n + 1]}]")
    s = multiplicity(knots, u)
    if s + r > p:
        raise ValueError(f"insert_knot: multiplicity {s} + {r} of u={u} would exceed degree {p}")
    k = int(np.searchsorted(knots, u, side="right")) - 1  # last index with knots[k] <= u
    new_knots = np.concatenate([knots[: k + 1], np.full(r, float(u)), knots[k + 1 :]])
    q = np.empty((n + 1 + r,) + ctrl.shape[1:])
    q[: k - p + 1] = ctrl[: k - p + 1]
    q[k - s + r : n + r + 1] = ctrl[k - s : n + 1]
    rw = ctrl[k - p : k - s + 1].copy()  # p-s+1 points
    tail = (1,) * (ctrl.ndim - 1)
    big_l = k - p
    for j in range(1, r + 1):
        big_l = k - p + j
        i = np.arange(p - j - s + 1)
        alpha = ((u - knots[big_l + i]) / (knots[i + k + 1] - knots[big_l + i])).reshape((-1,) + tail)
        rw[: p - j - s + 1] = alpha * rw[1 : p - j - s + 2] + (1.0 - alpha) * rw[: p - j - s + 1]
        q[big_l] = rw[0]
        q[k + r - j - s] = rw[p - j - s]
    # remaining interior points
    for i in range(big_l + 1, k - s):
        q[i] = rw[i - big_l]
    return new_knots, q


def to_bezier(knots, degree: int, ctrl) -> tuple[np.ndarray, np.ndarray]:
    """Extract the Bezier segments of a B-spline curve by knot insertion (NURBS Book A5.1 / A5.6).

    Every distinct knot value in the valid range [knots[p], knots[n+1]] (ends included) is inserted up to
    multiplicity p, so unclamped (e.g. periodic, flattened) knot vectors are handled as well as clamped
    ones. The Bezier net of span [x_i, x_{i+1}] is then the p+1 control points of that span.

    knots : (n+p+2,) float; ctrl : (n+1, ...) float.
    Returns (breaks : (k+1,) float, the distinct knots of the range; segs : (k, p+1, ...) float).
    """
    ctrl = np.asarray(ctrl, dtype=float)
    p = int(degree)
    knots = check_knots(knots, p, ctrl.shape[0])
    n = ctrl.shape[0] - 1
    a, b = knots[p], knots[n + 1]
    inside = knots[(knots >= a) & (knots <= b)]
    breaks = np.unique(inside)
    kn, cp = knots, ctrl
    if p > 0:
        for x in breaks:
            s = multiplicity(kn, x)
            if s < p:
                kn, cp = insert_knot(kn, p, cp, x, p - s)
    segs = []
    for x in breaks[:-1]:
        k = int(np.searchsorted(kn, x, side="right")) - 1  # last index of x: span [x, next)
        segs.append(cp[k - p : k + 1])
    return breaks, np.stack(segs)


def surface_to_bezier(uknots, vknots, p: int, q: int, ctrl) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Extract the Bezier patches of a tensor-product B-spline surface (u direction, then v).

    uknots : (nu+p+2,) float; vknots : (nv+q+2,) float; ctrl : (nu+1, nv+1, d) float (homogeneous for
    NURBS). Returns (ubreaks : (ku+1,), vbreaks : (kv+1,), patches : (ku, kv, p+1, q+1, d)).
    """
    ctrl = np.asarray(ctrl, dtype=float)
    if ctrl.ndim < 2:
        raise ValueError(f"surface_to_bezier: ctrl must be (nu+1, nv+1, ...), got shape {ctrl.shape}")
    ub, useg = to_bezier(uknots, p, ctrl)  # (ku, p+1, nv+1, ...)
    vb, vseg = to_bezier(vknots, q, np.moveaxis(useg, 2, 0))  # (kv, q+1, ku, p+1, ...)
    patches = np.moveaxis(vseg, (0, 1, 2, 3), (1, 3, 0, 2))  # (ku, kv, p+1, q+1, ...)
    return ub, vb, np.ascontiguousarray(patches)


def split_curve_at(knots, degree: int, ctrl, params) -> tuple[np.ndarray, np.ndarray]:
    """Bezier segments of a B-spline curve between consecutive split parameters and knots.

    The breakpoints are the union of the distinct knots of the valid range and ``params`` (which must
    lie in that range). Each segment is a sub-curve of one Bezier span, cut by blossoming.

    Returns (breaks : (k+1,) float sorted, segs : (k, p+1, ...) float).
    """
    breaks_k, spans = to_bezier(knots, degree, ctrl)
    params = np.atleast_1d(np.asarray(params, dtype=float))
    a, b = breaks_k[0], breaks_k[-1]
    if params.size and (params.min() < a or params.max() > b):
        raise ValueError(f"split_curve_at: parameters must lie in [{a}, {b}]")
    breaks = np.unique(np.concatenate([breaks_k, params]))
    segs = []
    for w0, w1 in zip(breaks[:-1], breaks[1:], strict=True):
        j = int(np.clip(np.searchsorted(breaks_k, w0, side="right") - 1, 0, len(spans) - 1))
        x0, x1 = breaks_k[j], breaks_k[j + 1]
        lo = (w0 - x0) / (x1 - x0)
        hi = 1.0 if w1 == x1 else (w1 - x0) / (x1 - x0)
        segs.append(spans[j] if (lo == 0.0 and hi == 1.0) else curve_segment(spans[j], lo, hi))
    return breaks, np.stack(segs)


def bspline_eval(knots, degree: int, ctrl, t) -> np.ndarray:
    """Evaluate a (non-rational or homogeneous) B-spline curve with scipy.interpolate.BSpline (de Boor).

    knots : (n+p+2,) float; ctrl : (n+1, ...) float; t : (k,) float in the valid range.
    Returns (k, ...) float (homogeneous if ctrl is; dehomogenize yourself).
    """
    from scipy.interpolate import BSpline  # lazy: keep the core import light

    ctrl = np.asarray(ctrl, dtype=float)
    knots = check_knots(knots, degree, ctrl.shape[0])
    return BSpline(knots, ctrl, int(degree), extrapolate=False)(np.asarray(t, dtype=float))


def merge_removable_spans(knots, degree: int, ctrl, tol: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The same B-spline without the knots across which it is one polynomial, or None if it has none.

    Exporters often give a curve or surface the union of several knot vectors (a loft's sections,
    a Boolean's operands), so knots appear where the spline does not break. Consecutive Bezier spans
    are joined while one polynomial, the longest span's carried over the group's interval by
    blossoming, stays within ``tol`` of every span's control points (the convex hull bounds the
    deviation by that). The result has each remaining break at multiplicity ``degree`` (C0 form, the
    same geometry); its valid range is the input's. Works along the first axis of ``ctrl``
    (homogeneous for NURBS: compare weights on the scale of the coordinates yourself)."""
    if np.shape(ctrl)[0] == degree + 1:  # one span (every Bezier written as a B-spline): nothing to join
        return None
    breaks, segs = to_bezier(knots, degree, ctrl)
    k = len(segs)
    if k < 2 or degree < 1:
        return None

    def joined(i0: int, i1: int) -> np.ndarray | None:
        a, b = breaks[i0], breaks[i1 + 1]
        lengths = np.diff(breaks[i0:i1 + 2])
        j = i0 + int(np.argmax(lengths))
        x0, x1 = breaks[j], breaks[j + 1]
        poly = curve_segment(segs[j], (a - x0) / (x1 - x0), (b - x0) / (x1 - x0))
        for m in range(i0, i1 + 1):
            sub = curve_segment(poly, (breaks[m] - a) / (b - a), (breaks[m + 1] - a) / (b - a))
            if np.abs(sub - segs[m]).max() > tol:
                return None
        return poly

    groups: list[tuple[int, int, np.ndarray]] = []
    i0, poly = 0, segs[0]
    for i in range(1, k):
        longer = joined(i0, i)
        if longer is not None:
            poly = longer
            continue
        groups.append((i0, i - 1, poly))
        i0, poly = i, segs[i]
    groups.append((i0, k - 1, poly))
    if len(groups) == k:
        return None
    p = int(degree)
    kn = [breaks[0]] * (p + 1)
    pts = [groups[0][2]]
    for g0, _, poly in groups[1:]:
        kn += [breaks[g0]] * p
        pts.append(poly[1:])
    kn += [breaks[-1]] * (p + 1)
    return np.array(kn, dtype=float), np.concatenate(pts, axis=0)
