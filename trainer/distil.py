"""Few-step students distilled from a model (trajectory distillation).

Progressive distillation (Salimans & Ho 2022) teaches a student to take in ONE
deterministic DDIM step what the teacher takes in two, and repeats. Here one round goes
straight to the student's step grid: the teacher (an exported model run by
:mod:`diffsampler_rt` with its high-order solver on ``teacher_steps``, a multiple of
``student_steps``) records its states at the student's timesteps, and the student,
initialised as the teacher, learns each hop between them as a single DDIM step. Since DDIM
is linear in the predicted noise, every hop has an exact target: the x0 that lands DDIM on
the teacher's next state. Loss: the squared error of the implied noise (the student's x0
error weighted by SNR_t, as in the plain training loss; the paper's truncated-SNR weighting,
max(SNR, 1), is an option, but here it let the first, near-pure-noise hop dominate and cost
minimum distance), plus optionally the squared differences of the x0 error between
neighbouring cells (``difference_weight``).

The hop loss matches each hop's regression to the teacher's state: what a hop cannot
predict it averages, and the hops' errors add up at generation, so the student's sets come
out blurred (SOT's spectral peak lower and wider than the teacher's). ``spectrum_weight``
adds a distribution-level term: the student makes a few sets end to end (all its steps,
differentiable, from the teacher's starting noise) and their mean radial power spectrum
(:mod:`trainer.spectral`) is pulled towards the mean spectrum of all the teacher's sets
of that size, or with ``spectrum_target = "examples"`` towards the sampler's own sets (then
the student can end closer to the sampler than its teacher). ``spectrum_card`` makes those
sets as the runtime will, under a card's noise shaping and imposed structure, so the loss
scores what users get: LDBN's n-rooks imposition alone moved ldbn_fast's spectrum from
0.010 to 0.015 (mean absolute difference at n = 1024). ``projection_weight`` does the same
for the spectrum on the axes (the power of the sets' x and y coordinates), which the radial
bins average away and the star discrepancy weighs most.

A guided teacher (card ``"guide"``, autoguidance) can be distilled with its guidance
(``teacher_guidance``): its trajectories then follow (1 + w) eps_teacher - w eps_guide at
the card's weight for each grid size, so the student learns the guided sets in one network
evaluation a step, without the guide (guidance distillation, Meng et al. 2023).

Teacher trajectories are deterministic in the seed and cached under
:func:`trainer.data.cache_dir` (keyed by the teacher network's hash, and the guide's).
"""
from __future__ import annotations

import copy
import hashlib
import json
import os
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from diffsampler_rt.card import CARD_KEY, describe_devices, parse_card
from diffsampler_rt.grid import decode, encode_stratified
from diffsampler_rt.guidance import guided
from diffsampler_rt.metadata import network_digest, network_sha256
# the runtime's own start-noise settings, so the rollout starts as generation does
from diffsampler_rt.schedule import timesteps
from diffsampler_rt.solvers import SOLVERS, solve
from diffsampler_rt.spectrum import BIN_WIDTH, NUM_BINS
# the runtime's own imposition (unchecked: its decode already puts one point per cell)
from diffsampler_rt import per_size
from diffsampler_rt.finish import legacy
from diffsampler_rt.finish import pipeline as finishing

from . import zoo
from .data import cache_dir, make_pool
from .density import OLD_FLOOR
from .drop_blocks import drop_res_blocks
from .samplers import sample
from .spectral import AxisSpectrum, RadialSpectrum, grid_points
from .train import (CHECKPOINT, load_checkpoint, optimiser_step, restore_state,
                    run_loop)
from .unet import UNet, UNetConfig
from .warm_start import net_from_onnx

LOSS_WEIGHTINGS = ("snr", "truncated_snr")
#: what ``spectrum_target`` may name
SPECTRUM_TARGETS = ("teacher", "examples")


@dataclass(frozen=True)
class DistilConfig:
    """One distillation run; saved in the checkpoint and in the student's model card."""

    #: the teacher: a network name (``models/NAME.onnx``, :mod:`trainer.zoo`) or an ``.onnx`` path
    teacher: str
    #: the student's model name (its card and file name)
    name: str
    student_steps: int = 8
    teacher_steps: int = 24
    teacher_solver: str = "dpmpp_2m"
    #: the student's attention window (see trainer.unet.UNetConfig.attention_window); at
    #: the trained sides the attention level is at most 8 cells wide, so 8 changes nothing
    #: there and keeps big grids linear in n
    attention_window: int | None = 8
    sizes: tuple[int, ...] = (8, 16, 32)
    #: teacher trajectories per grid size (fixed pool, cached)
    trajectories: tuple[int, ...] = (2048, 1024, 512)
    #: (state, hop) pairs per size per optimiser step
    batch_sizes: tuple[int, ...] = (64, 32, 16)
    #: "snr": squared error of the implied noise (= SNR_t-weighted x0 error, the plain
    #: training loss's weighting: the low-noise hops that place the points dominate);
    #: "truncated_snr": max(SNR_t, 1)-weighted x0 error (Salimans & Ho 2022), which here
    #: lets the first, near-pure-noise hop dominate
    loss_weighting: str = "snr"
    #: weight of the squared differences of the x0 error between neighbouring cells: an
    #: error that differs from cell to cell moves neighbouring points against each other
    #: (it costs minimum distance), a smooth one moves them together
    difference_weight: float = 0.0
    steps: int = 1500
    lr: float = 1e-4
    warmup_steps: int = 50
    ema_decay: float = 0.995
    grad_clip: float = 1.0
    seed: int = 0
    threads: int = 1
    checkpoint_every_s: float = 180.0
    log_every: int = 10
    #: a later stage: start from this student export (``.onnx``, e.g. the previous stage's)
    #: instead of the teacher's weights; its card's distillation steps are counted in
    init_from: str | None = None
    #: follow the teacher's card guide (autoguidance at its weight per size) in the
    #: trajectories; the student itself runs unguided
    teacher_guidance: bool = False
    #: changes to the teacher's architecture for a smaller (faster) student, as
    #: trainer.unet.UNetConfig fields, e.g. {"base_channels": 24}; such a student cannot
    #: start from the teacher's weights, so it starts from fresh ones (seeded by ``seed``)
    #: unless ``init_from`` names an earlier stage of it, or an earlier student of the same
    #: net but for more res blocks a level (cut down: trainer.drop_blocks)
    student_unet: dict[str, Any] | None = None
    #: weight of the spectrum loss: the squared difference, over the radial bins up to
    #: ``spectrum_radius`` sqrt(n), between the mean spectrum of ``spectrum_sets`` sets the
    #: student makes end to end (all its steps, from the teacher's starting noise) and the
    #: mean spectrum of all the teacher's sets of that size; at the grid sides
    #: ``spectrum_sizes`` (each one of ``sizes``). The hop loss alone leaves the student's
    #: sets blurred: each hop's regression to the teacher's state averages what it cannot
    #: predict, and the errors of the hops add up
    spectrum_weight: float = 0.0
    spectrum_sizes: tuple[int, ...] = (32,)
    spectrum_sets: int = 8
    spectrum_radius: float = 3.0
    #: what the spectrum loss pulls towards: ``"teacher"``, the mean spectrum of the
    #: teacher's sets, or ``"examples"``, of the sampler's own sets as the teacher learned
    #: them (its training pool at that side, or ``spectrum_examples`` fresh sets of a
    #: sampler drawn fresh every step), so the student can come closer to the sampler than
    #: its teacher (uniform teachers only)
    spectrum_target: str = "teacher"
    spectrum_examples: int = 1024
    #: card sampling settings the spectrum rollout follows, to score the sets as the
    #: runtime will make them: a dict of card entries over the teacher's card (a recipe
    #: keeps them), or a model (bundled name or ``.onnx`` path) whose card to take: fresh
    #: starting noise shaped by ``"coarse_noise"`` and ``"structure_temperature"``, and
    #: ``"structure"`` imposed on the clean-set prediction of the last
    #: ``"structure_guidance"`` steps and on the decoded set. The imposition (a sort, not
    #: differentiable) passes gradients straight through: the set moves with the net's output
    spectrum_card: str | dict[str, Any] | None = None
    #: weight of the projection loss: the squared difference, over frequencies 1 ..
    #: ``spectrum_radius`` sqrt(n), between the mean power spectrum of the student's sets'
    #: x and y coordinates (sets made as for the spectrum loss, with its card) and the
    #: target's (``spectrum_target``), at the grid sides ``projection_sizes``. The radial
    #: bins average the axes away; a net on a k x k grid can leave the grid's period in its
    #: sets' projections (sot_32_fast: power at j ~ k where SOT's peak lies below it), which
    #: the star discrepancy sees. ``projection_sets`` rollouts a step, scored as two halves
    #: (the product of their differences from the target: an unbiased estimate of the
    #: squared difference of the means, where the square of one noisy mean would also
    #: reward less power, whose noise is less)
    projection_weight: float = 0.0
    projection_sizes: tuple[int, ...] = (16,)
    projection_sets: int = 32

    def __post_init__(self) -> None:
        for name in ("sizes", "trajectories", "batch_sizes", "spectrum_sizes",
                     "projection_sizes"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.teacher_solver not in SOLVERS or self.teacher_solver == "ddpm":
            raise ValueError(f"teacher_solver must be a deterministic solver (ddim, dpmpp_2m), "
                             f"got {self.teacher_solver!r}")
        if self.student_steps < 1 or self.teacher_steps % self.student_steps:
            raise ValueError(f"teacher_steps ({self.teacher_steps}) must be a positive multiple "
                             f"of student_steps ({self.student_steps})")
        if not len(self.sizes) == len(self.trajectories) == len(self.batch_sizes):
            raise ValueError("sizes, trajectories and batch_sizes need one entry per size")
        if self.loss_weighting not in LOSS_WEIGHTINGS:
            raise ValueError(f"loss_weighting must be one of {LOSS_WEIGHTINGS}, "
                             f"got {self.loss_weighting!r}")
        if min(self.sizes) < 4:
            raise ValueError(f"grid sides must be >= 4, got {self.sizes}")
        if self.spectrum_weight < 0:
            raise ValueError(f"spectrum_weight must be >= 0, got {self.spectrum_weight}")
        if self.spectrum_weight and not set(self.spectrum_sizes) <= set(self.sizes):
            raise ValueError(f"spectrum_sizes {self.spectrum_sizes} must be among sizes "
                             f"{self.sizes}")
        if self.projection_weight < 0:
            raise ValueError(f"projection_weight must be >= 0, got {self.projection_weight}")
        if self.projection_weight and not set(self.projection_sizes) <= set(self.sizes):
            raise ValueError(f"projection_sizes {self.projection_sizes} must be among sizes "
                             f"{self.sizes}")
        if self.projection_sets < 2 or self.projection_sets % 2:
            raise ValueError(f"projection_sets must be even and >= 2, got {self.projection_sets}")
        if self.spectrum_sets < 1:
            raise ValueError(f"spectrum_sets must be >= 1, got {self.spectrum_sets}")
        if self.spectrum_target not in SPECTRUM_TARGETS:
            raise ValueError(f"spectrum_target must be one of {SPECTRUM_TARGETS}, "
                             f"got {self.spectrum_target!r}")
        if self.spectrum_examples < 1:
            raise ValueError(f"spectrum_examples must be >= 1, got {self.spectrum_examples}")
        if not BIN_WIDTH <= self.spectrum_radius <= NUM_BINS * BIN_WIDTH:
            raise ValueError(f"spectrum_radius must be in [{BIN_WIDTH}, "
                             f"{NUM_BINS * BIN_WIDTH}], got {self.spectrum_radius}")
        unknown = set(self.student_unet or ()) - {f.name for f in fields(UNetConfig)}
        if unknown:
            raise ValueError(f"unknown student_unet keys {sorted(unknown)}")
        if "attention_window" in (self.student_unet or ()):
            raise ValueError("student_unet may not set attention_window: the config's own "
                             "attention_window field sets it")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def load(cls, path: str | Path) -> "DistilConfig":
        d = json.loads(Path(path).read_text())
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown distil config keys {sorted(unknown)}")
        return cls(**d)


def hop_times(num_train_steps: int, student_steps: int) -> np.ndarray:
    """The student's timesteps followed by -1 (clean data): the hops it learns."""
    return np.append(timesteps(num_train_steps, student_steps), -1)


def guidance_weight(teacher, k: int) -> float:
    """The weight of the teacher card's guide at a k x k grid (0: none)."""
    spec = finishing.find(teacher.card["pipeline"], "guide")
    return per_size.value(spec["weight"], k * k) if spec else 0.0


def _guide(teacher):
    """The teacher's guide model (its card's ``guide`` step)."""
    return teacher.guide(finishing.find(teacher.card["pipeline"], "guide"))


def teacher_trajectories(teacher, k: int, count: int, *, teacher_steps: int,
                         student_steps: int, solver: str, seed: int,
                         batch: int = 64, guidance: bool = False) -> np.ndarray:
    """The teacher's states at the student's timesteps and its final clean sample.

    Returns float32 (student_steps + 1, count, 2, k, k): row j is the state at
    ``timesteps(T, student_steps)[j]``, the last row the teacher's output (scaled offsets).
    ``guidance``: the teacher's denoiser guided as its card says (:func:`guidance_weight`).
    """
    weight = guidance_weight(teacher, k) if guidance else 0.0
    denoise = (guided(teacher.denoise, _guide(teacher).denoise, weight) if weight
               else teacher.denoise)
    T = len(teacher.alpha_bar)
    ts = timesteps(T, teacher_steps)
    want = timesteps(T, student_steps)
    if not set(want) <= set(ts):
        raise ValueError(f"the {student_steps}-step grid is not part of the {teacher_steps}-step one")
    rows = {int(t): j for j, t in enumerate(want)}
    out = np.empty((student_steps + 1, count, 2, k, k), dtype=np.float32)
    rng = np.random.default_rng([seed, k])
    for start in range(0, count, batch):
        b = min(batch, count - start)
        x = rng.standard_normal((b, 2, k, k))

        def eps_fn(x: np.ndarray, t: int) -> np.ndarray:
            if t in rows:
                out[rows[t], start:start + b] = x
            return denoise(x, t)

        out[-1, start:start + b] = solve(solver, eps_fn, x, teacher.alpha_bar, ts)
    return out


def network_hash(path: Path) -> str:
    """The short SHA-1 a student's card records for its teacher: of the teacher's ONNX
    network without its metadata, so editing the teacher card's sampling defaults
    (``python -m export set-defaults``) keeps the record valid (the same bytes as onnx
    serialises without the metadata; read off the file, not parsed)."""
    return network_digest(path, "sha1")[:12]


def cached_trajectories(cfg: DistilConfig, teacher, teacher_sha1: str, k: int,
                        count: int) -> np.ndarray:
    """:func:`teacher_trajectories`, cached on disk (keyed by the teacher network's hash,
    and with guidance the guide network's and the weight)."""
    key = [teacher_sha1, k, count, cfg.teacher_steps, cfg.student_steps, cfg.teacher_solver,
           cfg.seed]
    weight = guidance_weight(teacher, k) if cfg.teacher_guidance else 0.0
    if weight:
        key += [network_sha256(_guide(teacher).path), weight]
    key = json.dumps(key)
    path = cache_dir() / f"traj_{teacher.name}_k{k}_{hashlib.sha1(key.encode()).hexdigest()[:12]}.npy"
    if path.exists():
        return np.load(path)
    traj = teacher_trajectories(teacher, k, count, teacher_steps=cfg.teacher_steps,
                                student_steps=cfg.student_steps, solver=cfg.teacher_solver,
                                seed=cfg.seed, guidance=cfg.teacher_guidance)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, traj)
    os.replace(tmp, path)
    return traj


def hop_loss(net: torch.nn.Module, x_t: torch.Tensor, x_next: torch.Tensor, t: torch.Tensor,
             t_next: torch.Tensor, alpha_bar: torch.Tensor,
             weighting: str = "snr", difference_weight: float = 0.0) -> torch.Tensor:
    """Weighted x0 error of one DDIM hop t -> t_next (t_next = -1: clean data).

    ``weighting``: "snr" (SNR_t: the squared error of the implied eps) or
    "truncated_snr" (max(SNR_t, 1)). ``difference_weight`` adds that weight times the
    squared differences of the error between horizontally and vertically adjacent cells.

    DDIM lands on x_next exactly when its x0 prediction equals
    (x_next - (s_next / s_t) x_t) / (a_next - (s_next / s_t) a_t).
    """
    ab_t = alpha_bar[t].view(-1, 1, 1, 1)
    ab_n = torch.where(t_next >= 0, alpha_bar[t_next.clamp(min=0)],
                       torch.ones_like(t_next, dtype=alpha_bar.dtype)).view(-1, 1, 1, 1)
    a_t, s_t = ab_t.sqrt(), (1 - ab_t).sqrt()
    a_n, s_n = ab_n.sqrt(), (1 - ab_n).sqrt()
    target = (x_next - (s_n / s_t) * x_t) / (a_n - (s_n / s_t) * a_t)
    eps = net(x_t, t.float())
    x0 = (x_t - s_t * eps) / a_t
    weight = ab_t / (1 - ab_t)
    if weighting == "truncated_snr":
        weight = torch.clamp(weight, min=1.0)
    elif weighting != "snr":
        raise ValueError(f"unknown weighting {weighting!r}; choose one of {LOSS_WEIGHTINGS}")
    err = x0 - target
    loss = torch.mean(weight * err ** 2)
    if difference_weight:
        dx = err[..., :, 1:] - err[..., :, :-1]
        dy = err[..., 1:, :] - err[..., :-1, :]
        loss = loss + difference_weight * (torch.mean(weight * dx ** 2)
                                           + torch.mean(weight * dy ** 2))
    return loss


class Distiller:
    """Runs one :class:`DistilConfig` in ``run_dir``; resumes from its checkpoint."""

    def __init__(self, cfg: DistilConfig, run_dir: str | Path, progress: bool = True,
                 device: str = "cpu"):
        import diffsampler_rt

        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.progress = progress
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.teacher = diffsampler_rt.Model(zoo.resolve(cfg.teacher), threads=cfg.threads)
        net, self.teacher_cfg, self.teacher_card = net_from_onnx(self.teacher.path)
        # the device is not part of the recipe: teacher trajectories and the random draws
        # stay on the CPU, the student trains where it is told
        self.device = torch.device(device)
        self.model = UNet(self.student_config().unet)
        self.earlier = {"steps": 0, "seconds": 0}  # of the stages before init_from
        self.cut_from = None  # res blocks a level of the earlier stages, if cut down
        if cfg.init_from:
            self.model.load_state_dict(self._earlier_stage(Path(cfg.init_from)).state_dict())
        elif not cfg.student_unet:  # another architecture keeps its fresh, seeded weights
            self.model.load_state_dict(net.state_dict())
        self.model.to(self.device)
        self.ema = copy.deepcopy(self.model).requires_grad_(False)
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr, weight_decay=0.0)
        self.alpha_bar = torch.tensor(self.teacher.alpha_bar, dtype=torch.float32).to(self.device)
        self.hops = torch.tensor(hop_times(len(self.teacher.alpha_bar), cfg.student_steps))
        self.teacher_sha1 = network_hash(self.teacher.path)  # once: saves repeat it
        self.trajectories = {k: torch.from_numpy(cached_trajectories(cfg, self.teacher,
                                                                     self.teacher_sha1, k, n))
                             for k, n in zip(cfg.sizes, cfg.trajectories)}
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.rollout_card = (self._rollout_card()
                             if cfg.spectrum_weight or cfg.projection_weight else None)
        bins = int(round(cfg.spectrum_radius / BIN_WIDTH))
        self.spectra = {k: self._target(RadialSpectrum(k * k, bins), k)
                        for k in cfg.spectrum_sizes if cfg.spectrum_weight}
        self.projections = {
            k: self._target(AxisSpectrum(k * k, max(1, round(cfg.spectrum_radius * k))), k)
            for k in cfg.projection_sizes if cfg.projection_weight}
        self.step = 0
        self.elapsed = 0.0
        self.devices = [self.device.type]  # every device the student has trained on
        ckpt = self.run_dir / CHECKPOINT
        if ckpt.exists():
            self._restore(load_checkpoint(ckpt))

    def _earlier_stage(self, path: Path) -> UNet:
        """The student of an earlier stage (same teacher, same architecture) and its record."""
        if path.suffix != ".onnx" or not path.is_file():
            raise FileNotFoundError(f"init_from {str(path)!r} must be an existing .onnx export")
        net, cfg, card = net_from_onnx(path)
        record = card.get("distillation")
        if not record or record["teacher"] != self.teacher_card["name"]:
            raise ValueError(f"init_from {str(path)!r} is not a student of "
                             f"{self.teacher_card['name']!r}")
        need = self.student_config().unet
        if cfg.unet != need:
            if (replace(cfg.unet, num_res_blocks=need.num_res_blocks) != need
                    or cfg.unet.num_res_blocks < need.num_res_blocks):
                raise ValueError(f"init_from {str(path)!r} has architecture {cfg.unet}, "
                                 f"this student needs {need}")
            # the same net but for more res blocks a level: start from it cut down
            net = drop_res_blocks(net, need.num_res_blocks)
            self.cut_from = cfg.unet.num_res_blocks
        else:  # a stage after a cut keeps the record of it
            self.cut_from = record.get("earlier_res_blocks")
        self.earlier = {"steps": record["steps"] + record.get("earlier_steps", 0),
                        "seconds": record["seconds"] + record.get("earlier_seconds", 0)}
        return net

    def _points(self, grid: torch.Tensor) -> torch.Tensor:
        """A batch of scaled offsets -> points, as the runtime decodes them."""
        return grid_points(grid / float(self.teacher_card["offset_scale"]),
                           stratified=self.teacher_card["embedding"] == "stratified",
                           toroidal=self.teacher_card.get("padding") == "circular")

    def _target(self, figure: torch.nn.Module, k: int) -> tuple[torch.nn.Module, torch.Tensor]:
        """A figure (a spectrum of sets of k*k points) and its mean over the sets the
        student's are pulled towards at side k (the teacher's or the sampler's,
        ``spectrum_target``)."""
        if self.cfg.spectrum_target == "examples":
            sets = torch.from_numpy(self._examples(k))
        else:
            sets = self._points(self.trajectories[k][-1].double())
        with torch.no_grad():
            target = sum(figure(sets[i:i + 64]) * len(sets[i:i + 64])
                         for i in range(0, len(sets), 64)) / len(sets)
        # the student's float32 once here, not at every step's call
        return figure.to(self.device, torch.float32), target.float().to(self.device)

    def _examples(self, k: int) -> np.ndarray:
        """The sampler's sets of k*k points as the teacher learned them: its training pool
        at side k (the same cached sets), or ``spectrum_examples`` fresh ones."""
        if "density" in self.teacher_card:
            raise ValueError("spectrum_target 'examples' needs a uniform teacher: "
                             f"{self.teacher_card['name']!r} learned its sets after a "
                             "density's map")
        data = self.teacher_cfg.data
        pool = dict(zip(data.sizes, data.pool_sizes)).get(k, 0)
        if pool > 0:
            grid = make_pool(data.sampler, data.embedding, k, pool, self.teacher_cfg.seed,
                             shifts=data.shifts)
            return decode(grid, stratified=data.embedding == "stratified")
        return sample(data.sampler, k * k, count=self.cfg.spectrum_examples,
                      seed=np.random.default_rng([self.cfg.seed, k]))

    def _rollout_card(self) -> dict[str, Any] | None:
        """The card the spectrum rollout follows (``spectrum_card``: a model, or card
        entries such as ``{"pipeline": [...]}`` over the teacher's card; format-1 fields
        are converted), validated as the runtime validates a model's card, or None."""
        import diffsampler_rt

        spec = self.cfg.spectrum_card
        if not spec:
            return None
        if isinstance(spec, str):
            return diffsampler_rt.Model(zoo.resolve(spec), threads=1).card
        if not isinstance(spec, dict):
            raise ValueError(f"spectrum_card must be a model or a dict of card entries, "
                             f"got {spec!r}")
        if any(key in legacy.FIELDS for key in spec):
            spec = {**{k: v for k, v in spec.items() if k not in legacy.FIELDS},
                    "pipeline": legacy.to_pipeline(spec)}
        return parse_card({CARD_KEY: json.dumps({**self.teacher_card, **spec})},
                          "spectrum_card")

    def _plan(self, k: int) -> finishing.Plan:
        """The rollout card's pipeline at a k x k grid (the runtime's own plan)."""
        return finishing.plan(self.rollout_card["pipeline"], k * k)

    def _imposed(self, k: int) -> bool:
        return bool(self.rollout_card) and self._plan(k).project is not None

    def _imposed_points(self, grid: torch.Tensor) -> np.ndarray:
        """A batch of scaled offsets (B, 2, k, k), decoded as the runtime does and with the
        rollout card's structure imposed: points (B, k*k, 2), float64, no gradient."""
        k = grid.shape[-1]
        scale = float(self.teacher_card["offset_scale"])
        pts = decode(grid.detach().cpu().double().numpy() / scale, stratified=True)
        return self._plan(k).project(pts)

    def _start_noise(self, k: int, count: int) -> torch.Tensor:
        """Starting noise of ``count`` rollouts at side k: the teacher's recorded noise of
        random trajectories, or with ``spectrum_card`` fresh noise shaped by its pipeline's
        noise steps, as the runtime shapes it."""
        card = self.rollout_card
        if card is None:
            traj = self.trajectories[k]
            return traj[0, torch.randint(0, traj.shape[1], (count,), generator=self.gen)]
        x = torch.randn((count, 2, k, k), generator=self.gen, dtype=torch.float64).numpy()
        plan = self._plan(k)
        return torch.from_numpy(plan.shape_noise(x, plan.context(k * k))).float()

    def _guided_steps(self, k: int) -> int:
        """How many of the last steps the rollout card's structure guidance steers at k."""
        if not self._imposed(k):
            return 0
        return sum(step.steps_at(params, k) for step, params in self._plan(k).steps["denoiser"]
                   if step.name == "structure_guidance")

    def rollout(self, x: torch.Tensor) -> torch.Tensor:
        """The student's deterministic DDIM from x at its first timestep to its clean
        sample (as the runtime runs it), differentiable; with ``spectrum_card`` its
        structure guidance too (the projection's move passed straight through)."""
        k = x.shape[-1]
        ts = self.hops[:-1].tolist()
        late = self._guided_steps(k)
        guided = set(ts[max(0, len(ts) - late):]) if late else set()
        for t, t_next in zip(ts, self.hops[1:].tolist()):
            ab_t = self.alpha_bar[t]
            eps = self.model(x, torch.full((len(x),), float(t), device=x.device))
            x0 = (x - (1 - ab_t).sqrt() * eps) / ab_t.sqrt()
            if t in guided:
                scale = float(self.teacher_card["offset_scale"])
                moved = encode_stratified(self._imposed_points(x0), k) * scale
                x0 = x0 + (torch.from_numpy(moved).to(x0) - x0).detach()
                eps = (x - ab_t.sqrt() * x0) / (1 - ab_t).sqrt()
            if t_next < 0:
                return x0
            ab_n = self.alpha_bar[t_next]
            x = ab_n.sqrt() * x0 + (1 - ab_n).sqrt() * eps
        return x

    def _rollout_points(self, k: int, count: int) -> torch.Tensor:
        """``count`` sets of k*k points the student makes end to end, differentiable (with
        ``spectrum_card``, as the runtime makes them)."""
        grid = self.rollout(self._start_noise(k, count).to(self.device))
        pts = self._points(grid)
        if self._imposed(k):  # the decoded set's structure, passed straight through
            moved = torch.from_numpy(self._imposed_points(grid)).to(pts)
            pts = pts + (moved - pts).detach()
        return pts

    def spectrum_loss(self, k: int) -> torch.Tensor:
        """Squared difference of the student's mean spectrum (``spectrum_sets`` sets made
        end to end) from the target's, weighted."""
        figure, target = self.spectra[k]
        pts = self._rollout_points(k, self.cfg.spectrum_sets)
        return self.cfg.spectrum_weight * torch.mean((figure(pts) - target) ** 2)

    def projection_loss(self, k: int) -> torch.Tensor:
        """Squared difference of the student's mean axis spectrum (its sets' projections)
        from the target's, weighted."""
        figure, target = self.projections[k]
        half = self.cfg.projection_sets // 2  # even (checked by the config)
        pts = self._rollout_points(k, self.cfg.projection_sets)
        return self.cfg.projection_weight * torch.mean((figure(pts[:half]) - target)
                                                       * (figure(pts[half:]) - target))

    def loss_names(self) -> list[str]:
        """The log's column for each loss :meth:`train_step` returns."""
        return ([f"loss_k{k}" for k in self.cfg.sizes]
                + [f"spectrum_k{k}" for k in self.spectra]
                + [f"projection_k{k}" for k in self.projections])

    def student_config(self):
        """The teacher's training config, renamed, with the student's sampling defaults (and
        a non-uniform teacher's density floor as its card has it now: the student maps its
        sets back with the teacher's table)."""
        data = self.teacher_cfg.data
        if "density" in self.teacher_card:
            data = replace(data, density_floor=self.teacher_card.get("density_floor",
                                                                     OLD_FLOOR))
        unet = dict(self.cfg.student_unet or {}, attention_window=self.cfg.attention_window)
        return replace(self.teacher_cfg, name=self.cfg.name, default_solver="ddim",
                       default_sample_steps=self.cfg.student_steps, data=data,
                       unet=replace(self.teacher_cfg.unet, **unet))

    def state(self) -> dict[str, Any]:
        distillation = {"teacher": self.teacher_card["name"],
                        "teacher_sha1": self.teacher_sha1,
                        "teacher_training_steps": self.teacher_card["training_steps"],
                        "steps": self.step, "seconds": round(self.elapsed),
                        "devices": self.devices, "config": self.cfg.to_dict()}
        earlier = ""
        if self.cfg.init_from:
            distillation.update(earlier_steps=self.earlier["steps"],
                                earlier_seconds=self.earlier["seconds"])
            earlier = (f" after {self.earlier['steps']} steps "
                       f"({self.earlier['seconds'] / 60:.0f} min) in earlier stages")
            if self.cut_from:
                distillation.update(earlier_res_blocks=self.cut_from)
                earlier += f", cut down from {self.cut_from} res blocks a level"
        guide = (finishing.find(self.teacher_card["pipeline"], "guide")
                 if self.cfg.teacher_guidance else None)
        guided_by = f"; guided by {guide['model']} as its card says" if guide else ""
        smaller = ""
        if self.cfg.student_unet:
            smaller = " in a net of its own (" + ", ".join(
                f"{k} {v}" for k, v in sorted(self.cfg.student_unet.items())) + ")"
        provenance = (f"{self.teacher_card['name']} (trained {self.teacher_card['training_steps']}"
                      f" steps{guided_by}) distilled to {self.cfg.student_steps} DDIM steps"
                      f"{smaller} with "
                      f"`python -m trainer distil` for {self.step} steps, "
                      f"{self.elapsed / 60:.0f} min on {describe_devices(self.devices)}{earlier}")
        return {"config": self.student_config().to_dict(), "distil_config": self.cfg.to_dict(),
                "step": self.step, "elapsed_s": self.elapsed,
                "training_steps": self.teacher_card["training_steps"],
                # the card's training figures are the teacher's: seconds and devices together
                "train_seconds": self.teacher_card.get("train_seconds"),
                "devices": self.teacher_card.get("train_devices", ["cpu"]),
                "card_extra": {"distillation": distillation, "provenance": provenance},
                # a non-uniform teacher's table (None: uniform), which the export puts in the card
                "density": self.teacher_card.get("density"),
                "model": self.model.state_dict(), "ema": self.ema.state_dict(),
                "opt": self.opt.state_dict(), "torch_gen": self.gen.get_state(),
                "student_devices": self.devices}

    def _restore(self, st: dict[str, Any]) -> None:
        restore_state(self, st, same_config=st.get("distil_config") == self.cfg.to_dict(),
                      devices=st.get("student_devices", ["cpu"]))

    def train_step(self) -> list[float]:
        """One optimiser step on one batch of hops per grid size; returns the loss per size."""
        def losses():
            for traj, b in zip(self.trajectories.values(), self.cfg.batch_sizes):
                j = torch.randint(0, self.cfg.student_steps, (b,), generator=self.gen)
                i = torch.randint(0, traj.shape[1], (b,), generator=self.gen)
                dev = self.device
                yield hop_loss(self.model, traj[j, i].to(dev), traj[j + 1, i].to(dev),
                               self.hops[j].to(dev), self.hops[j + 1].to(dev), self.alpha_bar,
                               self.cfg.loss_weighting, self.cfg.difference_weight)
            for k in self.spectra:
                yield self.spectrum_loss(k)
            for k in self.projections:
                yield self.projection_loss(k)

        return optimiser_step(self, losses())

    def run(self, until_step: int | None = None, max_seconds: float | None = None) -> Path:
        """Distil to ``until_step`` (default: the config's steps) or for ``max_seconds``."""
        return run_loop(self, columns=self.loss_names(), desc=f"distil {self.cfg.name}",
                        until_step=until_step, max_seconds=max_seconds)
