"""Slender patches cut across (``core.slender``): every piece is the patch over its part of the
square within the certified bound, neighbouring pieces share their cut bitwise, the cuts run
straight across where the patch's own iso-lines are slanted, and no piece stays slender."""

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from watertight_cli.core.bezier import curve_eval, dehomogenize, homogenize, surface_eval, surface_eval_grid
from watertight_cli.core.slender import cut_slender, slender_axis

from .helpers import seeds

SETTINGS = settings(max_examples=25, deadline=None)
RATIO, FLOOR, BUDGET = 100.0, 1e-9, 1e-9


def strip(rng, m: int, n: int, width: float, slant: float, length: float = 10.0) -> np.ndarray:
    """A curved strip (m+1, n+1, 3), long along axis 1: a random spine of degree n, offset across
    by ``width`` and along by ``slant`` (so its iso-lines across are diagonals that long)."""
    noise = 0.1 * length / max(n, 2)
    spine = np.stack([np.linspace(0.0, length, n + 1), rng.normal(scale=noise, size=n + 1),
                      rng.normal(scale=noise, size=n + 1)], axis=1)
    tangent = np.gradient(spine, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.cross(tangent, [0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    s = np.linspace(0.0, 1.0, m + 1)[:, None, None]
    bulge = 0.2 * width * np.sin(np.pi * s) * rng.normal(size=(1, n + 1, 3))
    return spine[None] + s * (width * normal + slant * tangent)[None] + bulge


def weights(rng, shape) -> np.ndarray:
    """Weights that vary along a strip and barely across it, as on real patches."""
    t = np.linspace(0.0, 1.0, shape[1])[None]
    s = np.linspace(0.0, 1.0, shape[0])[:, None]
    return 1.0 + 0.3 * np.sin(2 * np.pi * t + rng.uniform(0, 6)) + 0.01 * s * rng.normal(size=shape)


def narrowest(ctrl, rational, axis, n=1025):
    """Smallest distance from side 0's samples to side 1's polyline (the sides that run along
    ``axis``, n samples each)."""
    net = ctrl if axis == 1 else np.swapaxes(ctrl, 0, 1)
    lo, hi = (curve_eval(net[i], np.linspace(0.0, 1.0, n)) for i in (0, -1))
    if rational:
        lo, hi = dehomogenize(lo), dehomogenize(hi)
    d = np.diff(hi, axis=0)
    x = lo[:, None] - hi[None, :-1]
    t = np.clip(np.einsum("kij,ij->ki", x, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
    return float(np.linalg.norm(x - t[..., None] * d, axis=-1).min())


def on_patch(ctrl, rational, cut, k, grid=9):
    """Largest distance between piece k and the patch at the points its map sends it to."""
    piece = cut.pieces[k]
    net, p = (ctrl, piece) if cut.axis == 1 else (np.swapaxes(ctrl, 0, 1), np.swapaxes(piece, 0, 1))
    a = np.concatenate([[0.0], cut.a, [1.0]])
    b = np.concatenate([[0.0], cut.b, [1.0]])
    sg, ng = np.meshgrid(np.linspace(0, 1, grid), np.linspace(0, 1, grid), indexing="ij")
    sg, ng = sg.ravel(), ng.ravel()
    lo = a[k] + sg * (b[k] - a[k])
    hi = a[k + 1] + sg * (b[k + 1] - a[k + 1])
    want = surface_eval(net, sg, lo + ng * (hi - lo))
    got = surface_eval(p, sg, ng)
    if rational:
        want, got = dehomogenize(want), dehomogenize(got)
    return float(np.linalg.norm(want - got, axis=1).max())


@SETTINGS
@given(seeds, st.integers(1, 12), st.integers(1, 5), st.floats(0.002, 0.05), st.floats(0.0, 0.3),
       st.booleans(), st.booleans())
def test_pieces_are_the_patch_and_share_cuts(seed, m, n, width, slant, rational, transpose):
    rng = np.random.default_rng(seed)
    ctrl = strip(rng, m, n, width, slant)
    if rational:
        ctrl = homogenize(ctrl, weights(rng, ctrl.shape[:2]))
    # a strip, not two curves that nearly touch: where the random spine bends sharply, the offset
    # side can come within a hair of it while the net between bulges away, and "width" (the
    # distance between the sides, which the pieces are sized by) is no longer the patch's width
    assume(narrowest(ctrl, rational, 1) >= 0.25 * width)
    if transpose:
        ctrl = np.ascontiguousarray(np.swapaxes(ctrl, 0, 1))
    cut = cut_slender(ctrl, rational, RATIO, FLOOR, BUDGET, 25)
    assert cut is not None  # 10 long and at most 0.05 wide: slender
    assert cut.axis == (0 if transpose else 1)
    assert cut.bound <= BUDGET
    assert len(cut.pieces) >= 2
    for k in range(len(cut.pieces)):
        assert on_patch(ctrl, rational, cut, k) <= cut.bound + 1e-12
    # the cuts are shared bitwise, and the outer rows are the patch's own
    rows = [np.swapaxes(p, 0, 1) if cut.axis == 1 else p for p in cut.pieces]
    whole = np.swapaxes(ctrl, 0, 1) if cut.axis == 1 else ctrl
    for left, right in zip(rows[:-1], rows[1:], strict=True):
        np.testing.assert_array_equal(left[-1], right[0])
    if not cut.degree_raised:
        np.testing.assert_array_equal(rows[0][0], whole[0])
        np.testing.assert_array_equal(rows[-1][-1], whole[-1])
    # no piece is slender any more (a little slack: widths are measured on samples), except the
    # end pieces where the slanted end alone is longer than that
    inner = cut.pieces if slant < 0.8 * RATIO * width else cut.pieces[1:-1]
    for p in inner:
        assert slender_axis(p, rational, 1.2 * RATIO, FLOOR) is None


@SETTINGS
@given(seeds, st.integers(2, 10), st.integers(1, 4))
def test_cuts_run_straight_across_a_slanted_strip(seed, m, n):
    """Iso-lines 0.3 long across a strip 0.005 wide: the cuts go from side to side the short way
    (a straight line of the square is not the shortest path where the spine's speed varies: a few
    widths, against 60 for an iso-line)."""
    rng = np.random.default_rng(seed)
    width = 0.005
    ctrl = strip(rng, m, n, width, 0.3)
    cut = cut_slender(ctrl, False, RATIO, FLOOR, BUDGET, 25)
    assert cut is not None and len(cut.pieces) >= 5
    for p in cut.pieces[1:]:
        first = surface_eval_grid(p, np.linspace(0, 1, 33), [0.0])[:, 0]
        assert np.linalg.norm(np.diff(first, axis=0), axis=1).sum() < 8 * width


def test_not_slender_and_collapsed_are_left_alone():
    rng = np.random.default_rng(1)
    assert cut_slender(strip(rng, 3, 3, 0.5, 0.0), False, RATIO, FLOOR, BUDGET, 25) is None
    wedge = strip(rng, 3, 3, 0.01, 0.0)
    wedge[:, 0] = wedge[0, 0]  # one short side collapsed to a point
    assert cut_slender(wedge, False, RATIO, FLOOR, BUDGET, 25) is None
    # a long side against a short one near its end (a triangle made four-sided) is no strip
    tri = strip(rng, 3, 3, 0.01, 0.0)
    tri[-1] = tri[0, 0] + np.linspace(0.0, 1.0, 4)[:, None] * np.array([0.1, 0.0, 0.02])
    assert slender_axis(tri, False, RATIO, FLOOR) is None


def test_cuts_go_through_known_vertices_on_the_sides():
    """A vertex on a long side near where a cut would land takes the cut (two strips beside each
    other are cut at the same points)."""
    rng = np.random.default_rng(7)
    ctrl = strip(rng, 4, 3, 0.01, 0.0)
    plain = cut_slender(ctrl, False, RATIO, FLOOR, BUDGET, 25)
    t = plain.a[0] + 0.1 * (plain.a[1] - plain.a[0])
    vertex = curve_eval(ctrl[0], [t])[0]

    def snap(pts, radius):
        out = np.full(pts.shape, np.nan)
        near = np.linalg.norm(pts - vertex, axis=1) <= radius
        out[near] = vertex
        return out

    snapped = cut_slender(ctrl, False, RATIO, FLOOR, BUDGET, 25, snap, 1e-12)
    assert abs(snapped.a[0] - t) < 1e-12
    corner = snapped.pieces[0][0, -1]
    assert np.linalg.norm(corner - vertex) < 1e-12


def test_a_strip_that_narrows_between_samples_is_cut_finer_there():
    """Where a strip narrows to a hundredth of its width between the first look's samples (here
    where the random spine bends and the offset side comes close to it), the pieces there are
    still short enough: the sides are sampled finer where one step is too long for a piece."""
    ctrl = strip(np.random.default_rng(2), 1, 4, 0.0078125, 0.25)
    assert narrowest(ctrl, False, 1) < 0.01 * 0.0078125  # the strip does narrow that much
    cut = cut_slender(ctrl, False, RATIO, FLOOR, BUDGET, 25)
    assert cut is not None
    for p in cut.pieces:
        assert slender_axis(p, False, 1.2 * RATIO, FLOOR) is None
