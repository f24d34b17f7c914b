"""Thin lenses below the tolerance, taken out of the patch set (arrays in, arrays out).

Stage 1 leaves a triangular cell where a trimming curve runs nearly along a slab line and bulges
across it: the cell between the slab line through the curve's extreme point A (its collapsed
side) and the next slab line, which the curve crosses at B and C. The cell is a lens: its two
sides A -> B and A -> C are pieces of the trimming edge, its third side B -> C is a rung, and
every point of it lies within a hair of that rung (occt__bug24595_281390.stp: lenses 0.017 long
and 1.6e-5 to 2.6e-5 wide, against a tolerance of 1.5e-4). Made again as a four-sided patch it
has two flat corners and two cusps, its tessellation welds nodes across it (collapsed
triangles, no closed mesh), and I5 asks for no slivers below the tolerance.

``collapse_lenses`` removes such a lens when every point of it lies within ``width`` of its rung,
and the patch on the rung's other side (in the same face) closes over it:

- where the lens's two sides are pieces of one polynomial (its edge's curve, with no knot at A),
  that patch's side B -> C becomes the one row through both (fitted at the lowest degree that
  holds them within ``exact``, the watertight gap's scale): nothing else changes, and A is a
  T-vertex on it where other patches meet there;
- otherwise the patch is cut in two at A's foot A' on the rung, and its two halves take the
  lens's own sides B -> A and A -> C in place of the rung's pieces (elevated to a common degree
  where they differ); the cut's end at A' moves to A (a bilinear displacement of both halves'
  nets, zero at their other corners, so the cut stays one row, equal to the bit in both), and its
  far end is a new vertex on the patch's opposite side. The cut is a new edge near the lens's
  tip, where thin cells crowd (on bug24595, with every lens cut, a re-implementation of the
  independent checker's boundary-sample test found 13 samples by 4 of the 9 cuts matched to a
  third face's curve), so it is the second choice.

The lens is dropped; its sides pair with the other face as before, and the face still covers its
area. Each changed patch moves by at most its largest control-point change against the old
patch (or the exact half of it; convex hull), which is returned so that the deviation measure
(I4) includes it. A lens is kept unless its rung has exactly one partner side, that patch is
polynomial with no collapsed side, A' lies well inside the rung, and every move stays within
``width``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .core.bernstein import basis
from .core.bezier import (
    curve_eval,
    elevate_curve,
    elevate_surface,
    surface_eval_grid,
    surface_split_u,
    surface_split_v,
)
from .core.triangle import collapsed_side
from .topology import SIDE_ROWS, project

#: the four sides of a net as (index of the row, the axis it runs along)
_SIDES = {name: (SIDE_ROWS[name][0], 0 if name in ("bottom", "top") else 1) for name in SIDE_ROWS}
_CHECK = np.array([0.25, 0.5, 0.75])  # where a partner side is compared with a side
_GRID = 9  # samples per direction of a lens checked against its rung
#: a piece of the rung shorter than this (x the lens's width) would make a needle of its neighbour
_PIECE = 10.0


@dataclass
class Collapsed:
    """What ``collapse_lenses`` did: the nets (None where a lens was dropped), each changed net's
    largest move, and counts."""

    nets: list
    moved: dict[int, float] = field(default_factory=dict)
    parent: dict[int, int] = field(default_factory=dict)  # a net added past the input's -> the one cut
    collapsed: int = 0
    cut: int = 0  # of those, taken out by cutting the rung's patch in two (its side could not be one row)
    left: int = 0  # thin lenses found but kept (a condition above failed)
    width_max: float = 0.0


def _cart(row: np.ndarray) -> np.ndarray:
    return np.concatenate([row, np.ones((len(row), 1))], axis=1)


def _side(ctrl: np.ndarray, name: str) -> np.ndarray:
    return ctrl[_SIDES[name][0]]


def _corners(ctrl: np.ndarray) -> np.ndarray:
    return ctrl[[0, -1, -1, 0], [0, 0, -1, -1]]


def _xyz(net: tuple[np.ndarray, bool]) -> np.ndarray:
    ctrl, rational = net
    return ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl


class _Index:
    """Patch corners in a k-d tree, to find the patches at a point and the partner of a side."""

    def __init__(self, nets: list, eps: float):
        self.nets, self.eps = nets, eps
        self.live = [k for k, n in enumerate(nets) if n is not None]
        pts = np.array([_corners(_xyz(nets[k])) for k in self.live]).reshape(-1, 3)
        self.tree = cKDTree(pts) if len(pts) else None

    def at(self, p: np.ndarray) -> list[int]:
        """Patches with a corner within eps of p."""
        if self.tree is None:
            return []
        found = self.tree.query_ball_point(p, self.eps)
        return sorted({self.live[i // 4] for i in found if self.nets[self.live[i // 4]] is not None})

    def partners(self, row: np.ndarray, skip: int) -> list[tuple[int, str, bool]]:
        """(patch, side, reversed) of the other sides that run along the curve ``row`` (Cartesian)
        between the same ends."""
        a, b = row[0], row[-1]
        want = curve_eval(row, _CHECK)
        out = []
        for q in self.at(a):
            if q == skip:
                continue
            ctrl = _xyz(self.nets[q])
            for name in _SIDES:
                r = _side(ctrl, name)
                for rev, (x, y) in ((False, (r[0], r[-1])), (True, (r[-1], r[0]))):
                    if np.linalg.norm(x - a) > self.eps or np.linalg.norm(y - b) > self.eps:
                        continue
                    got = curve_eval(r, 1.0 - _CHECK if rev else _CHECK)
                    if float(np.linalg.norm(got - want, axis=1).max()) <= 10.0 * self.eps:
                        out.append((q, name, rev))
        return out


def _change(old: np.ndarray, new: np.ndarray) -> float:
    """Largest control-point change from ``old`` to ``new`` (old elevated to new's degrees)."""
    ru, rv = new.shape[0] - old.shape[0], new.shape[1] - old.shape[1]
    if ru or rv:
        old = elevate_surface(old, ru, rv)
    return float(np.linalg.norm(new - old, axis=-1).max())


def _displaced(ctrl: np.ndarray, corner: tuple[int, int], delta: np.ndarray, to: np.ndarray) -> np.ndarray:
    """The net moved by ``delta`` at ``corner`` ((0 or -1, 0 or -1)) and by nothing at the other
    corners, bilinearly in the Bernstein coefficients; the corner itself set to ``to``."""
    m, n = ctrl.shape[0] - 1, ctrl.shape[1] - 1
    wi = (np.arange(m, -1, -1) if corner[0] == 0 else np.arange(m + 1)) / m
    wj = (np.arange(n, -1, -1) if corner[1] == 0 else np.arange(n + 1)) / n
    out = ctrl + delta * wi[:, None, None] * wj[None, :, None]
    out[corner] = to
    return out


def _with_side(ctrl: np.ndarray, name: str, row: np.ndarray, max_degree: int) -> np.ndarray | None:
    """The net with one side replaced by ``row`` at a common degree (the net elevated along the
    side where the row's degree is higher); None past ``max_degree``."""
    index, axis = _SIDES[name]
    have, need = ctrl.shape[axis] - 1, len(row) - 1
    if need > max_degree:
        return None
    if need > have:
        ctrl = elevate_surface(ctrl, need - have, 0) if axis == 0 else elevate_surface(ctrl, 0, need - have)
    elif have > need:
        row = elevate_curve(row, have - need)
    out = ctrl.copy()
    out[index] = row
    return out


def _lens(ctrl: np.ndarray, eps: float, width: float):
    """For a polynomial net with one collapsed side that lies within ``width`` of the side facing
    it: (A, bottom A -> B, top A -> C, rung B -> C, its largest distance from the rung); else None."""
    k = collapsed_side(ctrl, eps)
    if k is None:
        return None
    P = np.rot90(ctrl, k)
    bottom, rung, top = P[:, 0], P[-1, :], P[:, -1]
    g = np.linspace(0.0, 1.0, _GRID)
    pts = surface_eval_grid(np.ascontiguousarray(P), g, g).reshape(-1, 3)
    far = float(project(_cart(rung), pts)[1].max())
    if far > width:
        return None
    return P[0, 0].copy(), bottom, top, rung, far


def collapse_lenses(nets: list[tuple[np.ndarray, bool]], eps: float, width: float,
                    max_degree: int = 25, exact: float = 0.0) -> Collapsed:
    """Take thin lenses out of ``nets`` (the patches of one shell or solid, ``(ctrl, rational)``;
    see the module docstring). ``eps``: the joining distance (corners this close are one vertex);
    ``width``: the largest distance a lens may have from its rung, and any patch may move;
    ``exact``: how close one row through both of a lens's sides must come to them (0: never
    tried, every lens is cut out)."""
    nets = [(np.asarray(c, dtype=float), r) for c, r in nets]
    out = Collapsed(nets=list(nets))
    cands = [k for k, (c, r) in enumerate(nets) if not r and collapsed_side(c, eps) is not None]
    for k in cands:
        if out.nets[k] is None:
            continue
        found = _lens(out.nets[k][0], eps, width)
        if found is not None and not _collapse(out, k, found, eps, width, max_degree, exact):
            out.left += 1
    return out


#: the corners of the two halves at the split point, per side of the rung's patch
_AT_SPLIT = {"left": ((0, -1), (0, 0)), "right": ((-1, -1), (-1, 0)),
             "bottom": ((-1, 0), (0, 0)), "top": ((-1, -1), (0, -1))}


def _collapse(out: Collapsed, k: int, found, eps: float, width: float, max_degree: int,
              exact: float) -> bool:
    A, bottom, top, rung, far = found
    part = _Index(out.nets, eps).partners(rung, k)
    if len(part) != 1:
        return False
    q, name, rev = part[0]
    ctrl, rational = out.nets[q]
    if rational or collapsed_side(ctrl, eps) is not None:
        return False
    joined = _joined(bottom[::-1], top, exact, max_degree) if exact > 0.0 else None
    if joined is not None:
        whole = _with_side(ctrl, name, joined[::-1] if rev else joined, max_degree)
        move = _change(ctrl, whole) if whole is not None else np.inf
        if move <= width:
            out.nets[q] = (whole, False)
            out.moved[q] = out.moved.get(q, 0.0) + move
            _dropped(out, k, far)
            return True
    tau = float(project(_cart(rung), A[None])[0][0])
    foot = curve_eval(rung, np.array([tau]))[0]
    if min(np.linalg.norm(foot - rung[0]), np.linalg.norm(foot - rung[-1])) <= _PIECE * far:
        return False
    axis = _SIDES[name][1]
    split = surface_split_u if axis == 0 else surface_split_v
    halves = list(split(ctrl, 1.0 - tau if rev else tau))
    # the rung's patch runs its side B -> C (or C -> B): its first half then takes the lens's side
    # B -> A (C -> A), its second A -> C (A -> B), each the lens's own row
    rows = (top[::-1], bottom) if rev else (bottom[::-1], top)
    made = []
    for half, corner, row in zip(halves, _AT_SPLIT[name], rows, strict=True):
        moved = _displaced(half, corner, A - half[corner], A)
        moved = _with_side(moved, name, row, max_degree)
        if moved is None:
            return False
        made.append((moved, _change(half, moved)))
    if max(m for _, m in made) > width:
        return False
    out.nets[q] = (made[0][0], False)
    out.nets.append((made[1][0], False))
    out.parent[len(out.nets) - 1] = q
    out.moved[q] = out.moved.get(q, 0.0) + max(m for _, m in made)
    out.cut += 1
    _dropped(out, k, far)
    return True


def _dropped(out: Collapsed, k: int, far: float) -> None:
    out.nets[k] = None
    out.moved[k] = max(out.moved.get(k, 0.0), far)
    out.collapsed += 1
    out.width_max = max(out.width_max, far)


#: samples per piece of ``_joined``'s fit, per control point of the higher piece
_JOIN_SAMPLES = 4


def _joined(first: np.ndarray, second: np.ndarray, exact: float, max_degree: int) -> np.ndarray | None:
    """One Bezier row through ``first`` (B -> A) and then ``second`` (A -> C) when the two are
    pieces of one polynomial (a lens's two sides are pieces of its edge's one curve unless a knot
    of it lies at A): the lowest degree, up to the pieces' own (a piece of a polynomial has its
    degree) and ``max_degree``, whose least-squares fit comes within ``exact`` of both, on the fit's
    samples and between them; its ends B and C exactly. None when none does. The pieces'
    parameter lengths are in the ratio of their speeds at A, where one polynomial runs on at one
    speed."""
    v1 = (len(first) - 1) * (first[-1] - first[-2])
    v2 = (len(second) - 1) * (second[1] - second[0])
    n1, n2 = float(np.linalg.norm(v1)), float(np.linalg.norm(v2))
    if n1 == 0.0 or n2 == 0.0 or float(v1 @ v2) < (1.0 - 1e-9) * n1 * n2:
        return None
    lam = n1 / (n1 + n2)
    top = min(max(len(first), len(second)) - 1, max_degree)
    s = np.linspace(0.0, 1.0, _JOIN_SAMPLES * (top + 1))
    mid = 0.5 * (s[:-1] + s[1:])

    def along(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.concatenate([lam * x, lam + (1.0 - lam) * x])
        return t, np.concatenate([curve_eval(first, x), curve_eval(second, x)])

    (t, pts), (tc, check) = along(s), along(mid)
    for d in range(1, top + 1):
        B = basis(d, t)
        row = np.linalg.lstsq(B, pts, rcond=None)[0]
        row[0], row[-1] = first[0], second[-1]
        if max(float(np.linalg.norm(B @ row - pts, axis=1).max()),
               float(np.linalg.norm(basis(d, tc) @ row - check, axis=1).max())) <= exact:
            return row
    return None
