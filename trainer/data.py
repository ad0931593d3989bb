"""Training batches: reference sets -> grid embedding -> scaled offsets, per grid size."""
from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path

import numpy as np

from diffsampler_rt.density import unwarp
from diffsampler_rt.grid import decode

from .config import DataConfig
from .density import FLOOR, fit_density, fit_density_legendre, fit_density_log_legendre
from .embedding import embed, symmetries
from .samplers import SLOW, TOROIDAL, sample

#: sets drawn per call of the sampler when a pool is built (also the unit of the RNG streams)
CHUNK = 64


def cache_dir() -> Path:
    """Where generated training pools live (outside git): $DIFFSAMPLER_CACHE or ~/.cache."""
    root = os.environ.get("DIFFSAMPLER_CACHE") or Path.home() / ".cache" / "diffsampler"
    return Path(root)


def _pool_chunk(sampler: str, embedding: str, k: int, count: int, seed: int, start: int,
                shifts: int, rng: np.random.Generator, workers: int = 1) -> np.ndarray:
    """Sets start .. start+count of a pool, each embedded ``shifts`` times (set-major)."""
    pts = sample(sampler, k * k, count=count, seed=rng, workers=workers)
    if shifts > 1:
        move = np.random.default_rng([seed, k, 1, start]).random((count, shifts - 1, 1, 2))
        pts = np.concatenate([pts[:, None], (pts[:, None] + move) % 1.0], axis=1)
        pts = np.where(pts >= 1.0, 0.0, pts).reshape(count * shifts, k * k, 2)
    return embed(pts, embedding)


def _cached_pools(root: Path, stem: str) -> dict[int, Path]:
    """The cached pools of ``stem`` by their number of sets."""
    found = (re.fullmatch(rf"{re.escape(stem)}_(\d+)\.npy", p.name)
             for p in root.glob(f"{stem}_*"))
    return {int(m.group(1)): root / m.group(0) for m in found if m}


def make_pool(sampler: str, embedding: str, k: int, count: int, seed: int,
              progress: bool = False, shifts: int = 1, workers: int = 1) -> np.ndarray:
    """``count`` reference sets embedded on the k x k grid: float32 (count * shifts, 2, k, k).

    Deterministic in the arguments and cached on disk under :func:`cache_dir`. A pool of
    fewer sets is the prefix of a larger one with the same arguments (sets come from
    per-set child streams), so a cached larger pool is reused, and a cached smaller pool
    of a slow sampler (without shifts) is extended by the sets it lacks: the result is the
    pool drawn from scratch, set for set. ``workers`` processes draw the sets of the slow
    samplers; the pool does not depend on it.
    """
    if shifts > 1 and sampler not in TOROIDAL:
        raise ValueError(f"shifts={shifts}: sampler {sampler!r} is not translation invariant "
                         f"on the torus; toroidal ones are {sorted(TOROIDAL)}")
    key = json.dumps([sampler, embedding, k, seed, shifts])
    stem = f"{sampler}_{embedding}_k{k}_x{shifts}_{hashlib.sha1(key.encode()).hexdigest()[:10]}"
    root = cache_dir()
    cached = _cached_pools(root, stem)
    if any(c >= count for c in cached):
        path = cached[min(c for c in cached if c >= count)]
        return np.load(path, mmap_mode="r")[: count * shifts].copy()
    rng = np.random.default_rng([seed, k])
    have = (np.load(cached[max(cached)]) if cached and sampler in SLOW and shifts == 1
            else None)
    start = 0 if have is None else len(have)
    # a slow sampler's set i is the i-th child stream spawned from rng: spawning the cached
    # sets' streams (without drawing them) puts the next set on the stream it would have had
    rng.spawn(start)
    chunks = range(start, count, CHUNK)
    if progress:
        from tqdm import tqdm
        chunks = tqdm(chunks, desc=f"pool {sampler} k={k}", unit="chunk", leave=False)
    pool = np.concatenate(([] if have is None else [have])
                          + [_pool_chunk(sampler, embedding, k, min(CHUNK, count - s), seed, s,
                                         shifts, rng, workers)
                             for s in chunks]).astype(np.float32)
    root.mkdir(parents=True, exist_ok=True)
    path = root / f"{stem}_{count}.npy"
    tmp = path.with_suffix(f".tmp{os.getpid()}.npy")
    np.save(tmp, pool)
    os.replace(tmp, path)
    return pool


def uniformise(pools: dict[int, np.ndarray], embedding: str, bins: int,
               sides: tuple[int, ...] = (), fit: str = "histogram",
               max_degree: int = 16,
               floor: float = FLOOR,
               mirror: bool = False) -> tuple[dict[int, np.ndarray], dict[str, list]]:
    """Fit the density to the pooled sets of ``sides`` (default: the largest side) and
    re-embed every pool after the density's map to the uniform square. ``mirror``: each
    pool is first followed by its sets mirrored in the diagonal (x <-> y)."""
    sides = sides or (max(pools),)
    if not set(sides) <= set(pools):
        raise ValueError(f"density_sides {list(sides)} must be among the pooled sides "
                         f"{sorted(pools)}")
    points = {k: decode(p) for k, p in pools.items()}
    if mirror:
        points = {k: np.concatenate([p, p[..., ::-1]]) for k, p in points.items()}
    smooth = {"legendre": fit_density_legendre, "log_legendre": fit_density_log_legendre}
    if fit in smooth:
        # the degree: what the sets of every pooled size share (their edge effects differ)
        table, _ = smooth[fit]([points[k] for k in sides], bins, max_degree=max_degree,
                               floor=floor, sizes=[points[k] for k in sorted(points)]
                               if len(points) > 1 else None)
    else:
        table = fit_density(np.concatenate([points[k].reshape(-1, 2) for k in sides]), bins,
                            floor=floor)
    return ({k: embed(unwarp(p, table), embedding).astype(np.float32)
             for k, p in points.items()}, table)


class Batches:
    """Draws one batch per grid size from fresh sets or from a cached pool.

    With ``density_bins`` the pools are taken to the uniform square first (see
    :func:`uniformise`); ``density`` is then the fitted table, else None.
    """

    def __init__(self, cfg: DataConfig, seed: int, progress: bool = False, workers: int = 1):
        if not len(cfg.sizes) == len(cfg.batch_sizes) == len(cfg.pool_sizes):
            raise ValueError("sizes, batch_sizes and pool_sizes must have the same length")
        if cfg.shifts < 1:
            raise ValueError(f"shifts must be >= 1, got {cfg.shifts}")
        self.cfg = cfg
        self.pools = {k: make_pool(cfg.sampler, cfg.embedding, k, p, seed, progress, cfg.shifts,
                                   workers)
                      for k, p in zip(cfg.sizes, cfg.pool_sizes) if p > 0}
        self.density = None
        if cfg.density_bins:
            if len(self.pools) != len(cfg.sizes) or cfg.shifts != 1:
                raise ValueError("density_bins needs a pool at every size (pool_sizes > 0) "
                                 "and shifts = 1: the density is fitted to the pooled sets")
            self.pools, self.density = uniformise(self.pools, cfg.embedding, cfg.density_bins,
                                                  cfg.density_sides, cfg.density_fit,
                                                  cfg.density_max_degree, cfg.density_floor,
                                                  cfg.mirror_diagonal)

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
