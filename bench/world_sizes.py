"""World frames against the world's size: ``bench.world`` at several static-triangle counts, one
table and one figure of the frame against Embree's two-level frame by size.

    python -m bench.world_sizes --out /tmp/sizes                  # 0.5M to 8M, 1 and 8 lidars
    python -m bench.world_sizes --triangles 5e5,2e6 --lidars 1 --frames 3 --out /tmp/sizes
    python -m bench.world_sizes --replot /tmp/sizes               # the table and figure again

Each size is one ``bench.world`` run (the world built from ``../shared/scenes`` up to that many
triangles, 40 moving cars, every engine side by side, its order turned every frame), written to
``OUT/<triangles>/world.json``; ``OUT/world-sizes.md`` gets the table and
``OUT/world-sizes.png`` the figure: Embree's median frame over each engine's, by size, one line a
lidar count.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bench import world
from bench.entry import description

#: The engines of the table and figure, with their names there.
SHOWN = {
    "dacrt changes": "dacrt with_changes",
    "service rig": "service rig",
    "dacrt": "dacrt new Scene",
}


def float_list(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x]


def load_runs(out: Path) -> list[dict]:
    """Every ``bench.world`` result under ``out`` (one folder a size), smallest world first."""
    runs = []
    for path in sorted(out.glob("*/world.json")):
        result = json.loads(path.read_text())
        result["counts"] = {int(n): record for n, record in result["counts"].items()}
        runs.append(result)
    return sorted(runs, key=lambda r: r["world"]["triangles"])


def size_table(runs: list[dict]) -> str:
    """One row a world size and lidar count: Embree's frame, each engine's frame and ratio."""
    engines = [e for e in SHOWN if any(e in row for r in runs for row in summaries(r).values())]
    lines = [
        "| static triangles | lidars | Embree two-level, ms | "
        + " | ".join(f"{SHOWN[e]}, ms: Embree / it" for e in engines)
        + " | load at start, end |",
        "|--:|--:|--:|" + "--:|" * len(engines) + "---|",
    ]
    for run in runs:
        for n, row in summaries(run).items():
            embree = row["embree"]["total"]
            cells = [
                f"{row[e]['total']:.1f}: **{embree / row[e]['total']:.2f}×**" if e in row else "—"
                for e in engines
            ]
            load = f"{run['load'][0]:.1f}, {run['load'][1]:.1f}"
            lines.append(
                f"| {run['world']['triangles']:,} | {n} | {embree:.1f} | "
                + " | ".join(cells)
                + f" | {load} |"
            )
    return "\n".join(lines)


def summaries(run: dict) -> dict:
    """``bench.world``'s summary of one run, lidar counts that Embree ran only."""
    return {n: row for n, row in world.summarise(run["counts"]).items() if "embree" in row}


def draw(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.plots import DACRT_COLORS

    sizes = [run["world"]["triangles"] / 1e6 for run in runs]
    counts = sorted({n for run in runs for n in summaries(run)})
    markers = dict(zip(counts, "osD^v"))
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5.4), dpi=130)
    for n in counts:
        rows = [summaries(run).get(n) for run in runs]
        embree = [row["embree"]["total"] if row else np.nan for row in rows]
        left.plot(sizes, embree, color="black", linestyle=(0, (5, 2)), marker=markers[n],
                  label=f"Embree, {n} lidar{'s' if n > 1 else ''}")  # fmt: skip
        for k, (engine, name) in enumerate(SHOWN.items()):
            frame = [row[engine]["total"] if row and engine in row else np.nan for row in rows]
            if np.isnan(frame).all():
                continue
            style = {"color": DACRT_COLORS[k], "marker": markers[n], "linewidth": 2}
            label = f"{name}, {n} lidar{'s' if n > 1 else ''}"
            left.plot(sizes, frame, label=label, **style)
            right.plot(sizes, np.divide(embree, frame), label=label, **style)
    for ax in (left, right):
        ax.set_xscale("log", base=2)
        ax.set_xticks(sizes, [f"{s:.2g}M" for s in sizes])
        ax.minorticks_off()
        ax.grid(True, alpha=0.35)
        ax.set_xlabel("static triangles of the world")
    left.set_yscale("log")
    left.set_ylabel("ms a frame (median)")
    left.set_title("Frame time", fontsize=12)
    right.axhline(1.0, color="gray", linewidth=1)
    right.set_ylabel("Embree frame / engine frame (above 1: faster than Embree)")
    right.set_title("Against Embree's two-level frame", fontsize=12)
    left.legend(fontsize=7, frameon=False, ncol=2, loc="upper left")
    right.legend(fontsize=7, frameon=False, ncol=2, loc="upper left")
    first = runs[0]
    fig.suptitle(
        f"World frames by world size: {first['args']['actors']} moving cars, "
        f"{first['args']['threads']} threads, {world.LIDAR_MODEL} lidars of "
        f"{64 * world.STEPS:,} rays; {first['machine']['cpu']}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def write(out: Path) -> str:
    runs = load_runs(out)
    if not runs:
        raise SystemExit(f"no bench.world results (*/world.json) under {out}")
    table = size_table(runs)
    (out / "world-sizes.md").write_text(table + "\n")
    draw(runs, out / "world-sizes.png")
    return table


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--triangles", type=float_list, default=[5e5, 1e6, 2e6, 4e6, 8e6])
    parser.add_argument("--lidars", default="1,8")
    parser.add_argument("--frames", type=int, default=7, help="timed frames per lidar count")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None, help="a folder for every size's run")
    parser.add_argument("--replot", type=Path, default=None, help="the table and figure again")
    args = parser.parse_args(argv)
    if args.replot:
        print(write(args.replot))
        return 0
    if args.out is None:
        parser.error("--out: the folder where each size's run goes")
    for triangles in args.triangles:
        print(f"world of {triangles:,.0f} triangles ...", file=sys.stderr, flush=True)
        status = world.main(
            [
                f"--triangles={triangles}",
                f"--lidars={args.lidars}",
                f"--frames={args.frames}",
                f"--threads={args.threads}",
                f"--out={args.out / str(int(triangles))}",
            ]
        )
        if status:
            return status
    print(write(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
