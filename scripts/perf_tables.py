#!/usr/bin/env python3
"""Markdown tables for docs/performance.md from `fogcast bench` reports (bench.json).

Usage: scripts/perf_tables.py out/bench/colonnade [out/bench/sponza ...]
       scripts/perf_tables.py --overlap out/bench/colonnade shared
Prints, per report: frame time and ratio to reference for every configuration and
viewer count of the path scenario, fog rays, FLIP, and the per-stage breakdown at the
fewest and most viewers. Numbers are copied as measured; nothing is recomputed beyond
rounding.
"""
import json
import sys
from pathlib import Path


def load(folder):
    return json.loads((Path(folder) / "bench.json").read_text())


def path_points(r):
    return [p for p in r["points"] if p["scenario"]["kind"] == "path"]


def main():
    for folder in sys.argv[1:]:
        r = load(folder)
        pts = path_points(r)
        configs = [c for c in dict.fromkeys(p["config"] for p in pts)]
        counts = sorted({p["viewers"] for p in pts})
        at = {(p["config"], p["viewers"]): p for p in pts}
        print(f"### {r['scene']} — `{r['command']}`\n")
        print(f"load average {r['load_average']}, {r['elapsed_s']:.0f} s\n")
        head = "| cameras | " + " | ".join(
            f"{c} ms (/ ref)" if c != "reference" else "reference ms" for c in configs
        ) + " |"
        print(head)
        print("|" + "---|" * (len(configs) + 1))
        for n in counts:
            cells = []
            for c in configs:
                p = at.get((c, n))
                if p is None:
                    cells.append("–")
                    continue
                ms = p["frame_gpu_ms"]["median"]
                ratio = p.get("frame_gpu_vs_reference")
                if c == "reference" or not ratio:
                    cells.append(f"{ms:.0f}")
                else:
                    cells.append(f"{ms:.0f} ({ratio['median']:.2f})")
            print(f"| {n} | " + " | ".join(cells) + " |")
        print()
        print("| cameras | " + " | ".join(f"{c} fog rays" for c in configs) + " |")
        print("|" + "---|" * (len(configs) + 1))
        for n in counts:
            cells = []
            for c in configs:
                p = at.get((c, n))
                cells.append("–" if p is None else f"{p['rays']['fog_total'] / 1000:.0f}k")
            print(f"| {n} | " + " | ".join(cells) + " |")
        print()
        flips = []
        for c in configs:
            if c == "reference":
                continue
            f = [at[(c, n)]["flip_vs_reference"] for n in counts if (c, n) in at]
            f = [x for x in f if x]
            if f:
                flips.append(
                    f"`{c}` {min(x['mean'] for x in f):.3f}–{max(x['mean'] for x in f):.3f}"
                    f" (worst image {max(x['max'] for x in f):.3f})"
                )
        print("Mean FLIP against `reference`: " + ", ".join(flips) + ".\n")
        stages = list(
            dict.fromkeys(s["stage"] for p in pts for s in p["stages"])
        )
        print("| cameras | configuration | " + " | ".join(stages) + " | frame |")
        print("|" + "---|" * (len(stages) + 3))
        for n in (counts[0], counts[-1]):
            for c in configs:
                p = at.get((c, n))
                if p is None:
                    continue
                by = {s["stage"]: s["gpu_ms"]["median"] for s in p["stages"]}
                cells = [f"{by[s]:.1f}" if s in by else "–" for s in stages]
                print(
                    f"| {n} | {c} | " + " | ".join(cells)
                    + f" | {p['frame_gpu_ms']['median']:.1f} |"
                )
        print()



def overlap_table(folder, config):
    """Time and fog-ray ratios to reference of `config` in the fixed-overlap scenario."""
    r = load(folder)
    pts = [p for p in r["points"] if p["scenario"]["kind"] == "overlap"]
    if not pts:
        return
    key = lambda p: (p["scenario"]["overlap_pct"], p["viewers"])
    ref = {key(p): p for p in pts if p["config"] == "reference"}
    mine = {key(p): p for p in pts if p["config"] == config}
    overlaps = sorted({k[0] for k in mine})
    counts = sorted({k[1] for k in mine})
    print(f"`{config}` / `reference` in the fixed-overlap scenario: frame time (median of per-frame ratios), fog rays\n")
    print("| cameras | " + " | ".join(f"{o:g} %" for o in overlaps) + " |")
    print("|" + "---|" * (len(overlaps) + 1))
    for n in counts:
        cells = []
        for o in overlaps:
            p, q = mine.get((o, n)), ref.get((o, n))
            if p is None or q is None:
                cells.append("–")
                continue
            t = p["frame_gpu_vs_reference"]["median"]
            rays = p["rays"]["fog_total"] / max(q["rays"]["fog_total"], 1)
            cells.append(f"{t:.2f}, {rays:.2f}")
        print(f"| {n} | " + " | ".join(cells) + " |")
    print()


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--overlap":
        overlap_table(sys.argv[2], sys.argv[3])
    else:
        main()
