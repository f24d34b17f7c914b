"""Composition with a rational cell map phi = (U/W, V/W) against pointwise evaluation."""

import numpy as np
from hypothesis import given, settings

from watertight_cli.core.bernstein import basis
from watertight_cli.core.bezier import rational_surface_eval
from watertight_cli.core.compose import compose

from .helpers import seeds


def _grid_eval(G, s, t):
    return basis(G.shape[0] - 1, s) @ G @ basis(G.shape[1] - 1, t).T


@settings(max_examples=25, deadline=None)
@given(seeds)
def test_rational_map_composes_exactly(seed):
    rng = np.random.default_rng(seed)
    m, n, a, b = rng.integers(1, 4, size=4)
    P = rng.normal(size=(m + 1, n + 1, 3))
    w = rng.uniform(0.5, 2.0, size=(m + 1, n + 1))
    H = np.concatenate([P * w[..., None], w[..., None]], axis=-1)
    W = rng.uniform(0.5, 2.0, size=(a + 1, b + 1))
    U = rng.uniform(0, 1, size=(a + 1, b + 1)) * W
    V = rng.uniform(0, 1, size=(a + 1, b + 1)) * W
    out = compose(H, U, V, W=W)
    assert out.shape == ((m + n) * a + 1, (m + n) * b + 1, 4)
    s = np.linspace(0, 1, 7)
    ss, tt = np.meshgrid(s, s, indexing="ij")
    ww = np.array([[_grid_eval(W, np.array([x]), np.array([y]))[0, 0] for y in s] for x in s])
    uu = np.array([[_grid_eval(U, np.array([x]), np.array([y]))[0, 0] for y in s] for x in s]) / ww
    vv = np.array([[_grid_eval(V, np.array([x]), np.array([y]))[0, 0] for y in s] for x in s]) / ww
    want = rational_surface_eval(H, uu.ravel(), vv.ravel())
    got = rational_surface_eval(out, ss.ravel(), tt.ravel())
    assert np.max(np.abs(got - want)) <= 1e-10 * (1 + np.max(np.abs(want)))
