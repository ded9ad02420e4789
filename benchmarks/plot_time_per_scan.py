"""Time per scan against scan index from a run's ``steps.csv``: is it flat?

    python benchmarks/plot_time_per_scan.py RUN_DIR [RUN_DIR ...] --out docs/campus_ms_per_scan.png

A benchmark, not a test: it prints, per run, the mean and median ms per scan over the first and the
last 10 % of the scans after the first submap (issue 16's flatness figure) and draws every
scan's time (dots) with a running median over 50 scans.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (with steps.csv and summary.json)")
    parser.add_argument("--out", type=Path, required=True, help="picture (.png/.svg)")
    args = parser.parse_args()

    import matplotlib.figure

    fig = matplotlib.figure.Figure(figsize=(9, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for run in args.runs:
        table = np.genfromtxt(run / "steps.csv", delimiter=",", names=True)
        ms, submap = np.atleast_1d(table["time_ms"]), np.atleast_1d(table["submap"]).astype(int)
        index = np.arange(ms.size)
        after = index[submap > 0] if np.any(submap > 0) else index     # beyond the first submap
        tenth = max(1, after.size // 10)
        first, last = ms[after[:tenth]].mean(), ms[after[-tenth:]].mean()
        # the mean carries the rare freezes (loop closure: seconds); the median the typical scan
        first_median, last_median = np.median(ms[after[:tenth]]), np.median(ms[after[-tenth:]])
        label = run.resolve().name if run.name != "latest" else run.resolve().parent.name
        print(f"{label}: {ms.size} scans, {submap.max() + 1} submaps; ms per scan, first 10 % beyond the first "
              f"submap {first:.2f}, last 10 % {last:.2f} (ratio {last / first:.2f}); medians {first_median:.2f} and "
              f"{last_median:.2f} (ratio {last_median / first_median:.2f}); mean {ms.mean():.2f}, "
              f"max {ms.max():.0f}")
        ax.plot(index, ms, ".", ms=2, alpha=0.35)
        k = 50
        if ms.size > k:
            running = np.array([np.median(ms[max(0, i - k):i + 1]) for i in index])
            ax.plot(index, running, lw=1.5, label=f"{label}: running median of {k}")
    ax.set_yscale("log")
    ax.set_xlabel("scan index")
    ax.set_ylabel("time per scan (ms; front end + filter + loop closure)")
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)
    fig.savefig(args.out, dpi=130)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
