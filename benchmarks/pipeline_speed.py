"""The generation path before and after a change, side by side in one run: milliseconds per
set (batch of 32, default solver and steps) for the default models at a square and a
thinned size, each tree timed in fresh child processes taking turns, median of the rounds.

    python benchmarks/pipeline_speed.py OLD_TREE [--models ...] [--rounds 3]

OLD_TREE is a checkout of the earlier commit (``git worktree add /tmp/old COMMIT``); the new
tree is this repository. Writes benchmarks/results/pipeline_speed.md.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("gbn_fast", "poisson_disk_fast", "sot_fast", "sobol_owen_fast", "ldbn_fast",
          "sot_ramp_fast", "rank1")
SIZES = (1024, 1000)
CHILD = """
import json, sys, time
import diffsampler_rt as rt
name, n, batch = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
m = rt.load(name)
m.generate(n, batch, seed=0)  # warm: sessions, caches
t = time.perf_counter(); m.generate(n, batch, seed=1); dt = time.perf_counter() - t
print(json.dumps(1e3 * dt / batch))
"""


def time_tree(tree: Path, name: str, n: int, batch: int) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, "-c", CHILD, name, str(n), str(batch)], env=env,
                         cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old", type=Path)
    p.add_argument("--models", nargs="*", default=list(MODELS))
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--batch", type=int, default=32)
    args = p.parse_args()
    rows = []
    for name in args.models:
        for n in SIZES:
            times = {"old": [], "new": []}
            for _ in range(args.rounds):
                times["old"].append(time_tree(args.old, name, n, args.batch))
                times["new"].append(time_tree(ROOT, name, n, args.batch))
            old, new = (statistics.median(times[k]) for k in ("old", "new"))
            rows.append(f"| {name} | {n} | {old:.1f} | {new:.1f} | {100 * (new / old - 1):+.1f} % |")
            print(rows[-1], flush=True)
    head = (f"# The generation path before and after, side by side\n\n"
            f"`python benchmarks/pipeline_speed.py {args.old} --rounds {args.rounds}` on "
            f"{cpu_name()}, {os.cpu_count()} cores: ms per set in a batch of {args.batch}, "
            f"default solver and steps, each figure the median of {args.rounds} fresh child "
            "processes, the two trees taking turns. *old*: the runtime whose Model wired the "
            "finishing steps by hand (format-1 cards); *new*: the card's pipeline "
            "(diffsampler_rt.finish) with border reflection.\n\n"
            "| model | n | old ms / set | new ms / set | change |\n|---|---|---|---|---|\n")
    out = ROOT / "benchmarks" / "results" / "pipeline_speed.md"
    out.write_text(head + "\n".join(rows) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
