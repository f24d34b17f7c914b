"""Stage 2's B-rep: patch faces joined into shells and solids along their shared boundaries.

After substitution, two patches that touch have the same boundary curve (the same control points,
or a subdivision of the same curve where a T-vertex splits one side). ``topology.connect`` finds
that structure from the patches (one vertex per corner, T-vertices, one edge per shared piece, at
``JOIN_REL`` x diagonal) and ``build.joined_faces`` builds it with ``BRep_Builder``: the pcurves are
straight segments on the sides of [0, 1]^2 and same-parameter by construction. (Sewing, used
before, recomputed pcurves by projection: some came back curved or off the sides, a pole's
degenerated edge was dropped, and such faces read back as trimmed.) A shell that was closed in
the input becomes a solid again, oriented by its volume from the patches (divergence theorem);
a solid's void shells stay in it.
"""

from __future__ import annotations

import numpy as np
from OCP.BRep import BRep_Builder
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid
from OCP.BRepGProp import BRepGProp
from OCP.GProp import GProp_GProps
from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS_Compound, TopoDS_Shape, TopoDS_Shell

from ..errors import KernelError
from ..topology import JOIN_REL
from .extract import indexed
from .structure import bodies as input_bodies
from .structure import compound


def input_groups(shape: TopoDS_Shape) -> list[tuple[list[int], bool, TopoDS_Shape]]:
    """The input's bodies as (face indices, is a solid, the body), in the model's face numbering
    and the order of ``structure.bodies``: every solid (all its shells: a void's faces are the
    solid's too), then every shell outside solids, then the faces outside shells."""
    fmap = indexed(shape, TopAbs_FACE)
    groups, seen = [], set()
    for body, solid in input_bodies(shape):
        faces = [i for i in _faces(body, fmap) if i not in seen]  # a face of two shells goes to the first
        seen.update(faces)
        groups.append((faces, solid, body))
    return groups


def _faces(shape, fmap) -> list[int]:
    out = []
    ex = TopExp_Explorer(shape, TopAbs_FACE)
    while ex.More():
        out.append(fmap.FindIndex(ex.Current()) - 1)
        ex.Next()
    return out


def _volume(shape, eps: float | None = None) -> float:
    props = GProp_GProps()
    if eps is None:
        BRepGProp.VolumeProperties_s(shape, props)
    else:
        BRepGProp.VolumeProperties_s(shape, props, eps)
    return float(props.Mass())


#: rounds of putting remade triangles on free edges back (``join``): each can leave a neighbour's
#: side free that the next round finds
_REVERT_PASSES = 3


def join(groups: list[tuple[list, bool]], diagonal: float, path: str, tick=None,
         fold: float = 0.0, fallbacks: list[dict] | None = None,
         splits: np.ndarray | None = None,
         clearance: tuple[float, float] | None = None) -> tuple[TopoDS_Shape, dict, list]:
    """Faces of each group of patches ``(ctrl, rational, reversed)`` bounded by shared edges
    (``topology.connect`` at ``JOIN_REL`` x diagonal, ``build.joined_faces``), one shell per
    connected part; a solid where the group was a solid's shell and no edge is left free. Patches
    without area are dropped: flat ones, needles, and folds (``topology.folded``) no farther than
    ``fold`` (model units) from their boundary curve; thin two-sided patches with three corners
    at one point are made again as ruled lenses (``topology.lens``) within the same distance.
    Returns the compound, counts (free edges left, shells, solids, T-vertices, largest edge
    deviation, patches dropped, lenses, the largest distance of a fold or lens, the degree, the
    larger of the two, of every face built, and the solids' summed volume from their patches), and
    per group what it became (a solid, a shell, a compound of several, or None), which
    ``structure.Output`` places in the input's tree.

    ``fallbacks``, per group, maps a patch's index in the group to the net it was made from
    (``(ctrl, rational)``, a triangle that ``stage2._untriangle`` made four-sided): where such a
    patch has a side left free, it goes back to that net and the group is connected again
    (``triangles_reverted`` counts them). ``splits`` (k, 3): points that become vertices inside
    the edges they lie on (``topology.split``); ``clearance``: ``(ratio, near)``, edges of the topology
    that is built split to be short for their clearance (``topology.clear``)."""
    from ..core.bezier import surface_volumes
    from ..topology import clear, connect, flat, folded, lens, needle, stray_needles
    from .build import joined_faces

    builder = BRep_Builder()
    out = TopoDS_Compound()
    builder.MakeCompound(out)
    info = {"free_edges": 0, "shells": 0, "solids": 0, "open_solid_shells": 0, "t_vertices": 0,
            "edge_deviation_max": 0.0, "flat_patches": 0, "folds": 0, "lenses": 0, "fold_width_max": 0.0,
            "triangles_reverted": 0, "degrees": [], "volume": 0.0, "spikes_taken_out": 0,
            "clearance_split_vertices": 0}
    bodies: list[TopoDS_Shape | None] = [None] * len(groups)
    for g, (nets, solid) in enumerate(groups):
        if not nets:
            continue
        back = dict(fallbacks[g]) if fallbacks else {}
        eps = JOIN_REL * diagonal
        keep = []
        for k, n in enumerate(nets):
            n = (*n, back.get(k))
            if flat(n[0], n[1], eps) or needle(n[0], n[1], eps):
                continue
            width = folded(n[0], n[1], eps, fold)
            if width is not None:
                info["folds"] += 1
                info["fold_width_max"] = max(info["fold_width_max"], width)
                continue
            remade = lens(n[0], n[1], eps, fold)
            if remade is not None:
                info["lenses"] += 1
                info["fold_width_max"] = max(info["fold_width_max"], remade[2])
                n = (remade[0], remade[1], n[2], None)
            keep.append(n)
        info["flat_patches"] += len(nets) - len(keep)
        nets = keep
        topo = connect([(c, r) for c, r, _, _ in nets], eps, splits)
        needles = stray_needles(topo, [(c, r) for c, r, _, _ in nets], eps)
        if needles:
            info["flat_patches"] += len(needles)
            nets = [n for i, n in enumerate(nets) if i not in needles]
            topo = connect([(c, r) for c, r, _, _ in nets], eps, splits)
        for _ in range(_REVERT_PASSES):
            # a remade triangle's new corner that its neighbour's side does not take (U_Joint_2:
            # 8 free edges where none were before the triangles were remade) goes back to being
            # a triangle, and the group is connected again
            on_free = {m.patch for e in topo.edges if not e.degenerate and len(e.members) == 1
                       for m in e.members}
            undo = sorted(i for i in on_free if nets[i][3] is not None)
            if not undo:
                break
            info["triangles_reverted"] += len(undo)
            for i in undo:
                c, r = nets[i][3]
                nets[i] = (c, r, nets[i][2], None)
            topo = connect([(c, r) for c, r, _, _ in nets], eps, splits)
        if clearance is not None:
            clear(topo, [(c, r) for c, r, _, _ in nets], eps, *clearance)
        nets = [n[:3] for n in nets]
        info["degrees"] += [max(c.shape[0], c.shape[1]) - 1 for c, _, _ in nets]
        faces = joined_faces(nets, topo, tick)
        free = topo.free_edges
        info["free_edges"] += free
        info["t_vertices"] += topo.t_vertices
        info["spikes_taken_out"] += topo.unspiked
        info["clearance_split_vertices"] += topo.cleared
        info["edge_deviation_max"] = max([info["edge_deviation_max"]]
                                         + [m.deviation for e in topo.edges for m in e.members])
        shells, parts = [], topo.components()
        for part in parts:
            shell = TopoDS_Shell()
            builder.MakeShell(shell)
            for i in part:
                builder.Add(shell, faces[i])
            closed = all(len(topo.edges[e].members) >= 2 or topo.edges[e].degenerate
                         for i in part for segs in topo.wires[i].values() for e, _ in segs)
            shell.Closed(closed)
            shells.append(shell)
        info["shells"] += len(shells)
        if solid and free == 0:
            # each shell's enclosed volume from its patches (divergence theorem, numpy), which
            # orients it: the kernel's integration took 14 s of bug33398's 291 s, and as much again
            # for the report's volume of the same solids
            sign = [-1.0 if n[2] else 1.0 for n in nets]
            each = surface_volumes([(c, r) for c, r, _ in nets])
            vols = [sum(sign[i] * float(each[i]) for i in part) for part in parts]
            made, sizes = _solids(shells, vols)
            info["solids"] += len(made)
            info["volume"] += sum(sizes)
        else:
            if solid:
                info["open_solid_shells"] += len(shells)
            made = shells
        for body in made:
            builder.Add(out, body)
        bodies[g] = made[0] if len(made) == 1 else compound(made) if made else None
    if out.IsNull():
        raise KernelError(f"{path}: joining the patches failed")
    return out, info, bodies


def _solids(shells: list, vols: list[float]) -> tuple[list, list[float]]:
    """Closed shells of one input solid as solids, with their volumes (``vols``: each shell's signed
    enclosed volume as built): one shell is one solid, turned to a positive volume; with several, a
    shell inside the largest is a void of it (its faces turned towards the void), and one outside
    it a solid of its own."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepClass3d import BRepClass3d_SolidClassifier
    from OCP.TopAbs import TopAbs_IN, TopAbs_VERTEX
    from OCP.TopoDS import TopoDS

    made = []
    for shell, v in zip(shells, vols, strict=True):
        body = BRepBuilderAPI_MakeSolid(shell).Solid()
        if v < 0:
            body.Reverse()
        made.append(body)
    size = [abs(v) for v in vols]
    if len(made) < 2:
        return made, size
    outer = max(range(len(made)), key=size.__getitem__)
    voids = []
    for k in range(len(made)):
        if k != outer:
            point = BRep_Tool.Pnt_s(TopoDS.Vertex_s(TopExp_Explorer(shells[k], TopAbs_VERTEX).Current()))
            if BRepClass3d_SolidClassifier(made[outer], point, 1e-9).State() == TopAbs_IN:
                voids.append(k)
    if not voids:
        return made, size
    mk = BRepBuilderAPI_MakeSolid()
    mk.Add(shells[outer] if vols[outer] >= 0 else TopoDS.Shell_s(shells[outer].Reversed()))
    for k in voids:
        mk.Add(TopoDS.Shell_s(shells[k].Reversed()) if vols[k] >= 0 else shells[k])
    rest = [k for k in range(len(made)) if k != outer and k not in voids]
    return ([mk.Solid(), *(made[k] for k in rest)],
            [size[outer] - sum(size[k] for k in voids), *(size[k] for k in rest)])


def volume(shape, adaptive: bool = False) -> float:
    """Summed volume of the shape's solids (kernel integration). ``adaptive`` integrates to a relative
    precision of 1e-9: on trimmed input faces the kernel's default rule is off by up to 0.6 % (a
    loft minus a cylinder: 24251.8 against 24386.2), while on untrimmed Bezier patches both agree
    to 1e-13."""
    total = 0.0
    ex = TopExp_Explorer(shape, TopAbs_SOLID)
    while ex.More():
        total += _volume(ex.Current(), 1e-9 if adaptive else None)
        ex.Next()
    return total


def is_valid(shape) -> bool:
    from OCP.BRepCheck import BRepCheck_Analyzer

    return bool(BRepCheck_Analyzer(shape).IsValid())
