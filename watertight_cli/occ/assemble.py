"""Stage 2's B-rep: patch faces joined into shells and solids along their shared boundaries.

After substitution, two patches that touch have the same boundary curve (the same control points,
or a subdivision of the same curve where a T-vertex splits one side). The faces are built one per
patch (``build.patch_face``) and joined per input shell by ``BRepBuilderAPI_Sewing`` at a tolerance
far below any feature (``JOIN_REL`` x diagonal): it finds the coincident edges, merges them into one
edge with two pcurves, and splits a long side at a T-vertex of its neighbours. A shell that was closed
in the input becomes a solid again; its orientation is checked by its volume.
"""

from __future__ import annotations

from OCP.BRep import BRep_Builder
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid, BRepBuilderAPI_Sewing
from OCP.BRepGProp import BRepGProp
from OCP.GProp import GProp_GProps
from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL, TopAbs_SOLID
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS, TopoDS_Compound, TopoDS_Shape

from ..errors import KernelError
from .extract import indexed
from .io import quiet

#: sewing tolerance relative to the diagonal: shared boundaries coincide to rounding, and no patch
#: side is shorter than a sliver (1e-8 x diagonal, ``Tolerances.sliver_rel``)
JOIN_REL = 1e-9


def input_groups(shape: TopoDS_Shape) -> list[tuple[list[int], bool]]:
    """The input's shells as (face indices, part of a solid), in the model's face numbering; faces in
    no shell form one more group."""
    fmap = indexed(shape, TopAbs_FACE)
    groups: list[tuple[list[int], bool]] = []
    seen: set[int] = set()
    ex = TopExp_Explorer(shape, TopAbs_SOLID)
    while ex.More():
        sx = TopExp_Explorer(ex.Current(), TopAbs_SHELL)
        while sx.More():
            faces = _faces(sx.Current(), fmap)
            groups.append((faces, True))
            seen.update(faces)
            sx.Next()
        ex.Next()
    sx = TopExp_Explorer(shape, TopAbs_SHELL, TopAbs_SOLID)
    while sx.More():
        faces = [i for i in _faces(sx.Current(), fmap) if i not in seen]
        if faces:
            groups.append((faces, False))
            seen.update(faces)
        sx.Next()
    rest = [i for i in range(fmap.Extent()) if i not in seen]
    if rest:
        groups.append((rest, False))
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


def join(groups: list[tuple[list, bool]], diagonal: float, path: str) -> tuple[TopoDS_Shape, dict]:
    """Sew each group of built faces; solids where the group was a solid's shell. Returns the
    compound and counts (free edges left, shells, solids)."""
    builder = BRep_Builder()
    out = TopoDS_Compound()
    builder.MakeCompound(out)
    info = {"free_edges": 0, "shells": 0, "solids": 0, "open_solid_shells": 0}
    for faces, solid in groups:
        if not faces:
            continue
        sewer = BRepBuilderAPI_Sewing(JOIN_REL * diagonal, True, True, True, False)
        for f in faces:
            sewer.Add(f)
        with quiet():
            sewer.Perform()
        sewn = sewer.SewedShape()
        if sewn is None or sewn.IsNull():
            raise KernelError(f"{path}: joining the patches failed")
        info["free_edges"] += sewer.NbFreeEdges()
        ex = TopExp_Explorer(sewn, TopAbs_SHELL)
        shells = []
        while ex.More():
            shells.append(TopoDS.Shell_s(ex.Current()))
            ex.Next()
        if not shells:  # a single face
            builder.Add(out, sewn)
            continue
        for shell in shells:
            info["shells"] += 1
            if solid and sewer.NbFreeEdges() == 0:
                maker = BRepBuilderAPI_MakeSolid(shell)
                body = maker.Solid()
                if _volume(body) < 0:
                    body.Reverse()
                builder.Add(out, body)
                info["solids"] += 1
            else:
                if solid:
                    info["open_solid_shells"] += 1
                builder.Add(out, shell)
    return out, info


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
