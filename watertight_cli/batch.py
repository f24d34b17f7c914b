"""Batch conversion: many inputs, one fresh worker process per file, reports for CI.

``plan`` turns the command line's inputs (files, folders, globs) into jobs whose outputs mirror the
input tree under one output folder, and refuses (``UsageError``) outputs that would overwrite an
input or that two inputs would both write. ``run_local`` runs the jobs in worker processes supervised
by this process; ``run_dask`` runs each job on a Dask cluster, where the task itself supervises a
worker process, so both executors isolate a file the same way:

- a worker that crashes (a segfault inside OCCT) fails its own file only;
- a worker past ``timeout`` seconds is killed and its file fails;
- a worker whose resident memory passes ``max_memory`` bytes is killed (the supervisor polls its
  RSS), and its address space is capped (RLIMIT_AS) at its size on start plus ``max_memory``, so a
  sudden allocation fails inside the worker instead of taking the machine;
- a killed or crashed worker's temporary file is removed from the output folder, and so is an
  output it wrote before it died (unverified); outputs are otherwise written atomically by
  ``convert_file``.

Order: the longest file first, so that no worker is left with a long file while the others idle.
Each successful conversion's wall time is kept in a small cache (``durations.json`` in
``$WATERTIGHT_CACHE_DIR``, else ``$XDG_CACHE_HOME/watertight`` or ``~/.cache/watertight``), keyed by
the input's SHA-256 and the stage; a file seen before is placed by its last time, a new one by its
size times the batch's median seconds per byte (by size alone when nothing is known). A CI job that
converts the same folder on every commit thus schedules from the previous run's times.

This module imports neither OCP nor click: the worker imports ``convert_file`` when it runs, and the
CLI turns the results (``FileResult``) into messages, reports and the exit code.

Test-only hook: the environment variable ``WATERTIGHT_TEST_FAULT`` (read by the supervisor when it
starts a worker, and passed to that worker) makes a worker misbehave on purpose, so that tests can
check the batch survives it. Its value is ``|``-separated ``KIND:NAME`` items, where NAME is an input
file's name and KIND is ``segv`` (the worker kills itself with SIGSEGV), ``hang`` (it makes the
temporary file of an atomic write of its output, then sleeps forever) or ``oom`` (it allocates memory
until stopped). It is not an option and is not meant for users.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import multiprocessing as mp
import os
import re
import signal
import statistics
import tempfile
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from multiprocessing.connection import wait
from pathlib import Path

from .errors import UsageError

BATCH_SCHEMA_VERSION = 1
CAD_SUFFIXES = (".step", ".stp", ".igs", ".iges")
FORMAT_SUFFIX = {"step": ".step", "iges": ".igs"}
FAULT_ENV = "WATERTIGHT_TEST_FAULT"
# modules the forkserver imports once, so that a fresh worker starts in milliseconds, not seconds
PRELOAD = ["watertight_cli." + m for m in ("batch", "convert", "inspect", "untrim", "verify", "stage2",
                                            "substitute", "occ.io", "occ.build", "occ.assemble")]
POLL_S = 0.2


@dataclass
class Job:
    """One file to convert. ``src``/``dst`` are absolute; ``shown``/``dst_shown`` are as the user wrote
    them (messages name those); ``rel`` is the output's path under the output folder."""

    shown: str
    src: str
    rel: str
    dst: str
    dst_shown: str
    options: dict = field(default_factory=dict)  # convert_file's: tol, stage, overwrite, fast
    timeout: float | None = None
    max_memory: int | None = None
    fault: str = ""  # test-only, see the module docstring
    debug: bool = False


@dataclass
class FileResult:
    """What happened to one file. ``failure`` is None when the conversion returned a report, else one of
    missing, exists, error, internal, memory, timeout, crash; ``reason`` is then one line naming the
    file. ``gate`` is set by the CLI when a gate or invariant fails (exit 3)."""

    shown: str
    rel: str
    dst_shown: str | None
    report: dict | None = None
    failure: str | None = None
    reason: str | None = None
    elapsed: float = 0.0  # wall time of its worker, s
    cpu: float | None = None  # CPU time of its worker (None when it died), s
    gate: str | None = None
    traceback: str | None = None

    @property
    def status(self) -> str:
        return "failed" if self.failure else "gate" if self.gate else "ok"


# ------------------------------------------------------------------------------ planning


def _has_magic(s: str) -> bool:
    return any(c in s for c in "*?[")


def _glob_base(pattern: str) -> Path:
    """The leading part of a glob without wildcards: matches are mirrored relative to it."""
    parts = Path(pattern).parts
    base = []
    for part in parts:
        if _has_magic(part):
            break
        base.append(part)
    return Path(*base) if base else Path(".")


def _folder_files(folder: Path, recursive: bool, skip: Path | None) -> list[Path]:
    """STEP/IGES files in ``folder``, without hidden ones and without those in the output folder
    ``skip`` when it lies inside (an earlier run's outputs); when ``folder`` is itself the output
    folder its files stay, and the output == input check refuses them."""
    if skip is not None and _inside(folder, skip):
        skip = None
    found = folder.rglob("*") if recursive else folder.iterdir()
    out = []
    for p in found:
        rel = p.relative_to(folder)
        if any(part.startswith(".") for part in rel.parts):  # hidden files, our own temporary files
            continue
        if skip is not None and _inside(p, skip):
            continue
        if p.is_file() and p.suffix.lower() in CAD_SUFFIXES:
            out.append(p)
    return sorted(out)


def _inside(p: Path, folder: Path) -> bool:
    try:
        p.resolve().relative_to(folder)
        return True
    except ValueError:
        return False


def plan(inputs: Iterable[str], outdir: str, recursive: bool = False, fmt: str | None = None,
         overwrite: bool = False, options: dict | None = None, timeout: float | None = None,
         max_memory: int | None = None) -> tuple[list[Job], list[FileResult]]:
    """Jobs for ``inputs`` (files, folders, globs) writing under ``outdir``, and the inputs that
    already failed (missing, nothing matched, output exists without ``overwrite``).

    A folder gives its STEP/IGES files (all levels with ``recursive``), mirrored relative to the
    folder; a glob gives its matches, mirrored relative to the glob's leading folder (``**`` needs
    ``recursive``); a file goes to the top of ``outdir``. ``fmt`` ("step"/"iges") sets the output
    suffix, else the input's is kept. Raises UsageError when an output would be an input, when two
    inputs would write one output, or when ``outdir`` is not a folder.
    """
    out_root = Path(outdir)
    if out_root.exists() and not out_root.is_dir():
        raise UsageError(f"{outdir}: the output folder is a file")
    out_resolved = out_root.resolve()
    found: list[tuple[str, Path, Path]] = []  # shown, path, rel
    failed: list[FileResult] = []
    for raw in inputs:
        p = Path(raw)
        if p.is_dir():
            found += [(str(f), f, f.relative_to(p)) for f in _folder_files(p, recursive, out_resolved)]
        elif p.exists():
            found.append((raw, p, Path(p.name)))
        elif _has_magic(raw):
            base = _glob_base(raw)
            matches = sorted(glob.glob(raw, recursive=recursive))
            n = 0
            for m in map(Path, matches):
                if m.is_dir():
                    fs = _folder_files(m, recursive, out_resolved)
                elif m.suffix.lower() in CAD_SUFFIXES and not _inside(m, out_resolved):
                    fs = [m]
                else:
                    fs = []
                found += [(str(f), f, f.relative_to(base)) for f in fs]
                n += len(fs)
            if not n:
                failed.append(FileResult(raw, raw, None, failure="missing",
                                         reason=f"{raw}: no STEP or IGES file matches"))
        else:
            failed.append(FileResult(raw, raw, None, failure="missing",
                                     reason=f"{raw}: no such file or folder"))

    inputs_resolved = {p.resolve(): shown for shown, p, _ in found}
    jobs: list[Job] = []
    by_dst: dict[Path, str] = {}
    seen: set[tuple[Path, Path]] = set()
    for shown, p, rel in found:
        if fmt:
            rel = rel.with_suffix(FORMAT_SUFFIX[fmt])
        dst = out_root / rel
        src_r, dst_r = p.resolve(), dst.resolve()
        if (src_r, dst_r) in seen:
            continue
        seen.add((src_r, dst_r))
        if dst_r in inputs_resolved or (dst.exists() and os.path.samefile(p, dst)):
            other = inputs_resolved.get(dst_r, shown)
            raise UsageError(f"{dst}: the output would overwrite the input {other} "
                             "(choose another -o folder or --format)")
        if dst_r in by_dst:
            raise UsageError(f"{dst}: both {by_dst[dst_r]} and {shown} would write it")
        by_dst[dst_r] = shown
        job = Job(shown, str(src_r), rel.as_posix(), str(dst_r), str(dst),
                  dict(options or {}, overwrite=overwrite), timeout, max_memory)
        if dst.exists() and not overwrite:
            failed.append(FileResult(shown, job.rel, job.dst_shown, failure="exists",
                                     reason=f"{dst}: exists (use --overwrite to replace it)"))
            continue
        jobs.append(job)
    return jobs, failed


# ------------------------------------------------------------------------------ the worker


def _fault(job: Job) -> str | None:
    name = os.path.basename(job.src)
    for item in job.fault.split("|"):
        kind, _, target = item.partition(":")
        if target and target == name:
            return kind
    return None


def _vm_size() -> int:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError):
        return 0


def _worker_main(conn, job: Job) -> None:
    """Runs in the worker process: convert one file, send ("ok", report) or (failure, reason, tb)."""
    if not job.debug:  # the kernel prints on the process's own stdout: keep --json's stdout clean
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
    if job.max_memory:
        import resource

        with contextlib.suppress(ValueError, OSError):
            cap = _vm_size() + job.max_memory
            resource.setrlimit(resource.RLIMIT_AS, (cap, resource.getrlimit(resource.RLIMIT_AS)[1]))
    kind = _fault(job)
    if kind == "segv":
        os.kill(os.getpid(), signal.SIGSEGV)
    elif kind == "hang":  # as if stuck inside the atomic write: its temporary file exists
        import tempfile

        d = Path(job.dst)
        tempfile.mkstemp(prefix=f".{d.stem}.", suffix=d.suffix, dir=d.parent)
        while True:
            time.sleep(3600)
    try:
        if kind == "oom":
            hog = []
            while True:
                hog.append(b"\1" * (32 << 20))
                time.sleep(0.01)
        from .convert import convert_file

        o = job.options
        report = convert_file(job.src, job.dst, o["tol"], o.get("stage", "full"), None,
                              o.get("overwrite", False), o.get("fast", False))
        msg = ("ok", report, None)
    except MemoryError:
        msg = ("memory", f"{job.src}: out of memory" + (" (--max-memory)" if job.max_memory else ""), None)
    except BaseException as exc:  # noqa: BLE001 - everything becomes this file's failure
        from .errors import WatertightError

        if isinstance(exc, WatertightError):
            msg = ("error", str(exc), None)
        else:
            import traceback

            text = str(exc).strip()
            reason = text.splitlines()[0] if text else type(exc).__name__
            msg = ("internal", f"{job.src}: internal error ({type(exc).__name__}: {reason}); "
                   "set WATERTIGHT_DEBUG=1 for details", traceback.format_exc())
    cpu = time.process_time()
    try:
        conn.send((*msg, cpu))
    except Exception as exc:  # noqa: BLE001 - e.g. a report that does not pickle
        conn.send(("internal", f"{job.src}: internal error (cannot send the report: {exc})", None, cpu))
    conn.close()
    os._exit(0)  # no interpreter teardown: the kernel's static destructors have nothing to add


# ------------------------------------------------------------------------------ supervision

_CTX = None


def _context():
    """forkserver (modules preloaded once) where available, else spawn: never fork a threaded parent."""
    global _CTX
    if _CTX is None:
        if "forkserver" in mp.get_all_start_methods():
            _CTX = mp.get_context("forkserver")
            _CTX.set_forkserver_preload(PRELOAD)
            from multiprocessing import forkserver

            forkserver.ensure_running()  # its start (the preload) is not charged to the first file
        else:  # pragma: no cover - Windows
            _CTX = mp.get_context("spawn")
    return _CTX


def _stat(path: str):
    try:
        st = os.stat(path)
        return st.st_ino, st.st_mtime_ns, st.st_size
    except OSError:
        return None


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


CACHE_ENV = "WATERTIGHT_CACHE_DIR"


def durations_file() -> Path:
    """Where the per-file wall times of earlier batches are kept (see the module doc)."""
    base = os.environ.get(CACHE_ENV)
    if not base:
        base = os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "watertight")
    return Path(base) / "durations.json"


def _content_key(job: Job) -> str | None:
    h = hashlib.sha256()
    try:
        with open(job.src, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return f"{h.hexdigest()}:{job.options.get('stage', 'full')}"


def _load_durations() -> dict[str, float]:
    try:
        data = json.loads(durations_file().read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: float(v) for k, v in data.items() if isinstance(v, int | float)}


def estimates(jobs: list[Job]) -> list[float]:
    """Expected seconds (or, when no file of the batch was seen before, bytes) per job: the order
    in which to start them is by this, largest first."""
    known = _load_durations()
    times = [known.get(k) if k else None for k in (_content_key(j) for j in jobs)]
    sizes = [_size(j.src) for j in jobs]
    rates = [t / s for t, s in zip(times, sizes, strict=True) if t is not None and s > 0]
    if not rates:
        return [float(s) for s in sizes]
    rate = statistics.median(rates)
    return [t if t is not None else s * rate for t, s in zip(times, sizes, strict=True)]


def record_durations(jobs: list[Job], results: list[FileResult]) -> None:
    """Keep the wall times of the files that converted (for the order of the next batch). Best
    effort: a cache that cannot be written is skipped silently."""
    fresh = {}
    for job, res in zip(jobs, results, strict=True):
        if res.failure is None and res.elapsed > 0:
            key = _content_key(job)
            if key:
                fresh[key] = round(res.elapsed, 3)
    if not fresh:
        return
    path = durations_file()
    try:
        data = _load_durations()
        data.update(fresh)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".durations.", dir=path.parent)
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh)
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError, UnboundLocalError):
            os.unlink(tmp)


def _rss(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def remove_temp_files(dst: str) -> list[str]:
    """Remove the temporary files an atomic write of ``dst`` may leave when its process is killed
    (``.STEM.XXXXXXXX.SUFFIX`` beside ``dst``, see ``occ.io.write_shape``)."""
    d = Path(dst)
    pat = re.compile(rf"^\.{re.escape(d.stem)}\.[A-Za-z0-9_]{{8}}{re.escape(d.suffix)}$")
    removed = []
    with contextlib.suppress(OSError):
        for p in d.parent.iterdir():
            if pat.match(p.name):
                with contextlib.suppress(OSError):
                    p.unlink()
                    removed.append(str(p))
    return removed


def _mb(n: int) -> str:
    return f"{n / 2**20:.0f} MB"


class _Running:
    def __init__(self, job: Job, proc, conn, before):
        self.job, self.proc, self.conn, self.before = job, proc, conn, before
        self.t0 = time.monotonic()
        self.msg = None
        self.conn_open = True
        self.killed: tuple[str, str] | None = None  # (failure, reason)


def _finish(rn: _Running) -> FileResult:
    job = rn.job
    rn.proc.join()
    with contextlib.suppress(OSError):
        rn.conn.close()
    res = FileResult(job.shown, job.rel, job.dst_shown, elapsed=time.monotonic() - rn.t0)
    if rn.killed is None and rn.msg is not None:
        kind, payload, tb, res.cpu = rn.msg
        if kind == "ok":
            payload["file"], payload["output"] = job.shown, job.dst_shown  # as the user named them
            res.report = payload
            return res
        res.failure, res.reason, res.traceback = kind, _shown(payload, job), tb
        return res
    if rn.killed is not None:
        res.failure, res.reason = rn.killed
    else:
        code = rn.proc.exitcode
        if code is not None and code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            res.failure, res.reason = "crash", f"{job.shown}: the worker crashed ({name})"
            if job.max_memory and -code in (signal.SIGABRT, signal.SIGKILL):
                res.reason += ", perhaps over --max-memory"
        else:
            res.failure = "crash"
            res.reason = f"{job.shown}: the worker exited with code {code} and no result"
    # a dead worker may leave its temporary file, or an output it wrote but did not verify
    remove_temp_files(job.dst)
    after = _stat(job.dst)
    if after is not None and after != rn.before:
        with contextlib.suppress(OSError):
            os.unlink(job.dst)
    return res


def _shown(reason: str, job: Job) -> str:
    """Messages from the worker name absolute paths; name them as the user did."""
    return reason.replace(job.dst, job.dst_shown).replace(job.src, job.shown)


_START_LOCK = threading.Lock()


def _start(proc) -> None:
    """Start a worker, also from a daemonic process (Dask's worker processes are daemons, and
    multiprocessing refuses them children). The worker is supervised and killed by its caller, never
    orphaned, so the flag is lifted for the start only (the usual work-around, under a lock)."""
    me = mp.current_process()
    with _START_LOCK:
        had, daemon = "daemon" in me._config, me._config.get("daemon")
        me._config["daemon"] = False
        try:
            proc.start()
        finally:
            if had:
                me._config["daemon"] = daemon
            else:
                me._config.pop("daemon", None)


def run_local(jobs: list[Job], n_jobs: int, on_start: Callable[[Job], None] | None = None,
              on_done: Callable[[FileResult], None] | None = None) -> list[FileResult]:
    """Run ``jobs`` with at most ``n_jobs`` worker processes at a time, one fresh process per file.

    Returns the results in the order of ``jobs``; ``on_start``/``on_done`` are called as files start
    and finish (in completion order).
    """
    ctx = _context()
    fault = os.environ.get(FAULT_ENV, "")
    debug = bool(os.environ.get("WATERTIGHT_DEBUG"))
    # longest first: a long file started last would keep one worker busy while the others idle
    est = estimates(jobs)
    pending = deque(sorted(enumerate(jobs), key=lambda ij: -est[ij[0]]))
    running: dict[int, _Running] = {}  # by index
    results: dict[int, FileResult] = {}

    def done(i: int, res: FileResult) -> None:
        results[i] = res
        running.pop(i, None)
        if on_done is not None:
            on_done(res)

    previous = _raise_on_sigterm()
    try:
        while pending or running:
            while pending and len(running) < max(1, n_jobs):
                i, job = pending.popleft()
                job.fault, job.debug = job.fault or fault, job.debug or debug  # a Dask job brings its own
                Path(job.dst).parent.mkdir(parents=True, exist_ok=True)
                recv, send = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=_worker_main, args=(send, job), daemon=True,
                                   name=f"watertight {job.rel}")
                rn = _Running(job, proc, recv, _stat(job.dst))
                try:
                    _start(proc)
                except Exception as exc:  # noqa: BLE001 - no worker for this file: its failure
                    send.close()
                    recv.close()
                    done(i, FileResult(job.shown, job.rel, job.dst_shown, failure="crash",
                                       reason=f"{job.shown}: cannot start a worker ({exc})"))
                    continue
                send.close()
                running[i] = rn
                if on_start is not None:
                    on_start(job)
            if not running:
                continue
            now = time.monotonic()
            wait_s = 1.0
            for rn in running.values():
                if rn.job.timeout:
                    wait_s = min(wait_s, max(0.0, rn.t0 + rn.job.timeout - now))
                if rn.job.max_memory:
                    wait_s = min(wait_s, POLL_S)
            objs = [rn.conn for rn in running.values() if rn.conn_open]
            objs += [rn.proc.sentinel for rn in running.values()]
            ready = set(wait(objs, timeout=wait_s))
            now = time.monotonic()
            for i, rn in list(running.items()):
                if rn.conn_open and (rn.conn in ready or rn.proc.sentinel in ready):
                    try:
                        if rn.conn.poll():
                            rn.msg = rn.conn.recv()
                            rn.conn_open = False
                        elif rn.proc.sentinel in ready:
                            rn.conn_open = False
                    except (EOFError, OSError):
                        rn.conn_open = False
                if rn.proc.sentinel in ready and not rn.conn_open:
                    done(i, _finish(rn))
                    continue
                job = rn.job
                if job.timeout and now - rn.t0 > job.timeout:
                    rn.killed = ("timeout", f"{job.shown}: timed out after {job.timeout:g} s (worker killed)")
                elif job.max_memory and (rss := _rss(rn.proc.pid) or 0) > job.max_memory:
                    rn.killed = ("memory", f"{job.shown}: over --max-memory {_mb(job.max_memory)} "
                                           f"(resident {_mb(rss)}; worker killed)")
                if rn.killed is not None:
                    rn.proc.kill()
                    done(i, _finish(rn))
    finally:
        for rn in running.values():  # interrupted: leave nothing running and nothing half-written
            with contextlib.suppress(Exception):
                rn.proc.kill()
                rn.proc.join()
            remove_temp_files(rn.job.dst)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return [results[i] for i in range(len(jobs))]


def _raise_on_sigterm():
    """SIGTERM (a CI job cancelled, ``kill``) raises SystemExit in the supervisor, so its cleanup runs
    and no worker is left running; returns the previous handler (None off the main thread)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None

    def stop(signum, frame):
        raise SystemExit(128 + signum)

    return signal.signal(signal.SIGTERM, stop)


def run_one(job: Job) -> FileResult:
    """One job in a supervised worker process (a Dask task calls this on the cluster)."""
    return run_local([job], 1)[0]


def run_dask(jobs: list[Job], scheduler: str, on_start: Callable[[Job], None] | None = None,
             on_done: Callable[[FileResult], None] | None = None) -> list[FileResult]:
    """Run ``jobs`` on the Dask cluster at ``scheduler``; each task supervises its own worker process.

    The cluster's workers need watertight installed and the same paths (a shared file system).
    Raises UsageError when dask.distributed is missing or the scheduler cannot be reached.
    """
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise UsageError("--executor dask needs dask.distributed: "
                         "pip install 'watertight_cli[dask]'") from None
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"cannot reach the Dask scheduler {scheduler} ({exc})") from None
    results: dict[int, FileResult] = {}
    try:
        futures = {}
        run_id = uuid.uuid4().hex[:8]
        est = estimates(jobs)
        for i, job in enumerate(jobs):
            job.fault = os.environ.get(FAULT_ENV, "")
            job.debug = bool(os.environ.get("WATERTIGHT_DEBUG"))
            Path(job.dst).parent.mkdir(parents=True, exist_ok=True)
            key = f"watertight-{run_id}-{i}-{job.rel}"
            # longest first (a higher priority runs earlier), as run_local does
            futures[client.submit(run_one, job, pure=False, key=key, priority=est[i])] = i
            if on_start is not None:
                on_start(job)
        for fut in as_completed(futures):
            i, job = futures[fut], jobs[futures[fut]]
            try:
                res = fut.result()
            except Exception as exc:  # noqa: BLE001 - the task itself failed (worker lost, ...)
                text = str(exc).strip().splitlines()
                res = FileResult(job.shown, job.rel, job.dst_shown, failure="crash",
                                 reason=f"{job.shown}: the Dask task failed ({type(exc).__name__}"
                                        + (f": {text[0]}" if text else "") + ")")
                remove_temp_files(job.dst)
            results[i] = res
            if on_done is not None:
                on_done(res)
    finally:
        client.close()
    return [results[i] for i in range(len(jobs))]


# ------------------------------------------------------------------------------ reports


def file_entry(r: FileResult) -> dict:
    rep = r.report or {}
    before, after = rep.get("before", {}), rep.get("after", {})
    return {
        "file": r.shown,
        "path": r.rel,
        "output": r.dst_shown if r.report is not None else None,
        "status": r.status,
        "failure": r.failure,
        "reason": r.reason or r.gate,
        "faces": rep.get("faces_in"),
        "patches": rep.get("patches_out"),
        "gap_before": before.get("gap_max"),
        "gap_after": after.get("gap_max"),
        "time_s": round(r.elapsed, 3),
        "cpu_s": None if r.cpu is None else round(r.cpu, 3),
        "report": r.report,
    }


def totals(results: list[FileResult], wall: float) -> dict:
    return {
        "files": len(results),
        "ok": sum(r.status == "ok" for r in results),
        "gate": sum(r.status == "gate" for r in results),
        "failed": sum(r.status == "failed" for r in results),
        "faces": sum((r.report or {}).get("faces_in", 0) for r in results),
        "patches": sum((r.report or {}).get("patches_out", 0) for r in results),
        "time_s": round(sum(r.elapsed for r in results), 3),
        "cpu_s": round(sum(r.cpu or 0.0 for r in results), 3),
        "wall_s": round(wall, 3),
    }


def batch_document(results: list[FileResult], wall: float, options: dict, tool: str) -> dict:
    return {
        "schema_version": BATCH_SCHEMA_VERSION,
        "tool": tool,
        "command": "convert",
        "options": options,
        "files": [file_entry(r) for r in results],
        "totals": totals(results, wall),
    }


def junit_xml(results: list[FileResult], wall: float, suite: str = "watertight convert") -> bytes:
    """JUnit XML: one test case per file; a failure element for failed files and for files that
    exceeded a gate or failed an invariant (exit 3)."""
    import socket
    import xml.etree.ElementTree as ET
    from datetime import UTC, datetime

    t = totals(results, wall)
    suites = ET.Element("testsuites", name=suite, tests=str(t["files"]),
                        failures=str(t["failed"] + t["gate"]), errors="0", time=f"{wall:.3f}")
    ts = ET.SubElement(suites, "testsuite", name=suite, tests=str(t["files"]),
                       failures=str(t["failed"] + t["gate"]), errors="0", skipped="0", time=f"{wall:.3f}",
                       timestamp=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S"),
                       hostname=socket.gethostname())
    for r in results:
        case = ET.SubElement(ts, "testcase", classname="watertight.convert", name=r.rel, file=r.shown,
                             time=f"{r.elapsed:.3f}")
        if r.failure or r.gate:
            kind = r.failure or "gate"
            msg = r.reason or r.gate or ""
            fail = ET.SubElement(case, "failure", message=msg, type=kind)
            fail.text = msg + ("\n" + r.traceback if r.traceback else "")
        if r.report is not None:
            e = file_entry(r)
            out = ET.SubElement(case, "system-out")
            out.text = (f"{r.shown} -> {r.dst_shown}: faces {e['faces']}, patches {e['patches']}, "
                        f"gap {_g(e['gap_before'])} -> {_g(e['gap_after'])}")
    ET.indent(suites)
    return ET.tostring(suites, encoding="utf-8", xml_declaration=True) + b"\n"


def _g(x) -> str:
    return "-" if x is None else f"{x:.3g}"


def summary_table(results: list[FileResult], wall: float) -> str:
    rows = [("file", "status", "faces", "patches", "gap before -> after", "time")]
    for r in results:
        e = file_entry(r)
        gap = f"{_g(e['gap_before'])} -> {_g(e['gap_after'])}" if r.report is not None else "-"
        rows.append((r.rel, r.status if not r.failure else f"failed ({r.failure})",
                     "-" if e["faces"] is None else str(e["faces"]),
                     "-" if e["patches"] is None else str(e["patches"]), gap, f"{r.elapsed:.1f}s"))
    t = totals(results, wall)
    rows.append((f"total {t['files']} files", f"ok {t['ok']}, gate {t['gate']}, failed {t['failed']}",
                 str(t["faces"]), str(t["patches"]), "", f"{wall:.1f}s wall"))
    widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]))]
    lines = []
    for n, row in enumerate(rows):
        if n == len(rows) - 1:
            lines.append("  ".join("-" * w for w in widths))
        cells = zip(row, widths, strict=True)
        lines.append("  ".join(c.ljust(w) if k < 2 else c.rjust(w) for k, (c, w) in enumerate(cells)))
        if n == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(line.rstrip() for line in lines)
