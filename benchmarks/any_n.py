"""Fidelity at sizes that are not perfect squares, against the reference samplers.

For an n that is not k*k, the runtime makes the next square's set, thins it (blue noise:
weighted sample elimination, the most crowded point first; other models: at random; lattice
models: then the nearest lattice of n points) and restores its large scales
(diffsampler_rt.elimination) before the card's polish and spacing. This measures what that
gives, as benchmarks/fidelity.py does at the square sizes (same
statistics, same reference batches A and B, the floor B vs A in brackets), next to the
plain alternative: the model's next-square set with k*k - n points dropped at random. For
context each model's figures at the nearest square measured in fidelity.md are quoted.
Samplers without sets of non-square size (ldbn) are left out, and so are the non-uniform
models (their references take about a minute a set at n = 1000).

Writes benchmarks/results/any_n.md and any_n.png (spectra at the largest size). Each
model's rows are kept in benchmarks/results/any_n/NAME.json: a run rewrites the models it
measures and reports them next to the kept ones (each section says when it was measured).

    python benchmarks/any_n.py [--models gbn_fast sot_fast] [--sizes 200 1000] [--workers 2]
    python benchmarks/any_n.py --report-only    # any_n.md / any_n.png from the kept rows
    python benchmarks/any_n.py --models gbn --sizes 1000 --ref-pool gbn:1000:32:2-3
        # more reference sets: cached files of further seeds pooled with the seed-1 draw
        # (--pool-only: those alone), as in fidelity.py
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from benchmarks.fidelity import (STATS, _fmt_rel, _per_set, _statistic,  # noqa: E402
                                 add_pool_options, check_pool_options, pool_text,
                                 reference, set_stats, settings_pools, tolerance)
from diffsampler_rt.low_frequencies import RESTORE_CUT  # noqa: E402
from diffsampler_rt.finish.pipeline import find  # noqa: E402
from trainer.stats import radial_spectrum, spectrum_mae  # noqa: E402

MODELS = ("poisson_disk", "poisson_disk_fast", "poisson_disk_torus_fast", "gbn", "gbn_fast",
          "gbn_torus_fast", "sot", "sot_fast", "sot_32", "sot_32_fast", "sobol_owen", "sobol_owen_fast", "rank1",
          "lattice")
SIZES = (200, 1000)
#: samplers with sets of any n (ldbn's are k x k only)
MEASURABLE = ("poisson_disk", "gbn", "sot", "sobol_owen", "rank1", "lattice")
NAMES = {"ot_energy": "OT energy", "l2_star": "L2*", "gauss_mse": "Gauss MSE",
         "heaviside_mse": "Heaviside MSE", "min_distance": "min dist"}


def dropped_at_random(sets: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Each set with all but n of its points dropped at random (the order kept)."""
    rng = np.random.default_rng(seed)
    keep = np.sort(np.stack([rng.permutation(sets.shape[1])[:n] for _ in sets]), axis=1)
    return np.take_along_axis(sets, keep[..., None], axis=1)


def row_of(pool, gen: np.ndarray, count: int, spec_a: np.ndarray, stats_a: dict,
           stats_b: dict) -> dict:
    """Spectrum MAE and the mean statistics of generated sets against reference batch A."""
    g = set_stats(pool, gen[:count])
    spec = radial_spectrum(gen)[1]
    row = {"mae": spectrum_mae(spec, spec_a), "spec_gen": spec.tolist()}
    for k in STATS:
        ma, mb = stats_a[k].mean(), stats_b[k].mean()
        row[k] = _statistic(g[k], float(ma), float(mb / ma - 1), _per_set(stats_a[k]))
    return row


def measure(pool, name: str, n: int, a) -> dict:
    model = diffsampler_rt.load(name)
    sampler = model.card["sampler"]
    count, _, ref_a, ref_b, ref_per_set, stats_a, stats_b = reference(pool, sampler, n, a)
    spec_a, spec_b = radial_spectrum(ref_a)[1], radial_spectrum(ref_b)[1]
    t = time.perf_counter()
    gen = model.generate(n, count, seed=a.seed)
    per_set = (time.perf_counter() - t) / count
    k = math.isqrt(n - 1) + 1
    square = model.generate(k * k, count, seed=a.seed)
    out = {"n": n, "k": k, "count": count, "floor": spectrum_mae(spec_b, spec_a),
           "spec_ref": spec_a.tolist(), "gen_ms": 1000 * per_set, "ref_ms": 1000 * ref_per_set,
           "eliminated": row_of(pool, gen, count, spec_a, stats_a, stats_b),
           "random": row_of(pool, dropped_at_random(square, n, a.seed), count, spec_a,
                            stats_a, stats_b)}
    e = out["eliminated"]
    if _prefixed(model.card):  # made from the next power of four's net
        e["grid"] = 1 << (k - 1).bit_length()
    print(f"{name} n={n}: MAE {e['mae']:.4f} (floor {out['floor']:.4f}, random drop "
          f"{out['random']['mae']:.4f}); "
          + ", ".join(f"{k} {100 * e[k]['rel']:+.1f}%" for k in STATS), flush=True)
    return out


def nearest_square_row(name: str, n: int) -> tuple[int, dict] | None:
    """The model's row in fidelity.md at the measured square size nearest n."""
    path = ROOT / "benchmarks" / "results" / "fidelity" / f"{name}.json"
    if not path.exists():
        return None
    rows = json.loads(path.read_text())["rows"]
    size = min(rows, key=lambda s: abs(math.log(int(s) / n)))
    return int(size), rows[size]


def store(out: Path, name: str) -> Path:
    """Where a model's measured rows are kept between runs."""
    return out / "any_n" / f"{name}.json"


def kept(out: Path) -> dict[str, dict]:
    """Every kept model's record ({"date", "options", "rows"}), in MODELS' order, then the
    others by name."""
    order = {m: i for i, m in enumerate(MODELS)}
    paths = sorted((out / "any_n").glob("*.json"),
                   key=lambda p: (order.get(p.stem, len(order)), p.stem))
    return {p.stem: json.loads(p.read_text()) for p in paths}


def _prefixed(card: dict) -> bool:
    """Whether the card's sets of n points are the first n of the next power of four's net."""
    return bool((find(card["pipeline"], "dyadic_net") or {}).get("prefix"))


def _restore_text(card: dict, record: dict) -> str:
    """How far the measured run restored the thinned sets' large scales (records from before
    the card field have the runtime's default, which was the only cut then)."""
    if find(card["pipeline"], "rank1_lattice") is not None:  # a lattice, not restored
        return ""
    if _prefixed(card):
        return ("sets of n points: the first n, in Sobol' order, of a net of the next "
                "power-of-four size (card `structure_prefix`, `diffsampler_rt.sobol_orbit`); ")
    cut = record.get("restore_cut", RESTORE_CUT)
    source = "the card's `restore_cut`" if cut != RESTORE_CUT else "the runtime's default"
    return f"thinned sets restored below {cut:g} sqrt(n) ({source}); "


def report(records: dict[str, dict], out: Path) -> None:
    lines = [
        "# Sets of any size: fidelity at n that are not perfect squares",
        "",
        f"`python benchmarks/any_n.py` ({os.cpu_count()} cores; each model's section says "
        "when and with which options it was measured). For n not a square the "
        "runtime makes the next square's set, k*k points, and removes k*k - n of them: "
        "blue-noise models (a card with a minimum spacing) by weighted sample elimination, "
        "the most crowded point first, the others at random; then it moves the kept points "
        "so that their density below 0.25 sqrt(n) is the full set's again (the holes' "
        "large-scale power taken out), and applies the card's sliced-OT polish and minimum "
        "spacing at n; the lattice models' thinned sets are replaced by their nearest "
        "lattice of n points instead (`diffsampler_rt.elimination`), and the sobol_owen "
        "models' sets are the first n points of a net of the next power-of-four size in the "
        "Sobol' order it is given (`diffsampler_rt.sobol_orbit`). *thinned* (*first n, Sobol' "
        "order*) is that (the default); *dropped at random* is the same k*k sets with "
        "k*k - n points dropped at "
        "random and nothing else, the plain alternative. Columns as in "
        "[fidelity.md](fidelity.md): spectrum MAE against reference batch A with the floor "
        "(batch B vs A) in brackets, relative differences of the means ± two standard errors "
        "(✗ / ✗?: a miss of ±5 %, min distance ±10 %, beyond / within noise) with the floor "
        "in brackets. *sets*: per side (slow samplers fewer). The last row of each model "
        "quotes its figures at the nearest square size from fidelity.md (other sets, other "
        "counts).",
        "",
    ]
    for name, record in records.items():
        rows = record["rows"]
        card = diffsampler_rt.load(name).card
        lines += [f"## {name}", "",
                  f"sampler `{card['sampler']}`; {_restore_text(card, record)}measured on "
                  f"{record['date']} with `{record['options']}`.", "",
                  "| n (grid) | sets | sets made by | spectrum MAE (floor) | "
                  + " | ".join(NAMES[k] for k in STATS) + " | gen ms/set | ref ms/set |",
                  "|---|---|---|---|" + "---|" * len(STATS) + "---|---|"]
        for r in rows:
            made = "**first n, Sobol' order**" if "grid" in r["eliminated"] else "**thinned**"
            for key, label in (("eliminated", made), ("random", "dropped at random")):
                e = r[key]
                ms = f"{r['gen_ms']:.0f} | {r['ref_ms']:.0f}" if key == "eliminated" else " | "
                side = e.get("grid", r["k"])
                lines.append(f"| {r['n']} ({side}x{side}) | {r['count']} | {label} | "
                             f"{e['mae']:.4f} ({r['floor']:.4f}) | "
                             + " | ".join(_fmt_rel(e[k], tolerance(k)) for k in STATS)
                             + f" | {ms} |")
            near = nearest_square_row(name, r["n"])
            if near:
                size, q = near
                lines.append(f"| {size} (fidelity.md) | {q['count']} | the square size | "
                             f"{q['mae']:.4f} ({q['floor']:.4f}) | "
                             + " | ".join(_fmt_rel(q[k], tolerance(k)) for k in STATS)
                             + " | | |")
        lines.append("")
    lines += ["![spectra](any_n.png)", ""]
    (out / "any_n.md").write_text("\n".join(lines))


def plot(records: dict[str, dict], out: Path) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot", file=sys.stderr)
        return
    names = list(records)
    cols = 4
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3.2 * rows), squeeze=False)
    x = np.arange(1, 80) * 0.0625
    for ax, name in zip(axes.flat, names):
        r = max(records[name]["rows"], key=lambda r: r["n"])
        ax.plot(x, r["spec_ref"], lw=1.5, label="reference")
        ax.plot(x, r["eliminated"]["spec_gen"], lw=1.2, ls="--", label="thinned")
        ax.plot(x, r["random"]["spec_gen"], lw=0.8, alpha=0.7, label="dropped at random")
        ax.set(title=f"{name}, n = {r['n']}", xlabel="|f| / sqrt(n)")
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "any_n.png", dpi=70)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", default=list(MODELS))
    p.add_argument("--sizes", type=int, nargs="*", default=list(SIZES))
    p.add_argument("--sets", type=int, default=128, help="sets per side (fast samplers)")
    p.add_argument("--slow-sets", type=int, default=32, help="sets per side, slow samplers")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=1, help="seed of the generated sets")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    add_pool_options(p)
    p.add_argument("--report-only", action="store_true",
                   help="rebuild any_n.md / any_n.png from the kept rows, measuring nothing")
    a = p.parse_args()
    check_pool_options(p, a)
    if a.report_only:
        records = kept(a.out)
        report(records, a.out)
        plot(records, a.out)
        print(f"wrote {a.out / 'any_n.md'}")
        return
    for n in a.sizes:
        if math.isqrt(n) ** 2 == n:
            p.error(f"--sizes: {n} is a perfect square (fidelity.py measures those)")
    # what fidelity.reference reads from its options
    a.slow_4096, a.spectrum_sets = a.slow_sets, a.sets
    samplers, restore_cuts = {}, {}
    for name in a.models:
        card = diffsampler_rt.load(name).card
        samplers[name] = card["sampler"]
        restore_cuts[name] = (find(card["pipeline"], "thin") or {}).get("restore_cut",
                                                                         RESTORE_CUT)
        if card.get("density") or card["sampler"] not in MEASURABLE:
            p.error(f"--models: {name}'s sampler {card['sampler']!r} is not measured here "
                    "(no reference sets of non-square size, or a density)")
    options = (f"--sizes {' '.join(map(str, a.sizes))} --sets {a.sets} "
               f"--slow-sets {a.slow_sets} --seed {a.seed}")
    store(a.out, "_").parent.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(a.workers) as pool:
        for name in a.models:
            record = {"date": dt.date.today().isoformat(),
                      "options": options + pool_text(settings_pools(a, samplers[name])),
                      "restore_cut": restore_cuts[name],
                      "rows": [measure(pool, name, n, a) for n in a.sizes]}
            store(a.out, name).write_text(json.dumps(record))
            report(kept(a.out), a.out)
    plot(kept(a.out), a.out)
    print(f"wrote {a.out / 'any_n.md'}")


if __name__ == "__main__":
    main()
