"""Training batches: reference sets -> grid embedding -> scaled offsets, per grid size."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .config import DataConfig
from .embedding import embed, symmetries
from .samplers import sample


def cache_dir() -> Path:
    """Where generated training pools live (outside git): $DIFFSAMPLER_CACHE or ~/.cache."""
    root = os.environ.get("DIFFSAMPLER_CACHE") or Path.home() / ".cache" / "diffsampler"
    return Path(root)


def make_pool(sampler: str, embedding: str, k: int, count: int, seed: int,
              progress: bool = False) -> np.ndarray:
    """``count`` embedded reference sets (count, 2, k, k), float32, deterministic in seed.

    Cached on disk under :func:`cache_dir` keyed by every argument.
    """
    key = json.dumps([sampler, embedding, k, count, seed])
    path = cache_dir() / f"{sampler}_{embedding}_k{k}_{count}_{hashlib.sha1(key.encode()).hexdigest()[:10]}.npy"
    if path.exists():
        return np.load(path)
    rng = np.random.default_rng([seed, k])
    chunks = range(0, count, 64)
    if progress:
        from tqdm import tqdm
        chunks = tqdm(chunks, desc=f"pool {sampler} k={k}", unit_scale=64, leave=False)
    pool = np.concatenate([embed(sample(sampler, k * k, count=min(64, count - s), seed=rng),
                                 embedding) for s in chunks]).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npy")
    np.save(tmp, pool)
    os.replace(tmp, path)
    return pool


class Batches:
    """Draws one batch per grid size from fresh sets or from a cached pool."""

    def __init__(self, cfg: DataConfig, seed: int, progress: bool = False):
        if not len(cfg.sizes) == len(cfg.batch_sizes) == len(cfg.pool_sizes):
            raise ValueError("sizes, batch_sizes and pool_sizes must have the same length")
        self.cfg = cfg
        self.pools = {k: make_pool(cfg.sampler, cfg.embedding, k, p, seed, progress)
                      for k, p in zip(cfg.sizes, cfg.pool_sizes) if p > 0}

    def draw(self, rng: np.random.Generator) -> list[np.ndarray]:
        """One float32 array (B_k, 2, k, k) per size, offsets times the offset scale."""
        out = []
        for k, b in zip(self.cfg.sizes, self.cfg.batch_sizes):
            if k in self.pools:
                grid = self.pools[k][rng.integers(0, len(self.pools[k]), size=b)]
            else:
                grid = embed(sample(self.cfg.sampler, k * k, count=b, seed=rng),
                             self.cfg.embedding)
            which = rng.choice(np.asarray(self.cfg.symmetries), size=b)
            grid = symmetries(grid, which) if np.any(which) else grid
            out.append((grid * self.cfg.offset_scale).astype(np.float32))
        return out
