"""OCCT on its own, for the benchmarks: the I/O floor and the tool chain a user would try instead.

The floor of a conversion is what no converter can avoid: reading its input and writing its output
with OCCT. ``io_floor`` times exactly that (the output is read untimed first, so that its shape can
be written again).

``bezier_baseline`` is what a user of OCCT alone would run to get Bezier faces: sewing
(``BRepBuilderAPI_Sewing``, its default tolerance 1e-6), ``ShapeFix_Shape``, ``BRepBuilderAPI_NurbsConvert``
and ``ShapeUpgrade_ShapeConvertToBezier`` (surfaces and 3D/2D curves). Its faces are Bezier pieces
that keep their trims, so most are not untrimmed; the benchmark counts them and measures the gap.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from OCP.BRepBuilderAPI import BRepBuilderAPI_NurbsConvert, BRepBuilderAPI_Sewing
from OCP.ShapeFix import ShapeFix_Shape
from OCP.ShapeUpgrade import ShapeUpgrade_ShapeConvertToBezier

from .io import quiet, read_shape, write_shape


def io_floor(src: str | Path, out: str | Path) -> dict[str, float]:
    """Seconds OCCT takes to read ``src`` and to write the shape held in ``out`` (as ``out``'s kind)."""
    t = time.perf_counter()
    read_shape(src)
    read_s = time.perf_counter() - t
    shape = read_shape(out).shape
    with tempfile.TemporaryDirectory(prefix="watertight_floor.") as tmp:
        t = time.perf_counter()
        write_shape(shape, Path(tmp) / f"floor{Path(out).suffix}")
        write_s = time.perf_counter() - t
    return {"read_s": read_s, "write_s": write_s}


def bezier_baseline(src: str | Path, dst: str | Path) -> dict[str, float]:
    """Run the OCCT-only chain on ``src`` and write its result to ``dst``; seconds per step."""
    times = {}
    t = time.perf_counter()
    shape = read_shape(src).shape
    times["read_s"] = time.perf_counter() - t
    t = time.perf_counter()
    with quiet():
        sewing = BRepBuilderAPI_Sewing()
        sewing.Add(shape)
        sewing.Perform()
        shape = sewing.SewedShape()
        fix = ShapeFix_Shape(shape)
        fix.Perform()
        shape = fix.Shape()
        nurbs = BRepBuilderAPI_NurbsConvert(shape, True)
        shape = nurbs.Shape()
        bezier = ShapeUpgrade_ShapeConvertToBezier(shape)
        bezier.SetSurfaceConversion(True)
        bezier.Set3dConversion(True)
        bezier.Set2dConversion(True)
        bezier.Perform()
        shape = bezier.Result()
    times["process_s"] = time.perf_counter() - t
    t = time.perf_counter()
    write_shape(shape, dst)
    times["write_s"] = time.perf_counter() - t
    return times
