"""Measure a fitted model against its held-out example sets and write the report
(:mod:`.report` has the figures and their noise)."""
from __future__ import annotations

import json
import math
from pathlib import Path

from .analysis import describe
from .report import compare, write_report

#: generated sets per size (the held-out side has what the split kept, up to 512)
GENERATED = 128
#: the larger size no example has: twice the largest example grid side, at most 4096 points
UNSEEN_MAX = 4096


def unseen_size(sizes: list[int]) -> int:
    k = math.isqrt(max(sizes))
    return min(UNSEEN_MAX, (2 * k) ** 2) if (2 * k) ** 2 > max(sizes) else max(sizes)


def report(model_path: Path, ex, sp, analysis, md: Path, *, seed: int = 12345,
           extra: list[str] | None = None) -> tuple[Path, Path]:
    """Generate at every example size and one larger, compare, write ``md``, its png and
    the figures as JSON (``md`` with the suffix .json)."""
    import diffsampler_rt
    model = diffsampler_rt.Model(model_path)
    rows = []
    largest = max(ex.sizes)
    held = {n: ex.take(n, sp.held_out[n]) for n in ex.sizes}
    for n in ex.sizes:
        gen = model.generate(n, GENERATED, seed=seed)
        figures, curves = compare(gen, held[n], uniform=analysis.uniform)
        rows.append((n, n, figures, curves, gen[0], held[n][0]))
    big = unseen_size(ex.sizes)
    if big != largest:
        gen = model.generate(big, max(16, GENERATED // 4), seed=seed)
        if analysis.uniform:
            figures, curves = compare(gen, held[largest], same_size=False)
            rows.append((big, largest, figures, curves, gen[0], held[largest][0]))
    header = [f"Model `{model_path.name}` ({model.card['training_steps']} training steps) "
              f"against held-out example sets: never trained on, never calibrated on. "
              f"{GENERATED} generated sets a size, seed {seed}.", "",
              "Pipeline after the network: " + "; ".join(
                  f"{i}. {line}" for i, line in enumerate(_describe(model.card))) + ".", "",
              "How each finishing step was chosen: " + " ".join(
                  f"`{c['step']}`: {c['how']}." for c in model.card.get("calibration", [])),
              "", "Analysis of the examples: " + "; ".join(describe(analysis)) + "."] + (["", *extra] if extra else [])
    png = md.with_suffix("").with_suffix(".report.png")
    write_report(md, png, f"{model.name}: generated sets against held-out examples", header,
                 rows)
    figures = {str(n): {f.name: {"generated": f.generated, "reference": f.reference,
                                 "noise": f.noise, "kind": f.kind, "verdict": f.verdict()}
                        for f in figs} | {"compared_with": ref_n}
               for n, ref_n, figs, _, _, _ in rows}
    md.with_suffix(".json").write_text(json.dumps(figures, indent=1))
    return md, png


def _describe(card: dict) -> list[str]:
    from diffsampler_rt.finish.pipeline import describe
    return describe(card["pipeline"])
