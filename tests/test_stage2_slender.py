"""Stage 2's splitting of slender patches' long sides (``stage2._split_slender``) around
triangles: a strip whose split points would land on a remade or kept triangle's side is left as
it is (wing_fuselage: a needle beside a strip cut twelve times left two holes and one solid fewer
when strips were cut into pieces; the rule stays for the split points)."""

import numpy as np

from watertight_cli.stage2 import _split_slender
from watertight_cli.tolerances import Tolerances


def _strip(y0: float, y1: float) -> np.ndarray:
    """A flat strip 10 long from y0 to y1, bidegree (1, 3), long along axis 1."""
    x = np.linspace(0.0, 10.0, 4)
    return np.stack([np.stack([x, np.full(4, y), np.zeros(4)], axis=1) for y in (y0, y1)])


def _run(strip_was, neighbour_was, neighbour=None):
    strip = _strip(0.0, 0.01)
    neighbour = _strip(0.01, 0.5) if neighbour is None else neighbour  # shares the side y = 0.01
    nets = [[(strip, False, strip_was)], [(neighbour, False, neighbour_was)]]
    pts, info = _split_slender(nets, Tolerances(), 10.0)
    return pts, info, nets


def test_a_strip_beside_a_plain_patch_is_split():
    pts, info, nets = _run(None, None)
    assert info["split"] == 1 and info["vertices"] == len(pts) > 1
    assert info["left_by_triangles"] == 0
    # on the strip's two long sides, spaced at most 250 widths (2.5) apart, the patches unchanged
    assert np.allclose(pts[:, 2], 0.0) and set(np.round(pts[:, 1], 12)) == {0.0, 0.01}
    for y in (0.0, 0.01):
        x = np.sort(np.concatenate([[0.0, 10.0], pts[np.isclose(pts[:, 1], y), 0]]))
        assert np.diff(x).max() <= 250 * 0.01 * (1 + 1e-9)
    assert len(nets[0]) == 1 and len(nets[1]) == 1


def test_a_strip_beside_a_remade_triangle_is_not_split():
    pts, info, nets = _run(None, "triangle")
    assert info["split"] == 0 and info["left_by_triangles"] == 1 and len(pts) == 0


def test_a_strip_beside_a_kept_triangle_is_not_split():
    """A wedge kept with its collapsed side (no remade quad) takes no split points on its sides."""
    wedge = _strip(0.01, 0.5)
    wedge[1] = wedge[1, 0]  # its far side collapsed to one point: a triangle
    pts, info, _ = _run(None, None, wedge)
    assert info["split"] == 0 and info["left_by_triangles"] == 1 and len(pts) == 0


def _flat(length: float, width: float) -> np.ndarray:
    """A flat strip ``length`` long along x and ``width`` wide in y, bidegree (1, 3)."""
    x = np.linspace(0.0, length, 4)
    return np.stack([np.stack([x, np.full(4, y), np.zeros(4)], axis=1) for y in (0.0, width)])


def test_a_sliver_is_split_at_twenty_times_the_ratio():
    """A strip narrower than thin_rel (5e-6 on a diagonal of 10) but wider than ten sliver floors
    (sliver_rel: 1e-7) is split too, into pieces up to 20 x 250 widths: the kernel's mesher left a
    hole in such a sliver of bug33398 whose one long side held many vertices and the other none."""
    width, length = 2e-6, 0.1
    sliver = _flat(length, width)
    pts, info = _split_slender([[(sliver, False, None)]], Tolerances(), 10.0)
    assert info["split"] == 1 and info["left_by_triangles"] == 0
    for y in (0.0, width):
        x = np.sort(np.concatenate([[0.0, length], pts[np.isclose(pts[:, 1], y, rtol=0, atol=1e-12), 0]]))
        assert len(x) > 2
        assert np.diff(x).max() <= 5000 * width * (1 + 1e-9)  # 20 x --max-aspect
        assert np.diff(x).min() > 250 * width  # not at the ratio itself: 200 pieces a side
    # the same stations on both sides
    lo, hi = (np.sort(pts[np.isclose(pts[:, 1], y, rtol=0, atol=1e-12), 0]) for y in (0.0, width))
    assert np.allclose(lo, hi, rtol=0, atol=1e-12)


def test_a_sliver_within_ten_sliver_floors_is_not_split():
    for width in (5e-8, 5e-7):  # below the sliver floor (1e-7), below ten of them
        pts, info = _split_slender([[(_flat(0.1, width), False, None)]], Tolerances(), 10.0)
        assert info["split"] == 0 and len(pts) == 0


def test_inf_splits_no_sliver():
    pts, info = _split_slender([[(_flat(0.1, 2e-6), False, None)]], Tolerances(slender_ratio=np.inf), 10.0)
    assert info["split"] == 0 and len(pts) == 0
