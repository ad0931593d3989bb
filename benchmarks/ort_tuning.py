"""onnxruntime settings for one denoiser evaluation on this machine: what the runtime uses.

Times one network evaluation (k = 32, i.e. n = 1024) of a bundled model per set, for
batch sizes: one session on every core's threads, one single-thread session per core
each on its slice of the batch (diffsampler_rt.shards, what the runtime does with a batch
of at least one set per core), one thread; and the fp16-stored file against its float32
form and its 8-bit convolutions (``python -m export
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
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

from diffsampler_rt.model import resolve, session_options  # noqa: E402
from diffsampler_rt.shards import Shards, usable_cores  # noqa: E402
from benchmarks.common import cpu_description, float_source  # noqa: E402
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


def split(path: str) -> Shards:
    """One single-thread session per core, each on its slice of a batch, side by side:
    the runtime's way (diffsampler_rt.shards)."""
    return Shards(lambda: session(path, threads=1), usable_cores())


def sharded(shards: Shards, batch: int):
    feed = inputs(batch)
    return lambda: shards.run(feed["x"], feed["t"])


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
    cores = usable_cores()
    rows = []
    default = session(path)
    one = session(path, threads=1)
    shards = split(path)  # its sessions made once, on the first batch
    for batch in (1, 4, 8, 16, 32, 64):
        rows.append((batch, ms_per_set(plain(default, batch), batch, a.repeats),
                     ms_per_set(sharded(shards, batch), batch, a.repeats) if batch >= cores
                     else float("nan"),
                     ms_per_set(plain(one, batch), batch, a.repeats)))
        print(rows[-1], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        f32, q8 = os.path.join(tmp, "f32.onnx"), os.path.join(tmp, "int8.onnx")
        float32_file(path, f32)
        quantize(path, q8)  # as the bundled 8-bit models are made
        files = [(label, ms_per_set(plain(session(f), 32), 32, a.repeats),
                  ms_per_set(sharded(split(f), 32), 32, a.repeats))
                 for label, f in (("fp16-stored weights", path), ("float32 weights", f32),
                                  ("8-bit convolutions (`python -m export quantize`)", q8))]
        profile = op_profile(path, 32, tmp)
        profile8 = op_profile(q8, 32, tmp)
    lines = [
        "# onnxruntime settings for one denoiser evaluation",
        "",
        f"`python benchmarks/ort_tuning.py --model {a.model}` on {dt.date.today().isoformat()}"
        f": {cores} cores of {cpu_description()}, onnxruntime {ort.__version__}; one "
        f"evaluation at k = 32 (n = 1024), ms per set, median of {a.repeats} calls. A "
        "sampling run costs its step count times this (8 steps for the distilled models, "
        "20 for the others).",
        "",
        f"| batch | one session, {cores} threads | {cores} single-thread sessions side by "
        "side, one slice each (runtime, batch >= cores) | one session, 1 thread |",
        "|---|---|---|---|",
        *[f"| {b} | {whole:.2f} | {'-' if np.isnan(split) else f'{split:.2f}'} | "
          f"{single:.2f} |" for b, whole, split, single in rows],
        "",
        f"| weights (batch 32) | one session, {cores} threads | {cores} single-thread "
        "sessions |",
        "|---|---|---|",
        *[f"| {label} | {v:.2f} | {w:.2f} |" for label, v, w in files],
        "",
        "Operator profile of one session (batch 32, all cores' threads, share of kernel "
        "time), float and 8-bit:",
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
