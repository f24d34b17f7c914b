"""The ``watertight`` command line.

Library errors (``WatertightError``) become one-line messages naming the file and the reason;
nothing here prints a traceback. Heavy modules (OCP, scipy) are imported inside the commands so
that ``watertight --help`` answers at once.

Exit codes (also in ``watertight --help``):
  0  all files processed and within the gates
  1  some file failed (unreadable, invalid, or the conversion failed)
  2  usage error (bad option or argument)
  3  a gate was exceeded (``--max-gap``)
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
  3  a gate (--max-gap) was exceeded
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


def _measure(path: str, tol) -> dict:
    from .inspect import inspect
    from .report import input_report

    return input_report(inspect(path, tol))


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
def report(models, as_json, max_gap, samples, quiet):
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
    for path in models:
        rep, error = _run_guarded(lambda p=path: _measure(p, tol), path)
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
              help="untrim: stage 1 only, every face becomes untrimmed Bezier patches that keep its "
                   "shape (neighbours do not share edges yet). full: stage 1 and stage 2 (shared "
                   "boundaries); stage 2 is not built yet.")
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
@click.option("-q", "--quiet", is_flag=True, help="No table and no progress bar on stderr.")
def convert(source, target, stage, max_degree, tolerance, as_json, overwrite, quiet):
    """Convert SOURCE (STEP or IGES) into untrimmed Bezier patches written to TARGET.

    TARGET's suffix picks the format (.step/.stp or .igs/.iges). Every patch is verified against
    its input face (sampled deviation within the bound, trimming sides on the input's
    surface(pcurve), summed patch area against the face area, no folds) before anything is
    written; the file is written atomically, so a failed run leaves no partial TARGET.

    The report gives each face's guaranteed deviation bound: the approximation where the degree
    budget forced one, plus the repairs of the input (closing uv gaps between consecutive
    pcurves, straightening pcurves that wiggle around an iso-line within half the tolerance).
    """
    from .convert import convert_file, format_untrim_table
    from .report import SCHEMA_VERSION
    from .tolerances import Tolerances

    if stage == "full":
        _err("the full conversion needs stage 2 (shared boundaries), which is not built yet; "
             "run with --stage untrim for stage 1 only")
        sys.exit(EXIT_USAGE)
    tol = Tolerances(approx_rel=tolerance, max_degree=max_degree)
    progress = _progress_factory(not quiet, source)
    try:
        rep, error = _run_guarded(
            lambda: convert_file(source, target, tol, stage, progress, overwrite), source)
    finally:
        if progress is not None:
            progress.close()
    run = RunReport()
    run.add(FileOutcome(source, rep, error))
    if error:
        _err(error)
    elif not quiet:
        click.echo(format_untrim_table(rep), err=True)
    if as_json:
        doc = rep or {"schema_version": SCHEMA_VERSION, "file": source, "error": error}
        sys.stdout.write(json.dumps(doc, indent=1, default=_jsonable) + "\n")
    sys.exit(run.exit_code)


if __name__ == "__main__":  # pragma: no cover
    main()
