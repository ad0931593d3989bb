"""The repository's networks, ``models/NAME.onnx``: every trained, distilled and guide
network under its own name (the runtime wheel ships one of them per sampler, under the
sampler's name). The trainer names teachers, starting points and cards by these names."""
from __future__ import annotations

import os
from pathlib import Path

import diffsampler_rt

#: the repository's model folder (``models/guides/``: networks kept only to guide others)
ZOO_DIR = Path(__file__).resolve().parents[1] / "models"


def networks() -> list[str]:
    """Names of the repository's networks (``models/*.onnx``; guides and float copies not
    included)."""
    return sorted(p.stem for p in ZOO_DIR.glob("*.onnx"))


def resolve(model: str | os.PathLike) -> Path:
    """A network name -> ``models/NAME.onnx`` where the repository has it; anything else
    (paths, bundled names) as the runtime resolves it."""
    if isinstance(model, str) and "/" not in model and os.sep not in model:
        path = ZOO_DIR / f"{model}.onnx"
        if path.is_file():
            return path
    return diffsampler_rt.model.resolve(model)


def use() -> None:
    """Bare names resolve to the repository's networks first, in this process and the
    processes it starts (the runtime's ``DIFFSAMPLER_MODELS`` search path): the benchmarks
    measure networks by these names, not the wheel's one-per-sampler copies."""
    from diffsampler_rt.model import MODELS_ENV, search_path
    folders = [str(p) for p in search_path()]
    if str(ZOO_DIR) not in folders:
        os.environ[MODELS_ENV] = os.pathsep.join([str(ZOO_DIR), *folders])
