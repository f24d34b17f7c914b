"""The second half of ``watertight convert``: substitute, build, write, verify the written file.

Invariants measured on the written file (read back with the same code as ``watertight report``):

- I1: every face is a single-span (Bezier) surface bounded by its parameter rectangle;
- I2: the largest gap over all edges (the edge's curve against each face's surface(pcurve), and
  the two faces' boundaries against each other) is at most ``watertight_rel`` x diagonal;
- I3: no free edges where the input had none, and no more than the input had; solids stay solids;
- I4: per face, the deviation bound (stage 1 + substitution) is at most the tolerance plus the
  input's largest gap on the face's edges and at their vertices.
"""

from __future__ import annotations

import time
from collections import Counter

import numpy as np

from .tolerances import Tolerances


def finish(ins, result, report: dict, tol: Tolerances, src: str, dst: str | None, progress,
           overwrite: bool, fast: bool, keep: dict | None = None, near: list | None = None) -> dict:
    from .occ.assemble import input_groups, is_valid, join, volume
    from .occ.io import write_shape
    from .occ.structure import Output
    from .report import edge_gap_rows
    from .substitute import substitute

    model = ins.model
    times = report["timings"]
    t = time.perf_counter()
    in_groups = input_groups(ins.shape)
    solid_faces = [i for faces, solid, _ in in_groups if solid for i in faces]
    vol_in = _patch_volume(model, result, solid_faces) if model.solids else None
    tick = progress("substitute", len(model.faces)) if progress else None
    sub = substitute(model, result, tol, tick, near)
    times["substitute"] = time.perf_counter() - t

    t = time.perf_counter()
    tick = progress("build", len(result.patches)) if progress else None
    lenses = _collapse_lenses(result, in_groups, tol, model.diagonal)
    nets, quads = _untriangle(result, tol, model.diagonal)
    for f, moved in lenses["per_face"].items():  # in each face's I4 measure, like the triangle fits
        quads["per_face"][f] = quads["per_face"].get(f, 0.0) + moved
    t_cut = time.perf_counter()
    splits, slender = _split_slender(nets, tol, model.diagonal)
    times["slender"] = time.perf_counter() - t_cut
    groups, fallbacks = [], []
    for faces, solid, _ in in_groups:
        items = [(c, r, model.faces[i].reversed, was) for i in faces for c, r, was in nets[i]]
        groups.append(([it[:3] for it in items], solid))
        fallbacks.append({k: it[3] for k, it in enumerate(items) if it[3] is not None})
    # a fold (a patch whose boundary runs along one curve and back, ``topology.folded``) is
    # dropped, and a thin lens with three corners at one point made again (``topology.lens``),
    # when it lies within half the tolerance of its boundary curve, which its neighbours share
    shape, joined, made = join(groups, model.diagonal, src, tick, fold=0.5 * tol.approx_rel * model.diagonal,
                               fallbacks=fallbacks, splits=splits,
                               clearance=(tol.slender_ratio, tol.approx_rel * model.diagonal))
    # remade triangles that left a side free went back to their triangles (``occ.assemble.join``);
    # their fit's deviation stays in their faces' I4 measure, an overestimate
    quads["remade"] -= joined["triangles_reverted"]
    quads["kept"] += joined["triangles_reverted"]
    if keep is not None:
        keep["shape"] = shape
    valid = is_valid(shape)
    times["build"] = time.perf_counter() - t - times["slender"]

    input_gap = _local_input_gaps(model, ins.gaps, tol)
    allowed_base = tol.approx_rel * model.diagonal
    faces = []
    for fr, fs, frep in zip(result.faces, sub.faces, report["faces"], strict=True):
        # per patch: its stage-1 bound plus its own substitution move (Patch.bound carries both)
        face = model.faces[fr.face]
        bound = max((p.bound for p in fr.patches), default=0.0) + face.approximation + fr.closure
        # I4 measures: each patch against its stage-1 patch at the same (s, t) on a grid, plus the
        # stage-1 patch's own deviation (its bound, and near trimming sides that the loop closure
        # moved, their sampled distance from S(pcurve)); the certified bound (which sums the steps'
        # bounds and the face's whole closure) decides where it holds
        measured = fs.deviation_sampled + face.approximation + quads["per_face"].get(fr.face, 0.0)
        bound += quads["per_face"].get(fr.face, 0.0)
        deviation = min(bound, measured)
        allowed = allowed_base + input_gap.get(fr.face, 0.0)
        frep.update({
            "substitution_move": fs.moved,
            "substitution_move_is_estimate": fs.estimated,
            "substitution_move_sampled": fs.moved_sampled,
            "bound_after": bound,
            "deviation_after": deviation,
            "deviation_after_is_sampled": bool(measured < bound),
            "bound_allowed": allowed,
            "t_sides": fs.inner_unpaired,
            "problems": frep["problems"] + fs.problems,
        })
        faces.append((deviation, allowed, fs, bound))
    i4_fail = [f for f, (d, a, _, _) in zip(result.faces, faces, strict=True) if d > a]
    problems = [p for _, _, fs, _ in faces for p in fs.problems]
    degrees = joined["degrees"]  # of the faces built: remade, reverted or as stage 2 left them
    vol_kernel = volume(ins.shape, adaptive=True) if model.solids else None
    vol_out = joined["volume"] if joined["solids"] else None  # from the patches, as vol_in

    report.update({
        "stage": "full",
        "patches_out": len(degrees),  # as built: remade triangles and slender pieces included
        "degree": {
            "max": max(degrees, default=0),
            "median": sorted(degrees)[len(degrees) // 2] if degrees else 0,
            "histogram": {str(k): v for k, v in sorted(Counter(degrees).items())},
        },
        "shared_curves": dict(Counter(sub.curves.values())),
        # per input edge (its index): "3d curve", "3d curve, polynomial fit", "midway between the
        # faces" or "pole"; edges absent here kept their stage-1 sides (no side could take a curve)
        "shared_curve_per_edge": {str(e): kind for e, kind in sorted(sub.curves.items())},
        "t_junctions": sub.t_vertices + sum(fs.inner_unpaired for fs in sub.faces),
        "t_vertices_on_edges": sub.t_vertices,
        "substitution_move_max": sub.moved,
        "bound_after_max": max((b for _, _, _, b in faces), default=0.0),
        "deviation_after_max": max((d for d, _, _, _ in faces), default=0.0),
        "before": {
            "gap_max": max((g.gap for g in ins.gaps), default=0.0),
            "free_edges": sum(1 for e in model.edges if not e.degenerate and e.uses == 1),
            "solids": model.solids,
            "shells": model.shells,
            "volume": vol_in,
            "volume_kernel": vol_kernel,
            "edge_gaps": edge_gap_rows(ins.gaps),
        },
        "after": {
            "faces": len(degrees),
            "shells": joined["shells"],
            "solids": joined["solids"],
            "free_edges_after_join": joined["free_edges"],
            # the built topology: T-vertices on longer sides, zero-area patches left out, and the
            # largest distance between an edge's curve and a face side at the mapped parameter
            "t_vertices": joined["t_vertices"],
            "flat_patches_dropped": joined["flat_patches"],
            "folds_dropped": joined["folds"],
            "lenses_remade": joined["lenses"],
            "fold_width_max": joined["fold_width_max"],
            # triangular cells thinner than half the tolerance, taken out (``lenses``): the patch
            # across each one's rung closes over it, as one row through the lens's two sides or
            # (``lenses_cut``) cut in two at its tip; those kept had no single such patch
            "lenses_collapsed": lenses["collapsed"],
            "lenses_cut": lenses["cut"],
            "lenses_kept": lenses["left"],
            "lens_width_max": lenses["width_max"],
            # patches with one collapsed side, made again with four (``core.triangle``), those
            # kept (no fit within the budget), and the largest two-sided distance of a new one;
            # ``triangles_tips_cut``: of those remade, the ones made again at their tip alone
            "triangles_remade": quads["remade"],
            "triangles_tips_cut": quads["tips"],
            "triangles_kept": quads["kept"],
            "triangles_reverted": joined["triangles_reverted"],
            "triangle_deviation_max": quads["deviation_max"],
            # patches more than ``Tolerances.slender_ratio`` times longer than wide whose long
            # sides were split into shorter edges, and the vertices put into them
            "slender_patches_split": slender["split"],
            "slender_split_vertices": slender["vertices"],
            "slender_left_by_triangles": slender["left_by_triangles"],
            # vertices put into edges longer than ``Tolerances.slender_ratio`` times their distance
            # to the nearest other edge (``topology.clearance_points``), beyond the slender ones
            "clearance_split_vertices": joined["clearance_split_vertices"],
            # vertices near a tangential corner taken out of the side that did not need them
            # (``topology.unspike``): each was a spike of no width in its patch's wire
            "spikes_taken_out": joined["spikes_taken_out"],
            "edge_deviation_max": joined["edge_deviation_max"],
            "valid": valid,
            "volume": vol_out,
            "volume_change_rel": (abs(vol_out - vol_in) / abs(vol_in)
                                  if vol_in and vol_out is not None else None),
        },
        "problems": problems,
        "structure": _structure_report(ins.structure, dst),
    })
    invariants = {"I4": not i4_fail and not problems, "valid": valid}
    if dst is not None:
        t = time.perf_counter()
        placed = [(body, out) for (_, _, body), out in zip(in_groups, made, strict=True)]
        write_shape(shape if ins.structure is None else Output.place(ins.structure, placed), dst,
                    overwrite=overwrite)
        times["write"] = time.perf_counter() - t
        if not fast:
            t = time.perf_counter()
            invariants.update(_verify_written(dst, report, tol, model, keep))
            times["verify_written"] = time.perf_counter() - t
    report["invariants"] = invariants
    report["ok"] = all(invariants.values())
    report["timings"] = times
    return report


def _collapse_lenses(result, in_groups, tol: Tolerances, diagonal: float) -> dict:
    """Thin triangular cells (every point within half the tolerance of the side facing the
    collapsed one) taken out of ``result`` in place, one input shell or solid at a time
    (``lenses.collapse_lenses``): the patch across each one's rung takes the lens's two sides,
    as one row or cut in two, and each face's largest move is returned for its I4 measure
    (``per_face``), the lens's own width included for its face."""
    from dataclasses import replace

    from .lenses import collapse_lenses
    from .topology import JOIN_REL

    info = {"collapsed": 0, "cut": 0, "left": 0, "width_max": 0.0, "per_face": {}}
    for faces, _, _ in in_groups:
        items = [(i, j) for i in faces for j in range(len(result.faces[i].patches))]
        # a rung that takes the lens's two sides as one row must hold them to a tenth of I2's gap
        done = collapse_lenses([(result.faces[i].patches[j].ctrl, result.faces[i].patches[j].rational)
                                for i, j in items],
                               JOIN_REL * diagonal, 0.5 * tol.approx_rel * diagonal, tol.max_degree,
                               exact=0.1 * tol.watertight_rel * diagonal)
        info["left"] += done.left
        if not done.collapsed:
            continue
        info["collapsed"] += done.collapsed
        info["cut"] += done.cut
        info["width_max"] = max(info["width_max"], done.width_max)
        dropped: dict[int, set[int]] = {}
        added: dict[int, list] = {}
        for k, moved in done.moved.items():
            i, j = items[k]
            face = result.faces[i].face
            info["per_face"][face] = max(info["per_face"].get(face, 0.0), moved)
            if done.nets[k] is None:
                dropped.setdefault(i, set()).add(j)
            else:
                result.faces[i].patches[j].ctrl = done.nets[k][0]
        for k, q in sorted(done.parent.items()):  # halves of a patch cut at a lens's tip
            i, j = items[q]
            added.setdefault(i, []).append(replace(result.faces[i].patches[j], ctrl=done.nets[k][0]))
        for i in faces:
            fr = result.faces[i]
            fr.patches = [p for j, p in enumerate(fr.patches) if j not in dropped.get(i, ())]
            fr.patches += added.get(i, [])
    return info


def _untriangle(result, tol: Tolerances, diagonal: float) -> tuple[list, dict]:
    """Per face, its patches as (ctrl, rational, the triangle's own net or None) for the build,
    where each patch with exactly one collapsed side is made again as a four-sided patch
    (``core.triangle.quad_from_triangle``) when it fits within half the tolerance: with a collapsed
    side the B-rep has a degenerated edge, and no tessellation of it is closed. Where the whole
    triangle misses, its tip is cut off and made again alone, the rest kept exactly
    (``quad_from_tip``). The fit's deviation is added to its face's. The build puts a remade patch
    back (the whole triangle, or the tip) where it leaves a side free."""
    from .core.triangle import collapsed_side, opposite_row, quad_from_tip, quad_from_triangle
    from .topology import JOIN_REL

    eps, budget = JOIN_REL * diagonal, 0.5 * tol.approx_rel * diagonal
    info = {"remade": 0, "kept": 0, "tips": 0, "deviation_max": 0.0, "per_face": {}}
    nets = []
    corners = None
    for fr in result.faces:
        face = []
        for p in fr.patches:
            if collapsed_side(p.ctrl, eps) is None:
                face.append((p.ctrl, p.rational, None))
                continue
            if corners is None:
                corners = _Corners(result)
            split = corners.split(opposite_row(p.ctrl, p.rational, eps), eps)
            quad = quad_from_triangle(p.ctrl, p.rational, eps, budget, tol.max_degree, split)
            made = [(quad, (p.ctrl, p.rational))] if quad is not None else []
            if quad is None:
                cut = quad_from_tip(p.ctrl, p.rational, eps, budget, tol.max_degree)
                if cut is not None:
                    info["tips"] += 1
                    made = [(cut[0], (cut[1], p.rational))]
                    face.append((cut[2], p.rational, None))
            if not made:
                info["kept"] += 1
                face.append((p.ctrl, p.rational, None))
                continue
            for (ctrl, rational, dev), was in made:
                info["remade"] += 1
                info["deviation_max"] = max(info["deviation_max"], dev)
                info["per_face"][fr.face] = max(info["per_face"].get(fr.face, 0.0), dev)
                face.append((ctrl, rational, was))
        nets.append(face)
    return nets, info


_SLIVER_RATIO = 20  # slivers' long sides: pieces up to this times --max-aspect widths
_SLIVER_FLOOR = 10  # and only slivers wider than this many sliver floors (Tolerances.sliver_rel)


def _split_slender(nets: list, tol: Tolerances, diagonal: float) -> tuple[np.ndarray, dict]:
    """Points that split the long sides of every patch (of ``_untriangle``'s nets) more than
    ``tol.slender_ratio`` times longer than wide into pieces no longer than that ratio times the
    strip's width there (``core.slender``: ``slender_axes``, then ``split_along``);
    ``topology.connect`` makes them vertices of the edges they lie on, so the strip's neighbours
    have them too. The patches stay whole
    and exact. Remade triangles take no points, and no point goes on a triangle's side (remade or
    kept with its collapsed side: the build may put a remade triangle back, and a needle or wedge
    took no T-vertex along its sides when strips were cut into pieces: wing_fuselage, six free
    edges).

    Slivers (narrower than ``tol.thin_rel`` somewhere; I5 counts them) are split too, but only into
    pieces up to ``_SLIVER_RATIO`` times the ratio, and only where they are wider than
    ``_SLIVER_FLOOR`` times ``tol.sliver_rel`` (the read-back's weld). The kernel's mesher left a
    hole in a sliver of bug33398 13.8 long and 5.3e-5 wide whose one long side held 45 vertices
    and the other none (six free mesh edges); split, its mesh closed. At the ratio itself that
    file's slivers took 135k vertices (+50 % time, a 516 MB file instead of 345) where 7k do;
    down to the weld itself, ec_turbine's and trj8's meshes had two more collapsed triangles each
    and the wing 35 % more split vertices."""
    from .core.slender import slender_axes, split_along, strip_measures
    from .core.triangle import collapsed_side
    from .topology import JOIN_REL

    info = {"split": 0, "vertices": 0, "left_by_triangles": 0}
    floor = tol.thin_rel * diagonal
    snap = _Vertices([(c, r) for face in nets for c, r, _ in face])
    eps = JOIN_REL * diagonal
    triangles = _Sides([(c, r) for face in nets for c, r, was in face
                        if was is not None or collapsed_side(c, eps) is not None])
    # the first look at every patch, in one pass per net shape (most patches are not slender)
    plain = [(c, r) for face in nets for c, r, was in face if was is None]
    shapes: dict[tuple, list[int]] = {}
    for k, (c, r) in enumerate(plain):
        shapes.setdefault((c.shape, r), []).append(k)
    axes = np.full(len(plain), -1)
    sliver = np.zeros(len(plain), dtype=bool)
    thin_ratio, thin_floor = _SLIVER_RATIO * tol.slender_ratio, _SLIVER_FLOOR * tol.sliver_rel * diagonal
    for (_, r), ks in shapes.items():
        ks = np.asarray(ks)
        seen = strip_measures(np.stack([plain[k][0] for k in ks]), r)
        axes[ks] = slender_axes(None, r, tol.slender_ratio, floor, seen)
        # a patch that is no strip above the floor but one above the sliver floor is a sliver
        thin = slender_axes(None, r, thin_ratio, thin_floor, seen)
        pick = (axes[ks] < 0) & (thin >= 0)
        axes[ks[pick]] = thin[pick]
        sliver[ks[pick]] = True
    found = []
    for k in np.flatnonzero(axes >= 0):
        ctrl, rational = plain[k]
        ratio, low = (thin_ratio, thin_floor) if sliver[k] else (tol.slender_ratio, floor)
        made = split_along(ctrl, rational, int(axes[k]), ratio, low, snap, eps)
        if made is None:
            continue
        pts = made.points
        if triangles.near(pts, floor):
            info["left_by_triangles"] += 1
            continue
        info["split"] += 1
        info["vertices"] += len(pts)
        found.append(pts)
        snap.add_points(pts)
    return (np.concatenate(found) if found else np.zeros((0, 3))), info


class _Sides:
    """The four sides of some nets, sampled, to ask whether points lie on one of them (within a
    distance, to the sampled polyline)."""

    _N = 65

    def __init__(self, nets: list[tuple[np.ndarray, bool]]):
        from scipy.spatial import cKDTree

        from .core.bezier import curve_eval

        s = np.linspace(0.0, 1.0, self._N)
        lines = []
        for c, r in nets:
            for row in (c[0], c[-1], c[:, 0], c[:, -1]):
                q = curve_eval(row, s)
                lines.append(q[:, :-1] / q[:, -1:] if r else q)
        self.lines = np.array(lines) if lines else np.zeros((0, self._N, 3))
        self.tree = cKDTree(self.lines.reshape(-1, 3)) if lines else None

    def near(self, pts: np.ndarray, eps: float) -> bool:
        """Whether any point lies within ``eps`` of a side."""
        if self.tree is None or not len(pts):
            return False
        pts = np.asarray(pts, dtype=float).reshape(-1, 3)
        _, idx = self.tree.query(pts, k=min(4, self.tree.n))
        line, k = np.divmod(np.atleast_2d(idx.T).T, self._N)  # (points, neighbours)
        # the segments beside the nearest samples, all at once (one at a time, this loop was 3 s of
        # occ22470's conversion): those starting at k - 1 and k, within the polyline (at its ends
        # the one segment there, twice)
        j = np.clip(np.stack([k - 1, k], axis=-1), 0, self._N - 2)  # (points, neighbours, 2)
        li = np.broadcast_to(line[..., None], j.shape)
        a = self.lines[li, j]
        d = self.lines[li, j + 1] - a
        dd = np.maximum(np.einsum("...i,...i->...", d, d), 1e-300)
        p = pts[:, None, None, :]
        t = np.clip(np.einsum("...i,...i->...", p - a, d) / dd, 0.0, 1.0)
        return bool((np.linalg.norm(a + t[..., None] * d - p, axis=-1) <= eps).any())


def _net_corners(nets: list[tuple[np.ndarray, bool]]) -> np.ndarray:
    """The four corner points of each net (Cartesian), (4 k, 3)."""
    pts = [c[[0, -1, 0, -1], [0, 0, -1, -1]] for c, _ in nets]
    pts = [p[:, :-1] / p[:, -1:] if r else p for p, (_, r) in zip(pts, nets, strict=True)]
    return np.concatenate(pts) if pts else np.zeros((0, 3))


class _Vertices:
    """The patches' corners, and split points added since, for ``core.slender``'s snapping:
    called with points (k, 3) and radii (k,), it returns the nearest one within each radius, or
    NaNs. Added points go into a k-d tree of their own, remade once 256 wait outside it."""

    def __init__(self, nets: list[tuple[np.ndarray, bool]]):
        self.trees = []
        self.loose = np.zeros((0, 3))
        self._tree(_net_corners(nets))

    def _tree(self, pts: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        if len(pts):
            self.trees.append((cKDTree(pts), pts))

    def add_points(self, pts: np.ndarray) -> None:
        self.loose = np.concatenate([self.loose, pts])
        if len(self.loose) >= 256:
            added = [pts for _, pts in self.trees[1:]] + [self.loose]
            self.trees = self.trees[:1]
            self._tree(np.concatenate(added))
            self.loose = np.zeros((0, 3))

    def __call__(self, pts: np.ndarray, radius: np.ndarray) -> np.ndarray:
        out = np.full(pts.shape, np.nan)
        best = np.full(len(pts), np.inf)
        for tree, tpts in self.trees:
            d, i = tree.query(pts)
            hit = (d <= radius) & (d < best)
            out[hit], best[hit] = tpts[i[hit]], d[hit]
        if len(self.loose):
            d = np.linalg.norm(pts[:, None, :] - self.loose[None], axis=2)
            j = d.argmin(axis=1)
            dj = d[np.arange(len(pts)), j]
            hit = (dj <= radius) & (dj < best)
            out[hit] = self.loose[j[hit]]
        return out


class _Corners:
    """Every patch corner of a stage-1 result, for ``_untriangle`` to find where a neighbour's corner
    stands on a triangle's side: the remade patch's new corner goes there, so that its two half
    sides are exactly the pieces the neighbours share. At their sides' parametric middle instead,
    Block's remade corners stood 4e-9 off the neighbours' (the neighbours met at 0.50000001 of
    the side), and the halves missed their neighbours' sides by 4.3e-9, beyond I2."""

    def __init__(self, result):
        from scipy.spatial import cKDTree

        pts = [p.ctrl[[0, -1, -1, 0], [0, 0, -1, -1]] for fr in result.faces for p in fr.patches]
        pts = [c[:, :3] / c[:, 3:4] if c.shape[1] == 4 else c for c in pts]
        self.points = np.concatenate(pts) if pts else np.zeros((0, 3))
        self.tree = cKDTree(self.points)

    def split(self, row, eps: float, lo: float = 0.2, hi: float = 0.8) -> float:
        """The parameter on the side ``row`` (homogeneous) of the corner within ``eps`` of it that
        stands nearest its middle, between ``lo`` and ``hi``; 0.5 when there is none."""
        from .core.bezier import rational_curve_eval
        from .topology import project

        if row is None or not len(self.points):
            return 0.5
        c = rational_curve_eval(row, np.linspace(0.0, 1.0, 17))
        reach = float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum())
        near = self.tree.query_ball_point(c[8], 0.5 * reach + eps)
        if not near:
            return 0.5
        s, d = project(row, self.points[near])
        ok = (d <= eps) & (s > lo) & (s < hi)
        return float(s[ok][np.argmin(np.abs(s[ok] - 0.5))]) if ok.any() else 0.5


def _local_input_gaps(model, gaps, tol: Tolerances) -> dict[int, float]:
    """Per face, the input's own gap near it (I4's allowance): the largest gap of its edges and of
    every edge that meets them at a vertex. A patch corner moves onto the model's vertex, so a
    corner where an edge with a larger gap ends moves by that edge's gap, not the face's own, and
    by the distance of its point from the curve ends there (``gaps.vertex_corners``)."""
    from .gaps import vertex_corners

    edge_gap = {g.edge: g.gap for g in gaps}
    # a corner at a vertex also moves by the distance of its point from the curve ends there
    vertex_gap: dict[int, float] = dict(enumerate(vertex_corners(model, tol.approx_rel * model.diagonal)[1]))
    for e in model.edges:
        for v in e.vertices:
            vertex_gap[v] = max(vertex_gap.get(v, 0.0), edge_gap.get(e.index, 0.0))
    out = {}
    for f in model.faces:
        worst = 0.0
        for lp in f.loops:
            for c in lp.coedges:
                e = model.edges[c.edge]
                worst = max(worst, edge_gap.get(e.index, 0.0), *(vertex_gap.get(v, 0.0) for v in e.vertices))
        out[f.index] = worst
    return out


def _patch_volume(model, result, faces: list[int]) -> float:
    """Volume enclosed by the stage-1 patches of the solids' faces (divergence theorem, numpy).

    This is the input's volume: stage 1 represents every trimmed face by untrimmed patches within
    its verified bound. The kernel's own integration over trimmed faces is not accurate enough
    for a 1e-6 check (on plate_with_holes.step, whose exact volume is 9600 - 200 pi = 8971.68147,
    it gives 8971.6963 by default and 8971.7220 at a requested precision of 1e-9); it is reported
    beside this one as ``volume_kernel``."""
    from .core.bezier import surface_volumes

    total = 0.0
    for i in faces:
        sign = -1.0 if model.faces[i].reversed else 1.0
        total += sign * float(surface_volumes([(p.ctrl, p.rational) for p in result.faces[i].patches]).sum())
    return abs(total)


def _structure_report(structure, dst: str | None) -> dict | None:
    """The input's tree (a STEP file's assemblies, parts, placements and names) and how it is
    written: "tree" (STEP output: the same tree around the converted parts), "flat" (IGES output:
    the parts as one compound, names not kept) or "plain" (one part and no names: nothing to
    keep). None where the input has no tree (IGES, or faces sewn)."""
    from .occ.io import format_of

    if structure is None:
        return None
    if structure.trivial():
        written = "plain"
    else:
        written = "tree" if dst is None or format_of(dst) == "step" else "flat"
    return {**structure.counts(), "written": written, "tree": structure.describe()}


def _verify_written(dst: str, report: dict, tol: Tolerances, model_in, keep: dict | None = None) -> dict:
    """Read the written file back and measure I1-I3 on it (I3 includes the tree and names where the
    output is a tree, ``_structure_report``), and what a mesher sees of it: the kernel's
    tessellation of the file as read, welded at the sliver floor (``meshcheck``; reported, not an
    invariant)."""
    from .inspect import inspect, trimmed
    from .occ.mesh import measure_tessellation
    from .occ.structure import same_tree
    from .report import edge_gap_rows

    # the file as written: without the reader's shape healing, which would hide what it repairs
    out = inspect(dst, tol, array_gaps=False, kernel_tracks=False, heal=False)
    if keep is not None:
        keep["read_back"] = out
    m = out.model
    gap = max((g.gap for g in out.gaps), default=0.0)
    free = sum(1 for e in m.edges if not e.degenerate and e.uses == 1)
    free_len, free_len_in = _free_length(m), _free_length(model_in)
    bezier = sum(1 for f in m.faces if f.surface.is_bezier and not trimmed(f))
    before_free = report["before"]["free_edges"]
    report["before"]["free_boundary_length"] = free_len_in
    report["after"].update({
        "read_back": True,
        "faces": len(m.faces),
        "untrimmed_bezier_faces": bezier,
        "gap_max": gap,
        "gap_max_relative": gap / m.diagonal if m.diagonal else None,
        "free_edges": free,
        "free_boundary_length": free_len,
        "solids": m.solids,
        "shells": m.shells,
        "edge_gaps": edge_gap_rows(out.gaps),
        "tessellation": measure_tessellation(out.shape, tol.sliver_rel * m.diagonal),
    })
    tree = report.get("structure") and report["structure"]["written"] == "tree"
    kept = None
    if tree:
        kept = out.structure is not None and same_tree(out.structure.describe(), report["structure"]["tree"])
        report["after"]["structure_kept"] = kept
    return {
        "I1": bezier == len(m.faces),
        "I2": gap <= tol.watertight_rel * model_in.diagonal,
        # open input: the free boundary is split into more edges, but keeps its length
        "I3": ((free == 0) if before_free == 0 else abs(free_len - free_len_in) <= 1e-6 * free_len_in)
              and m.solids >= model_in.solids and kept is not False,
    }


def _free_length(model) -> float:
    """Summed length of the free edges: polylines through 129 and 257 samples of each 3D curve,
    extrapolated (Richardson; the chord error falls as the square of the step). A plain 65-point
    polyline is short by 4e-4 of a whole circle and less on the shorter edges that the output
    splits the same boundary into: on marsCapsule the same free boundary measured 273.421 in and
    273.433 out, and I3 failed."""
    import numpy as np

    def polyline(pts: np.ndarray) -> float:
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())

    total = 0.0
    for e in model.edges:
        if e.degenerate or e.uses != 1 or e.curve is None:
            continue
        pts = e.curve.evaluate(np.linspace(e.first, e.last, 257))
        coarse, fine = polyline(pts[::2]), polyline(pts)  # the 129 points are every other one
        total += fine + (fine - coarse) / 3.0
    return total


def _structure_lines(st: dict | None, kept: bool | None) -> list[str]:
    if not st or st["written"] == "plain":
        return []
    back = "" if kept is None else f" (read back: {'same' if kept else 'NOT the same'})"
    how = {"tree": "written as the same tree" + back,
           "flat": "written flat (IGES: one compound, names not kept)"}[st["written"]]
    return [f"  structure: {st['assemblies']} assemblies, {st['parts']} parts, {st['instances']} placed, "
            f"{st['named_bodies']} named bodies; {how}"]


def _tessellation_lines(t: dict | None, closed: bool) -> list[str]:
    from .meshcheck import describe

    return [f"  tessellation: {describe(t, closed)}"] if t else []


def format_full_table(rep: dict) -> str:
    d = rep["diagonal"]
    b, a = rep["before"], rep["after"]
    inv = rep.get("invariants", {})
    lines = [
        f"{rep['file']} -> {rep['output'] or '(not written)'}",
        f"  faces in {rep['faces_in']}, patches out {rep['patches_out']}, degree max {rep['degree']['max']} "
        f"median {rep['degree']['median']:g}, T-junctions {rep['t_junctions']}, "
        f"thin patches {rep.get('thin_patches', 0)}"
        + (f", thin lenses taken out {a['lenses_collapsed']}" if a.get("lenses_collapsed") else "")
        + (f", slender patches split {a['slender_patches_split']} (vertices {a['slender_split_vertices']})"
           if a.get("slender_patches_split") else "")
        + (f", edges split for clearance (vertices {a['clearance_split_vertices']})"
           if a.get("clearance_split_vertices") else ""),
        f"  gap: before {b['gap_max']:.3g} -> after "
        + (f"{a['gap_max']:.3g} ({a['gap_max'] / d:.2g} of the diagonal)" if "gap_max" in a
           else "(not read back)"),
        f"  free edges: before {b['free_edges']} -> after {a.get('free_edges', a['free_edges_after_join'])}; "
        f"solids {b['solids']} -> {a['solids']}; valid {'yes' if a['valid'] else 'NO'}"
        + (f"; volume change {a['volume_change_rel']:.2g}" if a.get("volume_change_rel") is not None else ""),
        f"  deviation: {rep['deviation_after_max']:.3g} (measured per patch, within the bound where "
        f"smaller); bound {rep['bound_after_max']:.3g} (stage 1 {rep['bound_max']:.3g} + substitution "
        f"{rep['substitution_move_max']:.3g}); shared curves {rep['shared_curves']}",
        *_structure_lines(rep.get("structure"), a.get("structure_kept")),
        *_tessellation_lines(a.get("tessellation"), b["free_edges"] == 0),
        "  invariants: " + ", ".join(f"{k} {'ok' if v else 'FAILED'}" for k, v in inv.items()),
        "  time: " + ", ".join(f"{k} {v:.1f}s" for k, v in rep["timings"].items()),
    ]
    return "\n".join(lines)
