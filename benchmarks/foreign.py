"""``python -m trainer fit`` on point processes that no part of the project knows, as a new
user would meet it: each process's sets are made here, written to files, then fitted from
the files with default settings (one thread a fit, two fits at a time on a 2-core machine).
Writes benchmarks/results/foreign.md: what the fit found in each (embedding, uniformity,
structure, blue noise), the finishing steps its calibration chose, and its report's
figures at n = 1024 against held-out sets, verdicts included.

    python benchmarks/foreign.py [--cases thomas dart ...] [--minutes 20] [--jobs 2]

The processes (none is a built-in sampler; the fit is told nothing about them):

- ``jittered``: one uniform point per cell of the k x k grid (stratified, no net);
- ``thomas``: a Thomas cluster process, 8 points a cluster around uniform parents;
- ``dart``: dart throwing on the torus at 0.7 of the densest packing's radius (a hard core);
- ``lloyd``: uniform points after 10 Lloyd relaxation steps on the torus (relaxed);
- ``hex``: a shifted triangular lattice with Gaussian jitter of 0.15 of a row (lattice-like);
- ``trees``: clusters whose parents thin out from left to right (non-uniform, clustered: a
  stand-in for a measured pattern).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from fit import _fig, fit_files, relative, verdicts  # noqa: E402

#: sets written per example size
SIZES = {64: 128, 256: 96, 1024: 48}


def _in_square(p: np.ndarray) -> np.ndarray:
    p = p % 1.0
    return np.where(p >= 1.0, 0.0, p)


def jittered(n: int, rng: np.random.Generator) -> np.ndarray:
    k = math.isqrt(n)
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return (cells + rng.random((n, 2))) / k


def thomas(n: int, rng: np.random.Generator, kids: int = 8,
           parents: np.ndarray | None = None) -> np.ndarray:
    parents = rng.random((n // kids, 2)) if parents is None else parents
    return _in_square(parents[:, None] + rng.normal(0, 0.5 / math.sqrt(n), (len(parents), kids, 2))
                      ).reshape(-1, 2)


def dart(n: int, rng: np.random.Generator, frac: float = 0.7) -> np.ndarray:
    r = frac * math.sqrt(2 / (math.sqrt(3) * n))
    pts = np.empty((n, 2))
    count = 0
    while count < n:
        c = rng.random(2)
        d = np.abs(pts[:count] - c)
        d = np.minimum(d, 1 - d)
        if not count or (d * d).sum(1).min() >= r * r:
            pts[count] = c
            count += 1
    return pts


def lloyd(n: int, rng: np.random.Generator, steps: int = 10) -> np.ndarray:
    p = rng.random((n, 2))
    for _ in range(steps):  # centroids of the Voronoi cells, by Monte Carlo, on the torus
        m = rng.random((40 * n, 2))
        owner = cKDTree(p, boxsize=1.0).query(m)[1]
        angle = 2 * np.pi * m
        c, s = np.zeros((n, 2)), np.zeros((n, 2))
        np.add.at(c, owner, np.cos(angle))
        np.add.at(s, owner, np.sin(angle))
        p = _in_square(np.arctan2(s, c) / (2 * np.pi))
    return p


def hex_lattice(n: int, rng: np.random.Generator, jitter: float = 0.15) -> np.ndarray:
    k = math.isqrt(n)
    i, j = np.meshgrid(np.arange(k), np.arange(k))
    rows = np.stack([(i + 0.5 * (j % 2)) / k, j / k], -1).reshape(-1, 2)
    return _in_square(rows + rng.random(2) + rng.normal(0, jitter / k, (n, 2)))


def trees(n: int, rng: np.random.Generator) -> np.ndarray:
    """Parents drawn with density 1.6 - 1.2 x (x in [0, 1]): more clusters on the left."""
    count = n // 8
    x = rng.random(4 * count)
    keep = rng.random(4 * count) < (1.6 - 1.2 * x) / 1.6
    parents = np.stack([x[keep][:count], rng.random(count)], -1)
    return thomas(n, rng, parents=parents)


PROCESSES = {"jittered": jittered, "thomas": thomas, "dart": dart, "lloyd": lloyd,
             "hex": hex_lattice, "trees": trees}


def write_examples(case: str, work: Path) -> list[Path]:
    """The process's sets as one text file a set (``x y`` lines), made once."""
    folder = work / f"{case}_examples"
    marker = folder.with_name(folder.name + ".done")
    if not marker.exists():
        folder.mkdir(parents=True, exist_ok=True)
        for n, count in SIZES.items():
            rng = np.random.default_rng([11, n])
            for i in range(count):
                pts = PROCESSES[case](n, rng)
                assert pts.shape == (n, 2)
                np.savetxt(folder / f"set_{n}_{i:04d}.txt", pts, fmt="%.17g")
        marker.write_text("")
    return [folder]


def findings(model: Path) -> dict:
    """What the fit found and which finishing steps its calibration chose (from the card)."""
    import diffsampler_rt
    card = diffsampler_rt.Model(model).card
    a = card["fit"]["analysis"]
    return {"embedding": a["embedding"], "uniform": a["uniform"], "structure": a["structure"],
            # blue noise is what makes the calibration thin the most crowded points first
            "blue": any(e.get("drop") == "crowded" for e in card["pipeline"]),
            "pipeline": [e["step"] + (f" ({e['where']})" if "where" in e else "")
                         for e in card["pipeline"]]}


def run(case: str, work: Path, minutes: float) -> dict:
    result = fit_files(case, write_examples(case, work), work, minutes)
    if "error" not in result:
        result["found"] = findings(work / "out" / f"{case}.onnx")
    return result


def report(results: list[dict]) -> str:
    cpu = next((l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text()
                .splitlines() if l.startswith("model name")), platform.processor())
    runs = list(dict.fromkeys((r["command"], r.get("note", "")) for r in results))
    lines = ["# Fitting point processes the project does not know", "",
             "Made by " + "; ".join(f"({i}) `{c}`" + (f" ({n})" if n else "")
                                    for i, (c, n) in enumerate(runs, 1))
             + f" on {cpu} ({os.cpu_count()} cores), each fit one process "
             "with one thread, default settings otherwise. The processes are described in "
             "`benchmarks/foreign.py`; their sets (" + ", ".join(
                 f"{c} at n = {n}" for n, c in SIZES.items()) + ") were written as one "
             "`x y` text file a set and fitted from the files. What the fit found is its "
             "own analysis; the figures are its report's at n = 1024 against the held-out "
             "sets (never trained or calibrated on). Full reports: [fit/](fit/) "
             "(`CASE.report.md` and `.png`, of each process's latest run). Each fit plans its "
             "training steps from a speed probe at its start and stops at its budget; the "
             "training column gives the steps it took.", "",
             "| process | run | found | finishing steps chosen | training | spectrum MAE "
             "(floor) | pair correlation MAE (floor) | smallest distance | star L2 | verdicts |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    def run_of(r: dict) -> int:
        return runs.index((r["command"], r.get("note", ""))) + 1

    for r in results:
        if "error" in r:
            lines.append(f"| {r['case']} | {run_of(r)} | failed: {r['error']} | | "
                         f"{r['wall_s'] / 60:.1f} min | | | | | |")
            continue
        f, found = r["figures"]["1024"], r["found"]
        spec, pcf = _fig(f, "radial spectrum"), _fig(f, "pair correlation")
        mind, l2 = _fig(f, "smallest distance"), _fig(f, "star L2")

        what = (f"{found['embedding']}, {'uniform' if found['uniform'] else 'not uniform'}, "
                f"{'blue noise' if found['blue'] else 'not blue noise'}"
                + (f", {found['structure']}" if found["structure"] else ""))
        lines.append(f"| {r['case']} | {run_of(r)} | {what} | {', '.join(found['pipeline'])} | "
                     f"{r['trained'].removeprefix('trained ') or '?'}; "
                     f"{'resumed run' if r.get('resumed') else 'run'} {r['wall_s'] / 60:.0f} min"
                     f" | {spec['generated']:.4f} "
                     f"({spec['noise']:.4f}) | {pcf['generated']:.4f} ({pcf['noise']:.4f}) | "
                     f"{relative(mind)} | {relative(l2)} | {verdicts(f)} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", nargs="*", default=list(PROCESSES), choices=list(PROCESSES))
    p.add_argument("--minutes", type=float, default=20.0)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--work", type=Path,
                   default=Path.home() / ".cache" / "diffsampler" / "foreign_bench")
    p.add_argument("--report-only", action="store_true",
                   help="rewrite foreign.md from the kept foreign.json")
    p.add_argument("--note", default="", help="a sentence on the run for the report (e.g. what "
                   "else ran on the machine)")
    args = p.parse_args()
    out = ROOT / "benchmarks" / "results" / "foreign.md"
    kept = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(
        ".json").exists() else []
    if not args.report_only:
        args.work.mkdir(parents=True, exist_ok=True)
        with ThreadPoolExecutor(args.jobs) as pool:
            results = list(pool.map(lambda c: run(c, args.work, args.minutes), args.cases))
        command = (f"python benchmarks/foreign.py --cases {' '.join(args.cases)} "
                   f"--minutes {args.minutes:g} --jobs {args.jobs}")
        for r in results:
            r["command"], r["note"] = command, args.note
        # a run replaces its own earlier rows; other runs' rows stay (each names its run)
        new = {(r["case"], command) for r in results}
        kept = [r for r in kept if (r["case"], r["command"]) not in new] + results
        kept.sort(key=lambda r: list(PROCESSES).index(r["case"]))
        out.with_suffix(".json").write_text(json.dumps(kept, indent=1))
    out.write_text(report(kept))
    print(out.read_text())


if __name__ == "__main__":
    main()
