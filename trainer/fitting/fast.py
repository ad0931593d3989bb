"""``fit --fast``: the fitted model distilled into a few-step student (as the bundled
``_fast`` models were made, :mod:`trainer.distil`), within a time budget of its own."""
from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

#: the student's solver steps (the bundled students' default)
STUDENT_STEPS = 6
#: teacher trajectories per grid size (the teacher runs them once, cached)
TRAJECTORIES = 512


def _distiller(cfg, run_dir, device: str):
    """The first Distiller of a fit's student, or a ValueError that says what to do where the
    teacher's file cannot be read back into torch (a barely trained net's still-equal
    initial tensors are stored once for several layers)."""
    from ..distil import Distiller
    from ..warm_start import MissingWeightsError
    try:
        return Distiller(cfg, run_dir, progress=False, device=device)
    except MissingWeightsError as err:
        raise ValueError(f"{Path(cfg.teacher).name} is trained too briefly to distil (some "
                         "layers still hold their initial values): fit it for more minutes, "
                         "then run the same command with --fast") from err


def distil(teacher: Path, name: str, out: Path, sides: list[int], minutes: float, *,
           seed: int = 0, threads: int = 1, device: str = "cpu",
           progress: bool = True) -> Path:
    """``OUT/NAME_fast.onnx``: a student of ``teacher`` trained for about ``minutes``
    (its teacher's trajectories included); resumes from ``OUT/NAME_fast.run/``."""
    from export import export_checkpoint

    from ..distil import DistilConfig, Distiller
    from .data import batch_size
    cfg = DistilConfig(teacher=str(teacher), name=f"{name}_fast", student_steps=STUDENT_STEPS,
                       teacher_steps=24, teacher_solver="dpmpp_2m", sizes=tuple(sides),
                       trajectories=tuple(TRAJECTORIES for _ in sides),
                       batch_sizes=tuple(batch_size(k) for k in sides), steps=10**6,
                       lr=1e-4, warmup_steps=20, seed=seed, threads=threads,
                       checkpoint_every_s=60.0)
    run_dir = out / f"{name}_fast.run"
    started = time.monotonic()
    saved = run_dir / "fast_config.json"
    if saved.exists():
        cfg = DistilConfig.load(saved)
    else:
        with tempfile.TemporaryDirectory() as tmp:  # the trajectories get cached here too
            probe = _distiller(cfg, tmp, device)
            probe.train_step()
            t = time.perf_counter()
            for _ in range(2):
                probe.train_step()
            per_step = (time.perf_counter() - t) / 2
        left = 60 * minutes - (time.monotonic() - started)
        cfg = replace(cfg, steps=max(20, int(0.95 * left / per_step)))
        run_dir.mkdir(parents=True, exist_ok=True)
        tmp_path = saved.with_suffix(".tmp")
        tmp_path.write_text(json.dumps(cfg.to_dict(), indent=1))
        os.replace(tmp_path, saved)
    student = Distiller(cfg, run_dir, progress=progress, device=device)
    student.run()
    model = out / f"{name}_fast.onnx"
    partial = model.with_suffix(".partial.onnx")
    export_checkpoint(run_dir / "checkpoint.pt", partial, parity_sides=(8, 16), tolerance=1e-3)
    os.replace(partial, model)
    return model
