"""Reading and writing STEP and IGES through OCCT, with every status checked.

Formats are chosen by file suffix through one registry (``FORMATS``). OCCT prints progress and
warnings to the process's stdout; every kernel call here runs inside ``quiet()`` so that stdout
carries only our own output (``--json`` must pipe into ``jq`` untouched).
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from OCP.IFSelect import IFSelect_RetDone
from OCP.IGESControl import IGESControl_Reader, IGESControl_Writer
from OCP.IGESData import IGESData_IGESWriter
from OCP.IGESSelect import IGESSelect_WorkLibrary
from OCP.Interface import Interface_Static
from OCP.Message import Message, Message_Gravity
from OCP.Resource import Resource_DataMapOfAsciiStringAsciiString
from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer
from OCP.TCollection import TCollection_AsciiString, TCollection_HAsciiString
from OCP.TColStd import TColStd_SequenceOfAsciiString
from OCP.TopoDS import TopoDS_Shape

from ..errors import InputError, OutputError
from .structure import UNNAMED, Output, Structure, read_step, write_step

STEP_SUFFIXES = (".step", ".stp")
IGES_SUFFIXES = (".igs", ".iges")


@contextlib.contextmanager
def quiet():
    """Silence OCCT: its messenger's printers and anything written to file descriptor 1."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def _silence_messenger() -> None:
    printers = Message.DefaultMessenger_s().Printers()
    for i in range(1, printers.Length() + 1):
        printers.Value(i).SetTraceLevel(Message_Gravity.Message_Fail)


_silence_messenger()


@dataclass(frozen=True)
class ReadResult:
    shape: TopoDS_Shape
    format: str  # "step" | "iges"
    units: str  # length unit named in the file, e.g. "MM", "INCH"; geometry is returned in mm
    # a STEP file's tree of assemblies, parts and names (``structure``); ``shape`` then holds
    # each part once
    structure: Structure | None = None


def format_of(path: str | Path) -> str:
    """"step" or "iges" from the suffix; InputError otherwise."""
    suffix = Path(path).suffix.lower()
    if suffix in STEP_SUFFIXES:
        return "step"
    if suffix in IGES_SUFFIXES:
        return "iges"
    raise InputError(path, f"unknown file type '{suffix or '(none)'}' (expected .step, .stp, .igs or .iges)")


def _sniff(path: Path, fmt: str) -> None:
    """Cheap structural checks that give a clear reason before OCCT gives a vague one."""
    size = path.stat().st_size
    if size == 0:
        raise InputError(path, "empty file")
    with open(path, "rb") as fh:
        head = fh.read(4096)
        fh.seek(max(0, size - 4096))
        tail = fh.read()
    if b"\0" in head:
        raise InputError(path, f"not a {fmt.upper()} file (binary content)")
    if fmt == "step":
        if b"ISO-10303-21" not in head[:1024]:
            raise InputError(path, "not a STEP file (no ISO-10303-21 header)")
        if b"END-ISO-10303-21" not in tail:
            raise InputError(path, "truncated STEP file (no END-ISO-10303-21 trailer)")
    else:
        first = head.split(b"\n", 1)[0].rstrip(b"\r")
        if len(first) < 73 or first[72:73] not in (b"S", b"G", b"F", b"C"):
            raise InputError(path, "not an IGES file (no start section in column 73)")
        last = tail.rstrip(b"\r\n").rsplit(b"\n", 1)[-1].rstrip(b"\r")
        if len(last) < 73 or last[72:73] != b"T":
            raise InputError(path, "truncated IGES file (no terminate section)")


#: the switches of the shape healing (``ShapeFix_Shape``) that OCCT's readers run after a transfer,
#: each set to 0 (off) by ``read_shape(heal=False)``
_FIX_MODES = (
    "FixSolidMode", "FixShellMode", "FixShellOrientationMode", "FixFaceMode", "FixFaceOrientationMode",
    "FixWireMode", "FixOrientationMode", "FixSameParameterMode", "FixEdgeSameParameterMode",
    "FixVertexPositionMode", "FixVertexToleranceMode", "FixFreeShellMode", "FixFreeFaceMode",
    "FixFreeWireMode", "FixAddNaturalBoundMode", "FixMissingSeamMode", "FixSmallAreaWireMode",
    "RemoveSmallAreaFaceMode", "FixIntersectingWiresMode", "FixLoopWiresMode", "FixSplitFaceMode",
    "FixEdgeCurvesMode",
)


def no_healing(reader) -> None:
    """Switch a reader's shape healing off: the shape is what the file says. The read-back of a
    written file measures the file, not what healing would make of it (and healing was 80 % of the
    kernel's transfer of occt__bug24595's output: 17.2 s against 3.5 s without)."""
    params = Resource_DataMapOfAsciiStringAsciiString()
    for mode in _FIX_MODES:
        params.Bind(TCollection_AsciiString(f"FixShape.{mode}"), TCollection_AsciiString("0"))
    reader.SetShapeFixParameters(params)


def read_shape(path: str | Path, heal: bool = True) -> ReadResult:
    """Read a STEP or IGES file into one OCCT shape, in millimetres.

    ``heal`` False switches the STEP reader's shape healing off (``no_healing``): for the read-back
    of a file this tool wrote. IGES files are read with healing either way: the IGES reader's
    healing parameters outlive the reader in OCCT 7.9 (a read without healing left the next IGES
    input of the process unhealed, and occ22470.igs then read with no gap at all).

    Raises InputError naming the file and the reason for every failure: missing, unreadable,
    empty, garbage, truncated, unknown suffix, or a file that holds no geometry.
    """
    path = Path(path)
    fmt = format_of(path)
    if not path.exists():
        raise InputError(path, "no such file")
    if not path.is_file():
        raise InputError(path, "not a regular file")
    if not os.access(path, os.R_OK):
        raise InputError(path, "permission denied")
    _sniff(path, fmt)

    # Reader settings are process-wide in OCCT: set them before every read of a batch.
    Interface_Static.SetCVal_s("xstep.cascade.unit", "MM")
    structure = None
    if fmt == "step":
        Interface_Static.SetIVal_s("read.step.product.mode", 1)
        with quiet():
            parsed, structure, shape, reader = read_step(path, heal)
        if not parsed:
            raise InputError(path, "the kernel cannot parse this STEP file")
    else:
        reader = IGESControl_Reader()
        Interface_Static.SetIVal_s("read.iges.bspline.continuity", 0)
        with quiet():
            status = reader.ReadFile(str(path))
            if status != IFSelect_RetDone:
                raise InputError(path, f"the kernel cannot parse this IGES file (status {int(status)})")
            shape = reader.OneShape() if reader.TransferRoots() else None
    if shape is None or shape.IsNull():
        raise InputError(path, "the file holds no shapes the kernel can transfer")
    return ReadResult(shape=shape, format=fmt, units=_units(reader, fmt), structure=structure)


def _units(reader, fmt: str) -> str:
    if fmt == "step":
        lengths, angles, solids = (TColStd_SequenceOfAsciiString() for _ in range(3))
        try:
            reader.FileUnits(lengths, angles, solids)
        except Exception:  # noqa: BLE001 - units are informative only
            return "unknown"
        names = {lengths.Value(i).ToCString() for i in range(1, lengths.Length() + 1)}
        return ",".join(sorted(names)) or "unknown"
    try:
        code = reader.Model().GlobalSection().UnitFlag()
    except Exception:  # noqa: BLE001
        return "unknown"
    return {1: "INCH", 2: "MM", 4: "FT", 5: "MI", 6: "M", 7: "KM", 8: "MIL", 9: "UM", 10: "CM",
            11: "UIN"}.get(int(code), "unknown")


def write_shape(shape: TopoDS_Shape | Output, path: str | Path, overwrite: bool = True) -> None:
    """Write a shape to STEP or IGES (by suffix) atomically: temp file in the target folder, then rename.

    An ``Output`` (converted parts in their input's tree) is written to STEP with that tree and its
    names; IGES, which has no such tree here, gets its parts as one compound.
    Nothing is left behind on failure: the temporary file is removed and the target untouched.
    """
    path = Path(path)
    try:
        fmt = format_of(path)
    except InputError as exc:
        raise OutputError(path, exc.reason) from None
    if path.exists() and not overwrite:
        raise OutputError(path, "exists (use --overwrite to replace it)")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(path, f"folder {folder} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=folder)
    os.close(fd)
    try:
        Interface_Static.SetCVal_s("write.step.unit", "MM")
        with quiet():
            if isinstance(shape, Output) and (fmt != "step" or shape.structure.trivial()):
                shape = shape.shape()
            _declare_uncertainty(shape.shape() if isinstance(shape, Output) else shape)
            if isinstance(shape, Output):
                Interface_Static.SetIVal_s("write.step.schema", 4)  # AP214
                ok = write_step(shape, tmp)
            elif fmt == "step":
                writer = STEPControl_Writer()
                Interface_Static.SetIVal_s("write.step.schema", 4)  # AP214
                # a fixed product name: OCCT's default carries a per-process counter (I6)
                Interface_Static.SetCVal_s("write.step.product.name", path.stem)
                ok = writer.Transfer(shape, STEPControl_AsIs) == IFSelect_RetDone
                ok = ok and writer.Write(tmp) == IFSelect_RetDone
            else:
                Interface_Static.SetCVal_s("write.iges.unit", "MM")
                ok = _write_iges(shape, tmp)
        if not ok or os.path.getsize(tmp) == 0:
            raise OutputError(path, f"the kernel failed to write {fmt.upper()}")
        _normalise_header(tmp, fmt, path.name, named=isinstance(shape, Output))
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _declare_uncertainty(shape: TopoDS_Shape) -> None:
    """Write the shape's largest vertex tolerance as the file's length uncertainty (STEP) or
    resolution (IGES), instead of OCCT's default, the average tolerance.

    A reader takes that figure as the precision within which a vertex must lie on each of its
    edges' pcurves. Where stage 2 leaves a corner off a neighbour's side (fusee: 1.7e-7 at a cusp,
    within the joining tolerance), an uncertainty of 1e-7 made OCCT's reader drop that pcurve and
    project the 3D curve again; the new pcurve left [0, 1]^2 by 2.4e-8 and the face read back
    trimmed (I1). Every vertex tolerance is at least the 1e-7 the build gives, so files without
    such corners keep 1e-7."""
    from OCP.ShapeAnalysis import ShapeAnalysis_ShapeTolerance
    from OCP.TopAbs import TopAbs_VERTEX

    largest = ShapeAnalysis_ShapeTolerance().Tolerance(shape, 1, TopAbs_VERTEX)
    Interface_Static.SetIVal_s("write.precision.mode", 2)  # the value below ("session")
    Interface_Static.SetRVal_s("write.precision.val", float(max(largest, 1e-7)))


#: the fixed creation and change date of every IGES file written (as the STEP header's time stamp)
IGES_STAMP = "20000101.000000"


def _write_iges(shape: TopoDS_Shape, tmp: str) -> bool:
    """IGES in B-rep mode (186 solids) with reals written to 14 significant digits.

    OCCT's IGES writer rounds reals to 10 significant digits by default. Neighbouring patches share
    bitwise-equal boundary rows, but after that rounding the read-back faces were 1.6e-8 apart
    (loft_minus_cylinder.igs); at 14 digits (about what OCCT writes to STEP) they are 1.0e-12 apart.
    OCCT's zero suppression drops the exponent of numbers printed in 20 characters or more
    ("-6.6613381477510E-16" came out as "-6.661338148"), so it stays off.
    """
    writer = IGESControl_Writer("MM", 1)
    if not writer.AddShape(shape):
        return False
    writer.ComputeModel()
    if writer.Model().NbEntities() == 0:
        return False
    # the same bytes for the same input (I6): OCCT stamps the global section with the time of
    # writing (creation and last change) and the user's login name as the author
    stamp = TCollection_HAsciiString(IGES_STAMP)
    gs = writer.Model().GlobalSection()
    gs.SetDate(stamp)
    gs.SetLastChangeDate(stamp)
    gs.SetAuthorName(TCollection_HAsciiString(""))
    writer.Model().SetGlobalSection(gs)
    iw = IGESData_IGESWriter(writer.Model())
    iw.FloatWriter().SetFormat("%.13E", True)
    iw.FloatWriter().SetZeroSuppress(False)
    iw.SendModel(IGESSelect_WorkLibrary.DefineProtocol_s())
    buf = io.BytesIO()
    if not iw.Print(buf):
        return False
    with open(tmp, "wb") as fh:
        fh.write(buf.getvalue())
    return True


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _normalise_header(tmp: str, fmt: str, name: str, named: bool = False) -> None:
    """Make output bytes depend on the input only (invariant I6).

    OCCT writes the temporary file's name and the current time into the STEP header; put the
    final name and a fixed time stamp there instead. ``named``: the products carry the input's
    names (an ``Output``), which are kept as they are ("Part 1" is a name, not a counter).
    """
    if fmt != "step":
        return
    import re

    with open(tmp, "rb") as fh:
        data = fh.read()
    safe = name.replace("'", "").encode("utf-8", "replace")
    data = re.sub(rb"FILE_NAME\('[^']*','[^']*'",
                  b"FILE_NAME('" + safe.replace(b"\\", b"") + b"','2000-01-01T00:00:00'", data, count=1)
    if not named:  # OCCT appends a per-process counter to the product name ("part 1", "part 2", ...)
        data = re.sub(rb"PRODUCT\('([^']*) \d+','\1 \d+'", rb"PRODUCT('\1','\1'", data)
    else:  # unnamed items were written with a placeholder (``structure.UNNAMED``)
        data = re.sub(rb"'" + UNNAMED.encode() + rb"\w*'", b"''", data)
    # and numbers assembly usages with a per-process counter too: number them in file order
    counter = iter(range(1, 1 << 62))
    data = re.sub(rb"NEXT_ASSEMBLY_USAGE_OCCURRENCE\('\d+'",
                  lambda m: b"NEXT_ASSEMBLY_USAGE_OCCURRENCE('%d'" % next(counter), data)
    with open(tmp, "wb") as fh:
        fh.write(data)
