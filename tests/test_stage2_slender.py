"""Stage 2's cutting of slender patches (``stage2._cut_slender``) around remade triangles: a strip
whose cuts would end on a remade triangle's side stays whole (wing_fuselage: a needle beside a
strip cut twelve times left two holes and one solid fewer)."""

from types import SimpleNamespace

import numpy as np

from watertight_cli.stage2 import _cut_slender
from watertight_cli.tolerances import Tolerances


def _strip(y0: float, y1: float) -> np.ndarray:
    """A flat strip 10 long from y0 to y1, bidegree (1, 3), long along axis 1."""
    x = np.linspace(0.0, 10.0, 4)
    return np.stack([np.stack([x, np.full(4, y), np.zeros(4)], axis=1) for y in (y0, y1)])


def _run(strip_was, neighbour_was):
    strip = _strip(0.0, 0.01)
    neighbour = _strip(0.01, 0.5)  # shares the strip's side at y = 0.01; not slender itself
    nets = [[(strip, False, strip_was)], [(neighbour, False, neighbour_was)]]
    result = SimpleNamespace(faces=[SimpleNamespace(face=0), SimpleNamespace(face=1)])
    quads = {"per_face": {}}
    info = _cut_slender(result, nets, quads, Tolerances(), 10.0)
    return info, nets


def test_a_strip_beside_a_plain_patch_is_cut():
    info, nets = _run(None, None)
    assert info["cut"] == 1 and len(nets[0]) == info["pieces"] > 1
    assert info["left_by_triangles"] == 0
    assert len(nets[1]) == 1


def test_a_strip_beside_a_remade_triangle_stays_whole():
    info, nets = _run(None, "triangle")
    assert info["cut"] == 0 and info["left_by_triangles"] == 1
    assert len(nets[0]) == 1 and nets[0][0][2] is None


def test_a_strip_beside_a_kept_triangle_stays_whole():
    """A wedge kept with its collapsed side (no remade quad) takes no cut ends on its sides either."""
    strip = _strip(0.0, 0.01)
    wedge = _strip(0.01, 0.5)
    wedge[1] = wedge[1, 0]  # its far side collapsed to one point: a triangle
    nets = [[(strip, False, None)], [(wedge, False, None)]]
    result = SimpleNamespace(faces=[SimpleNamespace(face=0), SimpleNamespace(face=1)])
    info = _cut_slender(result, nets, {"per_face": {}}, Tolerances(), 10.0)
    assert info["cut"] == 0 and info["left_by_triangles"] == 1
