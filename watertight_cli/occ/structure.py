"""A STEP file's assembly structure and names, read through XCAF and written back around the
converted shapes (invariant I3: "assembly structure and names are kept").

A STEP file is a tree: assemblies hold components (an instance name and a placement) of other
assemblies or of parts, and a part (an XCAF simple shape, one product's geometry) holds bodies,
its solids and the shells outside solids. The pipeline converts every part once, in its own
coordinates, however many times the tree places it (``Structure.parts``); the output file gets the
same tree around the converted parts: the same assemblies, the same components at the same
placements, product and instance names, and the bodies' names (the names of the STEP
representation items, e.g. SolidWorks feature names on its solids).

Only this module touches XCAF. ``describe`` gives the tree as plain data (names, placements,
bodies), which the report shows and the read-back compares with the input's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from OCP.BRep import BRep_Builder
from OCP.IFSelect import IFSelect_RetDone
from OCP.Interface import Interface_Static
from OCP.STEPCAFControl import STEPCAFControl_Controller, STEPCAFControl_Reader, STEPCAFControl_Writer
from OCP.STEPControl import STEPControl_AsIs
from OCP.TCollection import TCollection_AsciiString, TCollection_ExtendedString
from OCP.TDataStd import TDataStd_Name
from OCP.TDF import TDF_Label, TDF_LabelSequence, TDF_Tool
from OCP.TDocStd import TDocStd_Document
from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL, TopAbs_SOLID
from OCP.TopExp import TopExp_Explorer
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS_Compound, TopoDS_Shape
from OCP.TopTools import TopTools_IndexedMapOfShape
from OCP.XCAFApp import XCAFApp_Application
from OCP.XCAFDoc import XCAFDoc_DocumentTool, XCAFDoc_ShapeTool

STEPCAFControl_Controller.Init_s()  # registers the write.stepcaf.* parameters

#: the name given to an unnamed node or component when written; ``io`` makes it '' in the file
UNNAMED = "watertight-unnamed-"
#: names that exporters write where an item has none (STEP's '' and CATIA's / SolidWorks' 'NONE')
_NO_NAME = ("", "NONE")


@dataclass
class Component:
    """One placement of a node inside an assembly."""

    name: str
    location: TopLoc_Location
    node: int  # index into Structure.nodes


@dataclass
class Node:
    """An assembly (``part`` None, with components) or a part (``part`` its index in Structure.parts)."""

    name: str
    part: int | None = None
    components: list[Component] = field(default_factory=list)


@dataclass
class Structure:
    """The tree of a STEP file: nodes, the roots (free shapes, in file order), the parts' shapes
    (each once, in its own coordinates) and per part its bodies' names (None where unnamed), in
    the order of ``bodies``."""

    nodes: list[Node]
    roots: list[int]
    parts: list[TopoDS_Shape]
    body_names: list[list[str | None]]

    def shape(self) -> TopoDS_Shape:
        """What the pipeline converts: the one part, or a compound of the parts (each once)."""
        if len(self.parts) == 1:
            return self.parts[0]
        return compound(self.parts)

    def trivial(self) -> bool:
        """One root part with no names worth keeping: writing it plainly loses nothing."""
        return (len(self.parts) == 1 and len(self.nodes) == 1 and not self.nodes[0].name
                and not any(n for n in self.body_names[0]))

    def describe(self) -> list[dict]:
        """The tree as plain data: per root, nested {"name", "components": [{"name", "placement",
        "node"}]} for an assembly, {"name", "bodies": [{"kind", "name"}]} for a part; a placement is
        the 3 x 4 matrix of its transformation (``same_tree`` compares two)."""

        def node(i: int) -> dict:
            n = self.nodes[i]
            if n.part is not None:
                shapes = bodies(self.parts[n.part])
                return {"name": n.name, "bodies": [
                    {"kind": "solid" if solid else "shell", "name": name}
                    for (_, solid), name in zip(shapes, self.body_names[n.part], strict=True)]}
            return {"name": n.name, "components": [
                {"name": c.name, "placement": _matrix(c.location).tolist(), "node": node(c.node)}
                for c in n.components]}

        return [node(r) for r in self.roots]

    def counts(self) -> dict:
        """Parts, assemblies, placed part instances (leaves of the tree) and named bodies."""

        def leaves(i: int) -> int:
            n = self.nodes[i]
            return 1 if n.part is not None else sum(leaves(c.node) for c in n.components)

        return {
            "parts": len(self.parts),
            "assemblies": sum(1 for n in self.nodes if n.part is None),
            "instances": sum(leaves(r) for r in self.roots),
            "named_bodies": sum(1 for names in self.body_names for n in names if n),
        }


def same_tree(a, b, placement_tol: float = 1e-9) -> bool:
    """Two ``Structure.describe`` trees are the same: names, kinds and nesting equal, placements
    within ``placement_tol`` (the 3 x 4 matrices, entry by entry)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return False
        return all(np.allclose(a[k], b[k], rtol=0.0, atol=placement_tol) if k == "placement"
                   else same_tree(a[k], b[k], placement_tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_tree(x, y, placement_tol) for x, y in zip(a, b, strict=True))
    return a == b


def bodies(shape: TopoDS_Shape) -> list[tuple[TopoDS_Shape, bool]]:
    """A shape's bodies as (shape, is a solid): its solids, then its shells outside solids, then
    its faces outside shells as one compound."""
    out = []
    for kind, avoid, solid in ((TopAbs_SOLID, None, True), (TopAbs_SHELL, TopAbs_SOLID, False)):
        ex = TopExp_Explorer(shape, kind) if avoid is None else TopExp_Explorer(shape, kind, avoid)
        while ex.More():
            out.append((ex.Current(), solid))
            ex.Next()
    loose = []
    ex = TopExp_Explorer(shape, TopAbs_FACE, TopAbs_SHELL)
    while ex.More():
        loose.append(ex.Current())
        ex.Next()
    if loose:
        out.append((compound(loose), False))
    return out


def read_step(path: str, heal: bool = True) -> tuple[bool, Structure | None, TopoDS_Shape | None, object]:
    """Read a STEP file through XCAF: (parsed, its structure, the shape to convert, the underlying
    STEP reader, for the file's units). The structure is None (and the shape the reader's one
    shape) where XCAF finds no part with faces in a file the reader transferred. ``heal`` False:
    without the reader's shape healing (``io.no_healing``)."""
    app = XCAFApp_Application.GetApplication_s()
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    app.InitDocument(doc)
    reader = STEPCAFControl_Reader()
    reader.SetNameMode(True)
    for off in (reader.SetColorMode, reader.SetLayerMode, reader.SetPropsMode, reader.SetGDTMode,
                reader.SetMatMode, reader.SetViewMode):
        off(False)
    step = reader.Reader()
    if reader.ReadFile(str(path)) != IFSelect_RetDone:
        return False, None, None, step
    if not heal:  # after reading: reading sets the parameters from the defaults
        from .io import no_healing  # io imports this module

        no_healing(reader)
        no_healing(step)  # the plain reader below, where XCAF finds no part
    structure = _structure(doc, step) if reader.Transfer(doc) else None
    if structure is None or not structure.parts:
        if step.NbShapes() == 0:
            step.TransferRoots()
        shape = step.OneShape() if step.NbShapes() else None
        return True, None, shape, step
    return True, structure, structure.shape(), step


def _name(label: TDF_Label) -> str:
    attr = TDataStd_Name()
    if label.FindAttribute(TDataStd_Name.GetID_s(), attr):
        name = attr.Get().ToExtString()
        return "" if name in _NO_NAME else name
    return ""


def _structure(doc, step) -> Structure | None:
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    free = TDF_LabelSequence()
    tool.GetFreeShapes(free)
    nodes: list[Node] = []
    parts: list[TopoDS_Shape] = []
    index: dict[str, int] = {}  # label entry -> node

    def visit(label: TDF_Label) -> int:
        entry = _entry(label)
        if entry in index:
            return index[entry]
        node = Node(name=_name(label))
        if XCAFDoc_ShapeTool.IsAssembly_s(label):
            comps = TDF_LabelSequence()
            XCAFDoc_ShapeTool.GetComponents_s(label, comps, False)
            for k in range(1, comps.Length() + 1):
                comp = comps.Value(k)
                ref = TDF_Label()
                if not XCAFDoc_ShapeTool.GetReferredShape_s(comp, ref):
                    continue
                node.components.append(Component(_name(comp), XCAFDoc_ShapeTool.GetLocation_s(comp),
                                                 visit(ref)))
        else:
            shape = XCAFDoc_ShapeTool.GetShape_s(label)
            if shape.IsNull() or not _has_faces(shape):
                node = None
            else:
                node.part = len(parts)
                parts.append(shape)
        if node is None:
            return -1
        index[entry] = len(nodes)
        nodes.append(node)
        return index[entry]

    roots = [r for r in (visit(free.Value(i)) for i in range(1, free.Length() + 1)) if r >= 0]
    # components whose node has no faces (a wireframe part) are left out
    for n in nodes:
        n.components = [c for c in n.components if c.node >= 0]
    transfer = step.WS().TransferReader()
    names = [[_item_name(transfer, b) for b, _ in bodies(p)] for p in parts]
    return Structure(nodes=nodes, roots=roots, parts=parts, body_names=names)


def _entry(label: TDF_Label) -> str:
    s = TCollection_AsciiString()
    TDF_Tool.Entry_s(label, s)
    return s.ToCString()


def _has_faces(shape: TopoDS_Shape) -> bool:
    return TopExp_Explorer(shape, TopAbs_FACE).More()


def _first_face(shape: TopoDS_Shape) -> TopoDS_Shape | None:
    ex = TopExp_Explorer(shape, TopAbs_FACE)
    return ex.Current() if ex.More() else None


def _item_name(transfer, shape: TopoDS_Shape) -> str | None:
    """The name of the STEP representation item (a solid's or shell's entity) that gave ``shape``."""
    try:
        item = transfer.EntityFromShapeResult(shape, 1)
    except Exception:  # noqa: BLE001 - a name is informative only
        return None
    name = getattr(item, "Name", None) if item is not None else None
    if name is None:
        return None
    text = name().ToCString()
    return None if text in _NO_NAME else text


def _matrix(location: TopLoc_Location) -> np.ndarray:
    t = location.Transformation()
    return np.array([[t.Value(i, j) for j in range(1, 5)] for i in range(1, 4)])


def compound(shapes) -> TopoDS_Compound:
    """The shapes in one compound."""
    builder = BRep_Builder()
    out = TopoDS_Compound()
    builder.MakeCompound(out)
    for s in shapes:
        builder.Add(out, s)
    return out


@dataclass
class Output:
    """A converted model to be written with its input's tree: per part, its output bodies (in the
    order of ``bodies`` of the input part; None where a body gave nothing)."""

    structure: Structure
    parts: list[list[TopoDS_Shape | None]]

    @classmethod
    def place(cls, structure: Structure, made: list[tuple[TopoDS_Shape, TopoDS_Shape | None]]) -> Output:
        """The output of every input body (``made``: pairs of an input body of the converted shape and
        what it became) placed in its part."""
        # a body is known by its first face (the loose faces' compound is made anew by ``bodies``),
        # looked up in one map rather than compared with every other body's
        firsts, outs = TopTools_IndexedMapOfShape(), []
        for body, out in made:
            face = _first_face(body)
            if face is not None and not firsts.Contains(face):
                firsts.Add(face)
                outs.append(out)
        parts = []
        for part in structure.parts:
            row = []
            for b, _ in bodies(part):
                face = _first_face(b)
                k = firsts.FindIndex(face) if face is not None else 0
                row.append(outs[k - 1] if k > 0 else None)
            parts.append(row)
        return cls(structure, parts)

    def shape(self) -> TopoDS_Shape:
        """The converted parts as one compound (each part once), for formats without a tree."""
        return compound([s for part in self.parts for s in part if s is not None])


def write_step(out: Output, tmp: str) -> bool:
    """Write ``out`` as STEP (AP214) through XCAF: the input's tree around the converted parts."""
    app = XCAFApp_Application.GetApplication_s()
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    app.InitDocument(doc)
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    st = out.structure
    labels: dict[int, TDF_Label] = {}

    def make(i: int) -> TDF_Label:
        if i in labels:
            return labels[i]
        node = st.nodes[i]
        if node.part is not None:
            shapes = [s for s in out.parts[node.part] if s is not None]
            names = st.body_names[node.part]
            # a part of one unnamed body is that body; a named body must be a sub-shape of its
            # part to carry its name, so it goes into a compound
            shape = shapes[0] if len(shapes) == 1 and not any(names) else compound(shapes)
            label = tool.AddShape(shape, False, False)
            for s, name in zip(out.parts[node.part], names, strict=True):
                if s is not None and name:
                    sub = tool.AddSubShape(label, s)
                    if not sub.IsNull():
                        _set_name(sub, name)
        else:
            label = tool.NewShape()
            for c in node.components:
                comp = tool.AddComponent(label, make(c.node), c.location)
                # a component without a name reads back named by its usage id, which ``io``
                # numbers in file order: the input's own names (its ids where it had no names) are kept
                _set_name(comp, c.name or f"{UNNAMED}c")
        # unnamed, the writer would name it with a per-process counter: a placeholder instead,
        # which ``io`` makes '' again (``UNNAMED``)
        _set_name(label, node.name or f"{UNNAMED}{i}")
        labels[i] = label
        return label

    for r in st.roots:
        make(r)
    tool.UpdateAssemblies()
    Interface_Static.SetIVal_s("write.stepcaf.subshapes.name", 1)
    writer = STEPCAFControl_Writer()
    writer.SetNameMode(True)
    writer.SetColorMode(False)
    writer.SetLayerMode(False)
    writer.SetPropsMode(False)
    writer.SetDimTolMode(False)
    writer.SetMaterialMode(False)
    if not writer.Transfer(doc, STEPControl_AsIs):
        return False
    return writer.Write(tmp) == IFSelect_RetDone


def _set_name(label: TDF_Label, name: str) -> None:
    TDataStd_Name.Set_s(label, TCollection_ExtendedString(name, True))
