"""The gap report of an input model: a JSON-ready dict and a readable table.

The dict carries ``schema_version``; bump it when a key changes meaning or disappears.
"""

from __future__ import annotations

import statistics

from . import __version__
from .gaps import PER_SPAN
from .inspect import Inspection, trimmed

SCHEMA_VERSION = 1
WORST_IN_TABLE = 10


def input_report(ins: Inspection) -> dict:
    """Everything ``watertight report`` says about one file."""
    m = ins.model
    gaps = sorted(ins.gaps, key=lambda g: -g.gap)
    values = [g.gap for g in gaps]
    max_gap = values[0] if values else 0.0
    if m.sewing is not None:  # the unsewn input's own gaps count too
        max_gap = max(max_gap, m.sewing.input_max_gap)
    edges = [e for e in m.edges if not e.degenerate]
    over = sum(1 for g in gaps if g.gap > g.tolerance)
    report = {
        "schema_version": SCHEMA_VERSION,
        "tool": f"watertight {__version__}",
        "file": m.path,
        "format": ins.format,
        "units_in_file": m.units,
        "length_unit": "mm",
        "diagonal": m.diagonal,
        "faces": len(m.faces),
        "surface_types": m.surface_types(),
        "trimmed_faces": sum(trimmed(f) for f in m.faces),
        "approximated_faces": sum(1 for f in m.faces if f.approximation > 0),
        "edges": len(edges),
        "seam_edges": sum(1 for e in edges if e.seam),
        "degenerate_edges": sum(1 for e in m.edges if e.degenerate),
        "free_edges": sum(1 for e in edges if e.uses == 1),
        "nonmanifold_edges": sum(1 for e in edges if e.uses > 2),
        "solids": m.solids,
        "shells": m.shells,
        # a STEP file's assemblies, parts, placements and names; faces, solids and gaps above count
        # every part once, however often the assemblies place it
        "structure": None if ins.structure is None else {**ins.structure.counts(),
                                                          "tree": ins.structure.describe()},
        "sewing": None if m.sewing is None else {
            "tolerance": m.sewing.tolerance,
            "free_edges_before": m.sewing.free_edges_before,
            "free_edges_after": m.sewing.free_edges_after,
            "edges_joined": m.sewing.edges_joined,
            "max_join_distance": m.sewing.max_join_distance,
            "max_gap_before_sewing": m.sewing.input_max_gap,
        },
        "gap": {
            "max": max_gap,
            "max_relative": max_gap / m.diagonal if m.diagonal else None,
            "max_curve_to_face": max((g.curve_gap for g in gaps), default=0.0),
            "max_face_to_face": max((g.face_gap for g in gaps), default=0.0),
            "median": statistics.median(values) if values else 0.0,
            "edges_over_tolerance": over,
            "max_edge_tolerance": max((e.tolerance for e in edges), default=0.0),
            "samples_per_edge": ins.samples,
            "samples_per_knot_span": PER_SPAN,
        },
        "conversion": {
            "note": "the B-spline arrays the pipeline works on: their gaps, and the error bound of "
                    "faces and curves that had to be approximated in their own parameterization",
            "max_gap": max((g.gap for g in ins.array_gaps), default=0.0),
            "max_approximation": max([f.approximation for f in m.faces]
                                     + [e.approximation for e in m.edges], default=0.0),
        },
        "edge_gaps": edge_gap_rows(gaps),
        "timing_s": {k: round(v, 4) for k, v in ins.timings.items()},
    }
    return report


def boundary_report(model, timings: dict | None = None) -> dict:
    """``report --boundary``: the topology-blind boundary gap (``boundary.boundary_gap``) as JSON."""
    import time

    from .boundary import PER_EDGE, boundary_gap

    t = time.perf_counter()
    g = boundary_gap(model)
    if timings is not None:
        timings["boundary"] = round(time.perf_counter() - t, 4)
    return {
        "note": "each boundary point's distance to the nearest boundary of another face, on the B-spline "
                "arrays (faces with angular parameters within 1e-10 of the diagonal of the kernel's)",
        "samples": g.samples,
        "samples_per_edge": PER_EDGE,
        "gap": g.matched_max,
        "gap_relative": g.matched_max / model.diagonal if model.diagonal else None,
        "where": None if g.where is None else [round(x, 9) for x in g.where],
        "unmatched": g.unmatched,
        "match_distance": g.match,
        "over_limit": g.over,
        "limit": g.limit,
    }


def edge_gap_rows(gaps) -> list[dict]:
    """Per-edge gaps as JSON rows, worst first (``where``: the worst sample's x, y, z)."""
    return [
        {"edge": g.edge, "faces": list(g.faces), "uses": g.uses, "gap": g.gap,
         "curve_to_face": g.curve_gap, "face_to_face": g.face_gap, "tolerance": g.tolerance,
         "where": [round(x, 9) for x in g.where]}
        for g in sorted(gaps, key=lambda g: -g.gap)
    ]


def format_table(r: dict) -> str:
    """A human-readable summary, worst edges first (for stderr)."""
    g = r["gap"]
    types = ", ".join(f"{k} {v}" for k, v in r["surface_types"].items())
    lines = [
        f"{r['file']}  ({r['format'].upper()}, units in file: {r['units_in_file']}, geometry in mm)",
        f"  faces {r['faces']} ({types}); trimmed {r['trimmed_faces']}",
        f"  edges {r['edges']} (seam {r['seam_edges']}, degenerate {r['degenerate_edges']}); "
        f"free {r['free_edges']}, non-manifold {r['nonmanifold_edges']}; solids {r['solids']}, "
        f"shells {r['shells']}; diagonal {r['diagonal']:.4g}",
    ]
    st = r.get("structure")
    if st and (st["assemblies"] or st["parts"] > 1):
        lines.append(f"  structure: {st['assemblies']} assemblies, {st['parts']} parts placed "
                     f"{st['instances']} times, {st['named_bodies']} named bodies (each part counted once "
                     "above)")
    if r["sewing"]:
        s = r["sewing"]
        lines.append(f"  sewn at tolerance {s['tolerance']:.3g}: free edges {s['free_edges_before']} -> "
                     f"{s['free_edges_after']}, {s['edges_joined']} joined, largest join distance "
                     f"{s['max_join_distance']:.3g}; max gap before sewing {s['max_gap_before_sewing']:.3g}")
    lines.append(f"  max gap {g['max']:.3g} ({g['max_relative']:.2g} of diagonal): curve-to-face "
                 f"{g['max_curve_to_face']:.3g}, face-to-face {g['max_face_to_face']:.3g}; median "
                 f"{g['median']:.3g}; {g['edges_over_tolerance']} edges exceed their tolerance")
    b = r.get("boundary")
    if b:
        lines.append(f"  boundary (topology-blind, {b['samples']} samples): largest distance to another "
                     f"face's boundary {b['gap']:.3g} ({(b['gap_relative'] or 0):.2g} of diagonal); "
                     f"{b['over_limit']} samples over {b['limit']:.3g}; {b['unmatched']} with no other "
                     f"boundary within {b['match_distance']:.3g}")
    worst = r["edge_gaps"][:WORST_IN_TABLE]
    if worst:
        lines.append(f"  {'edge':>6} {'faces':>10} {'gap':>10} {'C-S(pc)':>10} {'S1-S2':>10} "
                     f"{'tolerance':>10}  where")
        for e in worst:
            faces = ",".join(map(str, e["faces"])) or "-"
            where = " ".join(f"{x:.4g}" for x in e["where"])
            lines.append(f"  {e['edge']:>6} {faces:>10} {e['gap']:>10.3g} {e['curve_to_face']:>10.3g} "
                         f"{e['face_to_face']:>10.3g} {e['tolerance']:>10.3g}  ({where})")
    t = r["timing_s"]
    lines.append("  time " + ", ".join(f"{k} {v:.2f}s" for k, v in t.items()))
    return "\n".join(lines)
