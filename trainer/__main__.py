"""Command line: ``python -m trainer train|prepare CONFIG`` and ``python -m trainer sample NAME N``."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _save_points(points: np.ndarray, path: Path) -> None:
    suffix = path.suffix.lower()
    if suffix == ".npy":
        np.save(path, points)
    elif suffix in (".txt", ".csv"):
        sep = " " if suffix == ".txt" else ","
        with open(path, "w") as fh:
            for i, pts in enumerate(points.reshape((-1,) + points.shape[-2:])):
                if i:
                    fh.write("\n")
                np.savetxt(fh, pts, fmt="%.17g", delimiter=sep)
    else:
        raise ValueError(f"unknown output format {suffix!r}; use .npy, .txt or .csv")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)

    t = sub.add_parser("train", help="train (or resume) a model from a JSON config")
    t.add_argument("config", type=Path, help="e.g. trainer/configs/sobol_owen.json")
    t.add_argument("--run-dir", type=Path, help="default: runs/<config name>")
    t.add_argument("--steps", type=int, help="stop at this step (default: the config's)")
    t.add_argument("--minutes", type=float, help="stop after this much wall time")
    t.add_argument("--no-progress", action="store_true")

    r = sub.add_parser("prepare", help="build (and cache) a config's training pools")
    r.add_argument("config", type=Path)

    s = sub.add_parser("sample", help="draw point sets from a reference sampler")
    s.add_argument("name")
    s.add_argument("n", type=int)
    s.add_argument("--count", type=int, default=1)
    s.add_argument("--seed", type=int, default=None)
    s.add_argument("-o", "--output", type=Path, required=True, help=".npy, .txt or .csv")

    args = p.parse_args(argv)
    try:
        if args.cmd == "train":
            from .config import TrainConfig
            from .train import Trainer
            cfg = TrainConfig.load(args.config)
            run_dir = args.run_dir or Path("runs") / cfg.name
            tr = Trainer(cfg, run_dir, progress=not args.no_progress)
            path = tr.run(until_step=args.steps,
                          max_seconds=None if args.minutes is None else 60 * args.minutes)
            print(f"step {tr.step}: checkpoint {path}")
        elif args.cmd == "prepare":
            from .config import TrainConfig
            from .data import Batches
            cfg = TrainConfig.load(args.config)
            pools = Batches(cfg.data, cfg.seed, progress=sys.stderr.isatty()).pools
            for k, pool in pools.items():
                print(f"{cfg.name}: k={k} pool {pool.shape}")
        else:
            from .samplers import sample
            pts = sample(args.name, args.n, count=args.count, seed=args.seed,
                         progress=sys.stderr.isatty())
            _save_points(pts, args.output)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
