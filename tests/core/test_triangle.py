"""Patches with one collapsed side made again with four live sides (``core.triangle``)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.core.bezier import (
    curve_split,
    elevate_surface,
    rational_surface_eval_grid,
    surface_eval_grid,
)
from watertight_cli.core.triangle import collapsed_side, domain_map, quad_from_triangle

EPS = 1e-12


def _triangle(p: int, q: int, bump: float, angle: float) -> np.ndarray:
    """A polynomial net of degree (p, q) whose side s = 0 is one point (the origin): the ruled
    map (s, t) -> s * (direction at angle t * angle) composed with z = bump * (x^2 - y)."""
    s = np.linspace(0.0, 1.0, p + 1)[:, None]
    t = np.linspace(0.0, 1.0, q + 1)[None, :]
    x = s * (1.0 + 0.0 * t)
    y = s * t * np.tan(angle)
    z = bump * (x * x - y) * (s > 0)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def test_a_flat_triangle_is_made_exactly_with_the_same_sides():
    P = _triangle(3, 1, 0.0, 0.7)
    assert collapsed_side(P, EPS) == 0
    Q, rational, dev = quad_from_triangle(P, False, EPS, 1e-6)
    assert not rational and Q.shape == (4, 4, 3)
    assert dev < 1e-12
    # the bottom and the top are P's own curves, the right side is split in two at M
    assert np.allclose(Q[:, 0], P[:, 0], atol=1e-14)
    assert np.allclose(Q[0, :], P[:, -1], atol=1e-14)
    lower, upper = curve_split(P[-1, :], 0.5)
    g = np.linspace(0.0, 1.0, 9)
    q_pts = surface_eval_grid(Q, [1.0], g)[0]
    assert np.allclose(q_pts, surface_eval_grid(lower[None], [0.0], g)[0], atol=1e-13)
    # no side is collapsed any more
    assert collapsed_side(Q, 1e-9) is None
    for side in (Q[:, 0], Q[-1, :], Q[:, -1], Q[0, :]):
        assert np.linalg.norm(side - side[0], axis=-1).max() > 1e-3


def test_the_new_patch_turns_the_same_way():
    P = _triangle(4, 2, 0.3, 0.9)
    Q, _, dev = quad_from_triangle(P, False, EPS, 1e-3)
    g = np.linspace(0.1, 0.9, 5)

    def normal(net):
        ds = surface_eval_grid(np.diff(net, axis=0), g, g)
        dt = surface_eval_grid(np.diff(net, axis=1), g, g)
        return np.cross(ds, dt).reshape(-1, 3)

    assert (normal(Q) @ normal(P).sum(axis=0)).min() > 0.0
    assert dev <= 1e-3


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 3), st.integers(1, 4), st.integers(1, 3), st.floats(0.0, 0.5), st.floats(0.3, 1.2))
def test_any_turn_of_the_net_gives_the_same_surface(k, p, q, bump, angle):
    """The collapsed side may be any of the four; the new patch covers the same surface within
    the deviation it reports, and its boundary keeps the triangle's three corners."""
    P = np.rot90(_triangle(p, q, bump, angle), -k).copy()
    assert collapsed_side(P, EPS) == k
    out = quad_from_triangle(P, False, EPS, 1e-2)
    assert out is not None
    Q, _, dev = out
    g = np.linspace(0.0, 1.0, 21)
    on_p = surface_eval_grid(P, g, g).reshape(-1, 3)
    on_q = surface_eval_grid(Q, g, g).reshape(-1, 3)
    d = np.linalg.norm(on_q[:, None] - on_p[None], axis=2)
    # grid-to-grid distances exceed the true ones by at most the grid spacing on the patches
    spacing = max(np.linalg.norm(np.diff(surface_eval_grid(n, g, g), axis=a), axis=-1).max()
                  for n in (P, Q) for a in (0, 1))
    assert d.min(axis=1).max() <= dev + spacing
    assert d.min(axis=0).max() <= dev + spacing
    corners = {tuple(np.round(c, 9)) for c in P[[0, 0, -1, -1], [0, -1, 0, -1]]}
    assert corners <= {tuple(np.round(c, 9)) for c in Q[[0, 0, -1, -1], [0, -1, 0, -1]]}


def test_a_rational_triangle_keeps_its_curves_with_the_weights_agreed_at_the_collapsed_corner():
    P = _triangle(3, 2, 0.2, 0.8)
    H = np.concatenate([P, np.ones(P.shape[:2] + (1,))], axis=-1)
    w = 1.0 + 0.3 * np.linspace(0, 1, 3)[None, :] + 0.2 * np.linspace(0, 1, 4)[:, None]
    H = H * w[..., None]
    Q, rational, dev = quad_from_triangle(H, True, EPS, 1e-3)
    assert rational and dev <= 1e-3
    # the top (t = 1 of P, from the collapsed corner) is the same point set after the Moebius
    # change: every sample of it lies on Q's left side
    g = np.linspace(0.0, 1.0, 41)
    top = rational_surface_eval_grid(H, g, [1.0])[:, 0]
    left = rational_surface_eval_grid(Q, [0.0], np.linspace(0.0, 1.0, 2001))[0]
    assert np.linalg.norm(top[:, None] - left[None], axis=2).min(axis=1).max() < 1e-3
    assert Q[0, 0, 3] == H[0, 0, 3]


def _sphere_octant() -> np.ndarray:
    """The exact rational net (homogeneous, degree (2, 2)) of a unit sphere's octant: a quarter
    meridian from the pole (its side s = 0 is the pole) turned through a quarter circle."""
    h = np.sqrt(0.5)
    meridian = [(0.0, 1.0, 1.0), (1.0, 1.0, h), (1.0, 0.0, 1.0)]  # (radius, z, weight)
    circle = [(1.0, 0.0, 1.0), (1.0, 1.0, h), (0.0, 1.0, 1.0)]  # (x, y, weight)
    H = np.zeros((3, 3, 4))
    for i, (r, z, a) in enumerate(meridian):
        for j, (x, y, b) in enumerate(circle):
            H[i, j] = [r * x * a * b, r * y * a * b, z * a * b, a * b]
    return H


def test_a_sphere_octant_at_its_pole_is_made_again_on_the_sphere():
    # the pole's corner is 90 degrees wide: a fit to P composed with the domain map stays 3e-4
    # off at any degree up to 11; the fit to the projected Coons patch reaches 7.9e-6 at degree 7
    H = elevate_surface(_sphere_octant(), 5, 5)
    assert collapsed_side(H, EPS) == 0
    Q, rational, dev = quad_from_triangle(H, True, EPS, 1e-5)
    assert rational and dev <= 1e-5 and Q.shape == (8, 8, 4)
    assert collapsed_side(Q, 1e-6) is None
    g = np.linspace(0.0, 1.0, 37)
    radius = np.linalg.norm(rational_surface_eval_grid(Q, g, g), axis=-1)
    assert np.abs(radius - 1.0).max() <= 1e-5
    # Q's corner at the pole is a true corner: its two sides leave the pole at a right angle
    x = Q[..., :3] / Q[..., 3:4]
    a, b = x[1, 0] - x[0, 0], x[0, 1] - x[0, 0]
    assert abs(a @ b) <= 1e-9 * np.linalg.norm(a) * np.linalg.norm(b)


def test_a_patch_with_no_or_two_collapsed_sides_is_left_alone():
    grid = np.meshgrid(np.linspace(0, 1, 3), np.linspace(0, 2, 3), indexing="ij")
    box = np.stack(list(grid) + [np.zeros((3, 3))], -1)
    assert quad_from_triangle(box, False, EPS, 1.0) is None
    lens = _triangle(3, 2, 0.0, 0.5)
    lens[-1] = lens[-1, :1]
    assert quad_from_triangle(lens, False, EPS, 1.0) is None


def test_the_domain_map_sends_the_sides_where_they_belong():
    g = np.linspace(0.0, 1.0, 11)
    z, o = np.zeros_like(g), np.ones_like(g)
    assert np.allclose(np.stack(domain_map(g, z)), np.stack([g, z]))
    assert np.allclose(np.stack(domain_map(o, g)), np.stack([o, g / 2]))
    assert np.allclose(np.stack(domain_map(g, o)), np.stack([o, 1 - g / 2]))
    assert np.allclose(np.stack(domain_map(z[1:], g[1:])), np.stack([g[1:], o[1:]]))


@given(st.floats(0.2, 0.8))
def test_the_domain_map_sends_the_sides_where_they_belong_at_any_split(c):
    g = np.linspace(0.0, 1.0, 11)
    z, o = np.zeros_like(g), np.ones_like(g)
    assert np.allclose(np.stack(domain_map(g, z, c)), np.stack([g, z]))
    assert np.allclose(np.stack(domain_map(o, g, c)), np.stack([o, c * g]))
    assert np.allclose(np.stack(domain_map(g, o, c)), np.stack([o, 1 - (1 - c) * g]))
    assert np.allclose(np.stack(domain_map(z[1:], g[1:], c)), np.stack([g[1:], o[1:]]))


def test_the_new_corner_can_stand_where_a_neighbour_splits_the_side():
    """Block: two neighbours met on a triangle's side at 0.50000001 of it; Q's corner at the side's
    parametric middle left Q's halves 4.3e-9 off their sides, beyond I2's 1e-12 x diagonal."""
    from watertight_cli.core.triangle import opposite_row

    P = _triangle(4, 2, 0.3, 0.9)
    row = opposite_row(P, False, EPS)
    assert np.allclose(row[:, :3], P[-1, :]) and np.all(row[:, 3] == 1.0)
    Q, _, dev = quad_from_triangle(P, False, EPS, 1e-3, split=0.37)
    assert dev <= 1e-3
    lower, upper = curve_split(P[-1, :], 0.37)
    g = np.linspace(0.0, 1.0, 9)
    right, top = surface_eval_grid(Q, [1.0], g)[0], surface_eval_grid(Q, g, [1.0])[:, 0]
    assert np.allclose(right, surface_eval_grid(lower[None], [0.0], g)[0], atol=1e-13)
    assert np.allclose(top, surface_eval_grid(upper[::-1][None], [0.0], g)[0], atol=1e-13)


def test_a_triangle_that_misses_as_a_whole_is_made_again_at_its_tip():
    """A curved triangle whose whole fit misses a tight budget: its tip is cut off and fitted
    alone, the rest kept exactly; the two cover the triangle (same corners and cut row)."""
    from watertight_cli.core.bezier import curve_split
    from watertight_cli.core.triangle import quad_from_tip

    P = _triangle(4, 3, 0.8, 1.0)
    whole = quad_from_triangle(P, False, EPS, 1e-9)
    assert whole is None  # the budget is too tight for the whole triangle
    budget = 1e-3
    full = quad_from_triangle(P, False, EPS, 1e9)
    cut = quad_from_tip(P, False, EPS, budget)
    assert cut is not None
    (Q, rational, dev), tip, rest = cut
    assert not rational and dev <= budget and dev < full[2]
    assert collapsed_side(Q, 1e-9) is None and collapsed_side(tip, EPS) == 0
    c = None
    for c in (0.5, 0.25, 0.125):
        a, b = curve_split(P, c)
        if np.allclose(a, tip, atol=1e-15):
            break
    assert np.allclose(curve_split(P, c)[1], rest, atol=1e-15)
    # the tip's new patch ends on the cut row: its corners B and C are the row's ends, M its middle
    from watertight_cli.core.bezier import curve_eval

    corners = surface_eval_grid(Q, [0.0, 1.0], [0.0, 1.0])
    assert np.allclose(corners[1, 0], rest[0, 0], atol=1e-13)
    assert np.allclose(corners[0, 1], rest[0, -1], atol=1e-13)
    assert np.allclose(corners[1, 1], curve_eval(rest[0], [0.5])[0], atol=1e-13)


@settings(max_examples=10, deadline=None)
@given(st.integers(2, 25), st.integers(0, 2**31 - 1))
def test_the_tensor_product_fit_solves_the_dense_normal_equations(n, seed):
    """``_fit_plain`` (eigendecomposition of the one-direction Gram matrix) gives the solution of
    the dense normal equations with the pull that the rational fit solves, to 1e-9 of its size."""
    from watertight_cli.core.bernstein import basis
    from watertight_cli.core.triangle import _PULL, _fit_plain

    rng = np.random.default_rng(seed)
    g = np.linspace(0.0, 1.0, 2 * n + 1)
    b, a = basis(n, g), len(g)
    target, net, blend = (rng.standard_normal(s) for s in ((a, a, 3), (n + 1, n + 1, 3), (n + 1, n + 1, 3)))
    got = _fit_plain(b, target, net, blend).reshape(-1, 3)
    B = np.einsum("ai,bj->abij", b, b).reshape(a * a, -1)
    inner = np.zeros((n + 1, n + 1), bool)
    inner[1:-1, 1:-1] = True
    inner = inner.ravel()
    A = B[:, inner]
    mu = _PULL * float((A * A).sum()) / A.shape[1]
    resid = target.reshape(-1, 3) - B[:, ~inner] @ net.reshape(-1, 3)[~inner]
    rhs = A.T @ resid + mu * blend.reshape(-1, 3)[inner]
    want = np.linalg.solve(A.T @ A + mu * np.eye(A.shape[1]), rhs)
    assert np.abs(got - want).max() <= 1e-9 * np.abs(want).max()
