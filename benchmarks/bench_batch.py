"""Batch conversion wall time: ``--jobs 2`` against ``--jobs 1`` on one folder.

Run: ``python -m benchmarks.bench_batch [FOLDER] [--repeat N] [--recursive] [--stage full|untrim]``.
FOLDER defaults to the bundled fixtures (their top level: the broken files in ``fixtures/broken``
are left out). Each run is a fresh ``watertight convert FOLDER -o TMP -q --jobs N`` process, so the
figure includes the start of the worker pool. The target for the corpus folder is a ratio of at
most 0.65 (issue #6); on two cores the best possible is 0.5. ``run()`` returns the figures.

Not part of ``make bench``: on the corpus it takes about an hour of CPU.

Files start longest first by their last run's time (``watertight_cli.batch``, a per-user cache).
``--cache warm`` (default) gives all runs one private cache, so every run after the first schedules
from the times of the one before, as a CI job that converts the same folder on every commit does;
``--cache cold`` gives each run an empty cache (order by input size), as a first run does. The
user's own cache is never read or written.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"


def _convert(folder: Path, jobs: int, recursive: bool, stage: str,
             keep: Path | None = None, cache: Path | None = None) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory(prefix="bench_batch.") as tmp:
        env = dict(os.environ, WATERTIGHT_CACHE_DIR=str(cache or Path(tmp) / "cache"))
        out, report = Path(tmp) / "out", Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "watertight_cli.cli", "convert", str(folder), "-o", str(out), "-q",
               "--jobs", str(jobs), "--stage", stage, "--report", str(report)]
        if recursive:
            cmd.append("--recursive")
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True, env=env)
        wall = time.perf_counter() - t0
        if proc.returncode not in (0, 1, 3) or not report.exists():
            raise SystemExit(f"bench_batch: convert exited {proc.returncode}: {proc.stderr.strip()}")
        if keep is not None:  # the run's full report, for per-file figures
            keep.mkdir(parents=True, exist_ok=True)
            (keep / f"jobs{jobs}.json").write_text(report.read_text())
        return wall, json.loads(report.read_text())["totals"]


def run(folder: Path = FIXTURES, repeat: int = 1, recursive: bool = False, stage: str = "full",
        keep: Path | None = None, cache: str = "warm") -> dict:
    """Median wall times of ``--jobs 1`` and ``--jobs 2`` (alternating runs) and their ratio."""
    shared = Path(tempfile.mkdtemp(prefix="bench_batch_cache.")) if cache == "warm" else None
    walls: dict[int, list[float]] = {1: [], 2: []}
    busy: dict[int, list[float]] = {1: [], 2: []}  # summed per-file worker wall times
    cpu: dict[int, list[float]] = {1: [], 2: []}  # summed per-file worker CPU times
    totals = {}
    load = [os.getloadavg()[0]]
    for _ in range(repeat):
        for jobs in (1, 2):
            wall, totals[jobs] = _convert(folder, jobs, recursive, stage, keep, shared)
            walls[jobs].append(wall)
            busy[jobs].append(totals[jobs]["time_s"])
            cpu[jobs].append(totals[jobs]["cpu_s"])
            load.append(os.getloadavg()[0])
    if shared is not None:
        shutil.rmtree(shared, ignore_errors=True)
    t1, t2 = statistics.median(walls[1]), statistics.median(walls[2])
    res = {"folder": str(folder), "files": totals[1]["files"], "ok": totals[1]["ok"],
           "gate": totals[1]["gate"], "failed": totals[1]["failed"], "jobs1_s": t1,
           "jobs2_s": t2, "ratio": t2 / t1, "runs": walls, "file_time_sums": busy,
           "file_cpu_sums": cpu, "load": load, "cores": os.cpu_count(), "cache": cache}
    print(f"batch conversion of {res['files']} files in {folder} (stage {stage}, {cache} duration cache; "
          f"ok {res['ok']}, gate {res['gate']}, failed {res['failed']}; {res['cores']} cores):")
    print(f"  --jobs 1: {t1:8.2f} s (median of {repeat})")
    print(f"  --jobs 2: {t2:8.2f} s (median of {repeat})")
    print(f"  ratio --jobs 2 / --jobs 1: {res['ratio']:.3f} (target <= 0.65)")
    print(f"  summed per-file times: --jobs 1 {statistics.median(busy[1]):.1f} s, --jobs 2 "
          f"{statistics.median(busy[2]):.1f} s; their CPU times: {statistics.median(cpu[1]):.1f} s and "
          f"{statistics.median(cpu[2]):.1f} s (wall above CPU: the workers wait for a core)")
    print("  1-minute load average before and after each run: " + ", ".join(f"{x:.1f}" for x in load)
          + f" (other work on the machine distorts the ratio; {res['cores']} cores)")
    return res


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_batch", description=__doc__.splitlines()[0])
    ap.add_argument("folder", nargs="?", type=Path, default=FIXTURES)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--recursive", action="store_true")
    ap.add_argument("--stage", choices=["full", "untrim"], default="full")
    ap.add_argument("--keep-reports", type=Path, default=None, metavar="DIR",
                    help="write each run's --report JSON to DIR/jobsN.json")
    ap.add_argument("--cache", choices=["warm", "cold"], default="warm",
                    help="warm: the runs share one private duration cache (the first run fills it); "
                         "cold: each run starts with an empty one")
    args = ap.parse_args(argv)
    run(args.folder, args.repeat, args.recursive, args.stage, args.keep_reports, args.cache)


if __name__ == "__main__":
    main()
