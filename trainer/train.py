"""The training loop: loss summed over grid sizes, AdamW, EMA, checkpoints, exact resume."""
from __future__ import annotations

import copy
import csv
import math
import os
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import torch

from .config import TrainConfig
from .data import Batches
from .diffusion import Diffusion
from .unet import UNet, widen_stem

CHECKPOINT = "checkpoint.pt"
LOG = "log.csv"


def lr_at(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up then cosine decay to 10 % of the peak."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    frac = (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps)
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, frac))))


@torch.no_grad()
def update_ema(ema: torch.nn.Module, model: torch.nn.Module, decay: float) -> None:
    for pe, pm in zip(ema.parameters(), model.parameters()):
        pe.mul_(decay).add_(pm, alpha=1 - decay)


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write atomically so a kill mid-write never leaves a broken checkpoint."""
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    return torch.load(path, map_location="cpu", weights_only=False)


def model_from_checkpoint(state: dict[str, Any], ema: bool = True) -> tuple[UNet, TrainConfig]:
    """Rebuild the (EMA by default) network and its config from a checkpoint dict."""
    cfg = TrainConfig.from_dict(state["config"])
    net = UNet(cfg.unet)
    net.load_state_dict(state["ema" if ema else "model"])
    net.eval()
    return net, cfg


def native_bf16(device: torch.device) -> bool:
    """Whether ``device`` computes bfloat16 natively (CPU: avx512_bf16 or AMX, as oneDNN
    reports it). Where it cannot be told, True: no warning rather than a false one."""
    try:
        if device.type == "cpu":
            return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
        if device.type == "cuda":
            return bool(torch.cuda.is_bf16_supported())
    except (AttributeError, RuntimeError):
        pass
    return True


def initial_weights(cfg: TrainConfig) -> dict[str, torch.Tensor]:
    """The weights ``cfg.init_from`` names (an ``.onnx`` export or a checkpoint's EMA)."""
    path = Path(cfg.init_from)
    if not path.is_file():
        raise FileNotFoundError(f"init_from {cfg.init_from!r} does not exist")
    if path.suffix == ".onnx":
        from .warm_start import net_from_onnx
        net, src_cfg, _ = net_from_onnx(path)
    else:
        net, src_cfg = model_from_checkpoint(load_checkpoint(path))
    weights = net.state_dict()
    # the padding mode has no weights: a zero-padded net can start a circular one (a torus)
    if replace(src_cfg.unet, padding=cfg.unet.padding) != cfg.unet:
        more_bits = replace(src_cfg.unet, coord_bits=cfg.unet.coord_bits,
                            padding=cfg.unet.padding) == cfg.unet
        if not (more_bits and cfg.unet.coord_bits > src_cfg.unet.coord_bits):
            raise ValueError(f"init_from {cfg.init_from!r} has architecture {src_cfg.unet}, "
                             f"this config needs {cfg.unet}")
        weights["stem.weight"] = widen_stem(weights["stem.weight"], src_cfg.unet.coord_bits,
                                            cfg.unet.coord_bits)
    return weights


class Trainer:
    """Trains one config in ``run_dir``; resumes exactly from ``run_dir/checkpoint.pt``."""

    def __init__(self, cfg: TrainConfig, run_dir: str | Path, progress: bool = True,
                 device: str = "cpu", workers: int = 1, batches: Any = None):
        self.cfg = cfg
        # not part of the config: a run may move between CPU and GPU and still resume
        self.device = torch.device(device)
        if cfg.bf16 and not native_bf16(self.device):
            # emulated bf16 autocast is many times slower a step than float32 on CPUs
            # without native bf16: a 50-minute recipe would take most of a day
            warnings.warn(f"config {cfg.name!r} asks for bf16 autocast, which this "
                          f"{self.device.type} does not compute natively (no avx512_bf16 or "
                          "AMX): steps run ~16-20x slower than in float32; `python -m "
                          "trainer train --fp32` trains in float32 instead (not the recipe's "
                          "exact numerics)", stacklevel=2)
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.progress = progress
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.model = UNet(cfg.unet).to(self.device)
        self.ema = copy.deepcopy(self.model).requires_grad_(False)
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr,
                                     weight_decay=cfg.weight_decay)
        self.devices = [self.device.type]  # every device this run has trained on
        self.diffusion = Diffusion(cfg.schedule)
        # a fit's examples bring their own batches (trainer.fit.data.ExampleBatches)
        self.batches = batches if batches is not None else Batches(cfg.data, cfg.seed,
                                                                   progress, workers)
        self.rng = np.random.default_rng([cfg.seed, 1])
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.step = 0
        self.elapsed = 0.0
        ckpt = self.run_dir / CHECKPOINT
        if ckpt.exists():
            self._restore(load_checkpoint(ckpt))
        elif cfg.init_from:
            weights = initial_weights(cfg)
            self.model.load_state_dict(weights)
            self.ema.load_state_dict(weights)

    def state(self) -> dict[str, Any]:
        return {"config": self.cfg.to_dict(), "step": self.step, "elapsed_s": self.elapsed,
                "model": self.model.state_dict(), "ema": self.ema.state_dict(),
                "opt": self.opt.state_dict(), "rng": self.rng.bit_generator.state,
                "torch_gen": self.gen.get_state(), "devices": self.devices,
                "density": self.batches.density}

    def _restore(self, st: dict[str, Any]) -> None:
        restore_state(self, st, same_config=st["config"] == self.cfg.to_dict(),
                      devices=st.get("devices", ["cpu"]))
        self.rng.bit_generator.state = st["rng"]

    def train_step(self) -> list[float]:
        """One optimiser step on one batch per grid size; returns the loss per size."""
        def losses():
            for x0 in self.batches.draw(self.rng):
                with torch.autocast(self.device.type, dtype=torch.bfloat16,
                                    enabled=self.cfg.bf16):
                    yield self.diffusion.loss(self.model, torch.from_numpy(x0).to(self.device),
                                              self.gen)

        return optimiser_step(self, losses())

    def run(self, until_step: int | None = None, max_seconds: float | None = None) -> Path:
        """Train to ``until_step`` (default: the config's steps) or for ``max_seconds``."""
        return run_loop(self, columns=[f"loss_k{k}" for k in self.cfg.data.sizes],
                        desc=self.cfg.name,
                        until_step=until_step, max_seconds=max_seconds)


def restore_state(runner: Any, st: dict[str, Any], *, same_config: bool,
                  devices: list[str]) -> None:
    """Resume :class:`Trainer` or :class:`trainer.distil.Distiller` from its checkpoint
    ``st`` (written by the same config, else ValueError): weights, EMA, optimiser, torch
    generator, step and time; ``devices``: where it ran before, joined by this one."""
    if not same_config:
        raise ValueError(f"{runner.run_dir / CHECKPOINT} was written by a different config; "
                         "use a new run directory")
    runner.model.load_state_dict(st["model"])
    runner.ema.load_state_dict(st["ema"])
    runner.opt.load_state_dict(st["opt"])
    runner.gen.set_state(st["torch_gen"])
    runner.step = st["step"]
    runner.elapsed = st["elapsed_s"]
    runner.devices = sorted(set(devices) | {runner.device.type})


def average_gradients(model: torch.nn.Module) -> None:
    """Data-parallel training (``torchrun``, :mod:`torch.distributed` initialised): every
    process's gradients replaced by their mean over the processes, so that all of them take
    the same step and hold the same weights. A no-op in a single process."""
    import torch.distributed as dist
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat)
    flat /= dist.get_world_size()
    start = 0
    for g in grads:
        g.copy_(flat[start:start + g.numel()].view_as(g))
        start += g.numel()


def optimiser_step(runner: Any, losses: Iterable[torch.Tensor]) -> list[float]:
    """One step of :class:`Trainer` or :class:`trainer.distil.Distiller`: learning rate for
    ``runner.step``, gradients summed over ``losses`` (one per grid size, drawn lazily after
    the gradients are cleared), clipping, AdamW, EMA. Returns the losses as floats."""
    cfg = runner.cfg
    for group in runner.opt.param_groups:
        group["lr"] = lr_at(cfg, runner.step)
    runner.opt.zero_grad(set_to_none=True)
    values = []
    for loss in losses:
        loss.backward()  # summed over sizes: gradients accumulate
        values.append(loss.item())
    average_gradients(runner.model)
    torch.nn.utils.clip_grad_norm_(runner.model.parameters(), cfg.grad_clip)
    runner.opt.step()
    update_ema(runner.ema, runner.model, cfg.ema_decay)
    runner.step += 1
    return values


def save_run(runner: Any) -> Path:
    """Checkpoint :class:`Trainer` or :class:`trainer.distil.Distiller` in its run directory."""
    path = runner.run_dir / CHECKPOINT
    save_checkpoint(path, runner.state())
    return path


def run_loop(runner: Any, *, columns: list[str], desc: str,
             until_step: int | None = None, max_seconds: float | None = None) -> Path:
    """The step loop of :class:`Trainer` and :class:`trainer.distil.Distiller`.

    ``runner`` has ``cfg`` (steps, lr schedule, log_every, checkpoint_every_s), ``run_dir``,
    ``progress``, ``step``, ``elapsed``, ``train_step()`` (returns its losses: one per grid
    size, for a distiller with a spectrum loss one more per size it scores) and ``state()``
    (what its checkpoint holds); ``columns`` names the log's column for each of those losses. Logs to ``run_dir/log.csv``, checkpoints
    every few minutes and at the end.
    """
    cfg = runner.cfg
    until = cfg.steps if until_step is None else min(until_step, cfg.steps)
    log_path = runner.run_dir / LOG
    new_log = not log_path.exists()
    bar = None
    if runner.progress:
        from tqdm import tqdm
        bar = tqdm(total=until, initial=runner.step, desc=desc, unit="step")
    start = last_ckpt = time.monotonic()
    with open(log_path, "a", newline="") as fh:
        log = csv.writer(fh)
        if new_log:
            log.writerow(["step", "elapsed_s", "lr", "loss"] + list(columns))
        while runner.step < until:
            t0 = time.monotonic()
            losses = runner.train_step()
            runner.elapsed += time.monotonic() - t0
            if runner.step % cfg.log_every == 0 or runner.step == until:
                log.writerow([runner.step, f"{runner.elapsed:.1f}",
                              f"{lr_at(cfg, runner.step - 1):.3g}", f"{sum(losses):.5g}"]
                             + [f"{v:.5g}" for v in losses])
                fh.flush()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{sum(losses):.4g}")
            now = time.monotonic()
            if now - last_ckpt >= cfg.checkpoint_every_s:
                save_run(runner)
                last_ckpt = now
            if max_seconds is not None and now - start >= max_seconds:
                break
    if bar is not None:
        bar.close()
    return save_run(runner)
