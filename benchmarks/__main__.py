"""`make bench`: run every benchmark, print its figures and write benchmarks/results.json.

``python -m benchmarks [bench_convert options]``: the core micro-benchmark, then convert against the
OCCT floor per file, the scaling family and the ``--jobs 2`` speed-up on the fixtures
(``benchmarks.bench_convert``); results.json holds all of them.
"""

from __future__ import annotations

from . import bench_convert, bench_core


def main(argv: list[str] | None = None) -> None:
    core = bench_core.run()
    print()
    bench_convert.main(argv, extra={"core": core})


if __name__ == "__main__":
    main()
