"""Where slender patches' long sides are split (``core.slender``): the points lie on the long
sides, no piece of a long side is much longer than ``ratio`` times the strip's width along it, the
two sides are split opposite each other where the patch's own iso-lines are slanted, and known
vertices nearby take the stations."""

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from watertight_cli.core.bezier import curve_eval, dehomogenize, homogenize
from watertight_cli.core.slender import slender_axes, slender_axis, split_points

from .helpers import seeds

SETTINGS = settings(max_examples=25, deadline=None)
RATIO, FLOOR = 100.0, 1e-9


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


def sides(ctrl, rational, axis, n=2049):
    """The two long sides (running along ``axis``) sampled at n parameters, Cartesian."""
    net = ctrl if axis == 1 else np.swapaxes(ctrl, 0, 1)
    out = [curve_eval(net[i], np.linspace(0.0, 1.0, n)) for i in (0, -1)]
    return [dehomogenize(x) if rational else x for x in out]


def _to_polyline(pts, line):
    d = np.diff(line, axis=0)
    x = pts[:, None] - line[None, :-1]
    t = np.clip(np.einsum("kij,ij->ki", x, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
    return np.linalg.norm(x - t[..., None] * d, axis=-1).min(axis=1)


def pieces_fit(ctrl, rational, split, slack, skip_ends=False, n=2049):
    """Whether every piece of both long sides between the split points (and the ends) is at most
    ``slack`` x RATIO times longer than the strip's narrowest width along it."""
    lo, hi = sides(ctrl, rational, split.axis, n)
    s = np.linspace(0.0, 1.0, n)
    for own, other, params in ((lo, hi, split.a), (hi, lo, split.b)):
        width = _to_polyline(own, other)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(own, axis=0), axis=1))])
        ends = np.concatenate([[0.0], params, [1.0]])
        spans = list(zip(ends[:-1], ends[1:], strict=True))
        if skip_ends:
            spans = spans[1:-1]
        for x, y in spans:
            inside = (s >= x) & (s <= y)
            length = np.interp(y, s, arc) - np.interp(x, s, arc)
            if length > slack * RATIO * float(width[inside].min(initial=np.inf)):
                return False
    return True


@SETTINGS
@given(seeds, st.integers(1, 12), st.integers(1, 5), st.floats(0.002, 0.05), st.floats(0.0, 0.3),
       st.booleans(), st.booleans())
def test_split_points_lie_on_the_long_sides_and_pieces_fit(seed, m, n, width, slant, rational, transpose):
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
    split = split_points(ctrl, rational, RATIO, FLOOR)
    assert split is not None  # 10 long and at most 0.05 wide: slender
    assert split.axis == (0 if transpose else 1)
    assert len(split.a) >= 1 and len(split.a) == len(split.b)
    assert np.all(np.diff(split.a) > 0) and np.all(np.diff(split.b) > 0)
    assert 0.0 < split.a[0] and split.a[-1] < 1.0 and 0.0 < split.b[0] and split.b[-1] < 1.0
    net = ctrl if split.axis == 1 else np.swapaxes(ctrl, 0, 1)
    want = [curve_eval(net[0], split.a), curve_eval(net[-1], split.b)]
    want = np.concatenate([dehomogenize(w) if rational else w for w in want])
    np.testing.assert_allclose(split.points, want, rtol=0, atol=1e-12)
    # a little slack: widths are measured on samples; the end pieces may be as long as the
    # slanted end alone
    assert pieces_fit(ctrl, rational, split, 1.2, skip_ends=slant >= 0.8 * RATIO * width)


@SETTINGS
@given(seeds, st.integers(2, 10), st.integers(1, 4))
def test_sides_are_split_opposite_each_other_on_a_slanted_strip(seed, m, n):
    """Iso-lines 0.3 long across a strip 0.005 wide: each station on side 1 is the nearest point
    to its station on side 0 (a few widths away, against 60 for an iso-line)."""
    rng = np.random.default_rng(seed)
    width = 0.005
    ctrl = strip(rng, m, n, width, 0.3)
    split = split_points(ctrl, False, RATIO, FLOOR)
    assert split is not None and len(split.a) >= 4
    k = len(split.a)
    assert np.linalg.norm(split.points[:k] - split.points[k:], axis=1).max() < 8 * width


def test_not_slender_and_collapsed_are_left_alone():
    rng = np.random.default_rng(1)
    assert split_points(strip(rng, 3, 3, 0.5, 0.0), False, RATIO, FLOOR) is None
    wedge = strip(rng, 3, 3, 0.01, 0.0)
    wedge[:, 0] = wedge[0, 0]  # one short side collapsed to a point
    assert split_points(wedge, False, RATIO, FLOOR) is None
    # a long side against a short one near its end (a triangle made four-sided) is no strip
    tri = strip(rng, 3, 3, 0.01, 0.0)
    tri[-1] = tri[0, 0] + np.linspace(0.0, 1.0, 4)[:, None] * np.array([0.1, 0.0, 0.02])
    assert slender_axis(tri, False, RATIO, FLOOR) is None


def test_stations_go_to_known_vertices_on_the_sides():
    """A vertex on a long side near where a station would land takes it (two strips beside each
    other are split at the same points)."""
    rng = np.random.default_rng(7)
    ctrl = strip(rng, 4, 3, 0.01, 0.0)
    plain = split_points(ctrl, False, RATIO, FLOOR)
    t = plain.a[0] + 0.1 * (plain.a[1] - plain.a[0])
    vertex = curve_eval(ctrl[0], [t])[0]

    def snap(pts, radius):
        out = np.full(pts.shape, np.nan)
        near = np.linalg.norm(pts - vertex, axis=1) <= radius
        out[near] = vertex
        return out

    snapped = split_points(ctrl, False, RATIO, FLOOR, snap, 1e-12)
    assert abs(snapped.a[0] - t) < 1e-12
    assert np.linalg.norm(snapped.points[0] - vertex) < 1e-12


def test_a_strip_that_narrows_between_samples_is_split_finer_there():
    """Where a strip narrows to a hundredth of its width between the first look's samples (here
    where the random spine bends and the offset side comes close to it), the pieces there are
    still short enough: the sides are sampled finer where one step is too long for a piece."""
    ctrl = strip(np.random.default_rng(2), 1, 4, 0.0078125, 0.25)
    assert narrowest(ctrl, False, 1) < 0.01 * 0.0078125  # the strip does narrow that much
    split = split_points(ctrl, False, RATIO, FLOOR)
    assert split is not None
    assert pieces_fit(ctrl, False, split, 1.2)


@SETTINGS
@given(seeds, st.integers(1, 6), st.integers(1, 6), st.booleans())
def test_slender_axes_agree_with_slender_axis(seed, m, n, rational):
    """The stacked first look gives each patch the axis (or none) that the one-patch test gives:
    strips along either axis, wide patches, and wedges with a collapsed side, mixed."""
    rng = np.random.default_rng(seed)
    nets = []
    for k in range(12):
        width = [0.5, 0.01, 0.001, 0.05][k % 4]
        c = strip(rng, m, n, width, rng.uniform(0.0, 0.3))
        if k % 5 == 4:
            c[:, 0] = c[0, 0]  # a wedge
        if rational:
            c = homogenize(c, weights(rng, c.shape[:2]))
        nets.append(c if k % 2 else np.ascontiguousarray(np.swapaxes(c, 0, 1)))
    by_shape = {}
    for c in nets:
        by_shape.setdefault(c.shape, []).append(c)
    for group in by_shape.values():
        got = slender_axes(np.stack(group), rational, RATIO, FLOOR)
        want = [slender_axis(c, rational, RATIO, FLOOR) for c in group]
        assert [None if g < 0 else int(g) for g in got] == want


@SETTINGS
@given(seeds, st.integers(2, 400), st.integers(3, 400), st.floats(1e-4, 1.0))
def test_polyline_distance_by_nearby_segments_is_exact(seed, k, m, spread):
    """The k-d tree search for long polylines gives every point the distance that measuring every
    segment gives, and a foot on the polyline at that distance."""
    from watertight_cli.core import slender

    rng = np.random.default_rng(seed)
    b = np.cumsum(rng.normal(size=(m, 3)) * rng.uniform(0.01, 1.0, size=(m, 1)), axis=0)
    a = b[rng.integers(0, m, size=k)] + spread * rng.normal(size=(k, 3))
    a[: k // 3] = rng.normal(scale=10.0, size=(k // 3, 3))  # some far from it
    want, _ = slender._to_polyline(a, b) if k * m <= slender._BRUTE else _brute(a, b)
    got, where = slender._to_polyline_near(a, b)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * (1 + float(want.max())))
    j = np.minimum(where.astype(int), m - 2)
    foot = b[j] + (where - j)[:, None] * (b[j + 1] - b[j])
    np.testing.assert_allclose(np.linalg.norm(foot - a, axis=1), got, rtol=0, atol=1e-9)


def _brute(a, b):
    from watertight_cli.core import slender

    saved, slender._BRUTE = slender._BRUTE, 1 << 62
    try:
        return slender._to_polyline(a, b)
    finally:
        slender._BRUTE = saved
