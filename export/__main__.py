"""``python -m export CHECKPOINT -o MODEL.onnx``: export and check parity with torch."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m export", description=__doc__)
    p.add_argument("checkpoint", type=Path, help="runs/<name>/checkpoint.pt")
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--fp32", action="store_true", help="store float32 weights (default fp16)")
    p.add_argument("--tolerance", type=float, default=1e-4)
    p.add_argument("--sides", type=int, nargs="*", default=[8, 24, 25, 32, 64])
    args = p.parse_args(argv)
    if not args.checkpoint.exists():
        print(f"error: checkpoint {args.checkpoint} not found", file=sys.stderr)
        return 2
    import torch
    torch.set_num_threads(2)
    from . import ParityError, export_checkpoint
    try:
        out, diffs = export_checkpoint(args.checkpoint, args.output,
                                       fp16_weights=not args.fp32,
                                       parity_sides=tuple(args.sides), tolerance=args.tolerance)
    except ParityError as exc:
        print(f"parity check FAILED: {exc}", file=sys.stderr)
        return 1
    size = out.stat().st_size / 2**20
    print(f"wrote {out} ({size:.2f} MiB); parity max|diff| "
          + ", ".join(f"k={k}: {d:.2g}" for k, d in diffs.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
