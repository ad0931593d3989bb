"""What attention placement costs at inference: onnxruntime forward time per grid side.

The seed paper put self-attention at every U-Net level; its released code at none. Attention
over h*w tokens costs (h*w)^2, so at full resolution it dominates large grids. This exports
untrained nets of the bundled architecture with attention at different levels and times one
forward pass (batch 1 and batch 8) at k = 16, 32, 64, 128.
Writes benchmarks/results/attention_cost.md.

    python benchmarks/attention_cost.py
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

VARIANTS = {
    "none": dict(attention_levels=(), middle_attention=False),
    "lowest + middle (bundled)": dict(attention_levels=(2,), middle_attention=True),
    "every level (seed paper)": dict(attention_levels=(0, 1, 2), middle_attention=True),
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sides", type=int, nargs="*", default=[16, 32, 64, 128])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    a = p.parse_args()
    import onnxruntime as ort
    import torch

    from export.onnx_export import export_model, model_card
    from trainer.config import TrainConfig
    from trainer.unet import UNet

    torch.set_num_threads(a.threads)
    base = TrainConfig.load(ROOT / "trainer" / "configs" / "rank1.json")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, change in VARIANTS.items():
            cfg = replace(base, unet=replace(base.unet, **change))
            net = UNet(cfg.unet).eval()
            path = export_model(net, model_card(cfg, training_steps=0), Path(tmp) / "m.onnx")
            opts = ort.SessionOptions()
            opts.intra_op_num_threads = a.threads
            sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
            for k in a.sides:
                for b in (1, 8):
                    if b * k * k > 8 * 128 * 128 or (k >= 128 and "every" in label and b > 1):
                        continue
                    x = np.random.default_rng(0).standard_normal((b, 2, k, k)).astype(np.float32)
                    t = np.full(b, 500.0, np.float32)
                    sess.run(None, {"x": x, "t": t})
                    reps = max(2, int(0.5 / max(1e-3, _time(sess, x, t))))
                    ms = 1000 * min(_time(sess, x, t) for _ in range(min(reps, 20))) / b
                    rows.append((label, k, b, ms))
                    print(f"{label:28s} k={k:4d} batch={b}: {ms:8.2f} ms per set", flush=True)
    lines = ["# Attention placement: inference cost", "",
             f"`python benchmarks/attention_cost.py` ({a.threads} onnxruntime threads, "
             "untrained nets of the bundled architecture: base 32, levels 1-2-2, 2 res blocks). "
             "Milliseconds per set for ONE denoiser evaluation (a set needs `steps` of them).", "",
             "| attention | k | batch | ms per set |", "|---|---|---|---|"]
    lines += [f"| {l} | {k} | {b} | {ms:.2f} |" for l, k, b, ms in rows]
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "attention_cost.md").write_text("\n".join(lines) + "\n")


def _time(sess, x, t) -> float:
    t0 = time.perf_counter()
    sess.run(None, {"x": x, "t": t})
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
