"""``diffsampler``: generate point sets from the command line.

    diffsampler generate MODEL N [--count C] [--seed S] [--steps T] [--no-structure]
                             [--format txt|npy|csv] [-o FILE] [--threads K]
    diffsampler plot MODEL N [--count C] [--seed S] -o FIG.png   (or: plot POINTS.npy -o FIG.png)
    diffsampler list
    diffsampler info MODEL

Bad input prints one line on stderr and exits with status 2.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import warnings
from pathlib import Path
from typing import IO, Iterable

import numpy as np

from .solvers import SOLVERS

FORMATS = ("txt", "npy", "csv")


def _warn_one_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line on stderr, like the errors (not Python's file:line form)."""
    print(f"diffsampler: warning: {message}", file=sys.stderr)


_TERMINATED: list[int] = []


class _terminate_as_interrupt:
    """SIGTERM handled as Ctrl-C while a command runs (so a partial file is cleaned up and
    the command ends in one line); the previous handler restored afterwards."""

    def __enter__(self):
        import signal
        self.previous = None
        if threading.current_thread() is threading.main_thread():
            def handler(signum, frame):
                _TERMINATED.append(signum)
                raise KeyboardInterrupt
            self.previous = signal.signal(signal.SIGTERM, handler)
        return self

    def __exit__(self, *exc):
        import signal
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)
        return False


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (argparse prints usage too)
        self.exit(2, f"{self.prog}: error: {message}\n")


def _write(blocks: Iterable[np.ndarray], shape: tuple[int, ...], fmt: str,
           out: IO[bytes]) -> None:
    """Write the sets of ``blocks`` ((b, n, 2) arrays, ``shape`` in all) as they come, so
    that a large count never sits in memory whole. txt: 'x y' per line, sets separated by a
    blank line; csv: header set,x,y; npy: one array of ``shape``, as np.save writes it."""
    if fmt == "npy":
        np.lib.format.write_array_header_1_0(
            out, {"descr": np.lib.format.dtype_to_descr(np.dtype("<f8")),
                  "fortran_order": False, "shape": shape})
        for block in blocks:
            out.write(np.ascontiguousarray(block, dtype="<f8").tobytes())
        return
    if fmt == "csv":
        out.write(b"set,x,y\n")
    i = 0
    for block in blocks:
        for pts in block:
            if fmt == "txt":
                if i:
                    out.write(b"\n")
                out.write("".join(f"{x!r} {y!r}\n" for x, y in pts.tolist()).encode())
            else:
                out.write("".join(f"{i},{x!r},{y!r}\n" for x, y in pts.tolist()).encode())
            i += 1


def _model(name: str, threads: int | None, providers: list | None = None):
    """The loaded model (cached), or a model of its own with ``threads`` cores or other
    execution providers."""
    from .model import Model, load
    if threads is None and providers is None:
        return load(name)
    return Model(name, threads=threads, providers=providers)


def _check_output(path: Path | None, suffixes: tuple[str, ...] | None = None,
                  fmt: str | None = None) -> None:
    """Refuse an output path before any work: a folder, a missing folder, a suffix that
    contradicts the format, or one that is not among ``suffixes``."""
    if path is None:
        return
    if path.is_dir():
        raise ValueError(f"output {str(path)!r} is a folder; give a file name")
    if not path.parent.is_dir():
        raise ValueError(f"output {str(path)!r}: folder {str(path.parent)!r} does not exist")
    suffix = path.suffix.lstrip(".").lower()
    if fmt is not None and suffix in FORMATS and suffix != fmt:
        raise ValueError(f"output {str(path)!r} ends in .{suffix} but --format is {fmt}")
    if suffixes is not None and suffix not in suffixes:
        raise ValueError(f"output {str(path)!r}: the figure's format comes from its suffix; "
                         f"use {', '.join('.' + s for s in suffixes)}")


def _cmd_generate(args: argparse.Namespace) -> None:
    fmt = args.format
    _check_output(args.output, fmt=fmt)
    if fmt is None:
        suffix = args.output.suffix.lstrip(".").lower() if args.output else ""
        fmt = suffix if suffix in FORMATS else "txt"
    if fmt == "npy" and args.output is None and sys.stdout.isatty():
        # checked before the (possibly long) generation, not after it
        raise ValueError("refusing to write binary .npy data to a terminal; give -o FILE.npy "
                         "or redirect stdout")
    model = _model(args.model, args.threads, args.provider)
    show = args.count is not None and args.count > 1 and sys.stderr.isatty()
    # the sets block by block (the same sets as generate's); bad arguments fail here,
    # before any output
    blocks = model.iter_sets(args.n, 1 if args.count is None else args.count, seed=args.seed,
                             steps=args.steps, solver=args.solver, progress=show,
                             structure=not args.no_structure)
    shape = (args.n, 2) if args.count is None else (args.count, args.n, 2)
    if args.output is None:
        _write(blocks, shape, fmt, sys.stdout.buffer)
        sys.stdout.flush()
        return
    # written beside the file and renamed at the end: an interrupted run leaves no
    # truncated file under the name asked for
    partial = args.output.with_name(args.output.name + ".partial")
    try:
        with open(partial, "wb") as fh:
            _write(blocks, shape, fmt, fh)
        os.replace(partial, args.output)
    finally:
        partial.unlink(missing_ok=True)


def _cmd_plot(args: argparse.Namespace) -> None:
    _check_output(args.output, suffixes=("png", "pdf", "svg"))
    from .plot import plot_sets
    if str(args.source).endswith(".npy"):
        if args.n is not None:
            raise ValueError("N is taken from the points file; leave it out with a .npy source")
        pts = np.load(args.source)
        title = Path(args.source).stem
    else:
        if args.n is None:
            raise ValueError("plotting a model needs N, the number of points per set")
        model = _model(args.source, args.threads, args.provider)
        pts = model.generate(args.n, args.count, seed=args.seed, steps=args.steps,
                             solver=args.solver)
        title = model.name
    plot_sets(pts, title=title, path=args.output)


def _cmd_list(args: argparse.Namespace) -> None:
    from .model import MODELS_DIR, catalogue, listed_models, load
    cat = catalogue()
    rows = []
    for name, path in listed_models().items():
        entry = cat.get(name) if path.parent == MODELS_DIR else None
        if entry is None:  # a model of a DIFFSAMPLER_MODELS folder: its card only
            card = load(path).card
            entry = {"imitates": f"{card['sampler']} ({path.parent})", "network": card["name"],
                     "solver": card["default_solver"], "steps": card["default_steps"]}
        ms = entry.get("ms_per_set_1024")
        rows.append((name, entry["imitates"], f"network {entry['network']}",
                     f"{entry['solver']} {entry['steps']} steps",
                     f"{ms:g} ms a 1024-point set" if ms is not None else "not timed"))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    for row in rows:
        print("  ".join(f"{c:<{w}}" for c, w in zip(row, widths)) + "  " + row[4])
    cpus = {e["speed_cpu"] for e in cat.values() if e.get("speed_cpu")}
    if cpus:
        print(f"(times: batched, from the speed report, on {'; '.join(sorted(cpus))})")


def _cmd_info(args: argparse.Namespace) -> None:
    from .finish.pipeline import describe
    from .model import load
    m = load(args.model)
    card = dict(m.card)
    if not args.full:
        card.pop("config", None)
        card.pop("pipeline")
        if "density" in card:
            bins = len(card["density"]["x_cdf"]) - 1
            card["density"] = f"{bins} x {bins} table (--full prints it)"
    print(f"path: {m.path}")
    print(json.dumps(card, indent=2, sort_keys=True))
    if not args.full:  # the finishing steps in words, in the order they run
        print("pipeline (after the network, in order; --full prints the entries):")
        for i, line in enumerate(describe(m.card["pipeline"]) or ["none"]):
            print(f"  {i}. {line}")


def _add_sampling_options(parser: argparse.ArgumentParser) -> None:
    """The options `generate` and `plot` share: how the sets are drawn."""
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--steps", type=int, default=None, help="denoising steps")
    parser.add_argument("--solver", default=None, choices=list(SOLVERS),
                        help="default: the model card's")
    parser.add_argument("--threads", type=int, default=None,
                        help="cores to use (default: every core this process may run on)")
    parser.add_argument("--provider", action="append", default=None, metavar="NAME",
                        help="onnxruntime execution provider for the network, e.g. "
                             "CUDAExecutionProvider (repeat for a fallback order; default "
                             "the CPU)")


def main(argv: list[str] | None = None) -> int:
    p = _Parser(prog="diffsampler", description="Generate 2-d point sets with learned samplers.")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)
    g = sub.add_parser("generate", help="generate point sets")
    g.add_argument("model", help="bundled model name (see `diffsampler list`) or .onnx path")
    g.add_argument("n", type=int, help="points per set, >= 16 (a perfect square k*k is the "
                   "net's own size; other n are thinned from the next square)")
    g.add_argument("--count", type=int, default=None, help="number of sets (default 1)")
    _add_sampling_options(g)
    g.add_argument("--no-structure", action="store_true",
                   help="return the network's sets as decoded: every finishing step of the "
                        "model's pipeline skipped (`diffsampler info MODEL` lists them) but "
                        "thinning, which an n that is not a square needs (with its default "
                        "restore cut)")
    g.add_argument("--format", choices=FORMATS, default=None,
                   help="default: from the -o suffix, else txt")
    g.add_argument("-o", "--output", type=Path, default=None, help="default: stdout")
    g.set_defaults(func=_cmd_generate)
    pl = sub.add_parser("plot", help="points, 2-d and radial power spectrum as a figure")
    pl.add_argument("source", help="bundled model name, .onnx path, or a .npy file of points")
    pl.add_argument("n", type=int, nargs="?", default=None, help="points per set (models)")
    pl.add_argument("--count", type=int, default=16, help="sets averaged in the spectra")
    _add_sampling_options(pl)
    pl.add_argument("-o", "--output", type=Path, required=True, help=".png, .pdf or .svg")
    pl.set_defaults(func=_cmd_plot)
    lst = sub.add_parser("list", help="list the bundled models")
    lst.set_defaults(func=_cmd_list)
    info = sub.add_parser("info", help="show a model's card")
    info.add_argument("model")
    info.add_argument("--full", action="store_true",
                      help="include the training config and density table")
    info.set_defaults(func=_cmd_info)

    args = p.parse_args(argv)
    try:
        with warnings.catch_warnings(), _terminate_as_interrupt():
            warnings.showwarning = _warn_one_line  # restored with the caller's on exit
            args.func(args)
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (a partial output file is removed)
        print("diffsampler: interrupted", file=sys.stderr)
        return 143 if _TERMINATED else 130
    except BrokenPipeError:
        # the reader closed the pipe (`diffsampler generate ... | head`): not an error;
        # point stdout at devnull so the interpreter's final flush does not complain
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (ValueError, TypeError, OSError, ImportError) as exc:  # DiffsamplerError: ValueError/OSError
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"diffsampler: error: {msg}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
