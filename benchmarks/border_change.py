"""What folding points back into the square (instead of clamping them onto its border) does
to every bundled model's sets: per model at n = 1024 and 200, border coordinates per
100 k, the mean smallest distance and the radial spectrum, before (OLD_TREE, clamping) and
after (this tree), the same seeds, against the noise of the figures.

    python benchmarks/border_change.py OLD_TREE [--sets 64]

Writes benchmarks/results/border_change.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CHILD = """
import json, sys
import numpy as np
import diffsampler_rt as rt
from diffsampler_rt.spectrum import radial_spectrum
from scipy.spatial import cKDTree
sets, out = int(sys.argv[1]), {}
below = np.nextafter(1.0, 0.0)
for name in rt.list_models():
    for n in (1024, 200):
        p = rt.generate(name, n, sets, seed=2024)
        mins = [cKDTree(s).query(s, k=2)[0][:, 1].min() * np.sqrt(n) for s in p]
        out[f"{name} {n}"] = {"border": int(np.sum((p == 0) | (p >= below))),
                              "points": int(p.size), "min": mins,
                              "half": [radial_spectrum(p[:sets // 2])[1].tolist(),
                                       radial_spectrum(p[sets // 2:])[1].tolist()]}
        out[f"{name} {n}"]["spectrum"] = np.mean(out[f"{name} {n}"]["half"], axis=0).tolist()
print(json.dumps(out))
"""


def measure(tree: Path, sets: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(sets)], cwd=tree, check=True,
                         env={**os.environ, "PYTHONPATH": str(tree)}, capture_output=True,
                         text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old", type=Path)
    p.add_argument("--sets", type=int, default=64)
    a = p.parse_args()
    old, new = measure(a.old, a.sets), measure(ROOT, a.sets)
    rows = ["| model | n | border coords per 100 k, before -> after | mean smallest distance "
            "x sqrt(n), before -> after (+- se) | spectrum MAE before vs after (noise) |",
            "|---|---|---|---|---|"]
    for key in old:
        o, w = old[key], new[key]
        per = 1e5 / o["points"]
        m_o, m_w = np.mean(o["min"]), np.mean(w["min"])
        se = np.sqrt(np.var(o["min"], ddof=1) / len(o["min"]) + np.var(w["min"], ddof=1)
                     / len(w["min"]))
        mae = float(np.mean(np.abs(np.subtract(o["spectrum"], w["spectrum"]))))
        # the MAE two independent batches of this many sets would show: the halves' / sqrt 2
        noise = float(np.mean(np.abs(np.subtract(*o["half"])))) / np.sqrt(2)
        name, n = key.split()
        rows.append(f"| {name} | {n} | {o['border'] * per:.0f} -> {w['border'] * per:.0f} | "
                    f"{m_o:.4f} -> {m_w:.4f} ({m_w / m_o - 1:+.2%} +- {se / m_o:.2%}) | "
                    f"{mae:.4f} ({noise:.4f}) |")
    text = ("# Folding points back instead of clamping them: before and after\n\n"
            f"`python benchmarks/border_change.py {a.old} --sets {a.sets}`: every bundled model, "
            f"{a.sets} sets at n = 1024 and at 200 (seed 2024), made by the runtime before the "
            "change (points clamped onto the square's border) and after (folded back, "
            "`diffsampler_rt.grid.reflect`). The same seeds give the same sets except where a "
            "point left the square, so the differences are the clamped points' alone. "
            "*noise*: the mean absolute difference that two independent batches of this many "
            "sets would show (the halves' difference / sqrt 2), for scale: a difference far "
            "below it is far below anything the fidelity report can resolve.\n\n"
            + "\n".join(rows) + "\n")
    (ROOT / "benchmarks" / "results" / "border_change.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
