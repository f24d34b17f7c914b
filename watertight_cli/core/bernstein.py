"""Bernstein polynomials on [0, 1]: binomials, basis values, exact products, power-basis conversion.

Conventions
-----------
A univariate Bernstein polynomial of degree ``n`` is an array ``c`` of shape ``(n+1, ...)``; axis 0
indexes the coefficient and any trailing axes are independent channels (x, y, z, w, ...).
A bivariate (tensor-product) one of bidegree ``(p, q)`` has shape ``(p+1, q+1, ...)``.

Products use the *scaled* Bernstein form ``c_hat[k] = C(n, k) c[k]``: in that form the product of two
polynomials is the plain (direct, not FFT) convolution of their coefficient arrays (Farin, "Curves and
Surfaces for CAGD", ch. 5; Farouki & Rajan 1988, "Algorithms for polynomials in Bernstein form").
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = [
    "binom_table",
    "binom",
    "basis",
    "basis_and_lower",
    "product",
    "product2",
    "to_power",
    "from_power",
]


@functools.cache
def binom_table(n: int) -> np.ndarray:
    """Binomial coefficients C(i, k) for 0 <= i, k <= n, by Pascal's triangle.

    Returns
    -------
    (n+1, n+1) float, read-only; entry [i, k] = C(i, k) (0 where k > i). Cached per ``n``.
    Exact in float64 for n <= 56 (all entries below 2**53).
    """
    n = int(n)
    if n < 0:
        raise ValueError(f"binom_table: n must be >= 0, got {n}")
    table = np.zeros((n + 1, n + 1))
    table[:, 0] = 1.0
    for i in range(1, n + 1):
        table[i, 1 : i + 1] = table[i - 1, 0:i] + table[i - 1, 1 : i + 1]
    table.flags.writeable = False
    return table


def binom(n: int, k: int) -> float:
    """C(n, k) as a float; 0 when k < 0 or k > n."""
    if k < 0 or k > n or n < 0:
        return 0.0
    return float(binom_table(n)[n, k])


def _binom_row(n: int) -> np.ndarray:
    """(n+1,) float: C(n, 0..n)."""
    return binom_table(n)[n]


@functools.cache
def _exponents(n: int) -> np.ndarray:
    """(n+1,) float: 0, 1, ..., n (read-only, cached per ``n``)."""
    e = np.arange(n + 1.0)
    e.flags.writeable = False
    return e


def basis(n: int, t) -> np.ndarray:
    """Bernstein basis values B_{k,n}(t) = C(n, k) t^k (1 - t)^(n - k).

    Computed as the binomial row times the powers of t and of 1 - t (``np.power``, correctly
    rounded to an ulp each): three roundings per value, whatever the degree, so within 8e-17 of the
    exact values at degree 25 (the running products that this replaced, ``np.cumprod``, were within
    3e-16 and took 2.5 times as long for a few parameters, the common call here: 612k calls in
    stage 1 of gmsh__Block.stp).

    Parameters
    ----------
    n : int, degree >= 0
    t : (k,) float (a scalar is treated as (1,))

    Returns
    -------
    (k, n+1) float
    """
    t = _parameters("basis", n, t, 0)
    e = _exponents(n)
    return _binom_row(n) * np.power(t[:, None], e) * np.power((1.0 - t)[:, None], e[::-1])


def _parameters(name: str, n: int, t, lowest: int) -> np.ndarray:
    """t as a 1-D float array, after checking it and the degree n (at least ``lowest``)."""
    if n < lowest:
        raise ValueError(f"{name}: degree must be >= {lowest}, got {n}")
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if t.ndim != 1:
        raise ValueError(f"{name}: t must be 1-D, got shape {t.shape}")
    return t


def basis_and_lower(n: int, t) -> tuple[np.ndarray, np.ndarray]:
    """``(basis(n, t), basis(n - 1, t))`` with the powers of t computed once, for derivatives,
    where the powers are most of the cost on large grids. The same values to the bit: the powers
    of 1 - t are taken with the reversed exponents as ``basis`` does (numpy's power loop for a
    reversed, strided view of a table rounds differently in the last bit for short inputs).
    n >= 1."""
    t = _parameters("basis_and_lower", n, t, 1)
    e, s = _exponents(n), (1.0 - t)[:, None]
    pt = np.power(t[:, None], e)
    return (_binom_row(n) * pt * np.power(s, e[::-1]),
            _binom_row(n - 1) * pt[:, :-1] * np.power(s, _exponents(n - 1)[::-1]))


def scalar_fn(c):
    """f(t) = sum_k c_k B_{k,n}(t) as a plain Python function of one float (for root finders).

    Horner's rule in t/(1-t) for t <= 1/2 and in (1-t)/t above, each ratio at most 1 (the
    Bernstein form of Horner's rule, Schumaker and Volk 1986): O(n) float operations and no array
    allocation, some 20 times faster per call than ``basis`` on one parameter.
    """
    a = [float(x) for x in np.asarray(c, dtype=float).ravel()]
    n = len(a) - 1
    fwd = [a[k] * float(binom_table(n)[n, k]) for k in range(n + 1)]
    bwd = fwd[::-1]

    def f(t: float) -> float:
        t = float(t)
        s = 1.0 - t
        if t <= 0.5:
            q, coef, base = t / s if s else 0.0, fwd, s
        else:
            q, coef, base = s / t, bwd, t
        acc = coef[n]
        for k in range(n - 1, -1, -1):
            acc = acc * q + coef[k]
        return acc * base**n

    return f


def _scale(c: np.ndarray, axis: int, inverse: bool = False) -> np.ndarray:
    """Multiply (or divide) coefficients along ``axis`` by C(n, k), n = size-1."""
    n = c.shape[axis] - 1
    row = _binom_row(n)
    shape = [1] * c.ndim
    shape[axis] = n + 1
    row = row.reshape(shape)
    return c / row if inverse else c * row


def product(a, b, axis: int = 0) -> np.ndarray:
    """Exact product of two univariate Bernstein polynomials.

    c_k = sum_{i+j=k} C(p,i) C(q,j) / C(p+q,k) a_i b_j (Farin ch. 5; Farouki & Rajan 1988), computed as a
    direct convolution of the scaled coefficients.

    Parameters
    ----------
    a : (p+1, ...) float, degree p along ``axis``
    b : (q+1, ...) float, degree q along ``axis``; the other axes broadcast against a's
        (e.g. a (p+1, d) and b (q+1,) or (q+1, d)). Trailing-axis broadcasting follows numpy rules
        after moving ``axis`` to the front.
    axis : int, the coefficient axis of both arrays.

    Returns
    -------
    (p+q+1, ...) float, with the coefficient axis at ``axis``.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if axis != 0:  # (np.moveaxis costs more than the product of two short curves)
        a, b = np.moveaxis(a, axis, 0), np.moveaxis(b, axis, 0)
    p, q = a.shape[0] - 1, b.shape[0] - 1
    # b of shape (q+1,) against a of shape (p+1, d): broadcast channels as trailing axes.
    if b.ndim < a.ndim:
        b = b.reshape(b.shape + (1,) * (a.ndim - b.ndim))
    elif a.ndim < b.ndim:
        a = a.reshape(a.shape + (1,) * (b.ndim - a.ndim))
    ah, bh = _scale(a, 0), _scale(b, 0)
    if p > q:  # loop over the shorter factor
        ah, bh, p, q = bh, ah, q, p
    tail = np.broadcast_shapes(ah.shape[1:], bh.shape[1:])
    out = np.zeros((p + q + 1,) + tail)
    for i in range(p + 1):
        out[i : i + q + 1] += ah[i] * bh
    out = _scale(out, 0, inverse=True)
    return out if axis == 0 else np.moveaxis(out, 0, axis)


def product2(a, b) -> np.ndarray:
    """Exact product of two tensor-product Bernstein polynomials on [0, 1]^2.

    The bivariate analogue of :func:`product`: scale both coefficient grids by C(p,i) C(q,j), convolve
    directly in both axes, unscale by C(p+r, k) C(q+s, l).

    Parameters
    ----------
    a : (p+1, q+1, ...) float
    b : (r+1, s+1, ...) float; trailing axes broadcast against a's (missing ones are appended).

    Returns
    -------
    (p+r+1, q+s+1, ...) float
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim < 2 or b.ndim < 2:
        raise ValueError(f"product2: need arrays with >= 2 axes, got shapes {a.shape} and {b.shape}")
    if b.ndim < a.ndim:
        b = b.reshape(b.shape + (1,) * (a.ndim - b.ndim))
    elif a.ndim < b.ndim:
        a = a.reshape(a.shape + (1,) * (b.ndim - a.ndim))
    ah = _scale(_scale(a, 0), 1)
    bh = _scale(_scale(b, 0), 1)
    if ah.shape[0] * ah.shape[1] > bh.shape[0] * bh.shape[1]:
        ah, bh = bh, ah  # loop over the entries of the smaller factor
    p, q = ah.shape[0] - 1, ah.shape[1] - 1
    r, s = bh.shape[0] - 1, bh.shape[1] - 1
    tail = np.broadcast_shapes(ah.shape[2:], bh.shape[2:])
    out = np.zeros((p + r + 1, q + s + 1) + tail)
    for i in range(p + 1):
        for j in range(q + 1):
            out[i : i + r + 1, j : j + s + 1] += ah[i, j] * bh
    return _scale(_scale(out, 0, inverse=True), 1, inverse=True)


@functools.cache
def _to_power_matrix(n: int) -> np.ndarray:
    """(n+1, n+1) M with a = M c: M[k, i] = C(n, k) C(k, i) (-1)^(k-i) for i <= k."""
    tb = binom_table(n)
    k = np.arange(n + 1)
    sign = np.where((k[:, None] - k[None, :]) % 2 == 0, 1.0, -1.0)
    m = tb[n][:, None] * tb * sign
    m = np.tril(m)
    m.flags.writeable = False
    return m


@functools.cache
def _from_power_matrix(n: int) -> np.ndarray:
    """(n+1, n+1) M with c = M a: M[i, k] = C(i, k) / C(n, k) for k <= i."""
    tb = binom_table(n)
    m = np.tril(tb / tb[n][None, :])
    m.flags.writeable = False
    return m


def to_power(c) -> np.ndarray:
    """Bernstein -> power (monomial) coefficients: sum_i c_i B_{i,n}(t) = sum_k a_k t^k.

    c : (n+1, ...) float. Returns a : (n+1, ...) float. Ill-conditioned for high degree; for tests.
    """
    c = np.asarray(c, dtype=float)
    return np.tensordot(_to_power_matrix(c.shape[0] - 1), c, axes=(1, 0))


def from_power(a) -> np.ndarray:
    """Power (monomial) -> Bernstein coefficients on [0, 1]: c_i = sum_{k<=i} C(i,k)/C(n,k) a_k.

    a : (n+1, ...) float. Returns c : (n+1, ...) float.
    """
    a = np.asarray(a, dtype=float)
    return np.tensordot(_from_power_matrix(a.shape[0] - 1), a, axes=(1, 0))
