"""Micro-benchmark of the numeric core: composing bicubic patches with ruled cell maps.

Run: ``python -m benchmarks.bench_core``. ``run()`` prints the figures and returns them as a dict.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from watertight_cli.core.bezier import homogenize
from watertight_cli.core.compose import compose, compose_batch, composed_bidegree, ruled_map


def _median_time(fn, repeats: int, number: int) -> float:
    """Median over ``repeats`` of the mean time of ``number`` calls, in seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return statistics.median(times)


def run(n_batch: int = 1000, seed: int = 0) -> dict:
    """Time one bicubic x (ruled map of a cubic piece) composition and a batch of ``n_batch`` of them.

    The patches are rational (homogeneous, d = 4), as a NURBS face would give. Returns a dict with
    ``single_us`` (median, microseconds), ``batch_ms`` (median, milliseconds), ``per_patch_batch_us``,
    ``loop_ms`` (n_batch single calls in a Python loop, for comparison) and ``out_degree`` (ds, dt).
    """
    rng = np.random.default_rng(seed)
    ctrl = homogenize(rng.normal(size=(4, 4, 3)), rng.uniform(0.5, 2.0, (4, 4)))
    O = np.array([[0.2, 0.0], [0.2, 1.0]])  # iso side, degree 1 (elevated to 3 inside ruled_map)
    T = rng.random((4, 2))  # cubic trimming piece
    U, V = ruled_map(O, T)
    out_degree = composed_bidegree(3, 3, (U.shape[0] - 1, U.shape[1] - 1), (V.shape[0] - 1, V.shape[1] - 1))
    out = compose(ctrl, U, V)
    assert out.shape == (out_degree[0] + 1, out_degree[1] + 1, 4)

    single = _median_time(lambda: compose(ctrl, U, V), repeats=21, number=200)

    ctrls = homogenize(rng.normal(size=(n_batch, 4, 4, 3)), rng.uniform(0.5, 2.0, (n_batch, 4, 4)))
    Ts = rng.random((n_batch, 4, 2))
    maps = [ruled_map(O, t) for t in Ts]
    Us = np.stack([m[0] for m in maps])
    Vs = np.stack([m[1] for m in maps])
    batch = _median_time(lambda: compose_batch(ctrls, Us, Vs), repeats=7, number=1)

    def loop():
        for i in range(n_batch):
            compose(ctrls[i], Us[i], Vs[i])

    looped = _median_time(loop, repeats=3, number=1)

    res = {
        "out_degree": out_degree,
        "single_us": single * 1e6,
        "batch_ms": batch * 1e3,
        "per_patch_batch_us": batch * 1e6 / n_batch,
        "loop_ms": looped * 1e3,
        "n_batch": n_batch,
    }
    print(
        f"compose bicubic (rational) x ruled map of a cubic piece -> bidegree {out_degree[0]}x{out_degree[1]}"
    )
    print(f"  one patch:            {res['single_us']:8.1f} us (median)")
    print(
        f"  batch of {n_batch}:        {res['batch_ms']:8.2f} ms (median; "
        f"{res['per_patch_batch_us']:.1f} us per patch)"
    )
    print(f"  {n_batch} single calls:    {res['loop_ms']:8.2f} ms (Python loop, for comparison)")
    return res


if __name__ == "__main__":
    run()
