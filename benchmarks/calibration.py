"""``python -m trainer calibrate``'s procedure run on every shipped model: the finishing
steps it chooses from example sets of the model's sampler, beside the steps the model's card
carries, and what each does to the figures against HELD-OUT sets of the sampler.

    python benchmarks/calibration.py [--models gbn sot ...] [--sets 64] [--sizes 64 256 576 1024]
        [--adopt] [--taken-back MODEL WHY]

Per shipped model (its network in models/): held-in and held-out sets of its sampler at its
trained sizes (64, 256, 1024; fewer sets, or fewer sizes, for the slowest samplers: the
report says how many; ``--sizes`` adds sizes where a card's choice acts at one, e.g. 576),
the structure every held-in set has (``trainer.fitting.analysis``),
then ``trainer.fitting.calibrate.calibrate`` on a copy of the network (``--adopt``: the
network and its shipped copy take the calibrated card). Both pipelines make
sets from the same seeds, compared with the held-out sets by the fit report's figures
(``trainer.fitting.report.compare``: spectrum and pair-correlation mean absolute difference
next to their floors, nearest-neighbour and smallest distance, star L2 discrepancy).
Non-uniform models: every set unwarped by the sampler's exact density map first. Writes
benchmarks/results/calibration.md and calibration.json; example sets are cached under
~/.cache/diffsampler/calibration, and the fit benchmark's example files are used where they
exist.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RESULTS = ROOT / "benchmarks" / "results"
from benchmarks.common import cpu_description  # noqa: E402
SIZES = (64, 256, 1024)
#: sets a side (held in, held out) where a sampler takes seconds a set: n -> sets
SLOW_SETS = {"gbn_blob": {64: 32, 256: 16}, "sot_ramp": {64: 32, 256: 32, 1024: 20},
             "gbn": {64: 64, 256: 64, 1024: 20}, "sot": {64: 64, 256: 32, 1024: 20}}
#: models learned from few sets are calibrated from no more held-in sets than they learned
#: from (sot_32: 32 SOT sets a size; fewer at 1024, where SOT is slow)
MODEL_SETS = {"sot_32": {64: 32, 256: 32, 1024: 20}}
#: sets a side at sizes beyond the trained ones (--sizes 4096): as many points as 16 sets
#: of 4096, the calibration's own count there (``trainer.fitting.choice.search_sets``)
LARGE_POINTS = 16 * 4096


def _fit_bench_sets(sampler: str, n: int) -> np.ndarray | None:
    """The fit benchmark's example files of ``sampler`` at ``n`` (one 'x y' file a set)."""
    from trainer.data import cache_dir
    folder = cache_dir() / "fit_bench" / f"{sampler}_examples"
    files = sorted(folder.glob(f"set_{n}_*.txt"))
    return np.stack([np.loadtxt(f) for f in files]) if files else None


def examples(sampler: str, n: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(held-in, held-out) sets of the sampler, ``count`` each, cached."""
    from trainer.data import cache_dir
    from trainer.samplers import sample
    cache = cache_dir() / "calibration" / f"{sampler}_{n}_{count}.npy"
    if cache.exists():
        sets = np.load(cache)
    else:
        have = _fit_bench_sets(sampler, n)
        have = have if have is not None else np.empty((0, n, 2))
        more = max(0, 2 * count - len(have))
        if more:
            have = np.concatenate([have, sample(sampler, n, count=more, workers=1,
                                                seed=np.random.default_rng([11, n]))])
        sets = have[: 2 * count]
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.save(cache, sets)
    return sets[:count], sets[count:]


def _square(sampler: str):
    from trainer.samplers.densities import UNWARP
    unwarp = UNWARP.get(sampler)
    return (lambda s: s) if unwarp is None else (lambda s: unwarp(s))


def measure(path: Path, held_out: dict[int, np.ndarray], square, seed: int) -> dict:
    """The figures of the model in ``path`` at each size against the held-out sets."""
    import diffsampler_rt
    from trainer.fitting.report import compare
    model = diffsampler_rt.Model(path)
    out = {}
    for n, ref in held_out.items():
        gen = square(model.generate(n, len(ref), seed=seed))
        figures, _ = compare(gen, square(ref))
        out[str(n)] = [{"name": f.name, "generated": f.generated, "reference": f.reference,
                   "noise": f.noise, "kind": f.kind, "verdict": f.verdict()} for f in figures]
    return out


def run_model(name: str, sets: int, seed: int, adopt: bool = False,
              sizes: tuple[int, ...] = SIZES) -> dict:
    import diffsampler_rt
    from diffsampler_rt.finish.pipeline import describe
    from trainer.fitting.analysis import analyse
    from trainer.fitting.calibrate import calibrate
    from trainer.fitting.examples import read_examples
    entry = diffsampler_rt.model.catalogue()[name]
    network = ROOT / "models" / f"{entry['network']}.onnx"
    card = diffsampler_rt.Model(network).card
    sampler = card["sampler"]
    given = MODEL_SETS.get(name, SLOW_SETS.get(sampler))
    counts = dict(given) if given else {n: sets for n in sizes if n <= max(SIZES)}
    counts.update({n: LARGE_POINTS // n for n in sizes if n > max(SIZES) and n not in counts})
    # the default sizes where the network was trained at them; sizes asked for beyond them
    sizes = [n for n in sizes if n in counts and (n in card["trained_sizes"] or n not in SIZES)]
    t = time.monotonic()
    split = {n: examples(sampler, n, counts[n]) for n in sizes}
    held_in = {n: split[n][0] for n in sizes}
    held_out = {n: split[n][1] for n in sizes}
    drawn_s = time.monotonic() - t
    analysis = analyse(read_examples(list(held_in.values())))
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / network.name
        shutil.copy(network, copy)
        t = time.monotonic()
        calibrated = calibrate(copy, held_in, analysis.structure, analysis.structure_sizes,
                               seed=seed, log=lambda line: print(f"{name}: {line}", flush=True))
        calibrate_s = time.monotonic() - t
        square = _square(sampler)
        figures = {"card": measure(network, held_out, square, seed + 1),
                   "calibrated": measure(copy, held_out, square, seed + 1)}
        if adopt:  # the network and its shipped copy carry the calibrated card from now on
            shutil.copy(copy, network)
            shutil.copy(copy, Path(diffsampler_rt.__file__).parent / "models" / f"{name}.onnx")
            adopt_in_float(network, calibrated)
    return {"model": name, "network": entry["network"], "sampler": sampler,
            "sets": {str(n): counts[n] for n in sizes}, "structure": analysis.structure,
            "card_pipeline": describe(card["pipeline"]), "card_entries": card["pipeline"],
            "calibrated_pipeline": describe(calibrated["pipeline"]),
            "calibrated_entries": calibrated["pipeline"],
            "notes": calibrated.get("calibration", []), "figures": figures,
            "examples_s": round(drawn_s), "calibrate_s": round(calibrate_s)}


def adopt_in_float(network: Path, card: dict) -> None:
    """An 8-bit network's float source (models/float/, what `export quantize` re-makes it
    from) takes the same finishing steps, so the two cards stay one."""
    from export.defaults import edit_card
    source = network.parent / "float" / network.name
    if source.exists():
        edit_card(source, lambda c: c.update(pipeline=card["pipeline"],
                                             calibration=card["calibration"]))


def _cell(f: dict) -> str:
    if f["kind"] == "curve":
        return f"{f['generated']:.4f}" + ("" if f["verdict"] == "within noise" else " ✗")
    rel = 100 * (f["generated"] / f["reference"] - 1) if f["reference"] else float("nan")
    return f"{rel:+.1f} %" + ("" if f["verdict"] == "within noise" else " ✗")


def report(results: list[dict], command: str) -> str:
    names = ["radial spectrum, mean abs. difference", "pair correlation, mean abs. difference",
             "mean nearest-neighbour distance x sqrt(n)", "smallest distance x sqrt(n)",
             "star L2 discrepancy"]
    lines = ["# Finishing steps: the model cards' against `trainer calibrate`'s", "",
             f"`{command}`: each model's section names its run and CPU "
             f"({os.cpu_count()} cores). For each shipped model, the finishing steps "
             "`python -m trainer calibrate` chooses from held-in sets of its sampler "
             "(trainer/fitting/calibrate.py: structure, minimum spacing, then the searched "
             "steps) beside those its card carries, and the figures each gives against "
             "HELD-OUT sets of the sampler (never calibrated on), same seeds. Curves: mean "
             "absolute difference, floor in the heading; means: relative difference of the "
             "mean; ✗: beyond twice its noise (the fit report's verdict). Non-uniform models "
             "after the exact unwarping. The searched steps are taken only where they beat "
             "leaving them out by more than three standard errors of the gain on the held-in "
             "sets, so few sets keep a card short, and the integration figures (star L2, "
             "Gaussian integration error) veto and mend as the module says; each step's note "
             "lists every candidate's figures. What a card carries for sizes the examples "
             "lack (above the largest size a model has sets of, a thinned "
             "set's restore cut, a net's first-n prefix) cannot be chosen here and shows as "
             "a difference in the steps, not in these figures.", ""]
    lines += ["## Summary at each model's largest example size", "",
              "| model | ships | n | sets a side | structure found | calibrated steps | "
              "spectrum MAE: card / calibrated (floor) | smallest distance: card / calibrated "
              "| star L2: card / calibrated |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        n = list(r["sets"])[-1]
        card, cal = ({f["name"]: f for f in r["figures"][w][n]} for w in ("card", "calibrated"))
        spec, mind, l2 = names[0], names[3], names[4]
        steps = ", ".join(dict.fromkeys(line.split(":")[0] for line in r["calibrated_pipeline"]))
        ships = ("card (calibrated one taken back)" if r.get("reverted") else
                 "calibrated (adopted)" if r.get("adopted") else "card")
        lines.append(f"| {r['model']} | {ships} | {n} | {r['sets'][n]} | {r['structure'] or 'none'} | "
                     f"{steps} | {card[spec]['generated']:.4f} / {cal[spec]['generated']:.4f} "
                     f"({card[spec]['noise']:.4f}) | {_cell(card[mind])} / {_cell(cal[mind])} | "
                     f"{_cell(card[l2])} / {_cell(cal[l2])} |")
    lines.append("")
    for r in results:
        lines += [f"## {r['model']} (network `{r['network']}`, sampler {r['sampler']})", "",
                  "Sets a side: " + ", ".join(f"{c} at n = {n}" for n, c in r["sets"].items())
                  + f"; structure found in every held-in set: {r['structure'] or 'none'}; "
                  f"calibration took {r['calibrate_s']} s"
                  + ("; adopted: the shipped model now carries the calibrated steps, and "
                     "'card' is the card it replaced (hand-typed, or an earlier "
                     "calibration's)" if r.get("adopted") and not r.get("reverted") else "")
                  + (f"; adopted by this run, then taken back: {r['reverted']}"
                     if r.get("reverted") else "")
                  + f" (`{r['command']}` on {r['cpu']}).", "",
                  "| | card | calibrated |", "|---|---|---|"]
        steps = max(len(r["card_pipeline"]), len(r["calibrated_pipeline"]))
        for i in range(steps):
            a = r["card_pipeline"][i] if i < len(r["card_pipeline"]) else ""
            b = r["calibrated_pipeline"][i] if i < len(r["calibrated_pipeline"]) else ""
            lines.append(f"| step {i} | {a} | {b} |".replace("\n", " "))
        lines += ["", "| n | pipeline | " + " | ".join(names) + " |",
                  "|---|---|" + "---|" * len(names)]
        for n in r["sets"]:
            floors = {f["name"]: f["noise"] for f in r["figures"]["card"][n]
                      if f["kind"] == "curve"}
            for which in ("card", "calibrated"):
                figs = r["figures"][which][n]
                by = {f["name"]: f for f in figs}
                lines.append(f"| {n} | {which} | " + " | ".join(
                    _cell(by[k]) + (f" (floor {floors[k]:.4f})" if k in floors and which == "card"
                                    else "") if k in by else "–" for k in names) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main() -> None:
    import diffsampler_rt
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", default=diffsampler_rt.list_models())
    p.add_argument("--sets", type=int, default=64, help="held-in and held-out sets a size")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--report-only", action="store_true", help="rewrite the report from the "
                   "kept calibration.json")
    p.add_argument("--sizes", type=int, nargs="+", default=list(SIZES),
                   help="example sizes (squares; fast samplers only beyond 64, 256, 1024)")
    p.add_argument("--adopt", action="store_true", help="write the calibrated card into the "
                   "model's network in models/ and its shipped copy (their fidelity rows "
                   "must then be measured again)")
    p.add_argument("--taken-back", nargs=2, action="append", default=[],
                   metavar=("MODEL", "WHY"), help="record that MODEL's adopted card was taken "
                   "back (its files restored from git), and why, e.g. the fidelity report's "
                   "new misses; the report says so in its row (rewrites the report only)")
    a = p.parse_args()
    stored = RESULTS / "calibration.json"
    results = json.loads(stored.read_text()) if stored.exists() else []
    for name, why in a.taken_back:
        rows = [r for r in results if r["model"] == name and r.get("adopted")]
        if not rows:
            p.error(f"--taken-back {name}: no adopted row of that model in {stored}")
        rows[0]["reverted"] = why
    if a.taken_back:
        stored.write_text(json.dumps(results, indent=1, default=str))
    for name in [] if a.report_only or a.taken_back else a.models:
        t = time.monotonic()
        r = run_model(name, a.sets, a.seed, a.adopt, tuple(a.sizes))
        r["adopted"] = a.adopt
        r["command"] = "python benchmarks/calibration.py " + " ".join(sys.argv[1:])
        r["cpu"] = cpu_description()
        # read again: another run may have written its models meanwhile
        results = json.loads(stored.read_text()) if stored.exists() else []
        results = [x for x in results if x["model"] != name] + [r]
        results.sort(key=lambda x: x["model"])
        stored.write_text(json.dumps(results, indent=1, default=str))
        print(f"{name}: {time.monotonic() - t:.0f} s", flush=True)
    command = "python benchmarks/calibration.py [--models ...] [--sets S] [--adopt]"
    (RESULTS / "calibration.md").write_text(report(results, command))
    print(f"wrote {RESULTS / 'calibration.md'}")


if __name__ == "__main__":
    main()
