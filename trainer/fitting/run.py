"""``fit``: examples -> analysis -> held-out split -> pools -> training within a time budget
-> ONNX export -> calibrated finishing steps -> report. Restartable: a killed fit run
again with the same arguments resumes from its last checkpoint (``OUT/NAME.run/``)."""
from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .analysis import analyse, describe
from .data import ExampleBatches, batch_size, pool, split, training_sides
from .examples import read_examples

#: the default budget: training minutes on the machine it runs on (2 CPU cores: a usable
#: model within about half an hour with the export, calibration and report)
DEFAULT_MINUTES = 20.0
#: held-in sets embedded per training size at most
POOL_CAP = 2048
#: the bundled models' architecture, so that any of them can start a fit (--init)
UNET = {"attention_levels": (2,), "attention_window": 8, "base_channels": 32,
        "channel_mult": (1, 2, 2), "num_res_blocks": 2, "middle_attention": True}
#: network presets: "standard" (the bundled models', 1.6 M parameters) and "small" (about
#: 30 k parameters: quick trials and tests, not fidelity)
NETS = {"standard": UNET,
        "small": {"attention_levels": (1,), "attention_window": 8, "base_channels": 8,
                  "channel_mult": (1, 2), "num_res_blocks": 1, "middle_attention": True,
                  "num_heads": 2, "groups": 4}}


@dataclass(frozen=True)
class FitResult:
    model: Path
    report: Path
    figure: Path
    card: dict = field(repr=False)
    #: with ``fast``: the few-step student's result
    fast: "FitResult | None" = None


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name):
        raise ValueError(f"name must be 1-64 letters, digits, '_', '-' or '.', starting with "
                         f"a letter or digit, got {name!r}")
    return name


def _init_path(init: str | os.PathLike | None) -> str | None:
    if init is None:
        return None
    from .. import zoo
    return str(zoo.resolve(init))


def _config(name: str, analysis, sides: list[int], pools: dict[int, np.ndarray], *,
            init: str | None, seed: int, threads: int, steps: int, density: dict | None,
            net: str = "standard", bf16: bool = False):
    from ..config import DataConfig, TrainConfig
    from ..unet import UNetConfig
    data = DataConfig(sampler=f"examples:{name}", embedding=analysis.embedding,
                      sizes=tuple(sides), batch_sizes=tuple(batch_size(k) for k in sides),
                      pool_sizes=tuple(len(pools[k]) for k in sides),
                      symmetries=tuple(analysis.symmetries),
                      shifts=4 if analysis.toroidal else 1)
    padding = "circular" if analysis.toroidal else "zeros"
    if init:  # the model it starts from decides the architecture (any bundled one)
        from ..warm_start import net_from_onnx
        unet = replace(net_from_onnx(Path(init))[1].unet, padding=padding)
    else:
        unet = UNetConfig(**NETS[net], padding=padding)
    return TrainConfig(name=name, data=data, unet=unet, steps=steps,
                       lr=2.5e-4 if init else 5e-4, warmup_steps=min(100, steps // 10),
                       seed=seed, threads=threads, checkpoint_every_s=60.0, bf16=bf16,
                       init_from=init, default_sample_steps=20, default_solver="dpmpp_2m")


def uses_bf16(bf16: bool | None, device: str) -> bool:
    """Whether a fit trains with bf16 autocast: as asked, or (None) where ``device``
    computes bfloat16 natively."""
    if bf16 is not None:
        return bool(bf16)
    import torch

    from ..train import native_bf16
    return native_bf16(torch.device(device))


def _steps_for(cfg, batches, seconds: float, device: str) -> int:
    """Training steps that fit ``seconds``: a few steps timed on a throwaway copy."""
    import tempfile

    from ..train import Trainer
    with tempfile.TemporaryDirectory() as tmp:
        probe = Trainer(replace(cfg, steps=10**6, init_from=None), tmp, progress=False,
                        device=device, batches=batches)
        probe.train_step()
        t = time.perf_counter()
        for _ in range(3):
            probe.train_step()
        per_step = (time.perf_counter() - t) / 3
    return max(20, int(0.95 * seconds / per_step))


def _distributed(device: str) -> tuple[int, int, str]:
    """(rank, world size, device) of a ``torchrun`` launch (torch.distributed set up: gloo
    on CPUs, nccl on GPUs, one GPU per process), or (0, 1, device) for a single process."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world == 1:
        return 0, 1, device
    import torch.distributed as dist
    cuda = device.startswith("cuda")
    if not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    if cuda:
        device = f"cuda:{os.environ.get('LOCAL_RANK', '0')}"
    return dist.get_rank(), dist.get_world_size(), device


def _barrier(world: int) -> None:
    if world > 1:
        import torch.distributed as dist
        dist.barrier()


def fit(examples: Sequence[Any] | Any, *, name: str, out: str | os.PathLike = ".",
        minutes: float = DEFAULT_MINUTES, init: str | os.PathLike | None = None,
        device: str = "cpu", symmetries: Sequence[int] = (0,), toroidal: bool = False,
        seed: int = 0, threads: int | None = None, net: str = "standard",
        bf16: bool | None = None, fast: bool = False, progress: bool = True,
        log=print) -> FitResult | None:
    """Learn a sampler from example point sets; returns the paths of ``NAME.onnx``, its
    report and figure (in ``out``).

    Parameters
    ----------
    examples : files, folders or arrays
        Example sets (:func:`trainer.fitting.examples.read_examples`): (S, n, 2) or (n, 2)
        arrays, ``.npy`` files, ``diffsampler generate`` ``.txt`` / ``.csv`` files, or text
        files of ``x y`` lines; any mix of sizes n = k*k, k >= 4.
    name : str
        The model's name (``NAME.onnx``).
    minutes : float
        Training budget (the analysis, export, calibration and report come on top).
    init : str or path, optional
        Start from the weights of a bundled model or an exported file (fine-tuning).
    symmetries, toroidal
        Invariances you assert (symmetries of the square 0-7, translations on the torus):
        used as augmentations; the examples are checked against them (a warning where they
        disagree).
    net : {"standard", "small"}
        The network: the bundled models' (what ``init`` needs), or a small one for trials.
    bf16 : bool, optional
        bfloat16 autocast in training (weights, optimiser and export stay float32). The
        default, None, uses it where the device computes it natively (CPUs with AMX or
        avx512_bf16: about 1.6x the steps in a budget); elsewhere it is emulated and many
        times slower.
    fast : bool
        Also distil the model into a 6-step student (``NAME_fast.onnx``, calibrated and
        reported the same way), for half as many minutes again.

    Returns
    -------
    FitResult
        The paths and the card; None in the other processes of a ``torchrun`` launch.

    Examples
    --------
    >>> import trainer
    >>> from trainer.samplers import sample
    >>> sets = sample("sot", 64, count=32, seed=1)           # doctest: +SKIP
    >>> trainer.fit(sets, name="mine", out="/tmp", minutes=2)  # doctest: +SKIP
    """
    name = _check_name(name)
    if not (isinstance(minutes, (int, float)) and not isinstance(minutes, bool)
            and 0 < minutes <= 7 * 24 * 60):
        raise ValueError(f"minutes must be a number in (0, 10080], got {minutes!r}")
    if net not in NETS:
        raise ValueError(f"net must be one of {list(NETS)}, got {net!r}")
    if init is not None and net != "standard":
        raise ValueError("init takes the architecture of the model it starts from; leave "
                         "net at 'standard'")
    bad = [g for g in symmetries if g not in range(8)]
    if bad:
        raise ValueError(f"symmetries must be integers 0-7 (the symmetries of the square), "
                         f"got {bad[0]!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output {out} exists and is not a folder")
    init_path = _init_path(init)
    rank, world, device = _distributed(device)
    if rank:
        log = lambda *a, **k: None  # noqa: E731  (the first process speaks for all)
    ex = read_examples(examples)  # every set checked before any work
    sp = split(ex, seed)
    threads = threads or max(1, min(os.cpu_count() or 1, 8))
    log("examples: " + ", ".join(f"{ex.count(n)} sets of n = {n} ({len(sp.held_out[n])} "
                                  "held out)" for n in ex.sizes))
    analysis = analyse(ex, symmetries=list(symmetries), toroidal=toroidal)
    for line in describe(analysis):
        log(line)
    out.mkdir(parents=True, exist_ok=True)
    run_dir = out / f"{name}.run"
    started = time.monotonic()
    sides = training_sides(ex.sizes)
    density = None
    if not analysis.uniform:
        from ..density import fit_density_legendre
        held = [ex.take(k * k, sp.held_in[k * k][:POOL_CAP]) for k in sides]
        density, degree = fit_density_legendre(held, 64, max_degree=16,
                                               sizes=held if len(held) > 1 else None)
        log(f"density: Legendre series of degree {degree} fitted to the held-in sets "
            "(the net learns the sets mapped to the square; the runtime maps them back)")
    # each data-parallel process embeds and draws from its own shard of the held-in sets
    pools = {k: pool(ex, k * k, sp.held_in[k * k][rank::world][:POOL_CAP // world],
                     analysis.embedding, density=density, shifts=4 if toroidal else 1,
                     seed=seed, progress=progress and not rank)
             for k in sides}
    batches = ExampleBatches(pools, {k: batch_size(k) for k in sides}, 2.0,
                             tuple(analysis.symmetries), density=density)
    from ..train import Trainer
    if not rank:  # the first process sizes the run; the others read its config
        bf16 = uses_bf16(bf16, device)
        cfg, fresh = _load_or_make_config(run_dir, name, analysis, sides, pools, batches,
                                          init_path, seed, threads, minutes, density,
                                          device, net, bf16)
        trainer = Trainer(cfg, run_dir, progress=progress, device=device, batches=batches)
        if fresh:  # kept only once the trainer took it (a bad --init leaves no config)
            _save_config(run_dir, cfg)
    _barrier(world)
    if rank:
        from ..config import TrainConfig
        cfg = TrainConfig.load(run_dir / "fit_config.json")
        trainer = Trainer(cfg, run_dir / f"rank{rank}", progress=False, device=device,
                          batches=batches)
    # data-parallel processes must take the same number of steps: no wall-clock stop there
    trainer.run(max_seconds=None if world > 1 else max(1.0, 60 * minutes - trainer.elapsed))
    log(f"trained {trainer.step} of {cfg.steps} steps in {trainer.elapsed / 60:.1f} min"
        + (f" on {world} processes" if world > 1 else ""))
    _barrier(world)
    if rank:
        return None
    model = out / f"{name}.onnx"
    _export(run_dir, model, ex, sp, analysis, init_path)
    held_in = {n: ex.take(n, sp.held_in[n][:1024]) for n in ex.sizes}
    result = _calibrate_and_report(model, held_in, ex, sp, analysis, seed, log,
                                   f"Fit: {time.monotonic() - started:.0f} s in all, "
                                   f"{trainer.step} training steps.")
    if fast:
        from .fast import distil
        started = time.monotonic()
        path = distil(model, name, out, sides, minutes / 2, seed=seed, threads=threads,
                      device=device, progress=progress)
        student = _calibrate_and_report(path, held_in, ex, sp, analysis, seed, log,
                                        f"Distilled from {model.name} in "
                                        f"{time.monotonic() - started:.0f} s.")
        result = replace(result, fast=student)
    return result


def _calibrate_and_report(model: Path, held_in, ex, sp, analysis, seed: int, log,
                          note: str) -> FitResult:
    """A trained model's finishing steps from the held-in sets, then its report against the
    held-out ones (``MODEL.report.md``, ``.png``, ``.json`` beside it)."""
    from .calibrate import calibrate
    from .evaluate import report
    card = calibrate(model, held_in, analysis.structure, analysis.structure_sizes,
                     seed=seed, log=log)
    md, png = report(model, ex, sp, analysis, model.with_suffix(".report.md"), extra=[note])
    log(f"wrote {model}, {md}, {png}")
    return FitResult(model, md, png, card)


def _load_or_make_config(run_dir: Path, name, analysis, sides, pools, batches, init, seed,
                         threads, minutes, density, device, net, bf16):
    """(the run's config, whether it is new): read back on a restart (so that it resumes
    exactly), else made with as many steps as the budget allows."""
    from ..config import TrainConfig
    saved = run_dir / "fit_config.json"
    if saved.exists():
        return TrainConfig.load(saved), False
    draft = _config(name, analysis, sides, pools, init=init, seed=seed, threads=threads,
                    steps=10**6, density=density, net=net, bf16=bf16)
    steps = _steps_for(draft, batches, 60 * minutes, device)
    return replace(draft, steps=steps, warmup_steps=min(100, steps // 10)), True


def _save_config(run_dir: Path, cfg) -> None:
    saved = run_dir / "fit_config.json"
    run_dir.mkdir(parents=True, exist_ok=True)
    tmp = saved.with_suffix(".tmp")
    tmp.write_text(json.dumps(cfg.to_dict(), indent=1))
    os.replace(tmp, saved)


def _export(run_dir: Path, model: Path, ex, sp, analysis, init: str | None) -> None:
    """The run's EMA weights as ``model`` (written beside, then moved: never half-written),
    with the fit's record in the card."""
    import torch

    from export import export_checkpoint

    from ..train import CHECKPOINT, load_checkpoint
    ckpt = run_dir / CHECKPOINT
    state = load_checkpoint(ckpt)
    state["card_extra"] = {"fit": {
        "examples": {str(n): {"sets": ex.count(n), "held_out": len(sp.held_out[n])}
                     for n in ex.sizes},
        "analysis": analysis.to_dict(), "init_from": init},
        "provenance": f"learned from example sets by `python -m trainer fit` for "
                      f"{state['step']} steps" + (f", starting from {init}" if init else "")}
    torch.save(state, run_dir / "export.pt")
    tmp = model.with_suffix(".partial.onnx")
    export_checkpoint(run_dir / "export.pt", tmp, parity_sides=(8, 16), tolerance=1e-3)
    os.replace(tmp, model)
    (run_dir / "export.pt").unlink()
