"""The ``watertight`` command line.

Library errors (``WatertightError``) become one-line messages naming the file and the reason;
nothing here prints a traceback. Heavy modules (OCP, scipy) are imported inside the commands so
that ``watertight --help`` answers at once.

Exit codes (also in ``watertight --help``):
  0  all files processed and within the gates
  1  some file failed (unreadable, invalid, or the conversion failed)
  2  usage error (bad option or argument)
  3  a gate was exceeded (``--max-gap``, ``--max-deviation``) or, for convert, an invariant of
     the written model failed
"""

from __future__ import annotations

import json
import os
import sys

import click

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_GATE = 0, 1, 2, 3

EPILOG = """\b
Exit codes:
  0  all files processed and within the gates
  1  some file failed (unreadable, invalid or not convertible)
  2  usage error
  3  a gate (--max-gap, --max-deviation) was exceeded, or an invariant of a converted
     model (I1-I4, validity) failed; the output is written and the report says which
"""


def _jsonable(obj):
    """numpy scalars and arrays in a report become plain JSON numbers and lists."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _err(msg: str) -> None:
    click.echo(f"watertight: error: {msg}", err=True)


class FileOutcome:
    """What happened to one file: its report or its one-line error."""

    def __init__(self, path: str, report: dict | None = None, error: str | None = None,
                 gate: str | None = None):
        self.path, self.report, self.error, self.gate = path, report, error, gate


class RunReport:
    """Collects per-file outcomes; ``exit_code`` is the one place that decides the exit status."""

    def __init__(self):
        self.outcomes: list[FileOutcome] = []

    def add(self, outcome: FileOutcome) -> None:
        self.outcomes.append(outcome)

    @property
    def exit_code(self) -> int:
        if any(o.error for o in self.outcomes):
            return EXIT_FAILED
        if any(o.gate for o in self.outcomes):
            return EXIT_GATE
        return EXIT_OK


def _measure(path: str, tol, pages: list | None = None) -> dict:
    from .inspect import inspect
    from .report import input_report

    ins = inspect(path, tol)
    rep = input_report(ins)
    if pages is not None:  # --html: the pictures' arrays, while the shape is at hand
        from .scene import report_item

        pages.append(report_item(rep, ins))
    return rep


def _write_html(write, path: str, run: RunReport) -> None:
    """--html: write the page; a failure is one more failed file (exit 1), never a traceback."""
    _, error = _run_guarded(write, path)
    if error:
        _err(error)
        run.add(FileOutcome(path, error=error))


def _run_guarded(fn, path: str):
    """Run fn(); return (result, None) or (None, one-line reason). Never lets a traceback out."""
    from .errors import WatertightError

    try:
        return fn(), None
    except WatertightError as exc:
        return None, str(exc)
    except MemoryError:
        return None, f"{path}: out of memory"
    except Exception as exc:  # noqa: BLE001 - converted once, here, at the edge
        if os.environ.get("WATERTIGHT_DEBUG"):
            raise
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return None, (f"{path}: internal error ({type(exc).__name__}: {reason}); "
                      "set WATERTIGHT_DEBUG=1 for details")


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
             epilog=EPILOG)
@click.version_option(package_name="watertight_cli", prog_name="watertight")
def main():
    """Turn trimmed CAD models (STEP, IGES) into watertight models of untrimmed Bezier patches.

    Trimmed B-rep faces leave gaps where neighbours meet, because an edge's 3D curve and each
    face's surface(pcurve) are three different curves. `watertight report` measures those gaps.
    """


@main.command(epilog=EPILOG)
@click.argument("models", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True,
              help="Print the report as JSON on stdout (schema_version inside). The table still goes to "
                   "stderr unless -q.")
@click.option("--max-gap", type=float, default=None, metavar="X",
              help="Gate: exit 3 when a file's largest gap exceeds X (model units, mm).")
@click.option("--samples", type=click.IntRange(3, 10000), default=33, show_default=True,
              help="Samples per edge for gap measurement (equally spaced, ends included).")
@click.option("-q", "--quiet", is_flag=True, help="No table on stderr.")
@click.option("--html", "html_path", type=click.Path(dir_okay=False), default=None, metavar="PATH",
              help="Also write a self-contained HTML page to PATH: gap histogram, worst edges with "
                   "their locations, pictures of the model with edges coloured by gap.")
def report(models, as_json, max_gap, samples, quiet, html_path):
    """Measure how far MODELS are from watertight.

    For every edge: the largest distance between its 3D curve C and each face's surface(pcurve),
    and between the two faces' boundary curves S1(pc1) and S2(pc2), over equally spaced samples,
    next to the edge's tolerance. For the model: faces by surface type, trimmed faces, free and
    non-manifold edges, solids and shells, the diagonal and, for inputs whose faces are not
    connected (IGES 144, STEP surface models), what sewing recovered.

    A table goes to stderr, worst edges first; --json prints the full report on stdout.
    """
    from .tolerances import Tolerances

    tol = Tolerances(gap_samples=samples)
    run = RunReport()
    pages = [] if html_path else None
    for path in models:
        rep, error = _run_guarded(lambda p=path: _measure(p, tol, pages), path)
        gate = None
        if rep is not None and max_gap is not None and rep["gap"]["max"] > max_gap:
            gate = f"{path}: max gap {rep['gap']['max']:.3g} exceeds --max-gap {max_gap:g}"
        run.add(FileOutcome(path, rep, error, gate))
        if error:
            _err(error)
        elif not quiet:
            from .report import format_table

            click.echo(format_table(rep), err=True)
        if gate:
            _err(gate)
    if html_path:
        from .scene import write_report_html

        settings, errors = click.get_current_context().params, [o.error for o in run.outcomes if o.error]
        _write_html(lambda: write_report_html(html_path, pages, errors, settings), html_path, run)
    if as_json:
        from .report import SCHEMA_VERSION

        payload = [o.report or {"schema_version": SCHEMA_VERSION, "file": o.path, "error": o.error}
                   for o in run.outcomes]
        doc = payload[0] if len(payload) == 1 else {"schema_version": SCHEMA_VERSION, "files": payload}
        sys.stdout.write(json.dumps(doc, indent=1, default=_jsonable) + "\n")
    sys.exit(run.exit_code)


def _progress_factory(enabled: bool, path: str):
    """progress(stage, total) -> tick callable, drawing a tqdm bar on stderr (None when disabled)."""
    if not enabled:
        return None
    from tqdm import tqdm

    bars = []

    def make(stage: str, total: int):
        for b in bars:
            b.close()
        bar = tqdm(total=total, desc=f"{os.path.basename(path)}: {stage}", leave=False,
                   file=sys.stderr, disable=None)
        bars.append(bar)
        return bar.update

    make.close = lambda: [b.close() for b in bars]  # type: ignore[attr-defined]
    return make


@main.command(epilog=EPILOG)
@click.argument("source", type=click.Path(dir_okay=False))
@click.argument("target", type=click.Path(dir_okay=False))
@click.option("--stage", type=click.Choice(["full", "untrim"]), default="full", show_default=True,
              help="full: untrimmed Bezier patches whose neighbours share one boundary curve "
                   "(a watertight B-rep). untrim: stage 1 only, patches that keep their faces' "
                   "shapes but share no edges.")
@click.option("--max-degree", type=click.IntRange(1, 25), default=25, show_default=True,
              help="Largest patch degree. Cells whose exact degree is higher are approximated within "
                   "--tolerance.")
@click.option("--tolerance", type=click.FloatRange(min=0.0, min_open=True), default=1e-6,
              show_default=True, metavar="REL",
              help="Allowed deviation where approximation is needed, relative to the model's "
                   "bounding-box diagonal (1e-6: one micron on a one-metre part).")
@click.option("--json", "as_json", is_flag=True, help="Print the conversion report as JSON on stdout.")
@click.option("--overwrite/--no-overwrite", default=True, show_default=True,
              help="Replace TARGET when it exists.")
@click.option("--fast", is_flag=True, help="Do not read the written file back to verify it.")
@click.option("--max-gap", type=float, default=None, metavar="X",
              help="Gate: exit 3 when the gap after conversion exceeds X (model units).")
@click.option("--max-deviation", type=float, default=None, metavar="X",
              help="Gate: exit 3 when a face's deviation bound exceeds X (model units).")
@click.option("-q", "--quiet", is_flag=True, help="No table and no progress bar on stderr.")
@click.option("--html", "html_path", type=click.Path(dir_okay=False), default=None, metavar="PATH",
              help="Also write a self-contained HTML page to PATH: gaps before and after, worst edges, "
                   "pictures before and after, degrees and deviation per face, settings and times.")
def convert(source, target, stage, max_degree, tolerance, as_json, overwrite, fast, max_gap,
            max_deviation, quiet, html_path):
    """Convert SOURCE (STEP or IGES) into a watertight model of untrimmed Bezier patches, TARGET.

    Every trimmed face is split into Bezier patches on [0,1]^2 (stage 1); then every patch side
    on an edge takes the edge's one shared curve, so neighbouring faces meet exactly (stage 2),
    and the patches are joined into shells and solids. TARGET's suffix picks the format
    (.step/.stp or .igs/.iges).

    Checks: every stage-1 patch is verified against its input face (sampled deviation within
    the bound, trimming sides on the input's surface(pcurve), summed area, no folds) before
    anything is written; the file is written atomically (no partial TARGET); then it is read
    back and measured: all faces untrimmed Bezier (I1), gaps after at most 1e-12 of the
    diagonal (I2), no new free edges (I3), each face's deviation bound within the tolerance plus
    the input's own gap at its edges (I4), kernel validity. A failed invariant exits 3, with the
    file written.

    The report (stderr table, --json on stdout) gives the gap before and after, T-junctions,
    the shared curve used per edge, and per face the deviation bound: stage 1's (approximation
    where the degree budget forced one, repairs of the input) plus the substitution's move.
    """
    from .convert import convert_file, format_untrim_table
    from .report import SCHEMA_VERSION
    from .stage2 import format_full_table
    from .tolerances import Tolerances

    tol = Tolerances(approx_rel=tolerance, max_degree=max_degree)
    progress = _progress_factory(not quiet, source)
    keep = {} if html_path else None
    try:
        rep, error = _run_guarded(
            lambda: convert_file(source, target, tol, stage, progress, overwrite, fast, keep=keep), source)
    finally:
        if progress is not None:
            progress.close()
    gate = None
    if rep is not None and stage == "full":
        gate = _convert_gates(rep, max_gap, max_deviation)
    run = RunReport()
    run.add(FileOutcome(source, rep, error, gate))
    if error:
        _err(error)
    elif not quiet:
        click.echo((format_full_table if stage == "full" else format_untrim_table)(rep), err=True)
    if gate:
        _err(gate)
    if html_path and rep is not None:
        from .scene import write_convert_html

        settings = click.get_current_context().params
        _write_html(lambda: write_convert_html(html_path, rep, keep, settings, tol), html_path, run)
    if as_json:
        doc = rep or {"schema_version": SCHEMA_VERSION, "file": source, "error": error}
        sys.stdout.write(json.dumps(doc, indent=1, default=_jsonable) + "\n")
    sys.exit(run.exit_code)


def _convert_gates(rep: dict, max_gap, max_deviation) -> str | None:
    """The first reason to exit 3 for a converted file: a failed invariant or an exceeded gate."""
    failed = [k for k, v in rep.get("invariants", {}).items() if not v]
    if failed:
        return f"{rep['file']}: invariant {', '.join(failed)} failed (the output was written; see the report)"
    gap = rep["after"].get("gap_max")
    if max_gap is not None and gap is not None and gap > max_gap:
        return f"{rep['file']}: gap after {gap:.3g} exceeds --max-gap {max_gap:g}"
    if max_deviation is not None and rep["bound_after_max"] > max_deviation:
        return (f"{rep['file']}: deviation bound {rep['bound_after_max']:.3g} exceeds "
                f"--max-deviation {max_deviation:g}")
    return None


if __name__ == "__main__":  # pragma: no cover
    main()
