"""One typed config per training run: saved in every checkpoint and in the exported card."""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from .density import FLOOR
from .unet import UNetConfig


@dataclass(frozen=True)
class DataConfig:
    sampler: str
    embedding: str  # "stratified" or "ot"
    #: grid sides trained on at once (n = k*k points)
    sizes: tuple[int, ...] = (8, 16, 32)
    #: sets per size per step
    batch_sizes: tuple[int, ...] = (64, 32, 16)
    #: 0 = fresh sets every step (cheap samplers); > 0 = a fixed pool of that many sets per
    #: size, generated once from `seed` and cached on disk
    pool_sizes: tuple[int, ...] = (0, 0, 0)
    #: symmetries of the square applied at random (0..7, see trainer.embedding.symmetries);
    #: only those that provably keep the sampler's distribution
    symmetries: tuple[int, ...] = (0,)
    #: offsets (cell units) are multiplied by this before diffusion
    offset_scale: float = 2.0
    #: pool entries per generated set: the set itself and shifts - 1 copies translated by a
    #: uniform random vector modulo 1, each embedded anew (toroidal samplers only, whose
    #: distribution is invariant under translations of the torus)
    shifts: int = 1
    #: > 0 for non-uniform samplers: fit the density of the pooled training sets on a
    #: bins x bins histogram (trainer.density) and learn the sets after its Rosenblatt map
    #: to the uniform square; the table goes into the card and the runtime maps back
    density_bins: int = 0
    #: grid sides whose pooled sets the density is fitted to; empty = the largest only (a
    #: small set's intensity need not be the density: the leftmost point of a 64-point SOT
    #: ramp set sits near y = 0.5 in nearly every set)
    density_sides: tuple[int, ...] = ()
    #: how the density is fitted (trainer.density.FITS): "histogram" (density_bins bins) or
    #: "legendre" (a smooth series, degree by cross-validation up to density_max_degree,
    #: tabulated on density_bins x density_bins cells) or "log_legendre" (the same for the
    #: log density, fitted by maximum likelihood: positive, for densities near zero)
    density_fit: str = "histogram"
    density_max_degree: int = 16
    #: mass added to every cell of the density table, a fraction of the mean cell mass
    #: (trainer.density.FLOOR; sot_ramp and gbn_blob were trained with 1e-3)
    density_floor: float = FLOOR
    #: with density_bins: every pooled set is also learned mirrored in the diagonal
    #: (x <-> y) before the density fit and the map to the square, doubling the pool for
    #: non-uniform samplers whose distribution that mirror keeps (gbn_blob: GBN on the
    #: torus thinned by a density symmetric in x and y). The grid symmetries cannot stand
    #: in for it: the map to the square does not commute with them
    mirror_diagonal: bool = False

    def __post_init__(self) -> None:
        from .density import FITS, check_floor
        if self.density_fit not in FITS:
            raise ValueError(f"density_fit must be one of {FITS}, got {self.density_fit!r}")
        check_floor("density_floor", self.density_floor)
        if self.mirror_diagonal and not self.density_bins:
            raise ValueError("mirror_diagonal needs density_bins > 0 (uniform samplers: "
                             "symmetries 0-7 mirror the grid itself)")


@dataclass(frozen=True)
class TrainConfig:
    name: str
    data: DataConfig
    unet: UNetConfig = field(default_factory=UNetConfig)
    schedule: dict = field(default_factory=lambda: {
        "kind": "linear", "beta_start": 1e-4, "beta_end": 0.02, "num_steps": 1000})
    steps: int = 4000
    lr: float = 5e-4
    warmup_steps: int = 100
    weight_decay: float = 0.0
    grad_clip: float = 1.0
    ema_decay: float = 0.995
    seed: int = 0
    threads: int = 1
    #: bfloat16 autocast for forward/backward (weights, optimiser and EMA stay float32):
    #: ~1.6x faster per step on a CPU with avx512_bf16; emulated and 16-20x slower without
    #: (the trainer warns; `python -m trainer train --fp32` overrides it)
    bf16: bool = False
    checkpoint_every_s: float = 180.0
    log_every: int = 10
    #: sampling defaults written into the exported model card: DPM-Solver++(2M) with 20
    #: steps matched 50 DDIM steps in benchmarks/results/solver_sweep.md
    default_sample_steps: int = 20
    default_solver: str = "dpmpp_2m"
    #: start from the weights of an earlier stage instead of a random init: an exported
    #: ``.onnx`` file or a training ``checkpoint.pt`` (its EMA weights), path relative to the
    #: working directory; its architecture must equal ``unet``. Optimiser, EMA and data
    #: stream start afresh with this config's schedule (a second training stage).
    init_from: str | None = None

    def __post_init__(self) -> None:
        from diffsampler_rt.solvers import SOLVERS
        if self.default_solver not in SOLVERS:
            raise ValueError(f"default_solver {self.default_solver!r} is not one of {list(SOLVERS)}")
        if self.default_sample_steps < 1:
            raise ValueError(f"default_sample_steps must be >= 1, got {self.default_sample_steps}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrainConfig":
        d = dict(d)
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown config keys {sorted(unknown)}; known: {sorted(known)}")
        d["data"] = DataConfig(**{k: tuple(v) if isinstance(v, list) else v
                                  for k, v in d["data"].items()})
        if "unet" in d:
            d["unet"] = UNetConfig(**{k: tuple(v) if isinstance(v, list) else v
                                      for k, v in d["unet"].items()})
        return cls(**d)

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))
