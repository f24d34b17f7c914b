"""From measured models and converted patches to the arrays the HTML pages draw (``--html``).

The input's faces are triangulated by the kernel (``occ.mesh``); the output's patches are
evaluated here from their Bezier nets (so each triangle knows its source face, and the patch
sides are the drawn boundaries); edges come from the array model's 3D curves, coloured by their
measured gap. Budgets keep the arrays small whatever the model's size; ``html_report`` decimates
further for drawing.
"""

from __future__ import annotations

import time
from collections import defaultdict

import numpy as np

from .core.bernstein import basis
from .html_report import Scene, convert_page, report_page, write_html

EDGE_BUDGET = 8_000  # segments of gap-coloured edges handed to the renderer
PATCH_TRIANGLES = 60_000  # triangles of the evaluated patches before decimation
MARKS = 5  # numbered markers: the worst edges' worst samples


def edge_segments(model, gaps, budget: int = EDGE_BUDGET) -> tuple[np.ndarray, np.ndarray]:
    """Segments along the edges' 3D curves, worst gap first, and the gap of each segment.

    Points per edge shrink with the edge count (17 down to 2); past the budget the edges with
    the smallest gaps are left out.
    """
    order = sorted(gaps, key=lambda g: -g.gap)
    k = int(np.clip(budget // max(len(order), 1) + 1, 2, 17))
    segs, vals, used = [], [], 0
    for g in order:
        e = model.edges[g.edge]
        if e.curve is None or used >= budget:
            continue
        pts = e.curve.evaluate(np.linspace(e.first, e.last, k))
        segs.append(np.stack([pts[:-1], pts[1:]], axis=1))
        vals.append(np.full(k - 1, g.gap))
        used += k - 1
    if not segs:
        return np.zeros((0, 2, 3)), np.zeros(0)
    return np.concatenate(segs), np.concatenate(vals)


def _marks(gaps) -> np.ndarray:
    worst = sorted(gaps, key=lambda g: -g.gap)[:MARKS]
    return np.array([g.where for g in worst], dtype=float).reshape(-1, 3)


def input_scene(ins) -> Scene:
    """The input model: kernel triangles per face, edges coloured by the measured gaps."""
    from .occ.mesh import triangulate

    tris, groups = [], []
    for fi, (pts, t) in enumerate(triangulate(ins.shape)):
        if len(t):
            tris.append(pts[t])
            groups.append(np.full(len(t), fi))
    segs, vals = edge_segments(ins.model, ins.gaps)
    return Scene(triangles=np.concatenate(tris) if tris else np.zeros((0, 3, 3)),
                 groups=np.concatenate(groups) if groups else np.zeros(0, dtype=int),
                 edges=segs, edge_values=vals, marks=_marks(ins.gaps))


def patch_grids(patches, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every patch evaluated on an n x n grid of [0, 1]^2: ((P, n, n, 3), source face per patch).

    Patches of one shape are evaluated together (one einsum per degree pair and rationality).
    """
    s = np.linspace(0.0, 1.0, n)
    by_shape = defaultdict(list)
    for i, p in enumerate(patches):
        by_shape[p.ctrl.shape].append(i)
    out = np.zeros((len(patches), n, n, 3))
    for shape, idx in by_shape.items():
        c = np.stack([patches[i].ctrl for i in idx]).astype(float)
        g = np.einsum("ai,pijd,bj->pabd", basis(shape[0] - 1, s), c, basis(shape[1] - 1, s))
        if shape[2] == 4:  # homogeneous (premultiplied) rational net
            g = g[..., :3] / g[..., 3:]
        out[idx] = g
    return out, np.array([p.face for p in patches], dtype=int)


def output_scene(patches, read_back=None) -> Scene:
    """The converted model: its patches coloured by source face, their sides as boundary lines,
    and (when the written file was read back) its edges coloured by the gaps measured on it."""
    count = max(len(patches), 1)
    n = int(np.clip(np.sqrt(PATCH_TRIANGLES / (2 * count)) + 1, 2, 9))
    grids, faces = patch_grids(patches, n)
    a, b, c, d = (grids[:, :-1, :-1], grids[:, 1:, :-1], grids[:, 1:, 1:], grids[:, :-1, 1:])
    tris = np.concatenate([np.stack([a, b, c], axis=-2).reshape(-1, 3, 3),
                           np.stack([a, c, d], axis=-2).reshape(-1, 3, 3)])
    per = (n - 1) ** 2
    groups = np.concatenate([np.repeat(faces, per), np.repeat(faces, per)])
    sides = [grids[:, 0], grids[:, -1], grids[:, :, 0], grids[:, :, -1]]  # each (P, n, 3)
    lines = np.concatenate([np.stack([s[:, :-1], s[:, 1:]], axis=2).reshape(-1, 2, 3) for s in sides])
    notes = [f"{len(patches)} patches evaluated on {n} x {n} grids"]
    if read_back is not None:
        segs, vals = edge_segments(read_back.model, read_back.gaps)
        marks = _marks(read_back.gaps)
    else:
        segs, vals, marks = np.zeros((0, 2, 3)), None, np.zeros((0, 3))
        notes.append("edges not drawn: the written file was not read back (--fast)")
    return Scene(triangles=tris, groups=groups, edges=segs, edge_values=vals, lines=lines, marks=marks,
                 notes=notes)


# ------------------------------------------------------------------------------------ the pages


def report_item(rep: dict, ins) -> tuple[dict, Scene]:
    """What the report page needs of one measured file (built while its Inspection is alive)."""
    return rep, input_scene(ins)


def write_report_html(path: str, items: list[tuple[dict, Scene]], errors: list[str], settings: dict) -> None:
    write_html(path, report_page(items, errors, settings))


def write_convert_html(path: str, rep: dict, keep: dict, settings: dict, tol) -> float:
    """Build and write the convert page; returns the seconds it took."""
    t = time.perf_counter()
    ins, result = keep.get("inspection"), keep.get("result")
    before = input_scene(ins) if ins is not None else None
    after = output_scene(result.patches, keep.get("read_back")) if result is not None else None
    if "before" not in rep and ins is not None:  # --stage untrim: the input's gaps from its measurement
        from .report import edge_gap_rows

        m = ins.model
        rep = dict(rep, before={
            "gap_max": max((g.gap for g in ins.gaps), default=0.0),
            "free_edges": sum(1 for e in m.edges if not e.degenerate and e.uses == 1),
            "solids": m.solids, "shells": m.shells, "edge_gaps": edge_gap_rows(ins.gaps)})
    d = rep["diagonal"]
    marks = [("gap limit after (I2)", tol.watertight_rel * d, "#4c72b0"),
             ("--tolerance", tol.approx_rel * d, "#55a868")]
    text = convert_page(rep, before, after, settings, marks, time.perf_counter() - t)
    write_html(path, text)
    return time.perf_counter() - t
