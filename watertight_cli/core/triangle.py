"""A patch with one collapsed side, made again as a four-sided patch with no collapsed side.

Stage 1 leaves triangular cells where a loop turns at a corner of its face (two trimming edges
meeting at a vertex that is the loop's extreme in the slab direction) and at poles. Written as it
is, such a patch has a degenerated edge, and any tessellation of it holds a triangle with two
nodes at the collapsed point, so no mesh of the model is closed (OCCT's own sphere fails the
same way). The patch P is a triangle A, B, C: its side at s = 0 collapses onto A, the bottom
(t = 0) runs A -> B, the right side (s = 1) B -> C and the top (t = 1) A -> C. The new patch Q
has corners A, B, M, C with M the midpoint (in parameter) of the side opposite A, so its four
sides are the bottom, the two halves of the right side and the top, exactly the old curves
(elevated; the top's weights rescaled by a Moebius change of parameter where P is rational so
that its weight at A is the bottom's). Its inner control points are fitted, by linear least
squares with fixed weights, to P composed with a map m of [0, 1]^2 onto the triangle that sends
Q's sides onto those curves at those parameters, or, where that misses, to the foot points on P
of the Coons patch of Q's sides (m fans Q's corner out over the collapsed side, which a wide
corner such as a sphere's pole does not forgive). Q's corner at M is flat (its two sides run on
in one line), so the patch's Jacobian vanishes there; the fit is rejected where its normal
turns against P's on an inner grid, or where its net blows up.

The fit's deviation is measured by sampling, both ways: from Q's points on a grid finer than the
fit's (offset from it) to their foot points on P, started at m of the same parameters, and from
P's points at m of that grid to their foot points on Q. It bounds the two-sided distance between
the surfaces up to the sampling (m covers the triangle). Pure numpy: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np

from .bernstein import basis, basis_and_lower
from .bezier import curve_split, elevate_curve, rational_surface_eval

#: samples per degree in each direction of the fit and of the check (the check's grid is offset,
#: so no check point is a fit point)
_FIT_PER_DEGREE = 2
_CHECK_PER_DEGREE = 3
#: degrees tried above the lowest (max of P's degrees): a patch that needs more is kept as it is
_RAISE = 4
#: weight of the pull towards the Coons net, relative to the fit's mean squared column norm
_PULL = 1e-4
#: how far (x the boundary's size) an inner control point may lie from the boundary's box
_BLOWN_UP = 4.0
#: Gauss-Newton steps of the projection of the Coons patch onto P (``_fit(project=True)``),
#: started at m's parameters: the Coons points lie off P by up to the patch's bulge
_PROJECT_ITERS = 20
#: a first fit farther than this (x the budget) is not tried at higher degrees
_HOPELESS = 4.0


def collapsed_side(ctrl: np.ndarray, eps: float) -> int | None:
    """How many quarter turns (``np.rot90`` on the first two axes) bring the one collapsed side of
    a net (Cartesian or homogeneous, (m+1, n+1, d)) to s = 0; None unless exactly one side is
    collapsed (every control point of it within ``eps`` of its first)."""
    xyz = ctrl[..., :3] / ctrl[..., 3:4] if ctrl.shape[-1] == 4 else ctrl
    # a collapsed side has its two corners at one point: most nets have none, and the corners
    # alone say so (this runs on every patch of the model)
    c = xyz[[0, -1, -1, 0], [0, 0, -1, -1]]
    if int((np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1) <= eps).sum()) != 1:
        return None
    found = []
    for k in range(4):
        r = np.rot90(xyz, k)
        if float(np.linalg.norm(r[0] - r[0, 0], axis=-1).max()) <= eps:
            found.append(k)
    return found[0] if len(found) == 1 else None


def domain_map(sigma: np.ndarray, tau: np.ndarray, split: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The map m from Q's square onto P's triangle (broadcast over sigma, tau). On Q's sides, with
    c = ``split``: m(σ, 0) = (σ, 0), m(0, τ) = (τ, 1), m(1, τ) = (1, c τ), m(σ, 1) = (1, 1 - (1 - c) σ);
    near Q's corner (0, 0) the angle τ / (σ + τ) picks the direction out of A. t blends the
    angle's errors along Q's sides σ = 1 and τ = 1 (a transfinite correction, which the corner
    (1, 1) term keeps consistent; it is zero at c = 1/2). Orientation preserving."""
    s = 1.0 - (1.0 - sigma) * (1.0 - tau)
    total = sigma + tau
    g = np.where(total > 0.0, tau / np.where(total > 0.0, total, 1.0), 0.0)
    on_right = split * tau - tau / (1.0 + tau)  # target minus the angle on σ = 1
    on_top = 1.0 - (1.0 - split) * sigma - 1.0 / (1.0 + sigma)  # the same on τ = 1
    t = g + sigma * on_right + tau * on_top - sigma * tau * (split - 0.5)
    return s, np.clip(t, 0.0, 1.0)


def opposite_row(ctrl: np.ndarray, rational: bool, eps: float) -> np.ndarray | None:
    """The side facing a net's one collapsed side, as the homogeneous row that ``quad_from_triangle``
    splits (running from B to C); None unless exactly one side is collapsed."""
    k = collapsed_side(ctrl, eps)
    if k is None:
        return None
    return np.rot90(_homogeneous(ctrl, rational), k)[-1, :].copy()


def _homogeneous(ctrl: np.ndarray, rational: bool) -> np.ndarray:
    if rational:
        return np.asarray(ctrl, dtype=float)
    return np.concatenate([ctrl, np.ones(ctrl.shape[:2] + (1,))], axis=-1)


def _pairs(bs: np.ndarray, H: np.ndarray, bt: np.ndarray) -> np.ndarray:
    """sum_ij bs[k, i] H[i, j] bt[k, j] per k: one matrix product, then a row-wise sum."""
    rows = (bs @ H.reshape(H.shape[0], -1)).reshape(len(bs), H.shape[1], H.shape[2])
    return np.einsum("kjd,kj->kd", rows, bt)


def _boundary(P: np.ndarray, n: int, split: float = 0.5) -> np.ndarray:
    """Q's net of degree (n, n) with its boundary rows set (inner points zero), from P
    (homogeneous, collapsed at s = 0), its corner M at ``split`` on P's right side; None where the
    weights cannot be made to agree at A."""
    bottom, right, top = P[:, 0], P[-1, :], P[:, -1]
    lower, upper = curve_split(right, split)
    wb, wt = bottom[0, 3], top[0, 3]
    if wb <= 0.0 or wt <= 0.0:
        return None
    if wb != wt:
        # a Moebius change of the top's parameter: weights times lam c^k keep the curve, and keep
        # the weight at C (k = p) while the weight at A becomes the bottom's
        p = len(top) - 1
        c = (wt / wb) ** (1.0 / p)
        lam = wb / wt
        top = top * (lam * c ** np.arange(p + 1))[:, None]
    Q = np.zeros((n + 1, n + 1, 4))
    up = lambda row: elevate_curve(row, n - (len(row) - 1))  # noqa: E731
    Q[:, 0] = up(bottom)
    Q[0, :] = up(top)
    Q[-1, :] = up(lower)
    Q[:, -1] = up(upper[::-1])
    Q[0, 0] = Q[:, 0][0]  # the bottom's point and weight at A (the top's agree to rounding)
    return Q


def _coons(w: np.ndarray) -> np.ndarray:
    """The bilinearly blended Coons net of a net's boundary rows ((n+1, n+1, ...) values)."""
    n = w.shape[0] - 1
    u = np.linspace(0.0, 1.0, n + 1).reshape((-1, 1) + (1,) * (w.ndim - 2))
    v = np.linspace(0.0, 1.0, n + 1).reshape((1, -1) + (1,) * (w.ndim - 2))
    return ((1 - u) * w[:1, :] + u * w[-1:, :] + (1 - v) * w[:, :1] + v * w[:, -1:]
            - ((1 - u) * (1 - v) * w[0, 0] + u * (1 - v) * w[-1, 0]
               + (1 - u) * v * w[0, -1] + u * v * w[-1, -1]))


def quad_from_triangle(ctrl: np.ndarray, rational: bool, eps: float, budget: float,
                       max_degree: int = 25, split: float = 0.5) -> tuple[np.ndarray, bool, float] | None:
    """Q for a patch with exactly one collapsed side (within ``eps``): (ctrl, rational, deviation)
    with the net in the input's orientation (same loop direction and normal), its degree the
    lowest from max(P's degrees) up to ``_RAISE`` more (and ``max_degree``) whose sampled
    deviation from P is at most ``budget``; None for any other patch, or when no degree fits,
    the fit folds or its net blows up. Q's new corner M lies at ``split`` on the side facing the
    collapsed one (``opposite_row``'s parameter): where a neighbour's corner already stands on that
    side, M there keeps Q's two half sides the very pieces the neighbours share."""
    k = collapsed_side(ctrl, eps)
    if k is None:
        return None
    P = np.rot90(_homogeneous(ctrl, rational), k).copy()
    start = max(P.shape[0], P.shape[1]) - 1
    for n in range(max(start, 2), min(max(start, 2) + _RAISE, max_degree) + 1):
        fitted = None
        for project in (False, True):
            tried = _fit(P, n, budget, project, split)
            if tried is not None and (fitted is None or tried[1] < fitted[1]):
                fitted = tried
            if fitted is not None and fitted[1] <= budget:
                break
        if fitted is None:
            return None
        Q, dev = fitted
        if dev <= budget:
            Q = np.rot90(Q, -k).copy()
            return (Q if rational else np.ascontiguousarray(Q[..., :3] / Q[..., 3:4])), rational, dev
        if dev > _HOPELESS * budget:
            # raising the degree gains a factor of 1.5 to 2 at most over the few degrees tried
            # (a sphere's quarter at its pole fitted to P∘m, degree 11 to 15: 4.8e-3 to 2.4e-3)
            return None
    return None


#: where ``quad_from_tip`` cuts a triangle across (fractions of its s from the collapsed side): P
#: strays from its tangent plane at A by about the square of the distance from A, and a planar tip
#: is fitted exactly, so the tip's fit falls by about the square of the cut
_TIP_CUTS = (0.5, 0.25, 0.125)


def quad_from_tip(ctrl: np.ndarray, rational: bool, eps: float, budget: float,
                  max_degree: int = 25) -> tuple[tuple, np.ndarray, np.ndarray] | None:
    """For a triangle whose whole fit misses the budget (``quad_from_triangle``): P cut across at
    s = c (in the frame where its collapsed side is s = 0), the tip [0, c] made again as a
    four-sided patch and the rest [c, 1] kept exactly, at the first of ``_TIP_CUTS`` whose tip fits.
    Returns ((tip's new net, rational, deviation), the tip as it was, the rest), each net in the
    input's orientation, or None. The cut's ends stand on P's two live sides at A, which their
    neighbours share whole: the neighbours take them as T-vertices of those sides. On the corpus
    this made 32 of 68 kept triangles again (bug24595 3 of 3, marsCapsule 10, wing 9, Block 8).
    It does not help a cusp wedge, whose two live sides leave A tangent to each other (U_Joint:
    16, 7e-5 wide and 0.11 long): a four-sided patch with a zero angle at A folds onto itself, and
    its fit stays 1.7e-4 off at every cut."""
    k = collapsed_side(ctrl, eps)
    if k is None:
        return None
    P = np.rot90(_homogeneous(ctrl, rational), k)
    for c in _TIP_CUTS:
        tip, rest = curve_split(P, c)
        as_given = tip if rational else tip[..., :3] / tip[..., 3:4]
        quad = quad_from_triangle(as_given, rational, eps, budget, max_degree)
        if quad is None:
            continue

        def back(net: np.ndarray) -> np.ndarray:
            net = np.rot90(net, -k)
            return np.ascontiguousarray(net if rational else net[..., :3] / net[..., 3:4])

        return (np.ascontiguousarray(np.rot90(quad[0], -k)), rational, quad[2]), back(tip), back(rest)
    return None


def _fit(P: np.ndarray, n: int, budget: float = 0.0, project: bool = False,
         split: float = 0.5) -> tuple[np.ndarray, float] | None:
    """Q of degree (n, n) fitted to P, and its sampled two-sided deviation (that of the coarse
    check alone when it exceeds ``budget``); None when the weights or the fit fail.

    Each sample (σ, τ) of Q's square is fitted to a point of P: P(m(σ, τ)), or with ``project``
    the foot point on P of the Coons patch of Q's boundary at (σ, τ). m is not smooth at Q's
    corner A, where it fans the square's corner out over the collapsed side, so where the
    triangle's angle at A is wide, P∘m is a function no polynomial follows (a sphere's quarter
    at its pole, degree 11: 4.8e-3 off). The Coons patch is smooth there, and its foot points
    give P a smooth parameterization near A (the same quarter: 2.0e-5)."""
    Q = _boundary(P, n, split)
    if Q is None:
        return None
    w = _coons(Q[..., 3])
    if float(w[1:-1, 1:-1].min(initial=1.0)) <= 0.0:
        return None
    Q[1:-1, 1:-1, 3] = w[1:-1, 1:-1]
    plain = bool(np.all(P[..., 3] == 1.0))
    if plain:
        Q[..., 3] = 1.0  # a polynomial P: elevation and the Coons blend give weights 1 to rounding
    g = np.linspace(0.0, 1.0, _FIT_PER_DEGREE * n + 1)
    sg, tg = np.meshgrid(g, g, indexing="ij")
    sg, tg = sg.ravel(), tg.ravel()
    ms, mt = domain_map(sg, tg, split)
    blend = _coons(Q[..., :3])  # of the boundary rows (homogeneous points): a guess and a pull
    if project:
        coons = Q.copy()
        coons[1:-1, 1:-1, :3] = blend[1:-1, 1:-1]
        ms, mt, _ = _foot(P, rational_surface_eval(coons, sg, tg), ms, mt, iters=_PROJECT_ITERS)
    target = rational_surface_eval(P, ms, mt)
    if plain:
        if n >= 2:
            Q[1:-1, 1:-1, :3] = _fit_plain(basis(n, g), target.reshape(len(g), len(g), 3), Q[..., :3], blend)
        return _checked(P, Q, n, budget, split)
    bs, bt = basis(n, sg), basis(n, tg)
    B = (bs[:, :, None] * bt[:, None, :]).reshape(len(sg), -1)  # (k, (n+1)^2)
    W = B @ Q[..., 3].ravel()
    inner = np.zeros((n + 1, n + 1), bool)
    inner[1:-1, 1:-1] = True
    inner = inner.ravel()
    Qh = Q.reshape(-1, 4)
    # Euclidean residual (B h - W X) / W, linear in the inner homogeneous points h
    rhs = (W[:, None] * target - B[:, ~inner] @ Qh[~inner, :3]) / W[:, None]
    A = B[:, inner] / W[:, None]
    if A.shape[1]:
        # the high-degree inner points are nearly dependent on the samples, and a plain fit blows
        # the net up (a half disc at degree 22: control points 450 x the patch's size, which the
        # kernel's power-basis evaluation then misplaces by 0.01): pulled weakly towards the
        # Coons net of the boundary (in homogeneous points), the net stays the patch's size
        ref = blend.reshape(-1, 3)[inner]
        mu = _PULL * float(np.einsum("ij,ij->", A, A)) / A.shape[1]
        # normal equations (positive definite with the pull): a tenth of lstsq's time
        N = A.T @ A
        N[np.diag_indices_from(N)] += mu
        sol = np.linalg.solve(N, A.T @ rhs + mu * ref)
        Qh[inner, :3] = sol
    return _checked(P, Qh.reshape(n + 1, n + 1, 4), n, budget, split)


def _fit_plain(b: np.ndarray, target: np.ndarray, net: np.ndarray, blend: np.ndarray) -> np.ndarray:
    """``_fit``'s inner points for a polynomial net (weights 1) on the sample grid g x g: the same
    normal equations with the pull, solved through their tensor-product structure. With
    b = basis(n, g) and its inner columns Bi, the matrix is G (x) G + mu I for G = Bi^T Bi, so one
    eigendecomposition of G ((n - 1) x (n - 1)) diagonalizes it: O(n^3) against the dense solve's
    O(n^6) (at degree 25, forming and solving the 576 x 576 system was two thirds of a fit's time).
    ``target`` (a, a, 3), ``net`` the boundary rows (its inner points are ignored), ``blend`` the
    Coons net the pull draws towards; returns the (n - 1, n - 1, 3) inner points."""
    bd = net.copy()
    bd[1:-1, 1:-1] = 0.0
    resid = target - np.einsum("bj,ajd->abd", b, np.tensordot(b, bd, axes=(1, 0)))
    Bi = b[:, 1:-1]
    G = Bi.T @ Bi
    mu = _PULL * float(np.trace(G)) ** 2 / G.shape[0] ** 2
    lam, U = np.linalg.eigh(G)
    rhs = np.einsum("bj,ibd->ijd", Bi, np.tensordot(Bi, resid, axes=(0, 0))) + mu * blend[1:-1, 1:-1]
    C = np.einsum("bj,ibd->ijd", U, np.tensordot(U, rhs, axes=(0, 0)))  # U^T rhs U
    C /= (lam[:, None] * lam[None, :] + mu)[..., None]
    return np.einsum("jb,ibd->ijd", U, np.tensordot(U, C, axes=(1, 0)))  # U C U^T


def _checked(P: np.ndarray, Q: np.ndarray, n: int, budget: float,
             split: float) -> tuple[np.ndarray, float] | None:
    """The fitted Q and its sampled deviation from P (``_fit``), None where Q folds or blows up."""
    if not _same_turn(P, Q) or _blown_up(Q):
        return None
    # check on an offset grid: a coarse one first, whose deviation (a lower bound of the fine
    # grid's) already rejects most fits that miss the budget, then the fine one
    for per in (1, _CHECK_PER_DEGREE):
        dev = _two_sided(P, Q, per * n, split)
        if dev > budget:
            break
    return Q, dev


def _two_sided(P: np.ndarray, Q: np.ndarray, k: int, split: float = 0.5) -> float:
    """Largest distance of Q's samples to P (from their mapped parameters) and of P's samples to Q,
    on a k x k grid of cell centres plus the square's sides."""
    c = np.concatenate([[0.0], (np.arange(k) + 0.5) / k, [1.0]])
    sc, tc = np.meshgrid(c, c, indexing="ij")
    sc, tc = sc.ravel(), tc.ravel()
    ms, mt = domain_map(sc, tc, split)
    on_q, on_p = rational_surface_eval(Q, sc, tc), rational_surface_eval(P, ms, mt)
    return max(float(_foot(P, on_q, ms, mt)[2].max()), float(_foot(Q, on_p, sc, tc)[2].max()))


def _bases(k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Bernstein values of degree k and k - 1 at x (None for the lower when k = 0)."""
    return basis_and_lower(k, x) if k else (basis(0, x), None)


def _point_derivatives(H: np.ndarray, s: np.ndarray, t: np.ndarray):
    """Cartesian S, S_s, S_t of the homogeneous net H at the pairs (s[k], t[k])."""
    m, n = H.shape[0] - 1, H.shape[1] - 1
    (bs, bs1), (bt, bt1) = _bases(m, s), _bases(n, t)
    h = _pairs(bs, H, bt)
    hs = _pairs(bs1, m * np.diff(H, axis=0), bt) if m else np.zeros_like(h)
    ht = _pairs(bs, n * np.diff(H, axis=1), bt1) if n else np.zeros_like(h)
    w = h[:, 3:4]
    x = h[:, :3] / w
    return x, (hs[:, :3] - x * hs[:, 3:4]) / w, (ht[:, :3] - x * ht[:, 3:4]) / w


def _foot(H: np.ndarray, pts: np.ndarray, s: np.ndarray, t: np.ndarray, iters: int = 6):
    """Foot points of the points on the patch H, (s, t, distance): damped Gauss-Newton from the
    given start, kept in [0, 1]^2 (a foot on the patch's boundary is a local minimum there, which
    the clipped step finds). A point whose last step moved neither parameter by more than 1e-13
    is done; the others go on (most are done after two or three steps)."""
    s, t = s.astype(float), t.astype(float)
    live = np.arange(len(s))
    for _ in range(iters):
        if not len(live):
            break
        sl, tl = s[live], t[live]
        x, xs, xt = _point_derivatives(H, sl, tl)
        r = x - pts[live]
        a, b, c = (xs * xs).sum(1), (xs * xt).sum(1), (xt * xt).sum(1)
        f, g = (xs * r).sum(1), (xt * r).sum(1)
        lam = 1e-12 * (a + c) + 1e-300
        a, c = a + lam, c + lam
        det = a * c - b * b
        ok = det > 0
        det = np.where(ok, det, 1.0)
        s1 = np.clip(sl - np.where(ok, (c * f - b * g) / det, 0.0), 0.0, 1.0)
        t1 = np.clip(tl - np.where(ok, (a * g - b * f) / det, 0.0), 0.0, 1.0)
        step = np.maximum(np.abs(s1 - sl), np.abs(t1 - tl))
        s[live], t[live] = s1, t1
        live = live[step > 1e-13]
    return s, t, np.linalg.norm(rational_surface_eval(H, s, t) - pts, axis=1)


def _blown_up(Q: np.ndarray) -> bool:
    """An inner control point farther from the boundary's box centre than _BLOWN_UP x its size."""
    x = Q[..., :3] / Q[..., 3:4]
    edge = np.concatenate([x[0], x[-1], x[:, 0], x[:, -1]])
    centre, size = 0.5 * (edge.min(0) + edge.max(0)), float(np.ptp(edge, axis=0).max())
    return bool(np.linalg.norm(x - centre, axis=-1).max() > _BLOWN_UP * size)


def _normals(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Unnormalized normals (S_s x S_t) of a homogeneous net on the grid g x g."""
    s, t = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    _, xs, xt = _point_derivatives(H, s, t)
    return np.cross(xs, xt)


def _same_turn(P: np.ndarray, Q: np.ndarray) -> bool:
    """Q's normal keeps one sign against P's mean normal on an inner grid (the patches here are
    small pieces of one face), so Q neither folds nor turns the other way."""
    g = np.linspace(0.05, 0.95, 12)
    ref = _normals(P, g).sum(axis=0)
    nq = _normals(Q, g)
    return bool(np.linalg.norm(ref) > 0.0 and (nq @ ref).min() > 0.0)
