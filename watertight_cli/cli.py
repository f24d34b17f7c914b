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

from .tolerances import Tolerances

#: the options' defaults are the tolerance object's, documented with their reasons there
_DEFAULTS = Tolerances()

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


def _measure(path: str, tol, pages: list | None = None, boundary: bool = False) -> dict:
    from .inspect import inspect
    from .report import boundary_report, input_report

    ins = inspect(path, tol)
    rep = input_report(ins)
    if boundary:
        rep["boundary"] = boundary_report(ins.model, rep["timing_s"])
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
              help="Equally spaced samples per edge for gap measurement (ends included); 3 more go "
                   "inside every knot span of the edge's curves.")
@click.option("-q", "--quiet", is_flag=True, help="No table on stderr.")
@click.option("--html", "html_path", type=click.Path(dir_okay=False), default=None, metavar="PATH",
              help="Also write a self-contained HTML page to PATH: gap histogram, worst edges with "
                   "their locations, pictures of the model with edges coloured by gap.")
@click.option("--boundary", is_flag=True,
              help="Also measure the topology-blind boundary gap: 15 samples inside every edge of every "
                   "face's boundary, each measured to the nearest boundary of any other face, whatever "
                   "the edges say (slow on large models: minutes for 10000 faces).")
def report(models, as_json, max_gap, samples, quiet, html_path, boundary):
    """Measure how far MODELS are from watertight.

    For every edge: the largest distance between its 3D curve C and each face's surface(pcurve),
    and between the two faces' boundary curves S1(pc1) and S2(pc2), over equally spaced samples
    and three inside every knot span of C and the pcurves (knots crowd where a curve changes
    fast: a pcurve that runs at another speed than C near an end shows there), next to the
    edge's tolerance. For the model: faces by surface type, trimmed faces, free and non-manifold
    edges, solids and shells, the diagonal and, for inputs whose faces are not
    connected (IGES 144, STEP surface models), what sewing recovered.

    With --boundary, also: how far each face's boundary lies from the nearest boundary of another
    face, found among all boundaries within reach (not only the one with the nearest sample), and
    how many samples have none within 1e-6 of the diagonal (free boundary, or a wider gap).

    A table goes to stderr, worst edges first; --json prints the full report on stdout.
    """
    tol = Tolerances(gap_samples=samples)
    run = RunReport()
    pages = [] if html_path else None
    for path in models:
        rep, error = _run_guarded(lambda p=path: _measure(p, tol, pages, boundary), path)
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


CONVERT_EPILOG = EPILOG + """
\b
Batch form (IN... -o OUTDIR), for CI:
  watertight convert models/ -o out/ --recursive --jobs 4 --timeout 600 \\
      --report out/report.json --junit out/junit.xml
  Every file runs in a fresh worker process; a file that fails, crashes the worker, passes
  --timeout or --max-memory is reported in one line and the batch goes on (exit 1 at the end).
"""


class _Size(click.ParamType):
    """A memory size: 512M, 2G, 1.5G, or a number of megabytes."""

    name = "size"
    UNITS = {"k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}

    def convert(self, value, param, ctx):
        if isinstance(value, int):
            return value
        text = str(value).strip().lower().removesuffix("b").removesuffix("i")
        unit = self.UNITS.get(text[-1:], None)
        try:
            n = float(text[:-1] if unit else text) * (unit or 2**20)
        except ValueError:
            self.fail(f"{value!r} is not a size such as 512M or 2G", param, ctx)
        if not 0 < n < 2**62:  # also nan and inf
            self.fail(f"{value!r} is not a positive size", param, ctx)
        return int(n)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


BATCH_ONLY = {"recursive": "--recursive", "fmt": "--format", "jobs": "--jobs", "timeout": "--timeout",
              "max_memory": "--max-memory", "report_json": "--report", "junit": "--junit",
              "executor": "--executor", "scheduler": "--scheduler"}


@main.command(epilog=CONVERT_EPILOG)
@click.argument("paths", nargs=-1, required=True, metavar="IN [OUT] | IN... -o OUTDIR")
@click.option("-o", "--output-dir", "output_dir", type=click.Path(file_okay=False), default=None,
              metavar="OUTDIR",
              help="Batch form: convert every IN (files, folders, globs) into OUTDIR, mirroring the input "
                   "tree. Without it, IN OUT converts one file.")
@click.option("--recursive", is_flag=True, help="Batch: descend into folders (and let ** in globs recurse).")
@click.option("--format", "fmt", type=click.Choice(["step", "iges"]), default=None,
              help="Batch: output format (suffix .step or .igs). Default: the input's own kind and suffix.")
@click.option("--stage", type=click.Choice(["full", "untrim"]), default="full", show_default=True,
              help="full: untrimmed Bezier patches whose neighbours share one boundary curve "
                   "(a watertight B-rep). untrim: stage 1 only, patches that keep their faces' "
                   "shapes but share no edges.")
@click.option("--max-degree", type=click.IntRange(1, 25), default=_DEFAULTS.max_degree, show_default=True,
              help="Largest patch degree. Cells whose exact degree is higher are approximated within "
                   "--tolerance.")
@click.option("--tolerance", type=click.FloatRange(min=0.0, min_open=True), default=_DEFAULTS.approx_rel,
              show_default=True, metavar="REL",
              help="Allowed deviation where approximation is needed, relative to the model's "
                   "bounding-box diagonal (1e-6: one micron on a one-metre part).")
@click.option("--wrap-tips/--no-wrap-tips", default=_DEFAULTS.wrap_tips, show_default=True,
              help="Wrap each point where a trimming curve turns back in u (a hole's leftmost and "
                   "rightmost points) in cells turned by 90 degrees, instead of cutting the face "
                   "with a line tangent to the curve there, which leaves patch corners of zero "
                   "angle. --no-wrap-tips gives fewer patches.")
@click.option("--max-aspect", type=click.FloatRange(min=1.0, min_open=True), default=_DEFAULTS.slender_ratio,
              show_default=True, metavar="RATIO",
              help="Longest an edge along a patch may be for the patch's width. Stage 1 leaves "
                   "strips thousands of times longer than wide where knot lines or trimming curves "
                   "run close together; the long sides of such a strip, and its neighbours' sides "
                   "there, are split into shorter edges at the same points (the patches stay as "
                   "they are). Slivers (narrower than 5e-7 of the diagonal) are split at 20 x "
                   "RATIO. Every edge is likewise kept no longer than RATIO times its distance to "
                   "the nearest other edge, where that is above the tolerance. 'inf' splits "
                   "nothing.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the conversion report as JSON on stdout (batch: the --report document).")
@click.option("--overwrite/--no-overwrite", default=None,
              help="Replace outputs that exist. Default: replace for IN OUT (as before), refuse in the "
                   "batch form (such a file fails). An input is never overwritten.")
@click.option("--fast", is_flag=True, help="Do not read the written file back to verify it.")
@click.option("--max-gap", type=float, default=None, metavar="X",
              help="Gate: exit 3 when the gap after conversion exceeds X (model units).")
@click.option("--max-deviation", type=float, default=None, metavar="X",
              help="Gate: exit 3 when a face's deviation from its input exceeds X (model units): the "
                   "measured one (each patch against its stage-1 patch on a grid, plus stage 1's bound) "
                   "or the certified bound where that is smaller.")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None, metavar="N",
              help="Batch: worker processes at a time (default: the number of cores).")
@click.option("--timeout", type=click.FloatRange(min=0.0, min_open=True), default=None, metavar="SECONDS",
              help="Batch: kill a file's worker after SECONDS; that file fails.")
@click.option("--max-memory", type=_Size(), default=None, metavar="SIZE",
              help="Batch: kill a file's worker when its resident memory passes SIZE (512M, 2G; the "
                   "kernel library alone takes ~0.3G); that file fails.")
@click.option("--report", "report_json", type=click.Path(dir_okay=False), default=None, metavar="FILE.json",
              help="Batch: write per-file results and totals as JSON (schema_version inside).")
@click.option("--junit", type=click.Path(dir_okay=False), default=None, metavar="FILE.xml",
              help="Batch: write JUnit XML, one test case per file (failure: failed or over a gate).")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="Batch: local worker processes, or a Dask cluster (--scheduler; needs the [dask] extra, "
                   "watertight on every worker and the same paths).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Batch with --executor dask: the scheduler, e.g. tcp://10.0.0.5:8786.")
@click.option("-q", "--quiet", is_flag=True, help="No table and no progress bar on stderr.")
@click.option("--html", "html_path", type=click.Path(dir_okay=False), default=None, metavar="PATH",
              help="One-file form: also write a self-contained HTML page to PATH: gaps before and after, "
                   "worst edges, pictures before and after, degrees and deviation per face, settings and "
                   "times.")
def convert(paths, output_dir, stage, max_degree, tolerance, wrap_tips, max_aspect, as_json, overwrite, fast,
            max_gap, max_deviation, quiet, html_path, **batch_opts):
    """Convert STEP or IGES models into watertight models of untrimmed Bezier patches.

    Two forms: `watertight convert IN OUT` converts one file; `watertight convert IN... -o OUTDIR`
    converts files, folders and globs in parallel worker processes (see the batch options and the
    exit codes below).

    Every trimmed face is split into Bezier patches on [0,1]^2 (stage 1); then every patch side
    on an edge takes the edge's one shared curve, so neighbouring faces meet exactly (stage 2),
    and the patches are joined into shells and solids. OUT's suffix picks the format
    (.step/.stp or .igs/.iges).

    Checks: every stage-1 patch is verified against its input face (sampled deviation within
    the bound, trimming sides on the input's surface(pcurve), summed area, no folds) before
    anything is written; the file is written atomically (no partial OUT); then it is read
    back and measured: all faces untrimmed Bezier (I1), gaps after at most 1e-12 of the
    diagonal (I2), no new free edges (I3), each face's deviation within the tolerance plus the
    input's own gap at its edges, at the edges that meet them at a vertex and at those vertices
    (I4: each patch measured against its stage-1 patch on a 17 x 17 grid, plus the stage-1
    patch's certified bound or, near trimming sides that repairs of the input moved, their
    measured distance from the input's boundary; or the certified bound of the whole change
    where that is smaller), kernel validity. A failed
    invariant exits 3, with the file written.

    The report (stderr table, --json on stdout) gives the gap before and after, T-junctions,
    the shared curve used per edge, and per face the deviation bound: stage 1's (approximation
    where the degree budget forced one, repairs of the input) plus the substitution's move.
    """
    tol = Tolerances(approx_rel=tolerance, max_degree=max_degree, slender_ratio=max_aspect,
                     wrap_tips=wrap_tips)
    if output_dir is not None and html_path:
        _err("--html needs the one-file form: IN OUT")
        sys.exit(EXIT_USAGE)
    if output_dir is not None:
        sys.exit(_convert_batch(paths, output_dir, tol, stage, as_json, bool(overwrite), fast, max_gap,
                                max_deviation, quiet, **batch_opts))
    given = [name for key, name in BATCH_ONLY.items() if batch_opts.get(key) not in (None, False, "local")]
    if given:
        _err(f"{', '.join(given)} needs the batch form: IN... -o OUTDIR")
        sys.exit(EXIT_USAGE)
    if len(paths) != 2:
        _err(f"convert takes IN OUT, or IN... -o OUTDIR (got {len(paths)} path{'s' * (len(paths) != 1)} "
             "and no -o)")
        sys.exit(EXIT_USAGE)
    source, target = paths
    for path in (source, target):
        if os.path.isdir(path):
            _err(f"{path}: is a folder (the batch form is IN... -o OUTDIR)")
            sys.exit(EXIT_USAGE)
    if os.path.exists(target) and os.path.exists(source) and os.path.samefile(source, target):
        _err(f"{target}: the output would overwrite the input")
        sys.exit(EXIT_USAGE)
    sys.exit(_convert_one(source, target, tol, stage, as_json, True if overwrite is None else overwrite,
                          fast, max_gap, max_deviation, quiet, html_path))


def _convert_one(source, target, tol, stage, as_json, overwrite, fast, max_gap, max_deviation, quiet,
                 html_path=None) -> int:
    from .convert import convert_file, format_untrim_table
    from .report import SCHEMA_VERSION
    from .stage2 import format_full_table

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
    return run.exit_code


def _write_atomic(path: str, data: bytes) -> None:
    import tempfile

    folder = os.path.dirname(path) or "."
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", dir=folder)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _convert_batch(paths, output_dir, tol, stage, as_json, overwrite, fast, max_gap, max_deviation, quiet,
                   recursive, fmt, jobs, timeout, max_memory, report_json, junit, executor, scheduler) -> int:
    import time

    from . import __version__
    from .batch import batch_document, junit_xml, plan, record_durations, run_dask, run_local, summary_table
    from .errors import UsageError

    if executor == "dask" and not scheduler:
        _err("--executor dask needs --scheduler ADDRESS")
        return EXIT_USAGE
    if scheduler and executor != "dask":
        _err("--scheduler needs --executor dask")
        return EXIT_USAGE
    n_jobs = jobs or _cores()
    options = {"stage": stage, "tolerance": tol.approx_rel, "max_degree": tol.max_degree,
               "max_aspect": tol.slender_ratio, "wrap_tips": tol.wrap_tips, "fast": fast,
               "overwrite": overwrite, "recursive": recursive, "format": fmt, "output_dir": output_dir,
               "jobs": n_jobs, "timeout": timeout, "max_memory": max_memory, "executor": executor,
               "max_gap": max_gap, "max_deviation": max_deviation}
    try:
        todo, failed = plan(paths, output_dir, recursive, fmt, overwrite,
                            {"tol": tol, "stage": stage, "fast": fast}, timeout, max_memory)
        if not todo and not failed:
            raise UsageError(f"no STEP or IGES file in {' '.join(paths)}"
                             + ("" if recursive else " (--recursive descends into folders)"))
        os.makedirs(output_dir, exist_ok=True)
    except UsageError as exc:
        _err(str(exc))
        return EXIT_USAGE
    except OSError as exc:
        _err(f"{output_dir}: {exc.strerror or exc}")
        return EXIT_USAGE

    from tqdm import tqdm

    bar = tqdm(total=len(todo) + len(failed), unit="file", desc="convert", file=sys.stderr,
               disable=True if quiet else None, dynamic_ncols=True)
    current: list[str] = []

    def say(line: str) -> None:
        if bar.disable:
            click.echo(line, err=True)
        else:
            bar.write(line, file=sys.stderr)

    def on_start(job) -> None:
        current.append(job.rel)
        bar.set_postfix_str(", ".join(current[-2:]), refresh=True)

    def on_done(res) -> None:
        if res.rel in current:
            current.remove(res.rel)
        if res.report is not None and stage == "full":
            res.gate = _convert_gates(res.report, max_gap, max_deviation)
        if res.failure:
            say(f"watertight: error: {res.reason}")
            if res.traceback and os.environ.get("WATERTIGHT_DEBUG"):
                say(res.traceback.rstrip())
        elif res.gate:
            say(f"watertight: error: {res.gate}")
        bar.set_postfix_str(", ".join(current[-2:]) or res.rel, refresh=False)
        bar.update(1)

    t0 = time.perf_counter()
    try:
        for res in failed:
            on_done(res)
        if executor == "dask":
            results = run_dask(todo, scheduler, on_start, on_done)
        else:
            results = run_local(todo, n_jobs, on_start, on_done)
    except UsageError as exc:
        bar.close()
        _err(str(exc))
        return EXIT_USAGE
    finally:
        bar.close()
    wall = time.perf_counter() - t0
    record_durations(todo, results)
    results = failed + results

    run = RunReport()
    for r in results:
        run.add(FileOutcome(r.shown, r.report, r.reason if r.failure else None, r.gate))
    if not quiet:
        click.echo(summary_table(results, wall), err=True)
    doc = batch_document(results, wall, options, f"watertight {__version__}")
    text = json.dumps(doc, indent=1, default=_jsonable) + "\n"
    try:
        if report_json:
            _write_atomic(report_json, text.encode())
        if junit:
            _write_atomic(junit, junit_xml(results, wall))
    except OSError as exc:
        _err(f"{exc.filename or report_json or junit}: cannot write the report ({exc.strerror or exc})")
        return EXIT_FAILED
    if as_json:
        sys.stdout.write(text)
    return run.exit_code


def _convert_gates(rep: dict, max_gap, max_deviation) -> str | None:
    """The first reason to exit 3 for a converted file: a failed invariant or an exceeded gate."""
    failed = [k for k, v in rep.get("invariants", {}).items() if not v]
    if failed:
        return f"{rep['file']}: invariant {', '.join(failed)} failed (the output was written; see the report)"
    gap = rep["after"].get("gap_max")
    if max_gap is not None and gap is not None and gap > max_gap:
        return f"{rep['file']}: gap after {gap:.3g} exceeds --max-gap {max_gap:g}"
    dev = rep.get("deviation_after_max", rep["bound_after_max"])
    if max_deviation is not None and dev > max_deviation:
        return f"{rep['file']}: deviation {dev:.3g} exceeds --max-deviation {max_deviation:g}"
    return None


if __name__ == "__main__":  # pragma: no cover
    main()
