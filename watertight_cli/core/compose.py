"""Exact composition S(phi(s, t)) of a Bezier surface with a polynomial map of [0, 1]^2 (stage 1).

A cell map phi(s, t) = (u(s, t), v(s, t)) is given by two tensor-product Bernstein coefficient grids:
``U : (a+1, b+1)`` (u has bidegree (a, b) in (s, t)) and ``V : (c+1, e+1)``. For a surface S of bidegree
(m, n),

    S(phi) = sum_ij B_i^m(U) B_j^n(V) P_ij

is a Bezier patch of bidegree (m a + n c, m b + n e) (see :func:`composed_bidegree`). It is computed
exactly with Bernstein products (Farouki & Rajan 1988; DeRose, Goldman, Hagen & Mann 1993, "Functional
composition algorithms via blossoming"), never by interpolating samples:

1. B_i^k(X) for all i by the de Casteljau-type recurrence B_i^k = (1-X) B_i^{k-1} + X B_{i-1}^{k-1}, each
   product done in *scaled* Bernstein form, where a product is a plain 2-D convolution (one gather of
   the factor's Toeplitz matrix + one matmul); U and V share the calls when their shapes agree;
2. W_j = sum_i P_ij B_i^m(U) (one matmul over the control net, all d channels at once);
3. sum_j W_j * B_j^n(V): the t-direction convolutions for all j and all d channels in one matmul with
   the Toeplitz matrices of B_j^n(V), then n c + 1 shifted adds in the s-direction; then unscale.

Every step is vectorized over an optional leading batch axis (:func:`compose_batch`), so N patches cost
the same number of numpy calls as one. Measured by ``benchmarks/bench_core.py``.

Composition is linear in the control net, so homogeneous (rational) nets compose unchanged.
"""

from __future__ import annotations

import functools

import numpy as np

from .bernstein import binom_table
from .bezier import elevate_curve

__all__ = [
    "composed_bidegree",
    "compose",
    "compose_batch",
    "ruled_map",
    "paper_map",
    "identity_map",
]


def composed_bidegree(m: int, n: int, U_shape_degrees, V_shape_degrees) -> tuple[int, int]:
    """Exact bidegree of compose(S, U, V) for S of bidegree (m, n).

    U_shape_degrees : (a, b), the bidegree of U; V_shape_degrees : (c, e), the bidegree of V.
    Returns (m*a + n*c, m*b + n*e). Call this to check a degree budget before paying for composition.
    """
    a, b = (int(x) for x in U_shape_degrees)
    c, e = (int(x) for x in V_shape_degrees)
    return m * a + n * c, m * b + n * e


# ------------------------------------------------------------------------------- scaled 2-D products
#
# In scaled Bernstein form a product is a full 2-D convolution. A convolution here is a gather (np.take
# with a cached index into a zero-padded copy of one factor, giving its Toeplitz matrix) and a matmul.
# np.take is used rather than fancy indexing, which is several times slower for these sizes.


@functools.lru_cache(maxsize=512)
def _toeplitz2_index(pb: int, qb: int, pa: int, qa: int) -> np.ndarray:
    """Gather index for the 2-D convolution of a (pa, qa) grid A with a (pb, qb) grid B.

    Returns (pa*qa, K*L) int, K = pa+pb-1, L = qa+qb-1: entry [(k,l), (K,L)] is the flat index of
    B[K-k, L-l] in B.reshape(pb*qb), or pb*qb (a zero pad slot) when out of range, so that
    vec(conv(A, B)) = vec(A) @ B_padded[index].
    """
    k, l, kk, ll = np.meshgrid(
        np.arange(pa), np.arange(qa), np.arange(pa + pb - 1), np.arange(qa + qb - 1), indexing="ij"
    )
    bi, bj = kk - k, ll - l
    idx = np.where((bi >= 0) & (bi < pb) & (bj >= 0) & (bj < qb), bi * qb + bj, pb * qb)
    idx = idx.reshape(pa * qa, (pa + pb - 1) * (qa + qb - 1))
    idx.flags.writeable = False
    return idx


@functools.lru_cache(maxsize=512)
def _toeplitz_t_index(qb: int, qa: int) -> np.ndarray:
    """(qa, qa+qb-1) int: idx[l, L] = L - l if 0 <= L - l < qb else qb (the zero pad slot)."""
    j = np.arange(qa + qb - 1)[None, :] - np.arange(qa)[:, None]
    idx = np.where((j >= 0) & (j < qb), j, qb)
    idx.flags.writeable = False
    return idx


@functools.lru_cache(maxsize=512)
def _scale_grid(p: int, q: int) -> np.ndarray:
    """(p+1, q+1) float: C(p, i) C(q, j), the scaled-Bernstein factors of bidegree (p, q)."""
    g = binom_table(p)[p][:, None] * binom_table(q)[q][None, :]
    g.flags.writeable = False
    return g


def _tail_transpose(x: np.ndarray, perm: tuple[int, ...]) -> np.ndarray:
    """Permute the last len(perm) axes of x by perm (a view), leaving the leading axes alone."""
    k = x.ndim - len(perm)
    return x.transpose(tuple(range(k)) + tuple(k + p for p in perm))


def _flat_padded(x: np.ndarray, nlast: int) -> np.ndarray:
    """Flatten the last ``nlast`` axes and append one zero slot."""
    lead = x.shape[: x.ndim - nlast]
    flat = x.reshape(lead + (-1,))
    return np.concatenate([flat, np.zeros(lead + (1,))], axis=-1)


def _bernstein_of(x: np.ndarray, degrees: tuple[int, ...], w: np.ndarray | None = None) -> list[np.ndarray]:
    """Scaled Bernstein coefficients of B_i^k(X_r(s, t)), i = 0..k, for stacked maps X_r.

    x : (R, ..., a+1, b+1) float, the Bernstein coefficients of R maps of the same bidegree (a, b);
    degrees : (R,) ints k_r. Returns a list over r of (..., k_r+1, k_r a+1, k_r b+1) float arrays in
    scaled form (entry [i, k, l] multiplied by C(k_r a, k) C(k_r b, l)).

    Recurrence B_i^k = (1 - X) B_i^{k-1} + X B_{i-1}^{k-1} (Farin ch. 5); each step is one gather of the
    2-D Toeplitz matrices of (1 - X)^ and X^ and one matmul, and the R maps share every numpy call.

    w : optional (..., a+1, b+1) weight grid of a rational map X / w; then (w - X) replaces (1 - X) and
    the results are the homogeneous forms w^k B_i^k(X / w).
    """
    a1, b1 = x.shape[-2:]
    lead = x.shape[:-2]
    kmax = max(degrees)
    sc = _scale_grid(a1 - 1, b1 - 1)
    results: list[np.ndarray] = [np.ones(lead[1:] + (1, 1, 1))] * len(degrees)
    if kmax == 0:
        return results
    # factors (R, ..., 2, a+1, b+1): [(1 - X)^, X^]
    one = 1.0 if w is None else w
    factors = np.concatenate([((one - x) * sc)[..., None, :, :], (x * sc)[..., None, :, :]], axis=-3)
    fpad = _flat_padded(factors, 2)  # (R, ..., 2, (a+1)(b+1)+1)
    s = factors  # step 1: B_0^1 = 1 - X, B_1^1 = X;  s : (R, ..., k, P, Q) (k = degree + 1 rows)
    for r, k in enumerate(degrees):
        if k == 1:
            results[r] = s[r]
    for k in range(2, kmax + 1):
        p_, q_ = s.shape[-2:]
        kk, ll = p_ + a1 - 1, q_ + b1 - 1
        t = np.take(fpad, _toeplitz2_index(a1, b1, p_, q_), axis=-1)  # (R, ..., 2, P*Q, K*L)
        prod = s.reshape(s.shape[:-2] + (1, 1, p_ * q_)) @ t[..., None, :, :, :]
        # prod : (R, ..., k, 2, 1, K*L) -> new[i] = prod[i, 0] + prod[i-1, 1]
        prod = prod.reshape(prod.shape[:-4] + (k, 2, kk, ll))
        new = np.zeros(prod.shape[:-4] + (k + 1, kk, ll))
        new[..., :k, :, :] = prod[..., 0, :, :]
        new[..., 1:, :, :] += prod[..., 1, :, :]
        s = new
        for r, kd in enumerate(degrees):
            if kd == k:
                results[r] = s[r]
    return results


def _compose(ctrl: np.ndarray, U: np.ndarray, V: np.ndarray, W: np.ndarray | None = None) -> np.ndarray:
    """Batched core. ctrl (..., m+1, n+1, d); U (..., a+1, b+1); V (..., c+1, e+1) -> (..., ds+1, dt+1, d).

    Leading axes of ctrl, U, V broadcast. W (same shape as U and V) makes the map rational (U/W, V/W).
    """
    m, n, d = ctrl.shape[-3] - 1, ctrl.shape[-2] - 1, ctrl.shape[-1]
    if W is not None:
        bu, bv = _bernstein_of(np.concatenate([U[None], V[None]]), (m, n), W[None])
    elif U.shape == V.shape:
        bu, bv = _bernstein_of(np.concatenate([U[None], V[None]]), (m, n))
    else:
        (bu,) = _bernstein_of(U[None], (m,))
        (bv,) = _bernstein_of(V[None], (n,))
    x1, x2 = bu.shape[-2:]  # (m a + 1, m b + 1)
    y1, y2 = bv.shape[-2:]  # (n c + 1, n e + 1)
    ds, dt = x1 + y1 - 2, x2 + y2 - 2
    lead = (ctrl.shape[:-3], U.shape[:-2], V.shape[:-2])
    batch = np.broadcast_shapes(*lead) if any(lead) else ()
    # W[..., k, (c, j), l] = sum_i BU_i[k, l] P_ij[c]
    w = _tail_transpose(ctrl.reshape(ctrl.shape[:-3] + (m + 1, (n + 1) * d)), (1, 0)) @ bu.reshape(
        bu.shape[:-2] + (x1 * x2,)
    )  # (..., (n+1) d, x1 x2)
    w = w.reshape(w.shape[:-2] + (n + 1, d, x1, x2))
    w = _tail_transpose(w, (2, 1, 0, 3)).reshape(w.shape[:-4] + (x1 * d, (n + 1) * x2))  # (.., (k,c), (j,l))
    # Toeplitz of BV_j along t: tv[..., (j, l), (k', L)] = BV_j[k', L - l]
    tv = np.take(_flat_padded(bv, 1), _toeplitz_t_index(y2, x2), axis=-1)  # (..., n+1, y1, x2, L)
    tv = _tail_transpose(tv, (0, 2, 1, 3)).reshape(tv.shape[:-4] + ((n + 1) * x2, y1 * (dt + 1)))
    r = w @ tv  # (..., x1*d, y1*L): the t-direction convolutions, summed over j
    r = r.reshape(r.shape[:-2] + (x1, d, y1, dt + 1))
    # s-direction: out[K] = sum_k' r[K - k', k'] (short loop of shifted adds)
    out = np.zeros(batch + (ds + 1, d, dt + 1))
    for kp in range(y1):
        out[..., kp : kp + x1, :, :] += r[..., :, :, kp, :]
    out /= _scale_grid(ds, dt)[:, None, :]
    return np.ascontiguousarray(_tail_transpose(out, (0, 2, 1)))


def _check_budget(ds: int, dt: int, max_degree: int | None) -> None:
    if max_degree is not None and max(ds, dt) > max_degree:
        raise ValueError(f"composed bidegree ({ds}, {dt}) exceeds the degree budget {max_degree}")


def compose(ctrl, U, V, max_degree: int | None = None, W=None) -> np.ndarray:
    """Exact composition S o phi of a Bezier surface with a polynomial map phi = (U, V).

    With W (same shape as U and V) the map is rational, phi = (U/W, V/W); ctrl must then be homogeneous
    (its last channel the weight, 1 for a polynomial surface) and the result is a homogeneous net: the
    common factor W^(m+n) stays in every channel, which leaves the rational patch unchanged.

    Parameters
    ----------
    ctrl : (m+1, n+1, d) float, polynomial or homogeneous rational control net on [0, 1]^2
        (extra trailing axes are flattened into channels and restored).
    U : (a+1, b+1) float, Bernstein coefficients of u(s, t).
    V : (c+1, e+1) float, Bernstein coefficients of v(s, t).
    max_degree : optional; raise ValueError (before any work) if the output bidegree exceeds it.

    Returns
    -------
    (ds+1, dt+1, d) float with (ds, dt) = composed_bidegree(m, n, (a, b), (c, e)).
    """
    ctrl = np.asarray(ctrl, dtype=float)
    U = np.asarray(U, dtype=float)
    V = np.asarray(V, dtype=float)
    if W is not None:
        W = np.asarray(W, dtype=float)
        if not (W.shape == U.shape == V.shape):
            raise ValueError(
                f"compose: a rational map needs U, V, W of one shape; got {U.shape}, {V.shape}, {W.shape}")
    if ctrl.ndim < 2 or U.ndim != 2 or V.ndim != 2:
        raise ValueError(
            f"compose: need ctrl (m+1, n+1, d), U (a+1, b+1), V (c+1, e+1); got {ctrl.shape}, {U.shape}, "
            f"{V.shape}"
        )
    m, n = ctrl.shape[0] - 1, ctrl.shape[1] - 1
    ds, dt = composed_bidegree(m, n, (U.shape[0] - 1, U.shape[1] - 1), (V.shape[0] - 1, V.shape[1] - 1))
    _check_budget(ds, dt, max_degree)
    tail = ctrl.shape[2:]
    flat = ctrl.reshape(m + 1, n + 1, -1)
    return _compose(flat, U, V, W).reshape((ds + 1, dt + 1) + tail)


def compose_batch(ctrls, Us, Vs, max_degree: int | None = None) -> np.ndarray:
    """Compose N patches of the same degrees at once (one vectorized pass, no per-patch Python loop).

    ctrls : (N, m+1, n+1, d) float; Us : (N, a+1, b+1) or (a+1, b+1) (shared); Vs : (N, c+1, e+1) or
    (c+1, e+1). Returns (N, ds+1, dt+1, d) float.
    """
    ctrls = np.asarray(ctrls, dtype=float)
    Us = np.asarray(Us, dtype=float)
    Vs = np.asarray(Vs, dtype=float)
    if ctrls.ndim != 4 or Us.ndim not in (2, 3) or Vs.ndim not in (2, 3):
        raise ValueError(
            f"compose_batch: need ctrls (N, m+1, n+1, d), Us (N, a+1, b+1), Vs (N, c+1, e+1); got "
            f"{ctrls.shape}, {Us.shape}, {Vs.shape}"
        )
    nb = ctrls.shape[0]
    for name, arr in (("Us", Us), ("Vs", Vs)):
        if arr.ndim == 3 and arr.shape[0] != nb:
            raise ValueError(f"compose_batch: {name} has {arr.shape[0]} maps for {nb} patches")
    m, n = ctrls.shape[1] - 1, ctrls.shape[2] - 1
    ds, dt = composed_bidegree(
        m, n, (Us.shape[-2] - 1, Us.shape[-1] - 1), (Vs.shape[-2] - 1, Vs.shape[-1] - 1)
    )
    _check_budget(ds, dt, max_degree)
    return _compose(ctrls, Us, Vs)


# --------------------------------------------------------------------------------------------- maps


def ruled_map(O, T) -> tuple[np.ndarray, np.ndarray]:
    """Ruled cell map phi(s, t) = (1 - s) O(t) + s T(t).

    O, T : (k+1, 2) and (l+1, 2) float, planar Bezier curves in the surface's [0, 1]^2 parameter domain
    (O is the side at s = 0, T the side at s = 1); elevated to a common degree p = max(k, l) here.
    Returns (U, V), each (2, p+1) float, bidegree (1, p).
    """
    O = np.asarray(O, dtype=float)
    T = np.asarray(T, dtype=float)
    if O.ndim != 2 or T.ndim != 2 or O.shape[1] != 2 or T.shape[1] != 2:
        raise ValueError(f"ruled_map: O and T must be (k+1, 2) planar curves, got {O.shape} and {T.shape}")
    p = max(O.shape[0], T.shape[0]) - 1
    O = elevate_curve(O, p - (O.shape[0] - 1))
    T = elevate_curve(T, p - (T.shape[0] - 1))
    U = np.stack([O[:, 0], T[:, 0]])
    V = np.stack([O[:, 1], T[:, 1]])
    return U, V


def paper_map(
    f,
    u0: float = 0.0,
    t_range: tuple[float, float] = (0.0, 1.0),
    swap_uv: bool = False,
    swap_st: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's curved-trapezoid map (Li et al., stage 1), generalized.

    Default: u = u0 + s (f(t) - u0), v = v0 + t (v1 - v0) with (v0, v1) = t_range; u0 = 0 and t_range =
    (0, 1) give the paper's u = s f(t), v = t. The iso side is u = u0 (s = 0), the trimming side is the
    graph u = f (s = 1).

    f : (p+1,) float, Bernstein coefficients of f(t) on [0, 1].
    swap_uv : roles of u and v swapped: v = u0 + s (f(t) - u0), u = v0 + t (v1 - v0).
    swap_st : roles of s and t swapped (U and V grids transposed).

    Returns (U, V): U (2, p+1) and V (1, 2) by default, i.e. bidegrees (1, p) and (0, 1), so a surface of
    bidegree (m, n) composes to (m, m p + n).
    """
    f = np.asarray(f, dtype=float)
    if f.ndim != 1:
        raise ValueError(f"paper_map: f must be (p+1,) Bernstein coefficients, got shape {f.shape}")
    graph = np.stack([np.full_like(f, float(u0)), f])  # (2, p+1)
    iso = np.array([[float(t_range[0]), float(t_range[1])]])  # (1, 2)
    U, V = (iso, graph) if swap_uv else (graph, iso)
    if swap_st:
        U, V = U.T.copy(), V.T.copy()
    return U, V


def identity_map() -> tuple[np.ndarray, np.ndarray]:
    """phi(s, t) = (s, t): U = [[0], [1]] (bidegree (1, 0)), V = [[0, 1]] (bidegree (0, 1))."""
    return np.array([[0.0], [1.0]]), np.array([[0.0, 1.0]])
