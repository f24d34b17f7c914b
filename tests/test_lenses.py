"""Thin lenses below the tolerance are taken out (``watertight_cli.lenses``)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.lenses import collapse_lenses
from watertight_cli.topology import connect


def _ruled(a: np.ndarray, b: np.ndarray, n: int = 3) -> np.ndarray:
    """(n+1, n+1, 3) net: row j = 0 is the row ``a``, j = n the row ``b``, straight between."""
    t = np.linspace(0.0, 1.0, n + 1)[None, :, None]
    return (1.0 - t) * a[:, None, :] + t * b[:, None, :]


def _line(p: np.ndarray, q: np.ndarray, n: int = 3) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    return (1.0 - s) * p + s * q


def _scene(w: float, ax: float = 1.0):
    """A lens of width ``w`` between a straight rung B -> C and two sides through A = (ax, w), with
    its three neighbours: above A -> B, above A -> C (sharing the rung from A up), below B -> C."""
    A, B, C = np.array([ax, w, 0.0]), np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    up, left, right = np.array([ax, 1.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([2.0, 1.0, 0.0])
    rung = _line(B, C)
    bottom, top = _line(A, B), _line(A, C)
    s = np.linspace(0.0, 1.0, 4)[:, None, None]
    lens = (1.0 - s) * np.broadcast_to(A, (1, 4, 3)) + s * rung[None, :, :]  # P[0, :] = A, P[-1, :] = rung
    lens[:, 0], lens[:, -1] = bottom, top
    nb = _ruled(bottom, _line(up, left))
    nt = _ruled(top, _line(up, right))
    nr = _ruled(rung, _line(np.array([0.0, -1.0, 0.0]), np.array([2.0, -1.0, 0.0])))
    return [(lens, False), (nb, False), (nt, False), (nr, False)]


def _inner_free(topo) -> int:
    """Free edges of a topology that do not lie on the scene's outer boundary (|y| = 1, x = 0 or 2)."""
    n = 0
    for e in topo.edges:
        if e.degenerate or len(e.members) != 1:
            continue
        ends = topo.vertices[[e.va, e.vb]]
        x, y = ends[:, 0], ends[:, 1]
        outer = np.isclose(np.abs(y), 1.0) | np.isclose(x, 0.0) | np.isclose(x, 2.0)
        n += not outer.all()
    return n


def test_a_thin_lens_is_dropped_and_the_patch_across_its_rung_closes_over_it():
    nets = _scene(1e-5)
    eps = 1e-9
    done = collapse_lenses(nets, eps, width=1e-4)
    assert done.collapsed == 1 and done.nets[0] is None
    assert len(done.nets) == 5 and done.parent == {4: 3}  # the patch below, cut in two at A
    kept = [n for n in done.nets if n is not None]
    topo = connect(kept, eps)
    assert _inner_free(connect(nets, eps)) == 0 and _inner_free(topo) == 0
    lo, hi = done.nets[3][0], done.nets[4][0]
    lens = nets[0][0]
    # the halves carry the lens's own sides, B -> A and A -> C, where the rung was
    assert np.array_equal(lo[:, 0], lens[:, 0][::-1]) and np.array_equal(hi[:, 0], lens[:, -1])
    # their cut is one row, to the bit, and it ends at A
    assert np.array_equal(lo[-1, :], hi[0, :]) and np.array_equal(lo[-1, 0], lens[0, 0])
    # the upper patches did not change
    assert all(np.array_equal(done.nets[i][0], nets[i][0]) for i in (1, 2))
    assert max(done.moved.values()) <= 1e-5 * (1 + 1e-9)
    assert done.moved[0] == pytest.approx(1e-5)


def test_a_lens_wider_than_the_width_stays():
    nets = _scene(1e-3)
    done = collapse_lenses(nets, 1e-9, width=1e-4)
    assert done.collapsed == 0 and done.left == 0
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(nets, done.nets, strict=True))


def test_a_lens_whose_rung_has_no_single_partner_stays():
    nets = _scene(1e-5)[:3]  # nothing across the rung
    done = collapse_lenses(nets, 1e-9, width=1e-4)
    assert done.collapsed == 0 and done.left == 1
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(nets, done.nets, strict=True))


@settings(max_examples=25, deadline=None)
@given(w=st.floats(1e-7, 5e-5), ax=st.floats(0.2, 1.8))
def test_collapse_keeps_the_union_closed_and_moves_within_the_width(w, ax):
    nets = _scene(w, ax)
    done = collapse_lenses(nets, 1e-9, width=1e-4)
    assert done.collapsed == 1
    kept = [n for n in done.nets if n is not None]
    assert _inner_free(connect(kept, 1e-9)) == 0
    assert max(done.moved.values()) <= w * (1 + 1e-9) + 1e-15


def test_a_lens_whose_rung_belongs_to_a_rational_patch_stays():
    nets = _scene(1e-5)
    c = nets[3][0]
    nets[3] = (np.concatenate([2.0 * c, np.full(c.shape[:2] + (1,), 2.0)], axis=-1), True)  # weights 2
    done = collapse_lenses(nets, 1e-9, width=1e-4)
    assert done.collapsed == 0 and done.left == 1  # the rung's patch is rational: kept
    assert done.nets[3][1] and np.array_equal(done.nets[3][0], nets[3][0])


def _parabola_scene(w: float):
    """A lens whose two sides are the halves of one parabola K from B = (0, 0) through
    A = (1, w) to C = (2, 0), over the straight rung B -> C, with the same three neighbours."""
    from watertight_cli.core.bezier import curve_segment, elevate_curve

    K = np.array([[0.0, 0.0, 0.0], [1.0, 2.0 * w, 0.0], [2.0, 0.0, 0.0]])
    bottom, top = curve_segment(K, 0.5, 0.0), curve_segment(K, 0.5, 1.0)  # A -> B, A -> C
    A = bottom[0]
    rung = elevate_curve(np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), 1)
    s = np.linspace(0.0, 1.0, 3)[:, None, None]
    lens = (1.0 - s) * np.broadcast_to(A, (1, 3, 3)) + s * rung[None, :, :]
    lens[:, 0], lens[:, -1] = bottom, top
    up = np.array([1.0, 1.0, 0.0])
    nb = _ruled(bottom, _line(up, np.array([0.0, 1.0, 0.0]), 2), 2)
    nt = _ruled(top, _line(up, np.array([2.0, 1.0, 0.0]), 2), 2)
    nr = _ruled(_line(np.zeros(3), np.array([2.0, 0.0, 0.0])),
                _line(np.array([0.0, -1.0, 0.0]), np.array([2.0, -1.0, 0.0])))
    return K, [(lens, False), (nb, False), (nt, False), (nr, False)]


def test_a_lens_on_one_polynomial_is_closed_by_one_row_and_no_cut():
    K, nets = _parabola_scene(1e-5)
    done = collapse_lenses(nets, 1e-9, width=1e-4, exact=1e-13)
    assert done.collapsed == 1 and done.cut == 0 and done.nets[0] is None
    assert len(done.nets) == 4 and not done.parent  # nothing added
    nr = done.nets[3][0]
    # the patch below now runs along K itself (elevated to its degree 3), ends B and C exact
    from watertight_cli.core.bezier import elevate_curve

    assert np.abs(nr[:, 0] - elevate_curve(K, 1)).max() <= 1e-13
    assert np.array_equal(nr[0, 0], K[0]) and np.array_equal(nr[-1, 0], K[-1])
    assert all(np.array_equal(done.nets[i][0], nets[i][0]) for i in (1, 2))
    kept = [n for n in done.nets if n is not None]
    topo = connect(kept, 1e-9)
    assert _inner_free(topo) == 0 and topo.t_vertices == 1  # A, where the two above meet
    # the move is the control points' (K's elevated middle points stand 4/3 w off the rung)
    assert done.moved[3] == pytest.approx(4.0 / 3.0 * 1e-5) and done.moved[0] == pytest.approx(1e-5)


def test_a_lens_with_a_kink_at_its_tip_is_cut_out_instead():
    nets = _scene(1e-5)  # two straight sides: one row cannot hold both
    done = collapse_lenses(nets, 1e-9, width=1e-4, exact=1e-13)
    assert done.collapsed == 1 and done.cut == 1 and done.parent == {4: 3}


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), degree=st.integers(1, 9), split=st.floats(0.15, 0.85),
       up=st.integers(0, 4))
def test_joined_gives_back_the_polynomial_its_two_pieces_came_from(seed, degree, split, up):
    """Two pieces of one polynomial curve (each possibly elevated) are joined into that curve."""
    from watertight_cli.core.bezier import curve_segment, elevate_curve
    from watertight_cli.lenses import _joined

    K = np.random.default_rng(seed).normal(size=(degree + 1, 3))
    first, second = curve_segment(K, 0.0, split), elevate_curve(curve_segment(K, split, 1.0), up)
    row = _joined(first, second, 1e-11, 25)
    assert row is not None and len(row) - 1 <= degree
    assert np.abs(elevate_curve(row, degree - (len(row) - 1)) - K).max() <= 1e-9


def test_joined_refuses_pieces_that_meet_at_a_kink():
    from watertight_cli.lenses import _joined

    first = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    second = np.array([[1.0, 0.0, 0.0], [2.0, 1e-6, 0.0]])
    assert _joined(first, second, 1e-11, 25) is None
