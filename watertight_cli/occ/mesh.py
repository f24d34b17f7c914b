"""Triangles of a shape's faces, for pictures (``watertight_cli.scene`` and the HTML report).

The kernel's mesher (``BRepMesh_IncrementalMesh``) runs on a copy of the shape, coarse on purpose:
the pictures decimate to a few tens of thousands of triangles anyway. Nothing here is used for
measurement, apart from the read-back's tessellation check (``meshcheck``), which welds these
triangles and counts their edges.
"""

from __future__ import annotations

import numpy as np
from OCP.BRep import BRep_Tool
from OCP.BRepBuilderAPI import BRepBuilderAPI_Copy
from OCP.BRepMesh import BRepMesh_IncrementalMesh
from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL
from OCP.TopExp import TopExp_Explorer
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Shape

from .extract import diagonal, indexed
from .io import quiet


def triangulate(shape: TopoDS_Shape, deflection_rel: float = 2e-3, angle: float = 0.5, copy: bool = True,
                parallel: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per face, in the order of ``indexed(shape, TopAbs_FACE)`` (the model's face numbering):
    (vertices (n, 3) float, triangles (m, 3) int). A face the mesher leaves empty gives empty arrays.

    deflection_rel : chordal deflection relative to the bounding-box diagonal
    angle : angular deflection in radians
    copy : mesh a copy, so that the caller's shape stays unmeshed; False meshes the shape itself
        (a shape that is thrown away afterwards, such as the read-back's)
    parallel : the kernel meshes the faces on its thread pool (each face on its own, from the
        same edge discretization: the same triangles as one thread; 3.1 -> 1.6 s on
        occt__occ22470.igs's output, 3018 faces)
    """
    target = BRepBuilderAPI_Copy(shape, True, False).Shape() if copy else shape
    diag = diagonal(target) or 1.0
    with quiet():
        BRepMesh_IncrementalMesh(target, deflection_rel * diag, False, angle, parallel)
    fmap = indexed(target, TopAbs_FACE)
    out = []
    for fi in range(1, fmap.Extent() + 1):
        face = TopoDS.Face_s(fmap.FindKey(fi))
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(face, loc)
        if tri is None or tri.NbTriangles() == 0:
            out.append((np.zeros((0, 3)), np.zeros((0, 3), dtype=int)))
            continue
        trsf = loc.Transformation()
        identity = loc.IsIdentity()
        pts = np.empty((tri.NbNodes(), 3))
        for i in range(1, tri.NbNodes() + 1):
            p = tri.Node(i)
            pts[i - 1] = (p if identity else p.Transformed(trsf)).Coord()
        tris = np.array([tri.Triangle(i).Get() for i in range(1, tri.NbTriangles() + 1)], dtype=int) - 1
        out.append((pts, tris))
    return out


def measure_tessellation(shape: TopoDS_Shape, distance: float) -> dict:
    """``meshcheck.tessellation_check`` of the shape's faces, shell by shell (``shell_faces``),
    meshed in place (a shape the caller throws away afterwards, such as the read-back's), welded at
    ``distance``. A figure, not a gate: where the mesher fails, the summary holds the reason
    (``error``) and the caller goes on."""
    from ..meshcheck import tessellation_check

    try:
        faces = triangulate(shape, copy=False)
    except Exception as exc:  # the kernel's exceptions (Standard_Failure) share no narrower base
        text = str(exc).splitlines()
        return {"error": f"{type(exc).__name__}: {text[0] if text else 'no message'}"}
    return tessellation_check(faces, distance, shell_faces(shape))


def shell_faces(shape: TopoDS_Shape) -> list[list[int]]:
    """Per shell of the shape, the indices of its faces in ``indexed(shape, TopAbs_FACE)`` order."""
    fmap = indexed(shape, TopAbs_FACE)
    smap = indexed(shape, TopAbs_SHELL)
    out = []
    for si in range(1, smap.Extent() + 1):
        ex = TopExp_Explorer(smap.FindKey(si), TopAbs_FACE)
        faces = []
        while ex.More():
            faces.append(fmap.FindIndex(ex.Current()) - 1)
            ex.Next()
        out.append(sorted(set(faces)))
    return out
