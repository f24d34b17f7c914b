"""`make bench`: run every benchmark and print its figures."""

from __future__ import annotations

from . import bench_core


def main() -> None:
    bench_core.run()


if __name__ == "__main__":
    main()
