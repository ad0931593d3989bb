"""Generation speed of the bundled models next to their reference samplers, in one run.

Per model and n: seconds per set for one set alone and amortised over a batch (default
solver and steps of the model card, i.e. what ``diffsampler_rt.generate`` does), peak
resident memory of the process, and the reference sampler's own time for one set, measured
in the same run. Every measurement runs in a fresh child process (one at a time, so
timings do not compete and the peak memory is that of the measurement alone). Reference
samplers that are slow (iterative optimisers) are timed up to the size where one set would
exceed --ref-budget seconds (estimated from the previous size; the report says which were
skipped). Fidelity at the same default settings is quoted from
benchmarks/results/fidelity.json. Writes benchmarks/results/speed.md and speed.png.

    python benchmarks/speed.py [--models gbn sot] [--sizes 256 1024 4096 16384 65536]
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIZES = (256, 1024, 4096, 16384, 65536)
#: the speed targets at n = 1024 (2 cores): amortised over a batch of 32, and alone
TARGET_BATCH_MS, TARGET_ALONE_MS = 50.0, 150.0


def batch_for(n: int, batch: int) -> int:
    """Sets per batch: ``batch`` up to 4096 points, then about 128 k points per batch."""
    return batch if n <= 4096 else max(1, 131072 // n)


# ---- children: one measurement each, printed as one JSON line ---------------------------

def _peak_mib() -> float:
    """This process's peak resident memory. Linux's ru_maxrss survives exec, so a child
    would report its parent's size at the fork if that was larger (the parent that had
    loaded every model did: 297-356 MiB "peaks" of 1024-point runs in an earlier version); the
    kernel's VmHWM belongs to the process's own address space."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # kB
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def child_model(model: str, n: int, batch: int, repeats: int, threads: int | None) -> dict:
    sys.path.insert(0, str(ROOT))
    import numpy as np

    import diffsampler_rt
    t = time.perf_counter()
    m = diffsampler_rt.Model(model, threads=threads)
    load_s = time.perf_counter() - t
    m.generate(n, seed=0)  # warm-up: onnxruntime plans its kernels per input shape
    alone = []
    for r in range(repeats):
        t = time.perf_counter()
        pts = m.generate(n, seed=r)
        alone.append(time.perf_counter() - t)
    assert pts.shape == (n, 2) and np.isfinite(pts).all()
    out = {"load_s": load_s, "alone_s": float(np.median(alone)),
           "solver": m.card["default_solver"], "steps": m.card["default_steps"]}
    if batch > 1:
        m.generate(n, batch, seed=0)
        per_set = []
        for r in range(repeats):  # median: one call can be 10 % off on a shared machine
            t = time.perf_counter()
            m.generate(n, batch, seed=1 + r)
            per_set.append((time.perf_counter() - t) / batch)
        out["batch"] = batch
        out["batch_s_per_set"] = float(np.median(per_set))
        out["batch_s_range"] = [float(min(per_set)), float(max(per_set))]
    out["peak_mib"] = _peak_mib()
    return out


def child_reference(sampler: str, n: int) -> dict:
    sys.path.insert(0, str(ROOT))
    from trainer.samplers import sample
    sample(sampler, 64, seed=0)  # imports, caches
    t = time.perf_counter()
    sample(sampler, n, seed=1)
    return {"ref_s": time.perf_counter() - t, "peak_mib": _peak_mib()}


def _run_child(args: list[str], timeout: float) -> dict | None:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    try:
        res = subprocess.run([sys.executable, __file__, "--child", *args], capture_output=True,
                             text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return None
    if res.returncode != 0:
        raise RuntimeError(f"child {args} failed:\n{res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


# ---- parent -----------------------------------------------------------------------------

def fmt_s(s: float | None) -> str:
    if s is None:
        return "–"
    return f"{1000 * s:.1f} ms" if s < 1 else f"{s:.2f} s"


def earlier_reference(kept: dict, sampler: str, below: int, budget: float
                      ) -> tuple[int, float] | tuple[None, None]:
    """(n, seconds per set) at the largest size under ``below`` where a kept run timed
    ``sampler``'s reference (or had to stop it: 4x the budget), to start this run's estimate
    from; (None, None) if there is none."""
    best: tuple[int, float] | tuple[None, None] = (None, None)
    for result in kept.values():
        if result.get("sampler") != sampler:
            continue
        for n, row in result["rows"].items():
            n = int(n)
            seconds = row.get("ref_s")
            if seconds is None and "stopped" in row.get("ref_note", ""):
                seconds = 4 * budget
            if seconds is not None and n < below and (best[0] is None or n > best[0]):
                best = (n, seconds)
    return best


def card_of(model: str) -> dict:
    """A model's card, read from its file without an onnxruntime session (a loaded model
    would stay in this process, and its children would inherit the size: _peak_mib)."""
    from diffsampler_rt.card import parse_card
    from diffsampler_rt.metadata import read_metadata
    from diffsampler_rt.model import resolve
    path = resolve(model)
    return parse_card(read_metadata(path), str(path))


def measure(a, kept: dict | None = None) -> dict:
    """Time the models of ``a``; ``kept`` (speed.json's earlier results) seeds the estimate
    of a slow reference at the run's first size, so one known to take many minutes there is
    not started just to be stopped."""
    sys.path.insert(0, str(ROOT))
    from benchmarks.common import cpu_description
    from trainer import zoo
    zoo.use()  # model names are the repository's networks (models/), in the children too
    models = a.models or zoo.networks()
    cpu = cpu_description()
    results: dict = {}
    for name in models:
        sampler = card_of(name)["sampler"]
        rows = {}
        ref_est = 0.0
        prev_n, prev_ref = earlier_reference(kept or {}, sampler, min(a.sizes), a.ref_budget)
        failed_at = None  # the size whose reference failed: the larger ones say so, not a guess
        for n in a.sizes:
            r = _run_child(["model", name, str(n), str(batch_for(n, a.batch)), str(a.repeats),
                            str(a.threads or 0)], timeout=3600)
            # reference sampler: skip when the estimate from the previous size is over budget
            if prev_ref is not None:
                ref_est = prev_ref * (n / prev_n) ** 1.5
            gave_up = False  # this size's reference was stopped or failed
            if prev_ref is None or ref_est <= a.ref_budget:
                try:
                    ref = _run_child(["reference", sampler, str(n)],
                                     timeout=max(60, 4 * a.ref_budget))
                except RuntimeError as exc:  # the sampler's failure is a result, not the run's
                    ref = {"failed": str(exc).strip().splitlines()[-1][:120]}
                r["ref_s"] = None if ref is None else ref.get("ref_s")
                r["ref_peak_mib"] = None if ref is None else ref.get("peak_mib")
                gave_up = ref is None or "failed" in ref
                if ref is None:
                    r["ref_note"] = f"> {4 * a.ref_budget:.0f} s (stopped)"
                elif "failed" in ref:
                    r["ref_note"] = f"failed: {ref['failed']}"
                    failed_at = n
            else:
                r["ref_s"] = None
                r["ref_note"] = (f"not run (~{ref_est:.0f} s estimated)" if failed_at is None
                                 else f"not run (failed at n = {failed_at})")
            if r.get("ref_s") is not None:
                prev_n, prev_ref = n, r["ref_s"]
            elif gave_up:
                # a stopped (or failed) size must also skip the larger ones, not run each in turn
                prev_n, prev_ref = n, 4 * a.ref_budget
            rows[n] = r
            print(f"{name} n={n}: alone {fmt_s(r['alone_s'])}, batch "
                  f"{fmt_s(r.get('batch_s_per_set'))}/set, peak {r['peak_mib']:.0f} MiB, "
                  f"reference {fmt_s(r.get('ref_s'))} {r.get('ref_note', '')}", flush=True)
        results[name] = {"sampler": sampler, "rows": rows, "date": dt.date.today().isoformat(),
                         "cpu": cpu}
    return results


def last_run_date(md: Path) -> str | None:
    """The date of the run that made ``md`` (speed.md's first line of text), if any."""
    m = re.search(r"`python benchmarks/speed\.py` on (\d{4}-\d{2}-\d{2})",
                  md.read_text() if md.exists() else "")
    return m.group(1) if m else None


def _models_by(results: dict, key: str, missing: str | None = None) -> dict:
    """The models of ``results`` grouped by the value of ``key`` in their latest run
    (``missing`` where a kept run did not record it), in the order of results."""
    groups: dict = {}
    for m, r in results.items():
        groups.setdefault(r.get(key, missing), []).append(m)
    return groups


def _dates_text(results: dict, date: str) -> str:
    """"2026-12-02", or, where models' latest runs differ, "2026-12-02 (sot), 2026-11-28
    (the other 21 models)": each model's rows come from its latest run (speed.json)."""
    by_date = _models_by(results, "date")
    if len(by_date) < 2:  # one date, or none recorded (a speed.json from before dates)
        return next(iter(by_date), None) or date
    parts = [(d or "an earlier date", ms) for d, ms in sorted(by_date.items(),
                                                              key=lambda kv: len(kv[1]))]
    head = [f"{d} ({', '.join(ms)})" for d, ms in parts[:-1]]
    return ", ".join(head) + f", {parts[-1][0]} (the other {len(parts[-1][1])} models)"


def _cpus_text(results: dict) -> str:
    """The CPU of each model's latest run: one name, or, where they differ, each with its
    models (the same 2-core machine class has come with CPUs 2.5x apart)."""
    by_cpu = _models_by(results, "cpu", "a CPU not recorded")
    if len(by_cpu) < 2:
        return next(iter(by_cpu), "a CPU not recorded")
    parts = sorted(by_cpu.items(), key=lambda kv: (len(kv[1]), kv[0]))
    return "; ".join(f"{c} ({', '.join(ms)})" for c, ms in parts)


def report(results: dict, a, date: str) -> None:
    fid_path = ROOT / "benchmarks" / "results" / "fidelity.json"
    fid = json.loads(fid_path.read_text()) if fid_path.exists() else {}
    lines = [
        "# Generation speed vs the reference samplers",
        "",
        f"`python benchmarks/speed.py` on {_dates_text(results, date)}: {os.cpu_count()} cores "
        f"of {_cpus_text(results)}, onnxruntime "
        f"{_ort_version()}, intra-op threads: {a.threads or 'onnxruntime default (all cores)'}. "
        "Each figure comes from a fresh process that does nothing else (median of "
        f"{a.repeats} single-set runs after a warm-up; batches: median of {a.repeats} timed "
        "calls after a warm-up call, the range over those calls in brackets; rows without a "
        "range are kept from an earlier run that timed one batched call). *alone*: one set "
        "per call; *batched*: the time per set of one call that "
        "makes a batch of sets (32 up to 4096 points, then ~128 k points per call). "
        "Default solver and steps of each model card; rows from 2026-12-04 on run a batch "
        "of at least one set per core on one single-thread session per core "
        "(`diffsampler_rt.shards`), earlier rows on one session. The 8-bit (`_fast`) "
        "models' rows from 2026-12-06 on run without onnxruntime's "
        "`session.x64quantprecision` where the CPU has VNNI (the same outputs; with it, as "
        "in earlier rows on such CPUs, their networks took twice as long) and with it where "
        "the CPU has none (`diffsampler_rt.model.needs_exact_8bit`). *peak*: peak resident "
        "memory of the measuring process (model, onnxruntime arena, the set; its own VmHWM "
        "from 2026-12-04 on; earlier rows read ru_maxrss, which on Linux also counts the "
        "parent's size at the fork, so they may be too high). Reference: one set of the "
        "model's own reference sampler (`trainer.samplers`, numpy/scipy on one core) timed in "
        "the same run; slow samplers are not run where one set would take more than "
        f"{a.ref_budget:.0f} s (estimated from the previous size, growth n^1.5).",
        "",
        "Sizes measured: " + "; ".join(
            f"{', '.join(ms)}: n = {', '.join(map(str, sz))}" for sz, ms in _by_sizes(results)) + ".",
        "",
        f"Targets (issue 5, n = 1024): <= {TARGET_BATCH_MS:.0f} ms per set batched, "
        f"<= {TARGET_ALONE_MS:.0f} ms alone; >= 10x faster than gbn and sot at 1024 and 4096; "
        "n = 65536 in one call with memory < 4 GiB.",
        "",
        "| model | default sampling | n | alone | batched (per set) | peak MiB | reference | "
        "speed-up (batched) | spectrum MAE at 1024 (fidelity.md) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, res in results.items():
        f = fid.get(name, {}).get("1024")
        mae = f"{f['mae']:.4f} (floor {f['floor']:.4f})" if f else "not measured"
        if not f and (ROOT / "benchmarks" / "results" / "distilled" / f"{name}.md").exists():
            mae = f"in [distilled.md](distilled/{name}.md)"
        for n, r in res["rows"].items():
            per = r.get("batch_s_per_set", r["alone_s"])
            speedup = f"{r['ref_s'] / per:.2g}x" if r.get("ref_s") else ""
            mark = ""
            if n == 1024:
                ok = per * 1000 <= TARGET_BATCH_MS and r["alone_s"] * 1000 <= TARGET_ALONE_MS
                mark = " ✓" if ok else " ✗"
            ref = fmt_s(r.get("ref_s")) if r.get("ref_s") else r.get("ref_note", "")
            spread = ""
            if r.get("batch_s_range"):
                lo, hi = r["batch_s_range"]
                spread = f" ({1000 * lo:.0f}-{1000 * hi:.0f})" if hi < 1 else f" ({lo:.2f}-{hi:.2f})"
            lines.append(f"| {name} | {r['solver']} {r['steps']} | {n} | {fmt_s(r['alone_s'])}"
                         f" | {fmt_s(r.get('batch_s_per_set'))}{spread}{mark} | "
                         f"{r['peak_mib']:.0f} | "
                         f"{ref} | {speedup} | {mae if n == 1024 else ''} |")
    lines += ["", "![time per set vs n](speed.png)", ""]
    out = ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "speed.md").write_text("\n".join(lines))
    (out / "speed.json").write_text(json.dumps(kept_json(results), indent=1))
    plot(results, out / "speed.png")
    print(f"wrote {out / 'speed.md'}")


def _by_sizes(results: dict) -> list[tuple[tuple[int, ...], list[str]]]:
    """Models grouped by the sizes they were measured at (runs may cover different sizes)."""
    groups: dict[tuple[int, ...], list[str]] = {}
    for name, res in results.items():
        groups.setdefault(tuple(sorted(int(n) for n in res["rows"])), []).append(name)
    return sorted(groups.items(), key=lambda g: -len(g[0]))


def _ort_version() -> str:
    import onnxruntime
    return onnxruntime.__version__


def plot(results: dict, path: Path) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, (name, res) in enumerate(results.items()):
        ns = list(res["rows"])
        c = f"C{i % 10}"
        ax.loglog(ns, [r.get("batch_s_per_set", r["alone_s"]) for r in res["rows"].values()],
                  "-o", color=c, ms=3, label=f"{name} (learned, batched)")
        refs = [(n, r["ref_s"]) for n, r in res["rows"].items() if r.get("ref_s")]
        if refs:
            ax.loglog(*zip(*refs), ":x", color=c, ms=4, label=f"{res['sampler']} (reference)")
    ax.set(xlabel="points per set", ylabel="seconds per set", title="time per set, 2 cores")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    if sys.argv[1:2] == ["--child"]:
        kind, *rest = sys.argv[2:]
        if kind == "model":
            name, n, batch, repeats, threads = rest
            out = child_model(name, int(n), int(batch), int(repeats), int(threads) or None)
        else:
            out = child_reference(rest[0], int(rest[1]))
        print(json.dumps(out))
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", help="default: every bundled model")
    p.add_argument("--sizes", type=int, nargs="*", default=list(SIZES))
    p.add_argument("--batch", type=int, default=32, help="sets per batched call (n <= 4096)")
    p.add_argument("--repeats", type=int, default=3, help="single-set runs (median)")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime intra-op threads")
    p.add_argument("--fresh", action="store_true",
                   help="drop the kept measurements of models not measured in this run")
    p.add_argument("--ref-budget", type=float, default=120.0,
                   help="skip reference sets estimated to take longer (seconds)")
    p.add_argument("--report-only", action="store_true",
                   help="rebuild speed.md / speed.png from the kept speed.json")
    a = p.parse_args()
    # keep other models' earlier measurements (speed.json), so models or sizes can be
    # measured in separate runs; the report covers every model measured so far
    path = ROOT / "benchmarks" / "results" / "speed.json"
    kept = json.loads(path.read_text()) if path.exists() else {}
    results = {} if a.report_only else measure(a, kept)
    if kept and not a.fresh:
        results = merge_kept(kept, results)
    date = dt.date.today().isoformat()
    if a.report_only:  # measures nothing: the header keeps the date of the last measuring run
        date = last_run_date(ROOT / "benchmarks" / "results" / "speed.md") or date
    report(dict(sorted(results.items())), a, date)


def kept_json(results: dict) -> dict:
    """speed.json's content: per model its sampler, its rows by n and the date of its latest
    run (which the next run's header needs, so it is kept with the rows)."""
    return {m: {"sampler": res["sampler"], "rows": {str(n): r for n, r in res["rows"].items()},
                **{k: res[k] for k in ("date", "cpu") if k in res}}
            for m, res in results.items()}


def merge_kept(old: dict, new: dict) -> dict:
    """speed.json's kept results with this run's on top, size by size: a run over some
    sizes of a model replaces those rows and keeps the model's others."""
    out = {m: {"sampler": r["sampler"], "rows": {int(n): row for n, row in r["rows"].items()},
               **{k: r[k] for k in ("date", "cpu") if k in r}}
           for m, r in old.items()}
    for m, r in new.items():
        rows = {**out.get(m, {}).get("rows", {}), **r["rows"]}
        out[m] = {**r, "rows": dict(sorted(rows.items()))}
    return out


if __name__ == "__main__":
    main()
