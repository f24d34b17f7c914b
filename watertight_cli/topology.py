"""The output B-rep's topology, worked out from the patches themselves (arrays in, arrays out).

After stage 2, two patches that touch have the same boundary curve: the same control points, or
a piece of it where a T-vertex splits the longer side. This module finds that structure directly:

- **vertices**: the patch corners, clustered within ``eps`` (one vertex per corner point);
- **T-vertices**: vertices that lie on the inside of a patch side (within ``eps``), found with a
  k-d tree over the vertices and a projection onto the side's Bezier curve;
- **segments**: every side cut at its T-vertices; a segment runs between two vertices;
- **edges**: segments with the same two end vertices whose curves coincide (the midpoint of one
  lies on the other within ``eps``) are one edge. The first is the edge's *owner*: the edge's 3D
  curve is the owner's side, restricted to the segment's parameter range.

Each other member of an edge gets a parameter map from the edge's parameter t (the owner's side
parameter) to its own side parameter s. Bezier subdivision keeps the parameter affine, so the map
is usually ``s = s0 + (t - t0) (s1 - s0) / (t1 - t0)`` and the member's pcurve is a straight
segment on the side of [0, 1]^2 that is exactly same-parameter. A rational side whose weights were
changed by a Moebius transformation (``substitute._put``) runs along the same curve at another
speed; its map is then the rational linear (Moebius) one, still a straight segment, fitted
through the midpoint. The deviation that remains is measured and returned, so the builder can
give the edge an honest tolerance.

A side whose control points all coincide (a pole, a collapsed rung), or stay within the joining
tolerance, is *degenerate*: it keeps one vertex and no 3D curve.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .core.bernstein import binom_table
from .core.bezier import elevation_matrix

#: the four sides of a patch net as (row of the net, corner at s = 0, corner at s = 1); the side
#: parameter runs along the net's axis 0 for bottom/top and axis 1 for left/right
SIDE_ROWS = {
    "bottom": ((slice(None), 0), (0, 0), (1, 0)),
    "right": ((-1, slice(None)), (1, 0), (1, 1)),
    "top": ((slice(None), -1), (0, 1), (1, 1)),
    "left": ((0, slice(None)), (0, 0), (0, 1)),
}
SIDE_NAMES = tuple(SIDE_ROWS)
#: joining tolerance relative to the diagonal: corners this close are one vertex (shared boundaries
#: coincide to rounding, and no patch side is shorter than a sliver, 1e-8 x diagonal,
#: ``Tolerances.sliver_rel``); stage 2 makes such corners one point (``substitute``)
JOIN_REL = 1e-9
_CORNERS = ((0, 0), (1, 0), (1, 1), (0, 1))
_COLLAPSED_REL = 1e-12  # a side whose control points stay this close (x patch size) is one point
_MERGE = 4.0  # a vertex this close to a side's end (x eps) is that end
#: corners this close (x diagonal) end up as one vertex: within JOIN_REL directly, or as a vertex on
#: a side within _MERGE x JOIN_REL of its end; stage 2 clusters corners at this distance
MERGE_REL = _MERGE * JOIN_REL
_NEEDLE = 1000.0  # a patch closed on its own and within this x eps is a needle (``stray_needles``)
_CLEAR_SAMPLES = 16  # sample steps per edge for ``clearance_points`` (the checker looks up 15 per edge)
_CLEAR_NEAREST = 8  # nearest samples among which ``clearance_points`` looks for another edge's
_MAP_DEGREE = 5  # degree of spline parameter maps
_MAP_REL = 1e-4  # a parameter map is refined while it leaves more than this x eps (I2 asks 1e-3 eps)
_CHECK = np.array([0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875])  # where parameter maps are measured


@dataclass
class Member:
    """One patch side's use of an edge: the edge's parameter a in [0, 1] (a = (t - t0) / (t1 - t0)
    on the owner's side parameter t) maps to this side's parameter
    s(a) = ((1 - a) s0 + a w s1) / ((1 - a) + a w); w = 1 is affine."""

    patch: int
    side: str
    s0: float
    s1: float
    w: float = 1.0
    deviation: float = 0.0  # max distance between the owner's curve and this side at mapped parameters
    smap: tuple | None = None  # when set: s(a) as a B-spline (knots, coefficients) instead


@dataclass
class TopoEdge:
    va: int
    vb: int
    t0: float
    t1: float
    members: list[Member]  # members[0] is the owner (s0 = t0, s1 = t1)
    degenerate: bool = False

    @property
    def owner(self) -> Member:
        return self.members[0]


@dataclass
class Topology:
    vertices: np.ndarray  # (V, 3)
    vertex_tolerance: np.ndarray  # (V,) largest distance from a vertex to a corner or curve end it stands for
    edges: list[TopoEdge]
    # per patch, per side name: the side's edges in increasing side parameter, as (edge, member index)
    wires: list[dict[str, list[tuple[int, int]]]] = field(default_factory=list)
    # side pieces added by ``split`` (a vertex put inside an edge splits the side of every member):
    # no T-vertices, as every face on the edge has the vertex
    split_pieces: int = 0
    # vertices taken out of a side near a tangential corner (``unspike``)
    unspiked: int = 0
    # vertices put into edges that ran too long for their clearance (``clearance_points``)
    cleared: int = 0

    @property
    def free_edges(self) -> int:
        return sum(1 for e in self.edges if not e.degenerate and len(e.members) == 1)

    @property
    def t_vertices(self) -> int:
        return sum(max(0, len(segs) - 1) for w in self.wires for segs in w.values()) - self.split_pieces

    def components(self) -> list[list[int]]:
        """Patches connected through shared edges, each list in increasing patch order."""
        n = len(self.wires)
        rows, cols = [], []
        for e in self.edges:
            first = e.members[0].patch
            for m in e.members[1:]:
                rows.append(first)
                cols.append(m.patch)
        graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        count, labels = connected_components(graph, directed=False)
        out: list[list[int]] = [[] for _ in range(count)]
        for i, lab in enumerate(labels):
            out[lab].append(i)
        return out


# ------------------------------------------------------------------------------ curves of the sides


def side_row(ctrl: np.ndarray, rational: bool, side: str) -> np.ndarray:
    """(n+1, 4) homogeneous control points of one side (weights 1 for a polynomial patch)."""
    row = np.asarray(ctrl[SIDE_ROWS[side][0]], dtype=float)
    if not rational:
        row = np.concatenate([row, np.ones((len(row), 1))], axis=1)
    return row


def _basis(n: int, s: np.ndarray) -> np.ndarray:
    """Bernstein basis C(n, k) s^k (1 - s)^(n - k) at s in [0, 1], by powers: one vectorized
    expression instead of ``basis``'s recurrence, which dominated the projections (low degrees,
    few points, many calls); the terms are all positive, so there is no cancellation."""
    if n < 0:
        return np.zeros((len(s), 0))
    k = np.arange(n + 1)
    s = s[:, None]
    return binom_table(n)[n] * s ** k * (1.0 - s) ** (n - k)


def _evaluate(row: np.ndarray, s: np.ndarray) -> np.ndarray:
    h = _basis(len(row) - 1, np.clip(s, 0.0, 1.0)) @ row
    return h[:, :3] / h[:, 3:4]


def _bases3(n: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_basis`` of degrees n, n - 1 and n - 2 at s from one table of powers (the same values to
    the bit: the powers were two thirds of the Newton steps of ``project``)."""
    k = np.arange(n + 1)
    s = s[:, None]
    ps, pc = s ** k, (1.0 - s) ** k
    out = []
    for j in (n, n - 1, n - 2):
        out.append(binom_table(j)[j] * ps[:, :j + 1] * pc[:, j::-1] if j >= 0 else np.zeros((len(s), 0)))
    return out[0], out[1], out[2]


def _derivatives(row: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """C, C', C'' of a homogeneous row at s (quotient rule on the homogeneous derivatives)."""
    n = len(row) - 1
    b0, b1, b2 = _bases3(n, s)
    h = b0 @ row
    d1 = b1 @ (n * np.diff(row, axis=0)) if n >= 1 else np.zeros_like(h)
    d2 = b2 @ (n * (n - 1) * np.diff(row, 2, axis=0)) if n >= 2 else np.zeros_like(h)
    w, w1, w2 = h[:, 3:4], d1[:, 3:4], d2[:, 3:4]
    c = h[:, :3] / w
    c1 = (d1[:, :3] - c * w1) / w
    c2 = (d2[:, :3] - 2.0 * c1 * w1 - c * w2) / w
    return c, c1, c2


def project(row: np.ndarray, pts: np.ndarray, lo: float = 0.0, hi: float = 1.0,
            within: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closest parameters in [lo, hi] of the side curve ``row`` to the points (k, 3), and the
    distances: nearest of a dense sampling, then Newton on C'(s).(C(s) - p) = 0. With ``within``,
    points farther than that from the curve may come back unrefined (distance from the sampling,
    which is then larger than ``within`` too)."""
    pts = np.atleast_2d(pts)
    n = len(row) - 1
    grid = np.linspace(lo, hi, max(33, 4 * n + 1))
    samples = _evaluate(row, grid)
    d = np.linalg.norm(samples[None, :, :] - pts[:, None, :], axis=2)
    nearest = np.argmin(d, axis=1)
    s = grid[nearest]
    if within is not None:
        # a point within ``within`` of the curve is within that plus half the largest sample
        # spacing of a sample
        gap = float(np.linalg.norm(np.diff(samples, axis=0), axis=1).max()) if len(samples) > 1 else 0.0
        dmin = d[np.arange(len(pts)), nearest]
        far = dmin > within + gap
        if far.any():
            out_s, out_d = s.copy(), dmin.copy()
            if (~far).any():
                out_s[~far], out_d[~far] = project(row, pts[~far], lo, hi)
            return out_s, out_d
    for _ in range(12):
        c, c1, c2 = _derivatives(row, s)
        r = c - pts
        f = np.einsum("ij,ij->i", c1, r)
        df = np.einsum("ij,ij->i", c2, r) + np.einsum("ij,ij->i", c1, c1)
        step = np.where(df > 0, f / np.where(df > 0, df, 1.0), 0.0)
        s_new = np.clip(s - step, lo, hi)
        if np.all(np.abs(s_new - s) <= 1e-14):
            s = s_new
            break
        s = s_new
    dist = np.linalg.norm(_evaluate(row, s) - pts, axis=1)
    return s, dist


def _moebius(a: np.ndarray, s0: float, s1: float, w: float) -> np.ndarray:
    return ((1.0 - a) * s0 + a * w * s1) / ((1.0 - a) + a * w)


# ---------------------------------------------------------------------------------------- topology


def flat(ctrl: np.ndarray, rational: bool, eps: float) -> bool:
    """A patch with no area: every row (or every column) of its net is one point within ``eps``,
    so the patch is a curve (stage 1 can leave such a cell between two slab lines that meet)."""
    xyz = ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl
    return bool(np.linalg.norm(xyz - xyz[:, :1], axis=-1).max() <= eps
                or np.linalg.norm(xyz - xyz[:1, :], axis=-1).max() <= eps)


def needle(ctrl: np.ndarray, rational: bool, eps: float) -> bool:
    """A tiny patch (within _NEEDLE x eps) that is a curve: every sampled point lies within ``eps``
    of its longest side. Such a patch encloses nothing, and its neighbours pair across it
    directly. Stage 2 makes them where a side along a degenerate edge collapses onto its vertex
    beside a rung that is collapsed already (gmsh__U_Joint_2.stp: 8 patches whose other two sides
    run 1.4e-11 apart, 3.6e-6 long; written, the STEP reader rebuilt their pcurves and read them
    back trimmed)."""
    xyz = ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl
    if float(np.ptp(xyz.reshape(-1, 3), axis=0).max()) > _NEEDLE * eps:
        return False
    rows = [side_row(ctrl, rational, n) for n in SIDE_NAMES]
    lengths = [float(np.linalg.norm(np.diff(_evaluate(r, np.linspace(0.0, 1.0, 9)), axis=0), axis=1).sum())
               for r in rows]
    _, d = project(rows[int(np.argmax(lengths))], _grid_points(ctrl, rational, 9))
    return bool(d.max() <= eps)


def _grid_points(ctrl: np.ndarray, rational: bool, n: int) -> np.ndarray:
    """(n * n, 3) points of the patch on an n x n grid of [0, 1]^2."""
    g = np.linspace(0.0, 1.0, n)
    C = ctrl if rational else np.concatenate([ctrl, np.ones(ctrl.shape[:2] + (1,))], axis=-1)
    m1, n1 = C.shape[:2]
    h = _basis(n1 - 1, g)[None] @ (_basis(m1 - 1, g) @ C.reshape(m1, -1)).reshape(-1, n1, 4)
    return (h[..., :3] / h[..., 3:4]).reshape(-1, 3)


def _collapsed(ctrl: np.ndarray, rational: bool, eps: float) -> np.ndarray | None:
    """Per side in the loop's order (``SIDE_NAMES``: side k runs from corner k to corner k + 1 of
    (0,0), (1,0), (1,1), (0,1)), whether it is one point within ``eps``; None when fewer than two
    are (the corners alone decide that for most patches)."""
    xyz = ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl
    c = xyz[[0, -1, -1, 0], [0, 0, -1, -1]]
    close = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1) <= eps
    if int(close.sum()) < 2:
        return None
    g = np.linspace(0.0, 1.0, 17)
    for k in np.flatnonzero(close):
        pts = _evaluate(side_row(ctrl, rational, SIDE_NAMES[k]), g)
        close[k] = np.linalg.norm(pts - pts[0], axis=1).max() <= eps
    return close if int(close.sum()) >= 2 else None


def folded(ctrl: np.ndarray, rational: bool, eps: float, width: float) -> float | None:
    """A patch whose boundary runs along one curve and back: two of its sides collapse onto points
    (within ``eps``) and the other two are one curve, run in the two directions around the patch
    (each within ``eps`` of the other), while no point of the patch is farther than ``width`` from
    it. Returns that largest distance, or None for any other patch. Such a patch is a fold that
    encloses nothing: its two live sides pair with the neighbours across it in the same
    direction, which BRepCheck rejects (bad orientation in the solid), and the STEP reader rebuilds
    the pcurves of one with two adjacent collapsed sides (read back trimmed, with 0.009 edge
    tolerances). Dropped, its neighbours pair directly. Stage 2 makes them where a sliver cell
    between two slab lines that both lie along one edge gets that edge's curve on both rungs
    (gmsh__wing_fuselage.step face 9: 1e-5 wide, 0.35 long), and where both live sides of a cell
    take one curve (the wing at vertex 11, beside its 0.036 long edge 23). A full turn of a
    surface of revolution between two poles has the same boundary but is far from it, and is
    kept."""
    dead = _collapsed(ctrl, rational, eps)
    if dead is None or int(dead.sum()) != 2:
        return None
    a, b = (side_row(ctrl, rational, SIDE_NAMES[k]) for k in np.flatnonzero(~dead))
    g = np.linspace(0.0, 1.0, 17)
    if project(a, _evaluate(b, g))[1].max() > eps or project(b, _evaluate(a, g))[1].max() > eps:
        return None
    far = float(project(a, _grid_points(ctrl, rational, 9))[1].max())
    return far if far <= width else None


def lens(ctrl: np.ndarray, rational: bool, eps: float, width: float) -> tuple[np.ndarray, bool, float] | None:
    """A thin two-sided patch with three corners at one point A (two adjacent sides collapsed) and
    its two live sides running from A to the fourth corner C, within ``width`` of each other and
    of every point of the patch, made again as the ruled patch between those two sides: its other
    two sides collapse onto A and C (opposite sides, as at the two poles of a sphere). The live
    sides are the same curves, the loop runs the same way, and the new patch stays within the
    returned distance (the largest of the two measures) of the old one's boundary curve. Returns
    (ctrl, rational, distance), or None for any other patch. Stage 2 makes such a patch in a cusp
    of a face, where two of its edges run together to a vertex (gmsh__wing_fuselage.step face 9,
    edges 28 and 29: 1.1e-6 apart over 0.036); written as it was, the STEP reader rebuilt its
    pcurves (read back trimmed, with 0.009 edge tolerances)."""
    dead = _collapsed(ctrl, rational, eps)
    if dead is None or int(dead.sum()) != 2:
        return None
    k = next((k for k in range(4) if dead[k] and dead[(k + 1) % 4]), None)
    if k is None:
        return None
    odd = (k + 3) % 4  # the corner C the two live sides meet at, opposite the shared corner k + 1

    def along(side: int, into_c: bool) -> np.ndarray:
        """The live side as a row from A to C (bottom and right run forward in the loop)."""
        row = side_row(ctrl, rational, SIDE_NAMES[side])
        return row if (side in (0, 1)) == into_c else row[::-1]

    first = along((odd + 3) % 4, True)  # the side into C, run A -> C in the loop
    second = along(odd, False)  # the side out of C, which the loop runs C -> A
    n = max(len(first), len(second)) - 1
    first, second = (elevation_matrix(len(r) - 1, n - len(r) + 1) @ r for r in (first, second))
    g = np.linspace(0.0, 1.0, 17)
    far = max(float(project(first, _evaluate(second, g))[1].max()),
              float(project(first, _grid_points(ctrl, rational, 9))[1].max()))
    if far > width:
        return None
    # left (s = 0) is the second side and right (s = 1) the first: the loop then runs A -> C on
    # the right and back on the left, as the old one ran A -> C on the first and back on the second
    H = np.stack([second, first])
    return (H if rational else np.ascontiguousarray(H[..., :3])), rational, far


def stray_needles(topo: Topology, nets: list[tuple[np.ndarray, bool]], eps: float) -> set[int]:
    """Patches that make a closed part on their own and are tiny (within ``_NEEDLE`` x eps): two of
    their sides pair with each other, so they enclose nothing. Left in, each became a shell of its
    own inside the solid and BRepCheck found the solid invalid (gmsh__U_Joint_2.stp: 8 such
    patches, 2e-5 long, where five edges meet within 3e-5)."""
    out = set()
    for part in topo.components():
        if len(part) != 1:
            continue
        i = part[0]
        closed = all(len(topo.edges[e].members) >= 2 or topo.edges[e].degenerate
                     for segs in topo.wires[i].values() for e, _ in segs)
        c, r = nets[i]
        xyz = (c[..., :3] / c[..., 3:4] if r else c).reshape(-1, 3)
        if closed and float(np.ptp(xyz, axis=0).max()) <= _NEEDLE * eps:
            out.add(i)
    return out


def connect(nets: list[tuple[np.ndarray, bool]], eps: float, extra: np.ndarray | None = None) -> Topology:
    """The topology of patches (``(ctrl, rational)`` each) whose shared boundaries coincide within
    ``eps`` (model units). See the module docstring. ``extra`` (k, 3): points that become vertices
    inside the edges they lie on within ``eps`` (``split``).

    A patch whose wire still passes one vertex twice (a cusp corner: the vertex lies on both sides
    that meet there, and the faces around it form one fan, so ``_unpinch`` cannot split it) is no
    valid face: the vertex then stays off one of the two sides (its later side in the wire), which
    leaves that piece unpaired (free) instead, and the topology is worked out again."""
    drop: set[tuple[int, str, int]] = set()
    state: dict = {}
    for _ in range(4):
        topo = _connect(nets, eps, drop, state)
        more = _pinches(topo) - drop
        if not more:
            break
        drop |= more
    first_split = len(topo.vertices)
    if extra is not None and len(extra) and state:
        split(topo, state["rows"], np.asarray(extra, dtype=float).reshape(-1, 3), eps)
    topo.unspiked = unspike(topo, eps, first_split)
    return topo


def clear(topo: Topology, nets: list[tuple[np.ndarray, bool]], eps: float, ratio: float, near: float) -> int:
    """Put ``clearance_points`` into the edges of ``connect``'s topology of ``nets`` (``split``),
    in place, and return how many vertices went in (also ``topo.cleared``). Once, on the topology
    that is built: the pieces change no pairing, so nothing decided on an earlier one depends on
    them."""
    rows = [{name: side_row(c, r, name) for name in SIDE_NAMES} for c, r in nets]
    pts = clearance_points(topo, rows, ratio, near)
    topo.cleared = split(topo, rows, pts, eps) if len(pts) else 0
    return topo.cleared


def clearance_points(topo: Topology, rows, ratio: float, near: float) -> np.ndarray:
    """Points (k, 3) on the edges that split each into pieces no longer than ``ratio`` times their
    clearance: the distance from the piece to the nearest other edge. A check that samples every
    edge a fixed number of times (the independent one: 15 points it looks up, 272 it looks among)
    takes, for a point of one face's boundary, the curve of the nearest sample of another face; the
    partner's samples along a shared edge lie up to half their spacing from the point, so another
    face's boundary nearer than that wins, and the point counts as unmatched (free) when that
    boundary is more than its threshold away. ``stage2._split_slender`` keeps the long sides of
    strips short for their width before the topology exists; what it cannot see is a third face
    beyond a neighbour (fusee face 1703, a wedge 16.6 long and up to 2.3e-3 wide, narrower at its
    tip than a strip is measured (a sliver), whose neighbour 1704 shared one edge 16.6 long with
    it: 842 of fusee's samples unmatched), and a boundary that runs near an edge without sharing
    its patch.

    Each edge is sampled ``_CLEAR_SAMPLES`` + 1 times on its owner's side; a sample's clearance is
    its distance to the polyline of the nearest sample of another edge that shares no vertex with
    it (one that does meets it at a corner, where splitting cannot help), looked up among its
    ``_CLEAR_NEAREST`` nearest samples (none of another edge among them: farther than a quarter of
    the edge, never too near). Samples whose clearance is below ``near`` set no limit: a boundary
    that close counts as the same one for any check at that resolution, and splitting for it would
    put vertices down to the mesh's weld (tried at the checker's 1e-9 of the diagonal on
    sphere_cut_box: 2072 vertices, and its mesh no longer closed). Edges that are not longer than
    ``ratio`` x ``near`` never need a split; they are only looked up among. Such a check samples
    evenly in the edge's parameter, so the piece a sample allows is measured in parameter:
    ``ratio`` x clearance over the curve's speed there (a curve that runs slowly into a corner is
    sampled densely there already). A piece ends at a sample, so a piece is never shorter than a
    sample step (a tangential corner, whose clearance falls to nothing at the vertex, gets pieces
    growing away from it). No vertex goes within ``near`` of another edge (``_apart``) or on a
    side of a patch with a collapsed side. Degenerate edges and edges with a spline parameter map
    are left out (``split`` leaves the latter whole)."""
    n = _CLEAR_SAMPLES
    live = [i for i, e in enumerate(topo.edges)
            if not e.degenerate and all(m.smap is None for m in e.members)]
    if not live:
        return np.zeros((0, 3))
    a = np.linspace(0.0, 1.0, n + 1)
    X = np.empty((len(live), n + 1, 3))
    for q, i in enumerate(live):
        e = topo.edges[i]
        o = e.owner
        X[q] = _evaluate(rows[o.patch][o.side], e.t0 + a * (e.t1 - e.t0))
    length = np.concatenate([np.zeros((len(live), 1)),
                             np.cumsum(np.linalg.norm(np.diff(X, axis=1), axis=2), axis=1)], axis=1)
    long_ = np.flatnonzero(length[:, -1] > ratio * near)
    if not len(long_):
        return np.zeros((0, 3))
    pts = X.reshape(-1, 3)
    label = np.repeat(np.arange(len(live)), n + 1)
    at = np.tile(np.arange(n + 1), len(live))
    asked = (long_[:, None] * (n + 1) + np.arange(1, n)).ravel()  # the inner samples of long edges
    k = min(_CLEAR_NEAREST, len(pts))
    d, nb = cKDTree(pts).query(pts[asked], k=k)
    d, nb = d.reshape(len(asked), k), nb.reshape(len(asked), k)
    # an edge that shares a vertex with this one meets it there: near a corner no split helps (a
    # piece there has its samples as near the corner, for its length, as the whole edge had), and
    # near a tangential one it harms: the first piece puts all its samples where the edges run
    # within the partner's sample spacing of each other (sphere_cut_box: 2 -> 66 unmatched)
    ends = np.array([(topo.edges[i].va, topo.edges[i].vb) for i in live])
    mine, theirs = ends[label[asked]][:, None, :], ends[label[nb]]
    other = (label[nb] != label[asked][:, None]) & ~(
        (theirs[..., :1] == mine) | (theirs[..., 1:] == mine)).any(axis=2)
    first = np.argmax(other, axis=1)
    rows_ = np.arange(len(asked))
    j, p = nb[rows_, first], pts[asked]
    clear = d[rows_, first]
    for step in (-1, 1):  # the segments on either side of that sample
        ok = (at[j] + step >= 0) & (at[j] + step <= n)
        A, B = pts[j], pts[np.clip(j + step, 0, len(pts) - 1)]
        AB = B - A
        s = np.einsum("ij,ij->i", p - A, AB) / np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
        s = np.clip(s, 0.0, 1.0)
        clear = np.where(ok, np.minimum(clear, np.linalg.norm(A + s[:, None] * AB - p, axis=1)), clear)
    clear = np.where(other.any(axis=1) & (clear >= near), clear, np.inf).reshape(len(long_), n - 1)
    # a check samples the edge evenly in its parameter, so its spacing at a sample is the curve's
    # speed there times the piece's parameter span: the span a piece may have, per sample
    speed = np.linalg.norm(X[long_, 2:] - X[long_, :-2], axis=2) * (0.5 * n)
    allowed = np.full((len(long_), n + 1), np.inf)
    allowed[:, 1:n] = ratio * clear / np.maximum(speed, 1e-300)
    # no vertex goes on a side of a patch with a collapsed side (a triangle, kept or remade): the
    # same rule as ``stage2._split_slender``'s; a wedge of wing_fuselage whose two long sides run
    # within 1e-6 of each other over part of their length took five and its mesh four more edges
    # with three triangles
    pointed = {m.patch for e in topo.edges if e.degenerate for m in e.members}
    on_pointed = np.array([any(m.patch in pointed for m in topo.edges[live[q]].members) for q in long_],
                          dtype=bool)
    need = np.flatnonzero((allowed.min(axis=1) < 1.0) & ~on_pointed)
    if not len(need):
        return np.zeros((0, 3))
    # a vertex goes only where no other edge passes within ``near``: put into an edge a hair from
    # another (both sides of a sliver), it would become a vertex of both, and the mesher's
    # triangles between them would have two corners at one node
    free = _apart(X, X[long_[need], 1:n].reshape(-1, 3), np.repeat(long_[need], n - 1), near)
    free = free.reshape(len(need), n - 1)
    out = []
    for q, fr in zip(need, free, strict=True):
        lim = allowed[q]
        cut_ok = np.concatenate([[False], fr, [False]])
        i = 0
        while True:
            fits = a[i:] - a[i] <= np.minimum.accumulate(lim[i:])
            if fits.all():
                break
            j = i + max(int(np.argmin(fits)) - 1, 1)
            back = np.flatnonzero(cut_ok[i + 1:j + 1])
            ahead = np.flatnonzero(cut_ok[j + 1:])
            if len(back):
                i = i + 1 + int(back[-1])
            elif len(ahead):  # no vertex may go in this piece: the next place one may
                i = j + 1 + int(ahead[0])
            else:
                break
            out.append(X[long_[q], i])
    return np.array(out).reshape(-1, 3)


def _apart(X: np.ndarray, pts: np.ndarray, own: np.ndarray, near: float) -> np.ndarray:
    """For points (k, 3) on the edges ``own`` (k,) of the sampled edges X (E, m, 3): True where no
    other edge's polyline passes within ``near``. Each segment lies within half its length of its
    midpoint, so segments are looked up by their midpoints, in groups of one length class (a
    radius of ``near`` plus the class's largest half length finds every one that can be near)."""
    a, b = X[:, :-1].reshape(-1, 3), X[:, 1:].reshape(-1, 3)
    label = np.repeat(np.arange(len(X)), X.shape[1] - 1)
    half = 0.5 * np.linalg.norm(b - a, axis=1)
    level = np.floor(np.log2(np.maximum(half, 1e-300))).astype(int)
    ok = np.ones(len(pts), dtype=bool)
    for lv in np.unique(level):
        sel = np.flatnonzero(level == lv)
        hits = cKDTree(0.5 * (a[sel] + b[sel])).query_ball_point(pts, near + 2.0 ** (lv + 1))
        counts = np.fromiter((len(h) for h in hits), dtype=int, count=len(hits))
        if not counts.sum():
            continue
        qi = np.repeat(np.arange(len(pts)), counts)
        si = sel[np.concatenate([np.asarray(h, dtype=int) for h in hits])]
        keep = label[si] != own[qi]
        qi, si = qi[keep], si[keep]
        A, AB, P = a[si], b[si] - a[si], pts[qi]
        t = np.einsum("ij,ij->i", P - A, AB) / np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
        d = np.linalg.norm(A + np.clip(t, 0.0, 1.0)[:, None] * AB - P, axis=1)
        ok[qi[d < near]] = False
    return ok


def unspike(topo: Topology, eps: float, first_split: int | None = None) -> int:
    """Take out, in place, the vertices that make a patch's wire run out along one curve and back
    along another within ``eps`` of it (a spike at a corner): where a side leaves a corner nearly
    tangent to the other side there (a hole's circle at its extreme point in u, and the slab line
    through it), a vertex of the curve's other face stands within ``eps`` of both sides near the
    corner and became a vertex of both (``_unpinch`` then gives each fan its own copy at one
    point). The wire then goes from that vertex to the corner along one side and back to a copy
    of it along the other: a piece of the face of no width, which the kernel's mesher fills with
    triangles whose corners meet (occt__trj8 face 2009: 0.00126 long, at the hole of radius 3.81
    whose circle stays within 1.5e-7 of the slab line there; gmsh__Block, gmsh__917_fusee). The
    vertex goes out of the side where nothing else needs it: it is the end of two edges with the
    same members, which become one edge (every member's map affine, as before). Vertices from
    ``first_split`` on were put in by ``split`` and stay. Returns how many vertices were taken
    out."""
    V = topo.vertices
    uses = np.zeros(len(V), dtype=int)
    for e in topo.edges:
        if not e.degenerate:
            uses[e.va] += 1
            uses[e.vb] += 1
    gone: set[int] = set()
    taken = 0
    for wire in topo.wires:
        seq = list(_walk(wire))
        for i in range(len(seq)):
            side_a, _, ea, ka = seq[i - 1]
            side_b, nb, eb, kb = seq[i]
            if side_a == side_b or nb != 0 or ea in gone or eb in gone:
                continue
            a, b = topo.edges[ea], topo.edges[eb]
            if a.degenerate or b.degenerate:
                continue
            far_a = a.va if forward(a.members[ka]) else a.vb
            far_b = b.vb if forward(b.members[kb]) else b.va
            if far_a == far_b or np.linalg.norm(V[far_a] - V[far_b]) > eps:
                continue
            # the spike's far end: out of side b (past it along b), else out of side a
            for v, e_id in ((far_b, eb), (far_a, ea)):
                if first_split is not None and v >= first_split:
                    continue
                if uses[v] == 2 and _merge_at(topo, v, e_id, gone):
                    taken += 1
                    break
    if gone:
        _drop_edges(topo, gone)
    return taken


def _merge_at(topo: Topology, v: int, e_id: int, gone: set[int]) -> bool:
    """Make edge ``e_id`` and the other edge at vertex ``v`` one edge, when both have the same
    owner and the same members, each with an affine map that runs on across ``v``."""
    e = topo.edges[e_id]
    other = [j for j, f in enumerate(topo.edges)
             if j != e_id and j not in gone and not f.degenerate and v in (f.va, f.vb)]
    if len(other) != 1:
        return False
    f_id = other[0]
    f = topo.edges[f_id]
    if e.vb == v and f.va == v:
        first, second = e, f
    elif f.vb == v and e.va == v:
        first, second = f, e
    else:
        return False
    o1, o2 = first.owner, second.owner
    if (o1.patch, o1.side) != (o2.patch, o2.side) or abs(first.t1 - second.t0) > 1e-12:
        return False
    if not (first.t1 > first.t0 and second.t1 > second.t0):
        return False
    pairs = []
    for m in first.members:
        n = [x for x in second.members if (x.patch, x.side) == (m.patch, m.side)]
        if len(n) != 1 or m.w != 1.0 or n[0].w != 1.0 or m.smap is not None or n[0].smap is not None:
            return False
        n = n[0]
        rate1 = (m.s1 - m.s0) / (first.t1 - first.t0)
        rate2 = (n.s1 - n.s0) / (second.t1 - second.t0)
        if abs(m.s1 - n.s0) > 1e-12 or abs(rate1 - rate2) > 1e-9 * max(abs(rate1), abs(rate2)):
            return False
        pairs.append((m, n))
    if len(second.members) != len(pairs):
        return False
    merged = TopoEdge(first.va, second.vb, first.t0, second.t1,
                      [Member(m.patch, m.side, m.s0, n.s1, 1.0, max(m.deviation, n.deviation))
                       for m, n in pairs])
    keep, drop = (e_id, f_id) if first is e else (f_id, e_id)
    at = []
    for m in merged.members:  # the two pieces stand side by side on every member's side
        ids = [x for x, _ in topo.wires[m.patch][m.side]]
        if keep not in ids or drop not in ids or abs(ids.index(keep) - ids.index(drop)) != 1:
            return False
        at.append(min(ids.index(keep), ids.index(drop)))
    for k, (m, i) in enumerate(zip(merged.members, at, strict=True)):
        topo.wires[m.patch][m.side][i:i + 2] = [(keep, k)]
    topo.edges[keep] = merged
    gone.add(drop)
    return True


def _drop_edges(topo: Topology, gone: set[int]) -> None:
    """Remove edges that no wire uses any more, renumbering the wires' references."""
    new_id, kept = {}, []
    for j, e in enumerate(topo.edges):
        if j not in gone:
            new_id[j] = len(kept)
            kept.append(e)
    topo.edges = kept
    for wire in topo.wires:
        for side, segs in wire.items():
            wire[side] = [(new_id[j], k) for j, k in segs]


def split(topo: Topology, rows, pts: np.ndarray, eps: float) -> int:
    """Put the points ``pts`` that lie inside an edge (within ``eps`` of its curve, farther than
    ``_MERGE`` x eps from its ends and from each other) into it as vertices, in place: the edge
    becomes one edge per piece, and every member's side takes the same pieces, so each face on the
    edge has every new vertex (no T-vertex). Edges with a spline parameter map (``Member.smap``)
    stay whole. Returns how many vertices were put in.

    Where stage 1 leaves a strip much longer than wide, its long sides are split so (``stage2``):
    a check that samples each edge a fixed number of times then samples the strip's sides, and
    its neighbours' sides, as densely as the strip is wide."""
    if not len(pts):
        return 0
    tree = cKDTree(pts)
    V, vtol = [topo.vertices], [topo.vertex_tolerance]
    nv = len(topo.vertices)
    added = 0
    for e_id in range(len(topo.edges)):
        e = topo.edges[e_id]
        if e.degenerate or any(m.smap is not None for m in e.members):
            continue
        o = e.owner
        orow = rows[o.patch][o.side]
        xyz = orow[:, :3] / orow[:, 3:4]
        lo, hi = xyz.min(axis=0) - eps, xyz.max(axis=0) + eps
        found = tree.query_ball_point(0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)))
        if not found:
            continue
        cand = pts[found]
        cand = cand[np.all((cand >= lo) & (cand <= hi), axis=1)]
        if not len(cand):
            continue
        t, d = project(orow, cand, e.t0, e.t1, within=eps)
        t = np.sort(t[d <= eps])
        if not len(t):
            continue
        ends = _evaluate(orow, np.array([e.t0, e.t1]))
        at = _evaluate(orow, t)
        keep, last = [], ends[0]
        for tk, pk in zip(t, at, strict=True):
            if np.linalg.norm(pk - last) > _MERGE * eps and np.linalg.norm(pk - ends[1]) > _MERGE * eps:
                keep.append(tk)
                last = pk
        if not keep:
            continue
        a = np.concatenate([[0.0], (np.array(keep) - e.t0) / (e.t1 - e.t0), [1.0]])
        a[0], a[-1] = 0.0, 1.0
        ids = [e.va, *range(nv, nv + len(keep)), e.vb]
        new = _evaluate(orow, np.array(keep))
        tol = np.zeros(len(keep))
        for m in e.members:
            r = rows[m.patch][m.side]
            off = _evaluate(r, _moebius(a[1:-1], m.s0, m.s1, m.w)) - new
            tol = np.maximum(tol, np.linalg.norm(off, axis=1))
        V.append(new)
        vtol.append(tol)
        nv += len(keep)
        added += len(keep)
        pieces = []
        for j in range(len(a) - 1):
            t0, t1 = e.t0 + a[j] * (e.t1 - e.t0), e.t0 + a[j + 1] * (e.t1 - e.t0)
            if j == len(a) - 2:
                t1 = e.t1
            members = []
            for m in e.members:
                s = _moebius(a[j:j + 2], m.s0, m.s1, m.w)
                s[0] = m.s0 if j == 0 else s[0]
                s[1] = m.s1 if j == len(a) - 2 else s[1]
                # the Moebius map restricted to [a_j, a_j+1] is one again: end weights
                # 1 + a (w - 1) at both ends, normalized to 1 at the start
                w = (1.0 + a[j + 1] * (m.w - 1.0)) / (1.0 + a[j] * (m.w - 1.0))
                members.append(Member(m.patch, m.side, float(s[0]), float(s[1]), float(w), m.deviation))
            pieces.append(TopoEdge(ids[j], ids[j + 1], float(t0), float(t1), members))
        piece_ids = [e_id, *range(len(topo.edges), len(topo.edges) + len(pieces) - 1)]
        topo.edges[e_id] = pieces[0]
        topo.edges.extend(pieces[1:])
        for k, m in enumerate(e.members):
            side = topo.wires[m.patch][m.side]
            at_k = side.index((e_id, k))
            order = piece_ids if m.s1 > m.s0 else piece_ids[::-1]
            side[at_k:at_k + 1] = [(p, k) for p in order]
            topo.split_pieces += len(pieces) - 1
    if added:
        topo.vertices = np.concatenate(V)
        topo.vertex_tolerance = np.concatenate(vtol)
    return added


def _pinches(topo: Topology) -> set[tuple[int, str, int]]:
    """(patch, side, vertex): T-cuts to leave out so that no wire passes a vertex twice."""
    out = set()
    for p, wire in enumerate(topo.wires):
        seen: dict[int, str] = {}
        for side, n, e_id, k in _walk(wire):
            e = topo.edges[e_id]
            if e.degenerate:
                continue
            v = e.va if forward(e.members[k]) else e.vb
            if v in seen and n > 0:  # a cut inside this side at a vertex the wire has passed
                out.add((p, side, v))
            elif v in seen and n == 0 and seen[v] != side:
                out.add((p, seen[v], v))
            seen[v] = side
    return out


def _connect(nets: list[tuple[np.ndarray, bool]], eps: float, drop: set, state: dict) -> Topology:
    """One pass of ``connect``. ``state`` keeps what does not depend on ``drop`` (vertices, the
    whole-side pairs, the open sides) from the first pass for the next ones."""
    P = len(nets)
    if P == 0:
        return Topology(np.zeros((0, 3)), np.zeros(0), [], [])
    if state:
        return _assemble(P, eps, drop, **state)
    corners = np.empty((P, 4, 3))
    collapsed = np.zeros((P, 4), dtype=bool)
    rows: list[dict[str, np.ndarray]] = []
    for i, (ctrl, rational) in enumerate(nets):
        xyz = ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl
        for k, (a, b) in enumerate(_CORNERS):
            corners[i, k] = xyz[-a if a else 0, -b if b else 0]
        scale = float(np.ptp(xyz.reshape(-1, 3), axis=0).max()) or 1.0
        r = {name: side_row(ctrl, rational, name) for name in SIDE_NAMES}
        rows.append(r)
        for k, name in enumerate(SIDE_NAMES):
            p = r[name][:, :3] / r[name][:, 3:4]
            # one point: to rounding, or within the joining tolerance (its two ends are then one
            # vertex, and a loop edge shorter than that pairs with nothing: bug33398 had 25 such
            # sides of 2e-10 where two shared curves end a hair apart at one corner)
            spread = float(np.max(np.linalg.norm(p - p[0], axis=1)))
            collapsed[i, k] = spread <= max(_COLLAPSED_REL * scale, eps)

    side_corners = {"bottom": (0, 1), "right": (1, 2), "top": (3, 2), "left": (0, 3)}
    live = [(i, name) for i in range(P) for k, name in enumerate(SIDE_NAMES) if not collapsed[i, k]]
    xyz_rows = [rows[i][n][:, :3] / rows[i][n][:, 3:4] for i, n in live]
    lo = np.array([r.min(axis=0) for r in xyz_rows]).reshape(-1, 3)
    hi = np.array([r.max(axis=0) for r in xyz_rows]).reshape(-1, 3)
    flat_corners = corners.reshape(-1, 3)
    pairs = cKDTree(flat_corners).query_pairs(eps, output_type="ndarray")
    # a vertex on a side within _MERGE x eps of the side's end is that end, not a T-vertex (the
    # piece between them would be shorter than anything stage 1 makes, and near a corner such a
    # vertex can lie on both sides, so both tiny pieces would join into one edge used twice);
    # merging can bring new vertices onto sides, so repeat until nothing merges
    # Sides are first paired whole (most are: stage 2 copies shared sides); only the sides left
    # open can hold T-vertices, and only the ends of open sides can be T-vertices (a short side
    # that ends at a T-vertex has no whole partner), so the search runs on those alone.
    where = {side: n for n, side in enumerate(live)}
    for _ in range(8):
        V, vtol, label = _vertices(flat_corners, pairs)
        cid = label.reshape(P, 4)
        ends = {(i, name): (int(cid[i, side_corners[name][0]]), int(cid[i, side_corners[name][1]]))
                for i, name in live}
        whole: dict[tuple[int, int], list[tuple]] = {}
        for i, name in live:
            va, vb = ends[(i, name)]
            whole.setdefault((min(va, vb), max(va, vb)), []).append((i, name, 0, 0.0, 1.0, va, vb))
        paired_whole, open_sides = [], []
        for segs in whole.values():
            for pair, member in _pairs(segs, rows, eps):
                if member is None:
                    open_sides.append(segs[pair[0]][:2])
                else:
                    paired_whole.append((segs[pair[0]], segs[pair[1]], member))
        rows_idx = [where[side] for side in open_sides]
        cand = np.array(sorted({v for side in open_sides for v in ends[side]}), dtype=int)
        vt = vtol.copy()
        cuts, merges = _t_vertices(V, vt, cand, ends, rows, open_sides, lo[rows_idx], hi[rows_idx], eps, drop)
        if not merges:
            break
        # merge the corners the two vertices stand for
        first = {int(v): n for n, v in enumerate(label)}
        extra = np.array([(first[a], first[b]) for a, b in merges])
        pairs = np.concatenate([pairs.reshape(-1, 2), extra])
    state.update(V=V, vtol=vtol, cid=cid, ends=ends, rows=rows, collapsed=collapsed,
                 side_corners=side_corners, paired_whole=paired_whole, open_sides=open_sides, cand=cand,
                 lo=lo[rows_idx], hi=hi[rows_idx], pair_cache={})
    return _assemble(P, eps, drop, **{**state, "vtol": vt}, cuts=cuts)


def _assemble(P, eps, drop, V, vtol, cid, ends, rows, collapsed, side_corners, paired_whole, open_sides,
              cand, lo, hi, pair_cache, cuts=None) -> Topology:
    """Edges and wires from the whole-side pairs and the open sides cut at their T-vertices
    (``cuts``, or worked out here with ``drop`` left out). Pairings of groups of pieces are kept
    in ``pair_cache``: a later pass changes only the groups beside the cuts it leaves out."""
    if cuts is None:
        vtol = vtol.copy()
        cuts, _ = _t_vertices(V, vtol, cand, ends, rows, open_sides, lo, hi, eps, drop)
    wires: list[dict[str, list]] = [dict() for _ in range(P)]
    edges: list[TopoEdge] = []
    for i in range(P):
        for k, name in enumerate(SIDE_NAMES):
            if collapsed[i, k]:
                v = int(cid[i, side_corners[name][0]])
                edges.append(TopoEdge(v, v, 0.0, 1.0, [Member(i, name, 0.0, 1.0)], degenerate=True))
                wires[i][name] = [(len(edges) - 1, 0)]
    for own, other, member in paired_whole:
        i, name, _, s0, s1, v0, v1 = own
        edges.append(TopoEdge(v0, v1, s0, s1, [Member(i, name, s0, s1), member]))
        wires[i][name] = [(len(edges) - 1, 0)]
        wires[other[0]][other[1]] = [(len(edges) - 1, 1)]
    # the open sides cut at their T-vertices, grouped by their two end vertices, paired again
    groups: dict[tuple[int, int], list[tuple]] = {}
    for i, name in open_sides:
        pts = cuts[(i, name)]
        wires[i][name] = [None] * (len(pts) - 1)
        for n, ((s0, v0), (s1, v1)) in enumerate(zip(pts[:-1], pts[1:], strict=True)):
            groups.setdefault((min(v0, v1), max(v0, v1)), []).append((i, name, n, s0, s1, v0, v1))
    for segs in groups.values():
        key = tuple(segs)
        if key not in pair_cache:
            pair_cache[key] = _pairs(segs, rows, eps)
        for pair, member in pair_cache[key]:
            i, name, n, s0, s1, v0, v1 = segs[pair[0]]
            edge = TopoEdge(v0, v1, s0, s1, [Member(i, name, s0, s1)])
            wires[i][name][n] = (len(edges), 0)
            if member is not None:
                j, jname, jn, *_ = segs[pair[1]]
                edge.members.append(member)
                wires[j][jname][jn] = (len(edges), 1)
            edges.append(edge)

    V, vtol = _unpinch(edges, wires, V, vtol)

    # vertex tolerances cover the curve ends the vertices stand for, and the whole of a side
    # collapsed onto one (within the joining tolerance)
    for e in edges:
        if e.degenerate:
            m = e.members[0]
            r = rows[m.patch][m.side]
            vtol[e.va] = max(vtol[e.va], float(np.linalg.norm(r[:, :3] / r[:, 3:4] - V[e.va], axis=1).max()))
            continue
        o = e.owner
        ends = _evaluate(rows[o.patch][o.side], np.array([e.t0, e.t1]))
        vtol[e.va] = max(vtol[e.va], float(np.linalg.norm(ends[0] - V[e.va])))
        vtol[e.vb] = max(vtol[e.vb], float(np.linalg.norm(ends[1] - V[e.vb])))
    return Topology(V, vtol, edges, wires)


_TRAVERSAL = {"bottom": 1.0, "right": 1.0, "top": -1.0, "left": -1.0}  # wire direction along s


def forward(m: Member) -> bool:
    """Whether the member's face wire runs along its edge's parameter (the edge is FORWARD there):
    the wire goes bottom, right (s increasing), top, left (s decreasing)."""
    if m.s1 == m.s0:
        return _TRAVERSAL[m.side] > 0
    return (m.s1 - m.s0) * _TRAVERSAL[m.side] > 0


def _walk(wire: dict[str, list]):
    """(side, index along the side, edge, member) of a patch's wire in the order it runs."""
    for side in ("bottom", "right", "top", "left"):
        segs = wire[side]
        order = range(len(segs)) if _TRAVERSAL[side] > 0 else range(len(segs) - 1, -1, -1)
        for n, i in enumerate(order):
            yield side, n, *segs[i]


def wire_order(wire: dict[str, list]) -> list[tuple[int, int]]:
    """(edge, member) of a patch's wire in the order it runs."""
    return [(e_id, k) for _, _, e_id, k in _walk(wire)]


def _unpinch(edges: list[TopoEdge], wires: list[dict], V: np.ndarray, vtol: np.ndarray):
    """One vertex per fan of faces. Near a cusp corner two sheets of patches can touch at one
    vertex (a patch's top and left run within eps of each other for a while, and the T-vertex
    where they part lies on both): the wire of that patch then passes the vertex twice, which is
    no valid face. The face corners at each vertex are grouped into fans (corners that share an
    edge there); every fan after the first gets its own vertex at the same point."""
    parent: dict[tuple[int, int], tuple[int, int]] = {}

    def find(x):
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for w in wires:
        chain = wire_order(w)
        for (e_in, k_in), (e_out, _) in zip(chain, chain[1:] + chain[:1], strict=True):
            ei = edges[e_in]
            v = ei.vb if forward(ei.members[k_in]) else ei.va
            a, b = find((v, e_in)), find((v, e_out))
            if a != b:
                parent[a] = b
    fans: dict[int, dict] = {}
    for v, e in list(parent):
        fans.setdefault(v, {}).setdefault(find((v, e)), []).append(e)
    extra = []
    for v, by_root in fans.items():
        if len(by_root) < 2:
            continue
        for group in list(by_root.values())[1:]:
            if any(edges[e].va == edges[e].vb and not edges[e].degenerate for e in group):
                continue  # a closed edge at v: leave the pinch
            clone = len(V) + len(extra)
            extra.append(v)
            for e in group:
                edge = edges[e]
                if edge.va == v:
                    edge.va = clone
                if edge.vb == v:
                    edge.vb = clone
    if extra:
        V = np.concatenate([V, V[extra]])
        vtol = np.concatenate([vtol, vtol[extra]])
    return V, vtol


def _vertices(flat: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices of the corner points joined by ``pairs`` (connected components): positions (the
    mean), tolerances (largest distance to a member) and the label of every corner."""
    n = len(flat)
    pairs = pairs.reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    nv, label = connected_components(graph, directed=False)
    counts = np.bincount(label, minlength=nv)
    V = np.zeros((nv, 3))
    np.add.at(V, label, flat)
    V /= counts[:, None]
    vtol = np.zeros(nv)
    np.maximum.at(vtol, label, np.linalg.norm(flat - V[label], axis=1))
    return V, vtol, label


def _t_vertices(V, vtol, cand_ids, ends, rows, sides, lo, hi, eps, drop=frozenset()):
    """Per side, its cut parameters with their vertices (ends included, sorted), and the vertex
    pairs to merge (a vertex on a side within ``_MERGE`` x eps of one of its ends). Only the
    vertices ``cand_ids`` are tried."""
    cuts: dict[tuple[int, str], list[tuple[float, int]]] = {}
    merges: list[tuple[int, int]] = []
    if not sides:
        return cuts, merges
    tree = cKDTree(V[cand_ids]) if len(cand_ids) else None
    centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=1) + eps
    near = tree.query_ball_point(centre, radius) if tree is not None else [[] for _ in sides]
    for (i, name), found, a, b in zip(sides, near, lo, hi, strict=True):
        va, vb = ends[(i, name)]
        pts = [(0.0, va), (1.0, vb)]
        cand = cand_ids[found] if len(found) else np.zeros(0, dtype=int)
        cand = cand[(cand != va) & (cand != vb)]
        if len(cand):
            cand = cand[np.all((V[cand] >= a - eps) & (V[cand] <= b + eps), axis=1)]
        if len(cand):
            s, dist = project(rows[i][name], V[cand], within=eps)
            for sv, dv, c in zip(s, dist, cand, strict=True):
                if dv > eps or (i, name, int(c)) in drop:
                    continue
                end = min((va, vb), key=lambda v: np.linalg.norm(V[v] - V[c]))
                if np.linalg.norm(V[end] - V[c]) <= _MERGE * eps or not 0.0 < sv < 1.0:
                    merges.append((int(c), end))
                    continue
                pts.append((float(sv), int(c)))
                vtol[c] = max(vtol[c], float(dv))
        cuts[(i, name)] = sorted(pts)
    return cuts, merges


def _seg_args(seg: tuple) -> tuple:
    i, name, _, s0, s1, v0, v1 = seg
    return i, name, s0, s1, v0, v1


def _pairs(segs: list[tuple], rows, eps: float) -> list[tuple[tuple[int, ...], Member | None]]:
    """Segments between the same two vertices paired into edges: two whose curves coincide (the
    midpoint of the second on the first within eps). A manifold edge has two uses, so a group of
    more is matched to the most pairs, of different patches first: near a cusp corner, a vertex
    can lie on two sides of one patch, whose two pieces then run together with their neighbours'
    (trj8: a patch's top and left pieces beside two other patches' pieces). Unpaired segments are
    edges of their own (free). Returns index tuples into ``segs`` with the second's member."""
    n = len(segs)
    if n == 1:
        return [((0,), None)]
    ok, members = {}, {}
    for a in range(n):
        for b in range(a + 1, n):
            edge = TopoEdge(segs[a][5], segs[a][6], segs[a][3], segs[a][4],
                            [Member(segs[a][0], segs[a][1], segs[a][3], segs[a][4])])
            m = _match(edge, rows, *_seg_args(segs[b]), eps)
            if m is not None:
                ok[(a, b)] = 2 if segs[a][0] != segs[b][0] else 1  # a fold of one patch scores less
                members[(a, b)] = m
    # the most pairs, and among those the closest: where a boundary curve runs into a straight
    # side tangentially (a u-extremum on a slab line), a vertex near the touching point lies within
    # eps of both, and the pieces beside it coincide within eps with the wrong partner as well
    # (Block, trj8: 5e-8 and 8e-8 against rounding for the right one)
    best: tuple[tuple[int, float], list] = ((-1, 0.0), [])

    def search(free: list[int], chosen: list, score: int, dev: float) -> None:
        nonlocal best
        if (score, -dev) > best[0]:
            best = ((score, -dev), list(chosen))
        if not free or len(free) < 2:
            return
        a, rest = free[0], free[1:]
        for b in rest:
            if (a, b) in ok:
                search([x for x in rest if x != b], chosen + [(a, b)], score + ok[(a, b)],
                       dev + members[(a, b)].deviation)
        search(rest, chosen, score, dev)

    if n <= 8:
        search(list(range(n)), [], 0, 0.0)
        paired = best[1]
    else:  # greedy
        paired, used = [], set()
        for (a, b), _ in sorted(ok.items(), key=lambda kv: (-kv[1], members[kv[0]].deviation)):
            if a not in used and b not in used:
                paired.append((a, b))
                used.update((a, b))
    used = {x for p in paired for x in p}
    return [(p, members[p]) for p in paired] + [((a,), None) for a in range(n) if a not in used]


def _spline_map(orow, row, t0, t1, a0, a1, goal):
    """s(a), a in [0, 1], as a clamped B-spline of degree ``_MAP_DEGREE`` (knots, coefficients)
    that puts the side ``row`` on the owner's curve at t0 + a (t1 - t0), with s(0) = a0 and s(1) = a1 exactly:
    fitted to projected parameters, spans doubled until the deviation is within ``goal`` (at most
    64 spans). Returns the map and its deviation (65 samples per span)."""
    from scipy.interpolate import make_lsq_spline

    lo, hi = min(a0, a1), max(a0, a1)
    best, best_dev = None, np.inf
    spans = 1
    while spans <= 64:
        aa = np.linspace(0.0, 1.0, 8 * spans + 1)
        ss, _ = project(row, _evaluate(orow, t0 + aa * (t1 - t0)), lo, hi)
        ss[0], ss[-1] = a0, a1
        knots = np.concatenate([[0.0] * _MAP_DEGREE, np.linspace(0.0, 1.0, spans + 1), [1.0] * _MAP_DEGREE])
        spline = make_lsq_spline(aa, ss, knots, k=_MAP_DEGREE)
        coef = spline.c.copy()
        coef[0], coef[-1] = a0, a1
        dense = np.linspace(0.0, 1.0, 64 * spans + 1)
        spline.c = coef
        sm = np.clip(spline(dense), lo, hi)
        target = _evaluate(orow, t0 + dense * (t1 - t0))
        dev = float(np.linalg.norm(_evaluate(row, sm) - target, axis=1).max())
        if dev < best_dev:
            best, best_dev = (knots, coef), dev
        if dev <= goal:
            break
        spans *= 2
    return best, best_dev


def _match(edge: TopoEdge, rows, i: int, name: str, s0: float, s1: float, v0: int, v1: int,
           eps: float) -> Member | None:
    """The member that segment (s0, s1) of side ``name`` of patch i makes of ``edge``, or None when
    its curve is another one between the same two vertices."""
    if edge.degenerate:
        return None
    o = edge.owner
    orow, row = rows[o.patch][o.side], rows[i][name]
    if (s0, s1, edge.t0, edge.t1) == (0.0, 1.0, 0.0, 1.0) and row.shape == orow.shape:
        # the same side copied (stage 2 computes a shared side once), its homogeneous points
        # perhaps scaled by one factor: the same curve at the same parameter, no projection
        for cand, a0, a1, v in ((row, 0.0, 1.0, v0), (row[::-1], 1.0, 0.0, v1)):
            if v != edge.va:
                continue
            ratio = cand[:, 3] / orow[:, 3]
            if np.ptp(ratio) <= 1e-12 * ratio[0]:
                gap = float(np.linalg.norm(cand[:, :3] / cand[:, 3:] - orow[:, :3] / orow[:, 3:],
                                           axis=1).max())
                if gap <= 1e-3 * eps:
                    return Member(i, name, a0, a1, 1.0, gap)
    if edge.va != edge.vb:
        # a piece of a side cut at a T-vertex against the whole side beside it: Bezier subdivision
        # keeps the parameter affine, so most pieces coincide at affinely mapped parameters
        a0, a1 = (s0, s1) if v0 == edge.va else (s1, s0)
        target = _evaluate(orow, edge.t0 + _CHECK * (edge.t1 - edge.t0))
        dev = float(np.linalg.norm(_evaluate(row, a0 + _CHECK * (a1 - a0)) - target, axis=1).max())
        # within what a parameter map is refined to: at I2's 1e-3 eps, a rational piece of another
        # degree that runs along the side at another speed (fusee: 3.5e-12 from it) was taken
        # affinely, 4.7e-10 off at the same parameter, and read back as a gap past I2's goal
        if dev <= _MAP_REL * eps:
            return Member(i, name, a0, a1, 1.0, dev)
    # the curves coincide: three points of the segment on the edge's curve within eps
    pts = _evaluate(row, s0 + np.array([0.25, 0.5, 0.75]) * (s1 - s0))
    _, d = project(orow, pts, edge.t0, edge.t1, within=eps)
    if d.max() > eps:
        return None
    # which end of the segment sits at the edge's start
    if edge.va != edge.vb:
        forward = v0 == edge.va
    else:  # a closed edge: decide by a point a quarter along
        q = _evaluate(orow, np.array([edge.t0 + 0.25 * (edge.t1 - edge.t0)]))
        sq, _ = project(row, q, s0, s1)
        forward = sq[0] < 0.5 * (s0 + s1)
    a0, a1 = (s0, s1) if forward else (s1, s0)
    target = _evaluate(orow, edge.t0 + _CHECK * (edge.t1 - edge.t0))
    dev = float(np.linalg.norm(_evaluate(row, a0 + _CHECK * (a1 - a0)) - target, axis=1).max())
    w = 1.0
    if dev > 1e-3 * eps:
        # a Moebius map through the projected midpoint
        smid, _ = project(row, target[3:4], min(s0, s1), max(s0, s1))
        if smid[0] != a0 and smid[0] != a1 and (smid[0] - a0) * (a1 - smid[0]) > 0:
            wm = (smid[0] - a0) / (a1 - smid[0])
            devm = float(np.linalg.norm(_evaluate(row, _moebius(_CHECK, a0, a1, wm)) - target, axis=1).max())
            if devm < dev:
                w, dev = float(wm), devm
    if dev > _MAP_REL * eps:
        # the sides run along one curve at speeds no Moebius map relates (a polynomial side
        # against a rational one): s(a) as a spline through projected parameters
        smap, devp = _spline_map(orow, row, edge.t0, edge.t1, a0, a1, _MAP_REL * eps)
        if devp < dev:
            return Member(i, name, a0, a1, 1.0, devp, smap)
    return Member(i, name, a0, a1, w, dev)
