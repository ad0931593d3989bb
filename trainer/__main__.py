"""Command line: ``python -m trainer fit EXAMPLES... --name NAME`` (learn a sampler from
example sets), ``python -m trainer calibrate MODEL.onnx EXAMPLES...``,
``python -m trainer train|prepare|distil|spacing CONFIG``, ``python -m trainer
sample NAME N`` and ``python -m trainer optimise CHECKPOINT N`` (property optimisation of the
input noise)."""
from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import replace
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


def _warn_one_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line on stderr, like the errors (not Python's file:line form)."""
    print(f"warning: {message}", file=sys.stderr)


def _optimise(args: argparse.Namespace) -> None:
    if not args.checkpoint.exists():
        raise FileNotFoundError(f"checkpoint {args.checkpoint} not found")
    import torch

    from .optimise import optimise_noise
    from .train import load_checkpoint, model_from_checkpoint
    torch.set_num_threads(args.threads)
    net, cfg = model_from_checkpoint(load_checkpoint(args.checkpoint))
    if cfg.data.density_bins:
        raise ValueError(f"{args.checkpoint} is a non-uniform model (its net makes sets in the "
                         "uniform square, mapped to a density afterwards); the objectives "
                         "are for uniform samplers")
    show = sys.stderr.isatty()

    def report(it: int, values) -> None:
        if show or it % 10 == 0 or it == args.iterations:
            print(f"iteration {it}: {args.objective} mean {float(values.mean()):.4g}",
                  file=sys.stderr, flush=True)

    res = optimise_noise(net, schedule=cfg.schedule, offset_scale=cfg.data.offset_scale,
                         embedding=cfg.data.embedding, n=args.n, count=args.count,
                         objective=args.objective, steps=args.steps,
                         iterations=args.iterations, lr=args.lr, step_noise=args.step_noise,
                         seed=args.seed, callback=report)
    _save_points(res.points, args.output)
    if args.log:
        with open(args.log, "w") as fh:
            fh.write("iteration,mean," + ",".join(f"set{i}" for i in range(args.count)) + "\n")
            for row in res.trajectory:
                fh.write(f"{row['iteration']},{row['mean']!r},"
                         + ",".join(repr(v) for v in row["per_set"]) + "\n")


def _spacing(args: argparse.Namespace) -> None:
    from diffsampler_rt.grid import decode

    from .config import TrainConfig
    from .data import Batches
    from .stats import spacing_coefficient
    from .samplers import sample
    cfg = TrainConfig.load(args.config)
    if any(cfg.data.pool_sizes):
        pools = Batches(cfg.data, cfg.seed, progress=sys.stderr.isatty(),
                        workers=args.workers).pools
        # the pool's own sets only: its shifted copies are translated on the torus, which
        # changes Euclidean distances across the border
        sets = {k: decode(np.asarray(pool[::cfg.data.shifts], dtype=np.float64),
                          stratified=cfg.data.embedding == "stratified")
                for k, pool in pools.items()}
    else:  # trained on fresh sets: measure as many drawn from the sampler (config's seed)
        if args.fresh_sets < 1:
            raise ValueError(f"--fresh-sets must be >= 1, got {args.fresh_sets}")
        rng = np.random.default_rng(cfg.seed)
        sets = {k: sample(cfg.data.sampler, k * k, count=args.fresh_sets, seed=rng,
                          workers=args.workers) for k in sorted(cfg.data.sizes)}
    table = []
    for k, pts in sorted(sets.items()):
        c = spacing_coefficient(pts, args.percentile, mean=args.mean)
        table.append(f"{k * k}:{c:.4f}")
        what = "mean" if args.mean else f"percentile {args.percentile:g}"
        print(f"{cfg.name}: k={k} ({len(pts)} sets) spacing coefficient {c:.4f} "
              f"({what} of the sets' smallest distance, times sqrt(n))")
    print(f"{cfg.name}: per size: python -m export pipeline MODEL.onnx --update min_spacing "
          f"--c {','.join(table)}")


def _run_options(parser: argparse.ArgumentParser, run_dir_help: str) -> None:
    """Options shared by ``train`` and ``distil`` (both resumable step loops)."""
    parser.add_argument("--run-dir", type=Path, help=run_dir_help)
    parser.add_argument("--steps", type=int, help="stop at this step (default: the config's)")
    parser.add_argument("--minutes", type=float, help="stop after this much wall time")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--device", default="cpu",
                        help="torch device, e.g. cuda (default cpu); not part of the recipe, "
                             "so a run can resume on another device")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)

    t = sub.add_parser("train", help="train (or resume) a model from a JSON config")
    t.add_argument("config", type=Path, help="e.g. trainer/configs/sobol_owen.json")
    _run_options(t, "default: runs/<config file name without .json>")
    t.add_argument("--workers", type=int, default=1,
                   help="processes that build the slow samplers' pools (same pools for any)")
    t.add_argument("--fp32", action="store_true",
                   help="train in float32 where the config asks for bf16 autocast (for CPUs "
                        "without avx512_bf16 or AMX, where autocast is emulated and ~16-20x "
                        "slower); the run records bf16 false, so a resume needs --fp32 too")

    d = sub.add_parser("distil", help="distil a model into a few-step student")
    d.add_argument("config", type=Path, help="e.g. trainer/configs/distil/gbn_fast.json")
    _run_options(d, "default: runs/<config file name without .json>")

    r = sub.add_parser("prepare", help="build (and cache) a config's training pools")
    r.add_argument("config", type=Path)
    r.add_argument("--workers", type=int, default=1,
                   help="processes for the slow samplers (same pools for any number)")

    c = sub.add_parser("spacing", help="spacing coefficient of a config's training sets "
                       "(for the min_spacing step: `python -m export pipeline`)")
    c.add_argument("config", type=Path)
    which = c.add_mutually_exclusive_group()
    which.add_argument("--percentile", type=float, default=5.0,
                       help="share of the sets whose smallest distance is below the radius")
    which.add_argument("--mean", action="store_true",
                       help="the sets' mean smallest distance instead of a percentile")
    c.add_argument("--workers", type=int, default=1,
                   help="processes for the slow samplers, if the pools are not cached")
    c.add_argument("--fresh-sets", type=int, default=256,
                   help="sets drawn per grid size for a config trained on fresh sets")

    s = sub.add_parser("sample", help="draw point sets from a reference sampler")
    s.add_argument("name")
    s.add_argument("n", type=int)
    s.add_argument("--count", type=int, default=1)
    s.add_argument("--seed", type=int, default=None)
    s.add_argument("--workers", type=int, default=1, help="processes (slow samplers)")
    s.add_argument("-o", "--output", type=Path, required=True, help=".npy, .txt or .csv")

    o = sub.add_parser("optimise", help="optimise a trained net's input noise for a property")
    o.add_argument("checkpoint", type=Path, help="runs/<name>/checkpoint.pt (EMA weights used)")
    o.add_argument("n", type=int, help="points per set (a perfect square)")
    o.add_argument("--count", type=int, default=10)
    o.add_argument("--objective", default="l2_star", choices=["l2_star", "ot_proxy"])
    o.add_argument("--steps", type=int, default=50, help="reverse-process steps")
    o.add_argument("--iterations", type=int, default=100, help="Adam iterations")
    o.add_argument("--lr", type=float, default=0.05)
    o.add_argument("--step-noise", action="store_true", help="also optimise per-step noise")
    o.add_argument("--seed", type=int, default=0)
    o.add_argument("--threads", type=int, default=2)
    o.add_argument("-o", "--output", type=Path, required=True, help=".npy, .txt or .csv")
    o.add_argument("--log", type=Path, help="trajectory as CSV (iteration, mean, per set)")

    f = sub.add_parser("fit", help="learn a sampler from your own example point sets")
    f.add_argument("examples", nargs="+", help=".npy (S, n, 2) or (n, 2) arrays, .txt / .csv "
                   "files as `diffsampler generate` writes them, text files of 'x y' lines, "
                   "or folders of these; sizes n = k*k, k >= 4")
    f.add_argument("--name", required=True, help="the model's name: OUT/NAME.onnx")
    f.add_argument("-o", "--out", type=Path, default=Path("."), help="output folder")
    f.add_argument("--minutes", type=float, default=None,
                   help="training budget in minutes (default 20; export, calibration and "
                        "report come on top)")
    f.add_argument("--init", help="start from a float model: a network name of models/ or an "
                   "exported .onnx (fine-tuning)")
    f.add_argument("--symmetries", default="0",
                   help="symmetries of the square the examples have, as augmentations: "
                        "comma-separated 0-7 (1 mirror x, 2 mirror y, 4 swap x and y, and "
                        "their combinations), or 'all'; checked against the examples")
    f.add_argument("--toroidal", action="store_true",
                   help="the examples are sets on the torus (translation invariant): a "
                        "circular-padding net, shifted copies as augmentations")
    f.add_argument("--fast", action="store_true",
                   help="also distil a 6-step student, NAME_fast.onnx (half the minutes again)")
    f.add_argument("--device", default="cpu", help="torch device, e.g. cuda")
    f.add_argument("--threads", type=int, help="torch threads (default: the cores, <= 8)")
    f.add_argument("--net", default="standard", choices=["standard", "small"],
                   help="standard: the shipped models' network (needed by --init); small: "
                        "quick trials")
    f.add_argument("--fp32", action="store_true",
                   help="train in float32 where the device computes bfloat16 natively (by "
                        "default fit trains with bf16 autocast there: about 1.6x the steps)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--no-progress", action="store_true")

    cal = sub.add_parser("calibrate", help="choose a model's finishing steps from example "
                         "sets (the procedure fit runs), written into its card")
    cal.add_argument("model", type=Path, help="an exported .onnx (edited in place)")
    cal.add_argument("examples", nargs="+", help="example sets, as for fit")
    cal.add_argument("--seed", type=int, default=0)

    args = p.parse_args(argv)
    try:
        with warnings.catch_warnings():  # restores the caller's showwarning afterwards
            warnings.showwarning = _warn_one_line
            _run(args)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted (a fit or train run resumes from its last checkpoint when run "
              "again)", file=sys.stderr)
        return 130
    return 0


def _symmetries(text: str) -> list[int]:
    if text == "all":
        return list(range(8))
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--symmetries must be integers 0-7 separated by commas, or all; "
                         f"got {text!r}") from None
    return values


def _fit(args: argparse.Namespace) -> None:
    from .fitting.run import DEFAULT_MINUTES, fit
    fit(args.examples, name=args.name, out=args.out,
        minutes=DEFAULT_MINUTES if args.minutes is None else args.minutes, init=args.init,
        device=args.device, symmetries=_symmetries(args.symmetries), toroidal=args.toroidal,
        seed=args.seed, threads=args.threads, net=args.net, fast=args.fast,
        bf16=False if args.fp32 else None, progress=not args.no_progress)


def _calibrate(args: argparse.Namespace) -> None:
    import diffsampler_rt

    from .fitting.analysis import analyse
    from .fitting.calibrate import calibrate
    from .fitting.examples import read_examples
    model = diffsampler_rt.Model(args.model)  # a bad model file fails before any work
    ex = read_examples(args.examples)
    analysis = analyse(ex)
    held_in = {n: np.concatenate(list(ex.iter_sets(n)))[:1024] for n in ex.sizes}
    card = calibrate(model.path, held_in, analysis.structure, analysis.structure_sizes,
                     seed=args.seed)
    from diffsampler_rt.finish.pipeline import describe
    for i, line in enumerate(describe(card["pipeline"])):
        print(f"{i}. {line}")


def _run(args: argparse.Namespace) -> None:
    """The chosen subcommand."""
    if args.cmd == "train":
        from .config import TrainConfig
        from .train import Trainer
        cfg = TrainConfig.load(args.config)
        if args.fp32:
            cfg = replace(cfg, bf16=False)
        run_dir = args.run_dir or Path("runs") / args.config.stem
        tr = Trainer(cfg, run_dir, progress=not args.no_progress, device=args.device,
                     workers=args.workers)
        path = tr.run(until_step=args.steps,
                      max_seconds=None if args.minutes is None else 60 * args.minutes)
        print(f"step {tr.step}: checkpoint {path}")
    elif args.cmd == "distil":
        from .distil import DistilConfig, Distiller
        dcfg = DistilConfig.load(args.config)
        dist = Distiller(dcfg, args.run_dir or Path("runs") / args.config.stem,
                         progress=not args.no_progress, device=args.device)
        path = dist.run(until_step=args.steps,
                        max_seconds=None if args.minutes is None else 60 * args.minutes)
        print(f"step {dist.step}: checkpoint {path}")
    elif args.cmd == "prepare":
        from .config import TrainConfig
        from .data import Batches
        cfg = TrainConfig.load(args.config)
        pools = Batches(cfg.data, cfg.seed, progress=sys.stderr.isatty(),
                        workers=args.workers).pools
        for k, pool in pools.items():
            print(f"{cfg.name}: k={k} pool {pool.shape}")
    elif args.cmd == "spacing":
        _spacing(args)
    elif args.cmd == "optimise":
        _optimise(args)
    elif args.cmd == "fit":
        _fit(args)
    elif args.cmd == "calibrate":
        _calibrate(args)
    else:
        from .samplers import sample
        pts = sample(args.name, args.n, count=args.count, seed=args.seed,
                     progress=sys.stderr.isatty(), workers=args.workers)
        _save_points(pts, args.output)


if __name__ == "__main__":
    sys.exit(main())
