"""The shipped models' catalogue, generated from their cards and the reports: writes
diffsampler_rt/models/catalogue.json (what ``diffsampler list`` prints) and the "Which model
to use" table in README.md (between its catalogue markers).

    python benchmarks/catalogue.py

Each shipped model is a copy of a repository network (models/NAME.onnx); its figures are
that network's rows in benchmarks/results/speed.json (time per 1024-point set, batched and
alone) and benchmarks/results/fidelity.json (radial-spectrum mean absolute difference at
n = 1024 against the reference sampler, with its noise floor). Rerun it after either report
or a shipped model changes; tests/test_catalogue.py checks that nothing drifted.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SPEED = ROOT / "benchmarks" / "results" / "speed.json"
FIDELITY = ROOT / "benchmarks" / "results" / "fidelity.json"
CATALOGUE = ROOT / "diffsampler_rt" / "models" / "catalogue.json"
README = ROOT / "README.md"
BEGIN, END = "<!-- catalogue:begin -->\n", "<!-- catalogue:end -->"
#: at most this many example sets a grid size: the model's line says it learned from few
FEW_SETS = 64


def _network(path: Path) -> str:
    """The repository network a shipped model is a byte copy of."""
    data = path.read_bytes()
    for candidate in sorted((ROOT / "models").glob("*.onnx")):
        if candidate.stat().st_size == len(data) and candidate.read_bytes() == data:
            return candidate.stem
    raise ValueError(f"{path.name} is not a copy of any network in models/")


def _imitates(card: dict) -> str:
    from trainer.samplers import DESCRIPTIONS
    text = DESCRIPTIONS[card["sampler"]]
    pools = card.get("config", {}).get("data", {}).get("pool_sizes") or []
    if pools and 0 < max(pools) <= FEW_SETS:
        text += f", learned from {max(pools)} example sets a grid size"
    return text


def entry(name: str, speed: dict, fidelity: dict) -> dict:
    """One shipped model's line of the catalogue."""
    import diffsampler_rt
    path = diffsampler_rt.model.MODELS_DIR / f"{name}.onnx"
    card = diffsampler_rt.Model(path).card
    network = _network(path)
    timed = speed.get(network, {}).get("rows", {}).get("1024", {})
    fid = fidelity.get(network, {}).get("1024", {})
    return {"network": network, "imitates": _imitates(card),
            "solver": card["default_solver"], "steps": card["default_steps"],
            "trained_sizes": card["trained_sizes"],
            "ms_per_set_1024": _ms(timed.get("batch_s_per_set")),
            "ms_alone_1024": _ms(timed.get("alone_s")),
            "speed_cpu": speed.get(network, {}).get("cpu"),
            "spectrum_mae_1024": _round(fid.get("mae")), "noise_floor_1024": _round(fid.get("floor"))}


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else round(1000 * seconds, 1)


def _round(x: float | None) -> float | None:
    """Two significant digits; rounding error (the lattices' exact sets) is 0."""
    return None if x is None else 0.0 if abs(x) < 1e-12 else float(f"{x:.2g}")


def catalogue() -> dict:
    """name -> entry for every shipped model, from the cards and the two reports."""
    import diffsampler_rt
    speed, fidelity = json.loads(SPEED.read_text()), json.loads(FIDELITY.read_text())
    return {name: entry(name, speed, fidelity) for name in diffsampler_rt.list_models()}


def readme_table(cat: dict) -> str:
    """The README's "Which model to use" table."""
    lines = ["| model | imitates | network | sampling | ms a set at n = 1024 "
             "([speed](benchmarks/results/speed.md)) | spectrum MAE at 1024, noise floor "
             "([fidelity](benchmarks/results/fidelity.md)) |",
             "|---|---|---|---|---|---|"]
    for name, e in cat.items():
        ms = "–" if e["ms_per_set_1024"] is None else f"{e['ms_per_set_1024']:g}"
        mae = ("–" if e["spectrum_mae_1024"] is None
               else f"{e['spectrum_mae_1024']:g} ({e['noise_floor_1024']:g})")
        lines.append(f"| `{name}` | {e['imitates']} | [`{e['network']}`](docs/models.md) | "
                     f"{e['solver']}, {e['steps']} steps | {ms} | {mae} |")
    return "\n".join(lines) + "\n"


def with_table(readme: str, table: str) -> str:
    head, rest = readme.split(BEGIN, 1)
    return head + BEGIN + table + END + rest.split(END, 1)[1]


def main() -> None:
    cat = catalogue()
    CATALOGUE.write_text(json.dumps(cat, indent=1) + "\n")
    README.write_text(with_table(README.read_text(), readme_table(cat)))
    print(f"wrote {CATALOGUE.relative_to(ROOT)} and README.md's table ({len(cat)} models)")


if __name__ == "__main__":
    main()
