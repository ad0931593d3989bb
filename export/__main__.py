"""``python -m export CHECKPOINT -o MODEL.onnx``: export and check parity with torch.

``python -m export set-defaults MODEL.onnx [--solver S] [--steps N]``: change the default
solver and number of steps in an exported model's card.

``python -m export pipeline MODEL.onnx [--add STEP [--at I | --replace I] | --remove I |
--update I | --move I J] [--where structured|unstructured|always] [--PARAM VALUE ...]``:
show or edit the card's finishing pipeline (flags generated from the step registry; run it
with ``--help`` for every step's parameters).

``python -m export density-floor MODEL.onnx --floor F``: re-tabulate a non-uniform model's
density with another floor (the share of uniform mass in each cell).

``python -m export reexport MODEL.onnx -o OUT.onnx --attention-window W``: the same network
with windowed (W cells per side) or, with W = 0, global self-attention.

``python -m export quantize MODEL.onnx -o OUT.onnx [--sets N] [--seed S]``: the same network
with 8-bit convolutions, calibrated on its own sampling (about a third less time per
evaluation on x86 CPUs; measure its fidelity with benchmarks/quantized.py).

``python -m export channels-last-pads MODEL.onnx -o OUT.onnx``: a circular 8-bit file
whose wrap pads were quantised in place, rewritten with them copied channels-last (the same outputs bit
for bit; export/wrap_pad.py). ``python -m export migrate MODEL.onnx ...``: rewrite
format-1 model cards as format 2 in place.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


class UsageError(Exception):
    """Bad command-line input: :func:`main` prints it as one line and exits with status 2
    (as it does a ValueError from the functions the commands call)."""


def _parser(command: str, description: str, *, output: bool = True) -> argparse.ArgumentParser:
    """A subcommand's parser with its MODEL argument (and ``-o OUTPUT`` if ``output``)."""
    p = argparse.ArgumentParser(prog=f"python -m export {command}", description=description)
    p.add_argument("model", type=Path)
    if output:
        p.add_argument("-o", "--output", type=Path, required=True)
    return p


def _require(model: Path) -> None:
    """UsageError if the model file is not there."""
    if not model.exists():
        raise UsageError(f"model {model} not found")


def set_defaults_main(argv: list[str]) -> int:
    from diffsampler_rt.solvers import SOLVERS
    p = _parser("set-defaults", "change a model card's default solver and steps (its "
                "finishing steps: python -m export pipeline)", output=False)
    p.add_argument("--solver", choices=list(SOLVERS))
    p.add_argument("--steps", type=int)
    args = p.parse_args(argv)
    _require(args.model)
    from .defaults import set_defaults
    card = set_defaults(args.model, solver=args.solver, steps=args.steps)
    print(f"{args.model}: default solver {card.get('default_solver', 'ddim')}, "
          f"{card['default_steps']} steps")
    return 0


def migrate_main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m export migrate",
                                description="rewrite format-1 model cards as format 2")
    p.add_argument("models", type=Path, nargs="+")
    args = p.parse_args(argv)
    from .defaults import migrate
    for model in args.models:
        _require(model)
        card = migrate(model)
        print(f"{model}: format {card['format_version']}, {len(card['pipeline'])} steps")
    return 0


def pipeline_main(argv: list[str]) -> int:
    from diffsampler_rt.finish import STEPS
    from diffsampler_rt.finish.pipeline import describe

    from .pipeline_edit import edit_pipeline, parameter_help, parse_value
    steps = ", ".join(STEPS)
    p = _parser("pipeline", "show or edit a model card's finishing pipeline (the steps run "
                "after the network, in order); entries are named by position or by a "
                "unique step name. Parameter values: numbers, true / false, N:V,N:V "
                "per-size tables, JSON, or none (removes the parameter)", output=False)
    what = p.add_mutually_exclusive_group()
    what.add_argument("--add", metavar="STEP", help=f"append a step (or insert it --at I): "
                      f"{steps}")
    what.add_argument("--remove", metavar="I|STEP", help="remove an entry")
    what.add_argument("--update", metavar="I|STEP", help="change an entry's parameters")
    what.add_argument("--move", nargs=2, metavar=("I|STEP", "J"), help="move an entry to J")
    p.add_argument("--replace", metavar="I|STEP", help="with --add: put the new step there")
    p.add_argument("--at", type=int, metavar="I", help="with --add: the position")
    p.add_argument("--where", choices=["structured", "unstructured", "always"],
                   help="run the entry only where the pipeline's structure holds (or not)")
    helps = parameter_help()
    for name, text in helps.items():
        p.add_argument(f"--{name.replace('_', '-')}", dest=f"param_{name}", metavar="V",
                       help=text)
    args = p.parse_args(argv)
    _require(args.model)
    params = {name: parse_value(getattr(args, f"param_{name}")) for name in helps
              if getattr(args, f"param_{name}") is not None}
    if args.replace is not None and args.add is None:
        raise UsageError("--replace needs --add STEP (the step that takes its place)")
    if args.add or args.remove is not None or args.update is not None or args.move:
        card = edit_pipeline(args.model, add=args.add, at=args.at, remove=args.remove,
                             replace=args.replace, update=args.update,
                             move=tuple(args.move) if args.move else None, params=params,
                             where=args.where)
    else:
        if params or args.where:
            raise UsageError("parameters need --add, --update or --replace")
        import diffsampler_rt
        card = diffsampler_rt.Model(args.model).card
    for i, line in enumerate(describe(card.get("pipeline", []))):
        print(f"{i}. {line}")
    return 0


def density_floor_main(argv: list[str]) -> int:
    p = _parser("density-floor", "re-tabulate a non-uniform model's density with another "
                                 "floor", output=False)
    p.add_argument("--floor", type=float, required=True,
                   help="mass added to every cell, a fraction of the mean cell mass, in (0, 1)")
    args = p.parse_args(argv)
    _require(args.model)
    from .defaults import set_density_floor
    card = set_density_floor(args.model, args.floor)
    print(f"{args.model}: density table ({len(card['density']['x_cdf']) - 1} bins) now has "
          f"floor {card['density_floor']:g}")
    return 0


def reexport_main(argv: list[str]) -> int:
    p = _parser("reexport", "re-export a model with another attention window")
    p.add_argument("--attention-window", type=int, required=True,
                   help="cells per window side; 0 for global attention")
    args = p.parse_args(argv)
    _require(args.model)
    if args.attention_window < 0:
        raise UsageError(f"--attention-window must be >= 0, got {args.attention_window}")
    import torch
    torch.set_num_threads(2)
    from .reexport import reexport
    out, diffs = reexport(args.model, args.output, attention_window=args.attention_window or None)
    print(f"wrote {out} ({out.stat().st_size / 2**20:.2f} MiB); parity max|diff| "
          + ", ".join(f"k={k}: {d:.2g}" for k, d in diffs.items()))
    return 0


def quantize_main(argv: list[str]) -> int:
    p = _parser("quantize", "8-bit convolutions, calibrated on the model's own sampling "
                            "(export/quantize.py)")
    p.add_argument("--sets", type=int, default=8,
                   help="calibration sets generated per trained grid side (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the calibration sets")
    args = p.parse_args(argv)
    _require(args.model)
    from .quantize import quantize
    card = quantize(args.model, args.output, sets=args.sets, seed=args.seed)
    q = card["quantization"]
    print(f"wrote {args.output} ({args.output.stat().st_size / 2**20:.2f} MiB); calibrated on "
          f"{q['feeds']} solver inputs at grid sides {', '.join(map(str, q['sides']))}")
    return 0


def channels_last_pads_main(argv: list[str]) -> int:
    p = _parser("channels-last-pads", "copy a circular 8-bit file's wrap pads channels-last "
                                      "(exact; export/wrap_pad.py)")
    args = p.parse_args(argv)
    _require(args.model)
    from .quantize import wrap_pads_to_channels_last
    count = wrap_pads_to_channels_last(args.model, args.output)
    print(f"wrote {args.output}; {count} wrap pads now copied channels-last")
    return 0


def export_main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m export", description=__doc__)
    p.add_argument("checkpoint", type=Path, help="runs/<name>/checkpoint.pt")
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--fp32", action="store_true", help="store float32 weights (default fp16)")
    p.add_argument("--tolerance", type=float, default=1e-4)
    p.add_argument("--sides", type=int, nargs="*", default=[8, 24, 25, 32, 64])
    args = p.parse_args(argv)
    if not args.checkpoint.exists():
        raise UsageError(f"checkpoint {args.checkpoint} not found")
    import torch
    torch.set_num_threads(2)
    from . import export_checkpoint
    out, diffs = export_checkpoint(args.checkpoint, args.output, fp16_weights=not args.fp32,
                                   parity_sides=tuple(args.sides), tolerance=args.tolerance)
    size = out.stat().st_size / 2**20
    print(f"wrote {out} ({size:.2f} MiB); parity max|diff| "
          + ", ".join(f"k={k}: {d:.2g}" for k, d in diffs.items()))
    return 0


COMMANDS = {"set-defaults": set_defaults_main, "pipeline": pipeline_main,
            "migrate": migrate_main, "density-floor": density_floor_main,
            "reexport": reexport_main, "quantize": quantize_main,
            "channels-last-pads": channels_last_pads_main}


def main(argv: list[str] | None = None) -> int:
    """Run a subcommand (or, without one, the export of a checkpoint): exit status 0, 1 if
    an export's parity check fails, 2 with a one-line error for bad input."""
    from . import ParityError
    argv = sys.argv[1:] if argv is None else argv
    command = COMMANDS.get(argv[0]) if argv else None
    try:
        return command(argv[1:]) if command else export_main(argv)
    except ParityError as exc:
        print(f"parity check FAILED: {exc}", file=sys.stderr)
        return 1
    except (UsageError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
