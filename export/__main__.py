"""``python -m export CHECKPOINT -o MODEL.onnx``: export and check parity with torch.

``python -m export set-defaults MODEL.onnx [--solver S] [--steps N]
[--structure dyadic_net|n_rooks|rank1_lattice|none] [--structure-min-side K]
[--structure-guidance L] [--structure-sides K,K,...] [--structure-temperature T|none]
[--structure-block B|K:B,...|none] [--structure-prefix on|off]
[--structure-runs R|none]
[--sliced-ot K|N:K,...|none [--sliced-ot-directions D] [--sliced-ot-step S]] [--min-spacing C|N:C,...|none]
[--coarse-noise G|N:G,...|none [--coarse-noise-cut C]]
[--even-out G|N:G,...|none [--even-out-cut C]] [--projection-gain G|N:G,...|none]
[--restore-cut C|none] [--guide NAME|none [--guide-weight W|N:W,...]]``: change the sampling defaults in an
exported model's card.

``python -m export density-floor MODEL.onnx --floor F``: re-tabulate a non-uniform model's
density with another floor (the share of uniform mass in each cell).

``python -m export reexport MODEL.onnx -o OUT.onnx --attention-window W``: the same network
with windowed (W cells per side) or, with W = 0, global self-attention.

``python -m export quantize MODEL.onnx -o OUT.onnx [--sets N] [--seed S]``: the same network
with 8-bit convolutions, calibrated on its own sampling (about a third less time per
evaluation on x86 CPUs; measure its fidelity with benchmarks/quantized.py).

``python -m export channels-last-pads MODEL.onnx -o OUT.onnx``: a circular 8-bit file
quantised before session 70 with its wrap pads copied channels-last (the same outputs bit
for bit; export/wrap_pad.py).
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
    from diffsampler_rt.structure import STRUCTURES
    p = _parser("set-defaults", "change the sampling defaults of a model card", output=False)
    p.add_argument("--solver", choices=list(SOLVERS))
    p.add_argument("--steps", type=int)
    p.add_argument("--structure", choices=list(STRUCTURES) + ["none"],
                   help="structure imposed on generated sets: dyadic_net and n_rooks at "
                        "power-of-two grid sides of stratified models, rank1_lattice at every "
                        "size (none: remove)")
    p.add_argument("--structure-min-side", type=int, metavar="K",
                   help="impose the structure only at grid sides k >= K")
    p.add_argument("--structure-guidance", type=int, metavar="L",
                   help="also project the clean-set prediction of the last L solver steps "
                        "onto the structure (0: only the finished sets)")
    p.add_argument("--structure-sides", metavar="K,K,...",
                   help="impose the structure only at these grid sides")
    p.add_argument("--structure-temperature", metavar="T|none",
                   help="where the structure is imposed, scale the solver's starting noise by "
                        "T (its coarse modes keep the --coarse-noise gain; none: remove)")
    p.add_argument("--structure-block", metavar="B|K:B,K:B,...|none",
                   help="n_rooks: also stratify every aligned block of B, 2B, ... cells of a "
                        "column (row) at its own sub-strip width, as LDBN does from B = 16 "
                        "(B a power of two; K:B pairs give B per grid side K, plain n-rooks "
                        "at the sides not listed; none: remove)")
    p.add_argument("--structure-prefix", choices=["on", "off"],
                   help="dyadic_net: a set of n points, n not a power of four, is the first n "
                        "points in Sobol' order of a net of the next power-of-four size, imposed "
                        "onto the Owen-scrambled Sobol' nets (diffsampler_rt.sobol_orbit; off: "
                        "the network's own set of n points)")
    p.add_argument("--structure-runs", metavar="R|none",
                   help="n_rooks: at grid sides that are not powers of two, every run of R "
                        "cells of a column (row) puts its points in distinct sub-strips of "
                        "width 1/(R k), as LDBN's are (R = 16; none: remove)")
    p.add_argument("--min-spacing", metavar="C|N:C,N:C,...|none",
                   help="push apart pairs closer than C / sqrt(n); N:C pairs give C per size "
                        "(linear in log n between them). C from `python -m trainer spacing "
                        "CONFIG`; none: remove")
    p.add_argument("--sliced-ot", metavar="K|N:K,N:K,...|none",
                   help="finish with K sliced-OT iterations (SOT models); N:K pairs give K per "
                        "size (linear in log n between them, rounded); none: remove")
    p.add_argument("--sliced-ot-directions", type=int, metavar="D",
                   help="directions per sliced-OT iteration (default: the card's, else 64; "
                        "with --sliced-ot)")
    p.add_argument("--sliced-ot-step", type=float, metavar="S",
                   help="scale every sliced-OT move by S, 0 < S <= 2 (default: the card's, "
                        "else 1, the sampler's own update; with --sliced-ot)")
    _gain_table_flags(p, "--coarse-noise",
                      "scale the coarse Fourier modes of the solver's starting noise by G "
                      "(> 1: sets vary more at large scales)",
                      "modes up to C times the grid's Nyquist frequency, 0 < C <= 1 "
                      "(default 0.25")
    _gain_table_flags(p, "--even-out",
                      "shrink each set's density deviations from uniform at large scales "
                      "by the factor 1 - G (G < 0 amplifies them)",
                      "below C sqrt(n) cycles across the square, 0 < C <= 2 (default 1")
    p.add_argument("--projection-gain", metavar="G|N:G,N:G,...|none",
                   help="scale each axis's deviations of the sorted coordinates from evenly "
                        "spread positions by G, 0.5 <= G <= 1.5 (> 1: less even x and y "
                        "projections; not where a structure is imposed); N:G pairs give G "
                        "per size (linear in log n between them); none: remove")
    p.add_argument("--restore-cut", metavar="C|none",
                   help="where n is not a square, restore the thinned set's density from the "
                        "full set's below C sqrt(n), 0 < C <= 2 (none: the runtime's "
                        "default, 0.25)")
    p.add_argument("--guide", metavar="NAME|none",
                   help="autoguidance by a weaker model of the same sampler: NAME.onnx next "
                        "to the model, else a bundled model or guide (the sha256 of its "
                        "network goes into the card; none: remove)")
    p.add_argument("--guide-weight", metavar="W|N:W,N:W,...",
                   help="guidance weight (default 1; with --guide); N:W pairs give W per size "
                        "(linear in log n between them)")
    args = p.parse_args(argv)
    coarse = _gain_arg(args.coarse_noise, args.coarse_noise_cut, "--coarse-noise", 0.25)
    even = _gain_arg(args.even_out, args.even_out_cut, "--even-out", 1.0)
    sliced = args.sliced_ot
    for flag, value in (("directions", args.sliced_ot_directions),
                        ("step", args.sliced_ot_step)):
        if value is not None and (sliced is None or sliced == "none"):
            raise UsageError(f"--sliced-ot-{flag} needs --sliced-ot K or N:K,...")
    if sliced is not None and sliced != "none":
        table = _table_arg(sliced, "iterations", _whole, "--sliced-ot", "an integer", "N:K")
        # directions and step not given: the card's (set_defaults), else 64 and 1
        sliced = table if isinstance(table, dict) else {"iterations": table}
        if args.sliced_ot_directions is not None:
            sliced["directions"] = args.sliced_ot_directions
        if args.sliced_ot_step is not None:
            sliced["step"] = args.sliced_ot_step
    sides = args.structure_sides
    if sides is not None:
        try:
            sides = [int(v) for v in sides.split(",")]
        except ValueError:
            raise UsageError(f"--structure-sides must be grid sides separated by commas, got "
                             f"{sides!r}") from None
    temperature = _number_or_none(args.structure_temperature, "--structure-temperature")
    block = _block_arg(args.structure_block)
    spacing = args.min_spacing
    if spacing is not None and spacing != "none":
        spacing = _table_arg(spacing, "c", float, "--min-spacing", "a number", "N:C")
    restore = _number_or_none(args.restore_cut, "--restore-cut")
    projection = args.projection_gain
    if projection is not None and projection != "none":
        projection = _table_arg(projection, "gain", float, "--projection-gain", "a number",
                                "N:G")
    guide = args.guide
    if args.guide_weight is not None and (guide is None or guide == "none"):
        raise UsageError("--guide-weight needs --guide NAME")
    if guide is not None and guide != "none":
        weight = 1.0 if args.guide_weight is None else _table_arg(
            args.guide_weight, "weight", float, "--guide-weight", "a number", "N:W")
        guide = {"model": guide, **(weight if isinstance(weight, dict) else {"weight": weight})}
    _require(args.model)
    from diffsampler_rt.coarse_noise import describe as describe_coarse
    from diffsampler_rt.guidance import describe as describe_guide
    from diffsampler_rt.low_frequencies import RESTORE_CUT
    from diffsampler_rt.low_frequencies import describe as describe_even
    from diffsampler_rt.projections import describe as describe_projection
    from diffsampler_rt.sliced_ot import describe as describe_sliced
    from diffsampler_rt.spacing import describe as describe_spacing

    from .defaults import set_defaults
    card = set_defaults(args.model, solver=args.solver, steps=args.steps,
                        structure=args.structure, structure_min_side=args.structure_min_side,
                        structure_guidance=args.structure_guidance, structure_sides=sides,
                        structure_temperature=temperature, structure_block=block,
                        structure_prefix=(None if args.structure_prefix is None
                                          else args.structure_prefix == "on"),
                        structure_runs=_runs_arg(args.structure_runs),
                        sliced_ot=sliced, min_spacing=spacing, coarse_noise=coarse,
                        even_out=even, projection_gain=projection, restore_cut=restore,
                        guide=guide)
    print(f"{args.model}: default solver {card.get('default_solver', 'ddim')}, "
          f"{card['default_steps']} steps, structure {structure_text(card)}, "
          f"sliced OT {describe_sliced(card.get('sliced_ot'))}, "
          f"min spacing {describe_spacing(card.get('min_spacing'))}, "
          f"coarse noise {describe_coarse(card.get('coarse_noise'))}, "
          f"even out {describe_even(card.get('even_out'))}, "
          f"projection {describe_projection(card.get('projection_gain'))}, "
          f"restore cut {card.get('restore_cut', RESTORE_CUT):g} sqrt(n), "
          f"guide {describe_guide(card.get('guide'))}")
    return 0


def _gain_table_flags(p: argparse.ArgumentParser, flag: str, gain_help: str,
                      cut_help: str) -> None:
    """``flag`` (a card's gain table: G, N:G pairs or none) and ``flag``-cut (C or N:C
    pairs at the same sizes); ``cut_help`` ends inside its default's parenthesis."""
    p.add_argument(flag, metavar="G|N:G,N:G,...|none",
                   help=f"{gain_help}; N:G pairs give G per size (linear in log n between "
                        "them); none: remove")
    p.add_argument(f"{flag}-cut", metavar="C|N:C,N:C,...",
                   help=f"{cut_help}; with {flag}); N:C pairs give C per size, at the sizes "
                        f"of {flag}'s pairs")


def _gain_arg(value: str | None, cut: str | None, flag: str, default_cut: float):
    """A card's gain table {"cut": C or a list, "gain": G or "n"/"gain" lists} from
    ``flag``'s value and its ``-cut`` option, or "none" / None (not given) as given
    (UsageError for a bad value)."""
    if cut is not None and (value is None or value == "none"):
        raise UsageError(f"{flag}-cut needs {flag} G or N:G,...")
    if value is None or value == "none":
        return value
    table = _table_arg(value, "gain", float, flag, "a number", "N:G")
    cuts = default_cut if cut is None else _table_arg(cut, "cut", float, f"{flag}-cut",
                                                      "a number", "N:C")
    if isinstance(cuts, dict):  # a cut per size: the gain table's sizes, in its order
        if not isinstance(table, dict) or cuts["n"] != table["n"]:
            raise UsageError(f"{flag}-cut N:C pairs need {flag} N:G pairs at the same sizes, "
                             f"got {cut!r} for {value!r}")
        cuts = cuts["cut"]
    return {"cut": cuts, **(table if isinstance(table, dict) else {"gain": table})}


def _number_or_none(value: str | None, flag: str) -> float | str | None:
    """A flag's number, or ``"none"`` / None (not given) as given (UsageError: ``flag``
    takes a number or none)."""
    if value is None or value == "none":
        return value
    try:
        return float(value)
    except ValueError:
        raise UsageError(f"{flag} must be a number or none, got {value!r}") from None


def _block_arg(value: str | None) -> int | dict | str | None:
    """--structure-block's B (every side) or K:B pairs (per grid side: {"sides", "block"}),
    or "none" / None as given (UsageError: what it takes)."""
    if value is None or value == "none":
        return value
    try:
        if ":" not in value:
            return int(value)
        pairs = [tuple(int(v) for v in pair.split(":")) for pair in value.split(",")]
        if any(len(p) != 2 for p in pairs):
            raise ValueError(value)
        return {"sides": [p[0] for p in pairs], "block": [p[1] for p in pairs]}
    except ValueError:
        raise UsageError(f"--structure-block must be an integer, K:B pairs separated by "
                         f"commas, or none, got {value!r}") from None


def _runs_arg(value: str | None) -> int | str | None:
    """--structure-runs R (an integer >= 2) or none."""
    if value is None or value == "none":
        return value
    try:
        run = int(value)
    except ValueError:
        run = 0
    if run < 2:
        raise UsageError(f"--structure-runs must be an integer >= 2 or none, got {value!r}")
    return run


def structure_text(card: dict) -> str:
    """"n_rooks (k >= 16, guiding 5 steps)", "rank1_lattice (k in 8, 16, 32)", "none"
    (and the starting noise's temperature where the structure has one)."""
    if "structure" not in card:
        return "none"
    notes = [f"k >= {card['structure_min_side']}"] if "structure_min_side" in card else []
    if "structure_sides" in card:
        notes.append("k in " + ", ".join(map(str, card["structure_sides"])))
    if card.get("structure_guidance"):
        notes.append(f"guiding {card['structure_guidance']} steps")
    if "structure_temperature" in card:
        notes.append(f"starting noise at temperature {card['structure_temperature']:g}")
    if "structure_block" in card:
        from diffsampler_rt.structure import describe_block
        notes.append(describe_block(card["structure_block"]) + " stratified")
    if "structure_runs" in card:
        notes.append(f"other sides: runs of {card['structure_runs']} cells stratified")
    if card.get("structure_prefix"):
        notes.append("other n: a net's first n points in Sobol' order")
    return card["structure"] + (f" ({', '.join(notes)})" if notes else "")


def _table_arg(text: str, key: str, value, flag: str, one: str, pairs: str):
    """:func:`parse_table` of a flag's value (UsageError: what ``flag`` takes)."""
    try:
        return parse_table(text, key, value)
    except ValueError:
        raise UsageError(f"{flag} must be {one}, {pairs} pairs separated by commas, or none, "
                         f"got {text!r}") from None


def parse_table(text: str, key: str, value=float):
    """A value, or N:V pairs as a per-size table (ValueError): with key "c",
    "0.6" -> 0.6 and "64:0.7,1024:0.6" -> {"n": [64, 1024], "c": [0.7, 0.6]}."""
    if ":" not in text:
        return value(text)
    pairs = [item.split(":") for item in text.split(",")]
    if any(len(p) != 2 for p in pairs):
        raise ValueError(text)
    return {"n": [int(n) for n, _ in pairs], key: [value(v) for _, v in pairs]}


def _whole(text: str) -> int:
    """"3" or "3.0" -> 3; ValueError for anything not a whole number (2.5, inf, nan)."""
    v = float(text)
    if not v.is_integer():
        raise ValueError(text)
    return int(v)


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


COMMANDS = {"set-defaults": set_defaults_main, "density-floor": density_floor_main,
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
