"""Distilled few-step students vs their teachers, side by side with the reference sampler.

For every bundled model whose card has a ``distillation`` record (or the --models given),
and each n in --sizes, four rows against the same cached reference batch as
benchmarks/fidelity.py: the teacher at its own default, the teacher cut to the student's
number of steps (DDIM and DPM-Solver++(2M)), and the student at its default. Columns as in
benchmarks/solver_sweep.py (spectrum MAE with the floor between two reference batches,
relative differences of mean OT energy, L2*, integration MSEs and minimum distance; time per
set of a batched call). Before them, at n = 1024, how close each fast setting comes to the
teacher's own default output (what distillation aims at; no reference sampler needed).
Writes benchmarks/results/distilled.md.

    python benchmarks/distilled.py [--models gbn_fast] [--sizes 256 576 1024] [--sets 64]
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from trainer import zoo  # noqa: E402
zoo.use()  # model names are the repository's networks (models/), not the wheel's copies

import diffsampler_rt  # noqa: E402
from diffsampler_rt.card import describe_devices  # noqa: E402
from benchmarks.fidelity import TOL_MEAN, TOL_MIND  # noqa: E402
from benchmarks.solver_sweep import compare, table  # noqa: E402
from trainer.stats import min_distance, radial_spectrum, spectrum_mae  # noqa: E402


def students() -> list[str]:
    return [m for m in zoo.networks()
            if diffsampler_rt.load(m).card.get("distillation")]


def runs_for(student: str) -> list[tuple[str, str, str, int]]:
    card = diffsampler_rt.load(student).card
    teacher = card["distillation"]["teacher"]
    tcard = diffsampler_rt.load(teacher).card
    solver, steps = card["default_solver"], card["default_steps"]
    return [(f"{teacher}, {tcard['default_solver']} {tcard['default_steps']} (teacher default)",
             teacher, tcard["default_solver"], tcard["default_steps"]),
            (f"{teacher}, ddim {steps}", teacher, "ddim", steps),
            (f"{teacher}, dpmpp_2m {steps}", teacher, "dpmpp_2m", steps),
            (f"**{student}, {solver} {steps} (distilled)**", student, solver, steps)]


def to_teacher(student: str, n: int, sets: int) -> list[str]:
    """How close each fast setting comes to the teacher at its default (no reference sampler:
    cheap, so many sets). Floor: the teacher at its default from other noise."""
    card = diffsampler_rt.load(student).card
    teacher = diffsampler_rt.load(card["distillation"]["teacher"])
    base = teacher.generate(n, sets, seed=100)
    spec, mind = radial_spectrum(base)[1], min_distance(base).mean()
    lines = [f"Closeness to the teacher at its default, n = {n}, {sets} sets a side:", "",
             "| setting | spectrum MAE to the teacher | min distance vs the teacher |",
             "|---|---|---|"]
    runs = [("teacher default, other noise (floor)", teacher.name, None, None)] + [
        (label, model, solver, steps) for label, model, solver, steps in runs_for(student)[1:]]
    for label, model, solver, steps in runs:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gen = diffsampler_rt.load(model).generate(n, sets, seed=1, solver=solver, steps=steps)
        lines.append(f"| {label} | {spectrum_mae(radial_spectrum(gen)[1], spec):.4f} | "
                     f"{100 * (min_distance(gen).mean() / mind - 1):+.1f} % |")
        print(student, n, lines[-1], flush=True)
    return lines + [""]


def effort(d: dict) -> str:
    """"1500 optimiser steps, 35 min", with the earlier stages of a staged distillation."""
    text = f"{d['steps']} optimiser steps, {d['seconds'] / 60:.0f} min"
    if d.get("earlier_steps"):
        text += (f" after {d['earlier_steps']} steps ({d['earlier_seconds'] / 60:.0f} min) in "
                 "earlier stages")
    return text


def quantised(card: dict) -> str:
    """How the student's file differs from the network the distillation made, if it does."""
    if card.get("weights") != "int8":
        return ""
    return ("; its convolutions then quantised to 8 bits (`python -m export quantize`, "
            "benchmarks/results/quantized.md)")


def write_report(out: Path) -> None:
    """``out`` from the sections kept beside it, naming the students that have none yet."""
    kept = out.parent / "distilled"
    header = ["# Distilled students vs their teachers", "",
              f"`python benchmarks/distilled.py` ({os.cpu_count()} cores; ms/set is one "
              "batched call here, taken while other jobs ran: indicative only, "
              "benchmarks/results/speed.md has the clean timings). Every row: generated vs "
              "reference batch A (the sets of benchmarks/fidelity.py); the first row is an "
              "independent reference batch B (the noise floor). Relative differences of the "
              f"means; ✗: beyond ±{100 * TOL_MEAN:.0f} % (min distance ±{100 * TOL_MIND:.0f} "
              "%). Trained sides: 8, 16, 32 (n = 64, 256, 1024); 576 is unseen. Each model's "
              "section is kept in benchmarks/results/distilled/ and says how it was run.", ""]
    missing = [m for m in students() if not (kept / f"{m}.md").exists()]
    if missing:
        header += ["Not measured here yet: " + ", ".join(f"`{m}`" for m in missing)
                   + " (their fidelity against the sampler is in fidelity.md).", ""]
    sections = [p.read_text() for p in sorted(kept.glob("*.md"))]
    out.write_text("\n".join(header + sections))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", help="students (default: every distilled bundled model)")
    p.add_argument("--sizes", type=int, nargs="*", default=[256, 576, 1024])
    p.add_argument("--sets", type=int, default=64, help="sets per row (and reference batch)")
    p.add_argument("--ref-sets", type=int, nargs=3, metavar=("FAST", "SLOW", "SLOW_4096"),
                   default=[128, 64, 16],
                   help="reference sets per batch as in fidelity.py (--sets, --slow-sets, "
                        "--slow-4096; slow samplers use FAST at n = 1024): its cache is reused")
    p.add_argument("--teacher-sets", type=int, default=128,
                   help="sets a side for the closeness to the teacher (n = 1024)")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "distilled.md")
    a = p.parse_args()
    models = a.models or students()
    refs = argparse.Namespace(sets=a.ref_sets[0], slow_sets=a.ref_sets[1],
                              slow_4096=a.ref_sets[2], spectrum_sets=1024)
    kept = a.out.parent / "distilled"
    kept.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(a.workers) as pool:
        for name in models:
            card = diffsampler_rt.load(name).card
            d = card["distillation"]
            lines = [f"## {name}", "",
                     f"Distilled from `{d['teacher']}` ({d['config']['teacher_solver']} "
                     f"{d['config']['teacher_steps']} steps as teacher) to "
                     f"{card['default_solver']} {card['default_steps']} steps: "
                     f"{effort(d)} on {describe_devices(d.get('devices'))} (shared with "
                     "other jobs)"
                     f"{quantised(card)}. Measured {dt.date.today().isoformat()} with `--sets {a.sets} "
                     f"--ref-sets {' '.join(map(str, a.ref_sets))}`.", ""]
            lines += to_teacher(name, 1024, a.teacher_sets)
            for n in a.sizes:
                rows = compare(pool, card["sampler"], n, runs_for(name), a, refs)
                lines += [f"### n = {n} ({rows[0]['count']} sets a side)", ""] + table(rows) + [""]
            (kept / f"{name}.md").write_text("\n".join(lines))
    write_report(a.out)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
