"""onnxruntime settings for one denoiser evaluation on this machine: what the runtime uses.

Times one network evaluation (k = 32, i.e. n = 1024) of a bundled model per set, for
batch sizes, intra-op thread counts, two single-thread sessions splitting a batch, the
fp16-stored file against its float32 form and its 8-bit convolutions (``python -m export
quantize``, as the bundled ``_fast`` models are made; for those, the float file in
models/float/ is the starting point); plus operator profiles, float and 8-bit. Writes
benchmarks/results/ort_tuning.md.

    python benchmarks/ort_tuning.py [--model sot_fast] [--repeats 10]
"""
from __future__ import annotations

import argparse
import collections
import datetime as dt
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from diffsampler_rt.model import resolve, session_options  # noqa: E402
from benchmarks.common import float_source  # noqa: E402
from export.quantize import float32_file, quantize  # noqa: E402

K = 32


def session(path: str, threads: int | None = None, profile: str | None = None):
    opts = session_options(threads or None)  # as diffsampler_rt.Model does
    if profile:
        opts.enable_profiling = True
        opts.profile_file_prefix = profile
    return ort.InferenceSession(path, sess_options=opts, providers=["CPUExecutionProvider"])


def inputs(batch: int) -> dict:
    rng = np.random.default_rng(0)
    return {"x": rng.standard_normal((batch, 2, K, K)).astype(np.float32),
            "t": np.full(batch, 500.0, dtype=np.float32)}


def ms_per_set(run, batch: int, repeats: int) -> float:
    """Median over ``repeats`` calls of one evaluation's time, per set, after two warm-ups."""
    for _ in range(2):
        run()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        run()
        times.append(time.perf_counter() - t)
    return 1000 * float(np.median(times)) / batch


def plain(sess, batch: int):
    feed = inputs(batch)
    return lambda: sess.run(["eps"], feed)


def split_in_two(a, b, batch: int):
    """Two single-thread sessions, each on half the batch, in two Python threads."""
    feed = inputs(batch)
    h = batch // 2
    first = {k: v[:h] for k, v in feed.items()}
    second = {k: v[h:] for k, v in feed.items()}

    def run():
        th = threading.Thread(target=a.run, args=(["eps"], first))
        th.start()
        b.run(["eps"], second)
        th.join()
    return run


def op_profile(path: str, batch: int, tmp: str) -> list[tuple[str, float, int]]:
    sess = session(path, profile=os.path.join(tmp, "prof"))
    run = plain(sess, batch)
    for _ in range(5):
        run()
    events = json.loads(Path(sess.end_profiling()).read_text())
    total, count = collections.Counter(), collections.Counter()
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            total[e["args"]["op_name"]] += e["dur"]
            count[e["args"]["op_name"]] += 1
    whole = sum(total.values())
    return [(op, 100 * d / whole, count[op] // 5) for op, d in total.most_common(8)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="sot_fast")
    p.add_argument("--repeats", type=int, default=10)
    a = p.parse_args()
    path = str(float_source(a.model))
    rows = []
    default = session(path)
    one = session(path, threads=1)
    for batch in (1, 4, 8, 16, 32, 64):
        rows.append((f"batch {batch}", ms_per_set(plain(default, batch), batch, a.repeats),
                     ms_per_set(plain(one, batch), batch, a.repeats)))
        print(rows[-1], flush=True)
    halves = session(path, threads=1), session(path, threads=1)
    split = [ms_per_set(split_in_two(*halves, b), b, a.repeats) for b in (16, 32)]
    with tempfile.TemporaryDirectory() as tmp:
        f32, q8 = os.path.join(tmp, "f32.onnx"), os.path.join(tmp, "int8.onnx")
        float32_file(path, f32)
        quantize(path, q8)  # as the bundled 8-bit models are made
        files = [(label, ms_per_set(plain(session(f), 32), 32, a.repeats))
                 for label, f in (("fp16-stored weights", path), ("float32 weights", f32),
                                  ("8-bit convolutions (`python -m export quantize`)", q8))]
        profile = op_profile(path, 32, tmp)
        profile8 = op_profile(q8, 32, tmp)
    lines = [
        "# onnxruntime settings for one denoiser evaluation",
        "",
        f"`python benchmarks/ort_tuning.py --model {a.model}` on {dt.date.today().isoformat()}"
        f": {os.cpu_count()} cores, onnxruntime {ort.__version__}; one evaluation at k = 32 "
        f"(n = 1024), ms per set, median of {a.repeats} calls. A sampling run costs its step "
        "count times this (8 steps for the distilled models, 20 for the others).",
        "",
        "| batch | 2 threads (runtime default) | 1 thread |",
        "|---|---|---|",
        *[f"| {label.split()[1]} | {two:.2f} | {single:.2f} |" for label, two, single in rows],
        "",
        f"Two single-thread sessions, each on half the batch, in parallel: {split[0]:.2f} ms "
        f"per set at batch 16, {split[1]:.2f} at 32.",
        "",
        "| weights (batch 32, 2 threads) | ms per set |",
        "|---|---|",
        *[f"| {label} | {v:.2f} |" for label, v in files],
        "",
        "Operator profile of the runtime's session (batch 32, share of kernel time), float "
        "and 8-bit:",
        "",
        "| operator | share | nodes |",
        "|---|---|---|",
        *[f"| {op} | {share:.1f} % | {n} |" for op, share, n in profile],
        "",
        "| operator (8-bit) | share | nodes |",
        "|---|---|---|",
        *[f"| {op} | {share:.1f} % | {n} |" for op, share, n in profile8],
        "",
    ]
    out = ROOT / "benchmarks" / "results" / "ort_tuning.md"
    out.write_text("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
