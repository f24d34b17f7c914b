"""Convert time per file against the OCCT I/O floor and against OCCT's own tools (issue #7).

Run: ``python -m benchmarks.bench_convert [--timeout S] [--only NAME...] [--no-corpus] [--no-scaling]
[--out FILE.json]`` (``make bench`` runs it with the other benchmarks).

Per file (the bundled fixtures, then the corpus in ``../shared/corpus`` when it is there), each step
in a fresh process, all in the same run:

- ``watertight convert IN OUT --json``: the report's stage times (read, plan, cells, reparam, the
  stage-1 verify, conform, build, write, the read-back verify), the wall time of the process and
  its peak resident memory (``ru_maxrss`` of that child, from ``os.wait4``);
- the floor: OCCT reading IN plus OCCT writing the shape of OUT (``watertight_cli.occ.baseline.io_floor``);
- ``floor_ratio`` = the summed stage times of the conversion / the floor (both in-process, so the
  interpreter's start and imports are left out of both sides); ``floor_ratio_without_readback``
  leaves out the read-back of the written file (what ``--fast`` skips), a diagnostic;
- the OCCT chain a user would try instead (sewing, ShapeFix, NURBS conversion,
  ShapeConvertToBezier): its time, faces, untrimmed Bezier faces and boundary gap, measured with
  the project's own gap code on the written result.

A file whose conversion runs past ``--timeout`` seconds (default 90) is killed and recorded with
``status: "timeout"`` and ``floor_ratio_at_least``: the timeout over the OCCT read time of its
input, a lower bound (the write of an output that was never made is left out of that floor).

Scaling: ``loft_minus_cylinder`` tiled 1, 4 and 16 times (``fixtures/make_fixtures.write_tiled``),
converted with the same absolute tolerance (``--tolerance`` scaled by the diagonals), so every tile
asks for the same work; the figure is the summed stage time per input face.

``results.json`` (``--out``, default ``benchmarks/results.json``) holds every figure.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from watertight_cli.tolerances import Tolerances

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "fixtures"
CORPUS = ROOT.parent / "shared" / "corpus"
SUFFIXES = (".step", ".stp", ".igs", ".iges")
RESULTS = ROOT / "benchmarks" / "results.json"
#: the issue's stage names and the keys of the conversion report's ``timings`` that make them up
STAGES = {"read": ("read",), "plan": ("plan",), "cells": ("cells",), "reparam": ("reparam",),
          "conform": ("substitute", "slender"), "build": ("build",), "write": ("write",),
          "verify": ("verify", "verify_written")}
DEFAULT_TOLERANCE = Tolerances().approx_rel  # the CLI's --tolerance default


def model_files(corpus: bool = True) -> list[Path]:
    """The bundled fixtures (top level), then the corpus files when ``../shared/corpus`` exists."""
    files = sorted(p for p in FIXTURES.iterdir() if p.suffix.lower() in SUFFIXES)
    if corpus and CORPUS.is_dir():
        files += sorted(p for p in CORPUS.iterdir() if p.suffix.lower() in SUFFIXES)
    return files


def _run(cmd: list[str], timeout: float | None) -> tuple[int | None, str, str, float, float]:
    """Run ``cmd``; returns (exit code or None on timeout, stdout, stderr, wall s, peak RSS MiB)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    out: list[str] = []
    err: list[str] = []
    readers = [threading.Thread(target=lambda s=s, acc=acc: acc.append(s.read()), daemon=True)
               for s, acc in ((proc.stdout, out), (proc.stderr, err))]
    for r in readers:
        r.start()
    timer = None
    timed_out = threading.Event()
    if timeout is not None:
        def kill():
            timed_out.set()
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        timer = threading.Timer(timeout, kill)
        timer.start()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if timer is not None:
        timer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)
    for r in readers:
        r.join()
    rss = usage.ru_maxrss / 1024.0  # KiB on Linux
    return (None if timed_out.is_set() else proc.returncode), "".join(out), "".join(err), wall, rss


def _py(*args: str) -> list[str]:
    return [sys.executable, "-c",
            "import json, sys; from watertight_cli.occ import baseline as b; " + ";".join(args)]


def _convert(src: Path, dst: Path, timeout: float, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    cmd = [sys.executable, "-m", "watertight_cli.cli", "convert", str(src), str(dst), "--json", "-q",
           "--tolerance", repr(tolerance)]
    code, out, err, wall, rss = _run(cmd, timeout)
    res: dict = {"wall_s": wall, "peak_rss_mib": rss, "exit": code}
    if code is None:
        res["status"] = "timeout"
        return res
    if code not in (0, 3) or not out.strip():
        res["status"] = "failed"
        res["reason"] = err.strip().splitlines()[-1] if err.strip() else f"exit {code}"
        return res
    rep = json.loads(out)
    t = rep["timings"]
    res.update({
        "status": "ok" if code == 0 else "invariant or gate failed (exit 3)",
        "faces_in": rep["faces_in"], "patches_out": rep["patches_out"],
        "degree_max": rep["degree"]["max"], "degree_median": rep["degree"]["median"],
        "gap_before": rep["before"]["gap_max"], "gap_after": rep["after"].get("gap_max"),
        "t_junctions": rep.get("t_junctions"),
        "stages_s": {k: sum(t.get(x, 0.0) for x in keys) for k, keys in STAGES.items()},
        "timings_s": t,
    })
    res["convert_s"] = sum(t.values())
    return res


def _floor(src: Path, out: Path | None) -> dict:
    if out is None:  # no output: the read alone (a lower bound of the floor)
        code, so, se, _, _ = _run(_py("import time", "t=time.perf_counter()", f"b.read_shape({str(src)!r})",
                                      "print(json.dumps({'read_s': time.perf_counter()-t}))"), None)
    else:
        code, so, se, _, _ = _run(_py(f"print(json.dumps(b.io_floor({str(src)!r}, {str(out)!r})))"), None)
    if code != 0:
        return {"error": se.strip().splitlines()[-1] if se.strip() else f"exit {code}"}
    return json.loads(so)


_BASELINE = (
    "from watertight_cli.inspect import inspect, trimmed",
    "from watertight_cli.tolerances import Tolerances",
    "r = b.bezier_baseline(sys.argv[1], sys.argv[2])",
    "m = inspect(sys.argv[2], Tolerances())",
    "r['faces'] = len(m.model.faces)",
    "r['untrimmed_bezier_faces'] = sum(1 for f in m.model.faces if f.surface.is_bezier and not trimmed(f))",
    "r['gap_max'] = max((g.gap for g in m.gaps), default=0.0)",
    "r['free_edges'] = sum(1 for e in m.model.edges if not e.degenerate and e.uses == 1)",
    "print(json.dumps(r))",
)


def _baseline(src: Path, tmp: Path, timeout: float) -> dict:
    suffix = ".step" if src.suffix.lower() in (".step", ".stp") else ".igs"
    cmd = _py(*_BASELINE) + [str(src), str(tmp / f"baseline{suffix}")]
    code, so, se, wall, rss = _run(cmd, timeout)
    if code is None:
        return {"status": "timeout", "wall_s": wall}
    if code != 0:
        return {"status": "failed", "reason": se.strip().splitlines()[-1] if se.strip() else f"exit {code}"}
    r = json.loads(so)
    r.update(status="ok", time_s=r["read_s"] + r["process_s"] + r["write_s"], peak_rss_mib=rss)
    return r


def bench_file(src: Path, timeout: float, baseline: bool = True) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_convert.") as tmp:
        tmp = Path(tmp)
        dst = tmp / src.name
        res = {"file": src.name, "input_bytes": src.stat().st_size, **_convert(src, dst, timeout)}
        written = dst if dst.exists() and res["status"] not in ("timeout", "failed") else None
        res["floor"] = _floor(src, written)
        floor = res["floor"]
        if "convert_s" in res and "write_s" in floor:
            res["floor_s"] = floor["read_s"] + floor["write_s"]
            res["floor_ratio"] = res["convert_s"] / res["floor_s"]
            # what the same run would be without the read-back of the written file (``--fast``
            # skips it): the read-back reads the output with OCCT again, which alone costs more
            # than the floor's write of it (a diagnostic; the targets are on ``floor_ratio``)
            readback = (res.get("timings_s") or {}).get("verify_written", 0.0)
            res["floor_ratio_without_readback"] = (res["convert_s"] - readback) / res["floor_s"]
        elif res["status"] == "timeout" and "read_s" in floor:
            res["floor_ratio"] = None
            res["floor_ratio_at_least"] = timeout / floor["read_s"]
        else:
            res["floor_ratio"] = None
        if baseline:
            res["occt_baseline"] = _baseline(src, tmp, timeout)
    return res


def _load_fixture_script():
    spec = importlib.util.spec_from_file_location("make_fixtures", FIXTURES / "make_fixtures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _diagonal(path: Path) -> float:
    code, so, se, _, _ = _run(_py("from watertight_cli.occ.extract import diagonal",
                                  f"print(diagonal(b.read_shape({str(path)!r}).shape))"), None)
    if code != 0:
        raise SystemExit(f"bench_convert: cannot read {path}: {se.strip()}")
    return float(so)


def scaling(counts=(1, 4, 16), timeout: float = 600.0) -> dict:
    """Time per input face of the tiled family, at the same absolute tolerance."""
    fx = _load_fixture_script()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_scaling.") as tmp:
        tmp = Path(tmp)
        diag1 = None
        for n in counts:
            src = tmp / f"tiled_x{n}.step"
            fx.write_tiled(n, src)
            diag = _diagonal(src)
            diag1 = diag1 or diag
            tol = DEFAULT_TOLERANCE * diag1 / diag
            r = _convert(src, tmp / f"out_x{n}.step", timeout, tol)
            row = {"tiles": n, "tolerance_rel": tol, **{k: r.get(k) for k in (
                "status", "faces_in", "patches_out", "convert_s", "wall_s", "peak_rss_mib", "stages_s")}}
            if r.get("convert_s") and r.get("faces_in"):
                row["s_per_face"] = r["convert_s"] / r["faces_in"]
            rows.append(row)
    base = rows[0].get("s_per_face")
    for row in rows:
        row["per_face_vs_1x"] = row["s_per_face"] / base if base and row.get("s_per_face") else None
    return {"family": "loft_minus_cylinder tiled", "rows": rows,
            "max_per_face_ratio": max((r["per_face_vs_1x"] or float("inf")) for r in rows)}


def _fmt(x, spec: str = ".2f", none: str = "-") -> str:
    return none if x is None else format(x, spec)


def print_table(files: list[dict]) -> None:
    head = (f"{'file':34s} {'faces':>5s} {'patches':>7s} {'conv s':>8s} {'floor s':>7s} {'ratio':>7s} "
            f"{'MiB':>6s} | " + " ".join(f"{k:>7s}" for k in STAGES)
            + f" | {'occt s':>7s} {'untrim':>6s} {'gap occt':>9s} {'gap ours':>9s}")
    print(head)
    for r in files:
        ratio = (_fmt(r.get("floor_ratio"), ".1f") if r.get("floor_ratio") is not None
                 else f">{r['floor_ratio_at_least']:.0f}" if r.get("floor_ratio_at_least") else "-")
        st = r.get("stages_s") or {}
        b = r.get("occt_baseline") or {}
        ok = b.get("status") == "ok"
        untrim = f"{b['untrimmed_bezier_faces']}/{b['faces']}" if ok else b.get("status", "-")
        print(f"{r['file'][:34]:34s} {_fmt(r.get('faces_in'), 'd'):>5s} "
              f"{_fmt(r.get('patches_out'), 'd'):>7s} "
              f"{_fmt(r.get('convert_s'), '.1f') if 'convert_s' in r else r['status'][:8]:>8s} "
              f"{_fmt(r.get('floor_s'), '.2f'):>7s} {ratio:>7s} {r['peak_rss_mib']:6.0f} | "
              + " ".join(f"{_fmt(st.get(k), '.2f'):>7s}" for k in STAGES)
              + f" | {_fmt(b.get('time_s'), '.1f'):>7s} {untrim:>6s} {_fmt(b.get('gap_max'), '.1e'):>9s} "
              f"{_fmt(r.get('gap_after'), '.1e'):>9s}")


def summary(files: list[dict]) -> dict:
    ratios = [r["floor_ratio"] for r in files if r.get("floor_ratio") is not None]
    lower = [r["floor_ratio_at_least"] for r in files if r.get("floor_ratio_at_least") is not None]
    all_known = ratios + lower  # a lower bound stands for its file in the median (it can only be higher)
    nrb = [r["floor_ratio_without_readback"] for r in files
           if r.get("floor_ratio_without_readback") is not None]
    return {
        "files": len(files),
        "floor_ratio_median": statistics.median(all_known) if all_known else None,
        "floor_ratio_max": max(all_known, default=None),
        "floor_ratio_without_readback_median": statistics.median(nrb) if nrb else None,
        "timeouts": sum(1 for r in files if r["status"] == "timeout"),
        "failed": sum(1 for r in files if r["status"] == "failed"),
        "stage_totals_s": {k: sum((r.get("stages_s") or {}).get(k, 0.0) for r in files) for k in STAGES},
    }


def run(timeout: float = 90.0, corpus: bool = True, only: list[str] | None = None, scale: bool = True,
        jobs_speedup: bool = True, out: Path = RESULTS, extra: dict | None = None) -> dict:
    files = [p for p in model_files(corpus) if not only or p.name in only or p.stem in only]
    results = []
    for i, src in enumerate(files, 1):
        print(f"[{i}/{len(files)}] {src.name} ...", file=sys.stderr, flush=True)
        results.append(bench_file(src, timeout))
    print(f"\nconvert against the OCCT I/O floor (fresh process per step; --timeout {timeout:g} s; "
          f"{os.cpu_count()} cores):")
    print_table(results)
    summ = summary(results)
    print(f"floor_ratio: median {_fmt(summ['floor_ratio_median'], '.1f')} (target <= 3), max "
          f"{_fmt(summ['floor_ratio_max'], '.1f')} (target <= 10); timeouts {summ['timeouts']}, "
          f"failed {summ['failed']}; without the read-back of the written file (--fast): median "
          f"{_fmt(summ['floor_ratio_without_readback_median'], '.1f')}")
    tot = summ["stage_totals_s"]
    total = sum(tot.values()) or 1.0
    print("time by stage over all files: " + ", ".join(
        f"{k} {v:.1f} s ({100 * v / total:.0f}%)" for k, v in sorted(tot.items(), key=lambda kv: -kv[1])))
    res = {"schema_version": 1, "cores": os.cpu_count(), "timeout_s": timeout, **(extra or {}),
           "files": results, "summary": summ}
    if scale:
        sc = scaling()
        res["scaling"] = sc
        print(f"\nscaling ({sc['family']}, same absolute tolerance):")
        for row in sc["rows"]:
            print(f"  x{row['tiles']:<3d} faces {_fmt(row.get('faces_in'), 'd'):>5s} patches "
                  f"{_fmt(row.get('patches_out'), 'd'):>6s} "
                  f"convert {_fmt(row.get('convert_s'), '.1f'):>7s} s  "
                  f"per face {_fmt(row.get('s_per_face'), '.4f')} s  "
                  f"({_fmt(row.get('per_face_vs_1x'), '.2f')}x)")
        print(f"  largest per-face ratio to 1x: {sc['max_per_face_ratio']:.2f} (target <= 1.3)")
    if jobs_speedup:
        from . import bench_batch

        print()
        res["batch"] = bench_batch.run()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(res, indent=1) + "\n")
    os.replace(tmp, out)
    print(f"\nwrote {out}")
    return res


def main(argv: list[str] | None = None, extra: dict | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_convert",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--timeout", type=float, default=90.0, help="seconds per conversion (default 90)")
    ap.add_argument("--only", nargs="*", default=None, metavar="NAME", help="only these files (name or stem)")
    ap.add_argument("--no-corpus", action="store_true", help="fixtures only")
    ap.add_argument("--no-scaling", action="store_true")
    ap.add_argument("--no-batch", action="store_true", help="skip the --jobs 2 / --jobs 1 figure")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    run(a.timeout, not a.no_corpus, a.only, not a.no_scaling, not a.no_batch, a.out, extra)


if __name__ == "__main__":
    main()
