"""``watertight convert``: read -> stage 1 (untrim) -> verify -> stage 2 (substitute) -> build ->
write -> verify the written file, with a before/after report.

``stage="untrim"`` stops after stage 1 and writes one open shell of untrimmed Bezier faces that keep
their input faces' shapes but share no edges. The full conversion substitutes one shared curve per
boundary (``substitute``), joins the patches per input shell into shells and solids
(``occ.assemble``), writes atomically, then reads the file back and measures invariants I1-I4 on it
with the project's own code (``--fast`` skips the re-read).

Nothing is written when the stage-1 verify fails: a wrong model is worse than no model.
"""

from __future__ import annotations

import statistics
import time
from collections import Counter
from pathlib import Path

from . import __version__
from .errors import WatertightError
from .tolerances import Tolerances

STAGES = ("full", "untrim")


class VerifyError(WatertightError):
    """The converted model failed the own verify step; nothing was written."""


def convert_file(src: str, dst: str | None, tol: Tolerances, stage: str = "full",
                 progress=None, overwrite: bool = True, fast: bool = False, keep: dict | None = None) -> dict:
    """Convert one file; returns its report. ``dst`` None: convert and verify, write nothing.

    ``progress(stage_name, total)`` returns a callable advanced by one per item (faces for untrim
    and verify, patches for build), or None.
    Raises WatertightError (one line, naming the file) on any failure, before anything is written.
    ``keep``, when given, receives the measured input ("inspection"), the patches ("result"), in a
    full conversion the joined B-rep ("shape", for diagnostics) and, after the read-back, the
    written file's measurement ("read_back"), for the HTML pictures.
    """
    from .inspect import inspect
    from .occ.build import input_face_areas, open_shell, patch_face
    from .occ.io import write_shape
    from .sameparam import retime
    from .verify import verify_untrim

    if stage not in STAGES:
        raise WatertightError(f"{src}: stage {stage!r} is not built yet")
    if dst is not None and Path(dst).exists() and not overwrite:
        raise WatertightError(f"{dst}: exists (use --overwrite to replace it)")
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    ins = inspect(src, tol, array_gaps=False)
    model = ins.model
    times["read"] = time.perf_counter() - t0

    # pcurves that run at another speed than their edge (real files, near edge ends) get an
    # exact re-timed copy, so the edge plan cuts every face at the same points (``sameparam``)
    t = time.perf_counter()
    pristine = list(model.faces)
    retimed = retime(model, tol)
    prepared = list(model.faces)
    t_retime = time.perf_counter() - t

    t = time.perf_counter()
    result = _stage1(model, tol, progress)
    # a re-timed pcurve is a repair: a face that stage 1 cannot decompose with it (cuts moved along
    # a wiggly near-iso pcurve can fold a cell) keeps its input pcurves, and stage 1 runs again
    failed = {fr.face for fr in result.faces if fr.problems}
    back = {r.face for r in retimed if r.face in failed}
    if back:
        model.faces[:] = [pristine[i] if i in back else f for i, f in enumerate(prepared)]
        retimed = [r for r in retimed if r.face not in back]
        result = _stage1(model, tol, progress)
    # stage 1 split in three: the edge plan, the cells, the reparameterization (which also takes
    # the retries and what the sub-timers do not see)
    sub = result.timings()
    times["plan"], times["cells"] = sub["plan"] + t_retime, sub["cells"]
    times["reparam"] = max(0.0, time.perf_counter() - t - sub["plan"] - sub["cells"])
    if keep is not None:
        keep.update(inspection=ins, result=result)

    t = time.perf_counter()
    areas = input_face_areas(ins.shape)
    tick = progress("verify", len(model.faces)) if progress else None
    check = verify_untrim(model, result, tol, areas, tick)
    times["verify"] = time.perf_counter() - t

    report = untrim_report(ins, result, check, tol, src, dst)
    report["retimed_pcurves"] = {
        "count": len(retimed),
        "mismatch_before_max": max((r.before for r in retimed), default=0.0),
        "mismatch_after_max": max((r.after for r in retimed), default=0.0),
        "trace_gap_max": max((r.trace_gap for r in retimed), default=0.0),
        "faces_kept_as_read": len(back),
    }
    report["timings"] = times
    if not check.ok:
        first = check.problems[0]
        more = len(check.problems) - 1
        raise VerifyError(f"{src}: verify failed, nothing written: {first}"
                          + (f" (and {more} more)" if more else ""))
    if stage == "full":
        from .stage2 import finish

        return finish(ins, result, report, tol, src, dst, progress, overwrite, fast, keep,
                      [fc.side_per_patch for fc in check.faces])
    if dst is not None:
        from .occ.assemble import input_groups
        from .occ.structure import Output
        from .topology import JOIN_REL, flat

        t = time.perf_counter()
        tick = progress("build", len(result.patches)) if progress else None
        faces: dict[int, list] = {}
        dropped = 0
        for p in result.patches:
            # a patch without area (every row one point: a cell between coinciding sides) is not a
            # face; written, the STEP reader rebuilt its pcurves across it (U_Joint_2: 4 trimmed
            # read-back faces). A full conversion drops the same patches when it joins them.
            if flat(p.ctrl, p.rational, JOIN_REL * model.diagonal):
                dropped += 1
            else:
                face = patch_face(p.ctrl, p.rational, model.faces[p.face].reversed)
                faces.setdefault(p.face, []).append(face)
            if tick is not None:
                tick(1)
        if ins.structure is None:
            shape = open_shell([f for i in sorted(faces) for f in faces[i]])
        else:  # one open shell per input body, placed in the input's tree
            shape = Output.place(ins.structure, [
                (body, open_shell([f for i in group for f in faces.get(i, [])]))
                for group, _, body in input_groups(ins.shape)])
        write_shape(shape, dst, overwrite=overwrite)
        report["faces_written"], report["flat_patches_dropped"] = sum(map(len, faces.values())), dropped
        times["write"] = time.perf_counter() - t
    report["timings"] = times
    return report


def _stage1(model, tol: Tolerances, progress):
    """Stage 1 on the whole model, with half the tolerance first (in a full conversion the
    substitution moves an approximated patch's boundary by up to its approximation error plus the
    input's gap, so stage 2 gets the other half), and the whole tolerance for faces that half
    cannot decompose (a fold that only a coarser side unfolds); the read-back check says if their
    total stays within. ``--stage untrim`` runs the same, so that its patches are the ones a full
    conversion substitutes (at the whole tolerance alone, gmsh__wing_fuselage.step face 13 kept a
    fold that the half-tolerance edge plan does not make)."""
    from .untrim import UntrimError, untrim, untrim_face

    tick = progress("untrim", len(model.faces)) if progress else None
    result = untrim(model, tol.with_(approx_rel=0.5 * tol.approx_rel), tick)
    for i, fr in enumerate(result.faces):
        if fr.problems:
            try:
                retry = untrim_face(model.faces[fr.face], model, result.plan_for(fr.face), tol)
            except UntrimError:
                continue
            if not retry.problems:
                result.faces[i] = retry
    return result


def untrim_report(ins, result, check, tol: Tolerances, src: str, dst: str | None) -> dict:
    from .report import SCHEMA_VERSION

    model = ins.model
    degrees = [max(p.degrees) for p in result.patches]
    faces = []
    for fr, fc in zip(result.faces, check.faces, strict=True):
        fd = [max(p.degrees) for p in fr.patches]
        faces.append({
            "face": fr.face,
            "surface_type": model.faces[fr.face].surface_type,
            "patches": len(fr.patches),
            "max_degree": max(fd, default=0),
            "approximated": fr.approximated,
            "bound": fr.bound,
            "bound_is_estimate": fr.estimated,
            "deviation_sampled": fc.deviation,
            "side_deviation_sampled": fc.side_deviation,
            "loop_closure": fr.closure,
            "area_in": fc.area_in,
            "area_out": fc.area_out,
            "folded_patches": fc.folded,
            "collapsed_rungs": fc.collapsed_rungs,
            "thin_patches": fc.thin,
            "plan_cuts_left_out": fr.strip_cuts,
            "pole_caps": fr.pole_caps,
            "wraps": fr.wraps,
            "problems": fc.problems,
        })
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": f"watertight {__version__}",
        "file": src,
        "output": dst,
        "stage": "untrim",
        "length_unit": "mm",
        "diagonal": model.diagonal,
        "tolerance": result.tolerance,
        "max_degree_allowed": result.max_degree,
        "faces_in": len(model.faces),
        "patches_out": len(degrees),
        "degree": {
            "max": max(degrees, default=0),
            "median": statistics.median(degrees) if degrees else 0,
            "histogram": {str(k): v for k, v in sorted(Counter(degrees).items())},
        },
        "approximated_faces": sum(f.approximated for f in result.faces),
        "bound_max": max((f.bound for f in result.faces), default=0.0),
        "deviation_max_sampled": max((c.deviation for c in check.faces), default=0.0),
        "folded_patches": sum(c.folded for c in check.faces),
        "collapsed_rungs": sum(c.collapsed_rungs for c in check.faces),
        "thin_patches": sum(c.thin for c in check.faces),
        "plan_cuts_left_out": sum(f.strip_cuts for f in result.faces),
        "pole_caps": sum(f.pole_caps for f in result.faces),
        "wraps": sum(f.wraps for f in result.faces),
        "verified": check.ok,
        "faces": faces,
    }


def format_untrim_table(rep: dict) -> str:
    d = rep["diagonal"]
    lines = [
        f"{rep['file']} -> {rep['output'] or '(not written)'}  [stage: {rep['stage']}]",
        f"  faces in {rep['faces_in']}, patches out {rep['patches_out']}, degree max {rep['degree']['max']} "
        f"median {rep['degree']['median']:g}, approximated faces {rep['approximated_faces']}",
        f"  deviation: bound {rep['bound_max']:.3g} ({rep['bound_max'] / d:.2g} of the diagonal), sampled "
        f"{rep['deviation_max_sampled']:.3g}; tolerance {rep['tolerance']:.3g}",
        f"  folded patches {rep['folded_patches']}, collapsed rungs {rep['collapsed_rungs']}, "
        f"thin patches {rep['thin_patches']}, "
        f"verified {'yes' if rep['verified'] else 'NO'}",
        "  time: " + ", ".join(f"{k} {v:.1f}s" for k, v in rep["timings"].items()),
    ]
    return "\n".join(lines)
