"""Load a model and measure it: the work behind ``watertight report``.

read (OCCT) -> sew if unconnected -> sample the input's edges with the kernel -> arrays -> gaps.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .gaps import EdgeGap, edge_gaps, max_gap, model_tracks
from .model import Model
from .tolerances import Tolerances


@dataclass
class Inspection:
    """A loaded model with its measured gaps.

    gaps : per edge, measured on the input geometry (kernel samples)
    array_gaps : per edge, measured on the array model (after conversion to B-splines)
    """

    model: Model
    format: str
    gaps: list[EdgeGap]
    array_gaps: list[EdgeGap]
    timings: dict[str, float] = field(default_factory=dict)
    samples: int = 0
    shape: object = None  # the prepared OCCT shape (sewn input); opaque outside watertight_cli.occ
    # a STEP file's assemblies, parts and names (``occ.structure.Structure``; None for IGES, and
    # where the faces were sewn, which makes new ones); opaque outside watertight_cli.occ
    structure: object = None


class _Clock:
    def __init__(self):
        self.times: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now


def inspect(path: str, tol: Tolerances, array_gaps: bool = True, kernel_tracks: bool = True,
            heal: bool = True) -> Inspection:
    """Read, sew if needed, convert to arrays and measure one file. Raises WatertightError.

    ``array_gaps`` False skips measuring the gaps of the array model (``Inspection.array_gaps``
    stays empty): only ``watertight report`` shows them, the conversion works from the kernel's.
    ``kernel_tracks`` False measures ``gaps`` on the array model instead of kernel samples (the
    read-back of a written file, whose faces are Bezier patches that the arrays hold exactly:
    the kernel's per-point evaluation took a third of the read-back). ``heal`` False reads
    without the kernel's shape healing (``occ.io.no_healing``; the read-back too).
    """
    from .errors import KernelError

    try:
        return _inspect(path, tol, array_gaps, kernel_tracks, heal)
    except KernelError as exc:  # name the file in every message
        if str(path) in str(exc):
            raise
        raise KernelError(f"{path}: {exc}") from exc


def _inspect(path: str, tol: Tolerances, want_array_gaps: bool = True,
             kernel_tracks: bool = True, heal: bool = True) -> Inspection:
    from .occ.extract import build_model, prepare, sample_tracks
    from .occ.io import read_shape

    clock = _Clock()
    read = read_shape(path, heal)
    clock.lap("read")
    shape, diag, sewing = prepare(read, str(path), tol)
    clock.lap("sew")
    params: dict = {}
    tracks = sample_tracks(shape, tol.gap_samples, params=params) if kernel_tracks else None
    clock.lap("sample")
    model = build_model(shape, read, diag, sewing, str(path), tol)
    clock.lap("arrays")
    if tracks is None:  # measured on the arrays: the same samples serve both
        gaps = edge_gaps(model, model_tracks(model, tol))
        array_gaps = gaps if want_array_gaps else []
    else:
        gaps = edge_gaps(model, tracks)
        array_gaps = edge_gaps(model, model_tracks(model, tol, params)) if want_array_gaps else []
    clock.lap("measure")
    if sewing is not None:
        # the input as read (faces apart): each face's own C vs S(pc), what other tools measure
        sewing.input_max_gap = max_gap(sample_tracks(read.shape, tol.gap_samples))
        joined = [g.face_gap for g in gaps if g.uses == 2]
        sewing.max_join_distance = max(joined, default=0.0)
        clock.lap("measure")
    return Inspection(model=model, format=read.format, gaps=gaps, array_gaps=array_gaps,
                      timings=clock.times, samples=tol.gap_samples, shape=shape,
                      structure=read.structure if sewing is None else None)


def trimmed(face, rel: float = 1e-9) -> bool:
    """True unless the face is a plain parameter rectangle of its surface.

    A face is untrimmed when it has one loop and every pcurve lies on a side of the face's own
    parameter box (all its poles on one iso-line u = u0, u = u1, v = v0 or v = v1): such a face
    needs no reparameterization, only a sub-box of its surface. A rectangular piece of a plane
    or a full cylinder between two circles is untrimmed in this sense.
    """
    if len(face.loops) != 1:
        return True
    u0, u1, v0, v1 = face.uv_bounds
    eu, ev = rel * max(1.0, u1 - u0), rel * max(1.0, v1 - v0)
    for ce in face.loops[0].coedges:
        if ce.pcurve is None:
            return True
        p = ce.pcurve.poles
        on = (np.all(np.abs(p[:, 0] - u0) <= eu) or np.all(np.abs(p[:, 0] - u1) <= eu)
              or np.all(np.abs(p[:, 1] - v0) <= ev) or np.all(np.abs(p[:, 1] - v1) <= ev))
        if not on:
            return True
    return False
