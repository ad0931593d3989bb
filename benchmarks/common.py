"""Shared by the benchmark scripts: cached reference sets and the seed paper's curves."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from trainer.data import cache_dir  # noqa: E402
from trainer.samplers import sample  # noqa: E402

SEED_CSV = ROOT.parent / "shared" / "reference" / "radial_spectra_original_n1024.csv"
SEED_COLUMNS = ["poisson_disk", "gbn", "sot", "ldbn", "sobol_owen", "rank1"]


def model_hash(model: str | Path) -> str:
    """sha256 of a bundled model's (or an .onnx path's) file: which model a result is of."""
    import hashlib

    from diffsampler_rt.model import resolve
    return hashlib.sha256(resolve(model).read_bytes()).hexdigest()


#: x86 features that change what an 8-bit or bf16 network costs (and, without VNNI,
#: what onnxruntime's 8-bit products need: diffsampler_rt.model.session_options)
CPU_FEATURES = ("avx2", "avx512f", "avx512_vnni", "avx_vnni", "avx512_bf16", "amx_int8")


def cpu_description(cpuinfo: str | Path = "/proc/cpuinfo") -> str:
    """The host's processor for a timing report: model name and which of
    :data:`CPU_FEATURES` it has, e.g. ``"AMD EPYC (avx2; no VNNI)"``; the machine type
    where /proc/cpuinfo cannot be read."""
    import platform
    try:
        text = Path(cpuinfo).read_text()
    except OSError:
        return platform.machine() or "unknown CPU"
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    fields = {k.strip(): v.strip() for k, v in fields.items()}
    name = fields.get("model name", platform.machine() or "unknown CPU")
    flags = set(fields.get("flags", "").split())
    have = [f for f in CPU_FEATURES if f in flags]
    from diffsampler_rt.model import VNNI_FLAGS
    vnni = "" if VNNI_FLAGS & flags else "; no VNNI"
    return f"{name} ({', '.join(have) or 'none of ' + '/'.join(CPU_FEATURES)}{vnni})"


FLOAT_DIR = ROOT / "models" / "float"


def float_source(model: str | Path, float_dir: Path = FLOAT_DIR) -> Path:
    """The float network of a model: its own file, or for an 8-bit model (card ``"weights":
    "int8"``) the float file it was quantised from, checked against the hash its card
    records (SystemExit naming the file otherwise)."""
    import diffsampler_rt
    from diffsampler_rt.model import resolve
    from trainer.distil import network_hash
    path = resolve(model)
    card = diffsampler_rt.load(path).card
    if card.get("weights") != "int8":
        return path
    source = float_dir / path.name
    if not source.exists():
        raise SystemExit(f"error: {card['name']}'s float model {source} is missing")
    want, found = card["quantization"]["float_network_sha1"], network_hash(source)
    if found != want:
        raise SystemExit(f"error: {source} is not the network {card['name']} was quantised "
                         f"from (hash {found}, card says {want})")
    return source


def seed_curve(sampler: str) -> np.ndarray | None:
    """The seed paper's mean radial spectrum of ``sampler`` at n = 1024 (79 bins), if any."""
    if not SEED_CSV.exists() or sampler not in SEED_COLUMNS:
        return None
    return np.loadtxt(SEED_CSV, delimiter=",", skiprows=1)[:, 1 + SEED_COLUMNS.index(sampler)]


def _chunk(args):
    name, n, count, seed = args
    t = time.perf_counter()
    pts = sample(name, n, count=count, seed=seed)
    return pts, time.perf_counter() - t


def generate(pool, name: str, n: int, count: int, seed: int, chunk: int):
    """``count`` sets from reference sampler ``name`` on the executor ``pool``.

    Returns the sets and the mean seconds per set (summed over workers: one-core time).
    """
    jobs = [(name, n, min(chunk, count - s), [seed, s]) for s in range(0, count, chunk)]
    parts = list(pool.map(_chunk, jobs))
    return np.concatenate([p for p, _ in parts]), sum(t for _, t in parts) / count


def reference_path(name: str, n: int, count: int, seed: int) -> Path:
    """Where :func:`cached_sets` keeps the sets of reference sampler ``name``."""
    return cache_dir() / "reference" / f"{name}_n{n}_c{count}_s{seed}.npz"


def cached_sets(pool, name: str, n: int, count: int, seed: int):
    """The sets of :func:`generate`, cached on disk (deterministic in the arguments).

    Chunks of count // 8 sets, each from its own seed, whatever the number of workers.

    Returns (sets, seconds per set when they were made, whether they came from the cache).
    """
    path = reference_path(name, n, count, seed)
    if path.exists():
        z = np.load(path)
        return z["pts"], float(z["per_set"]), True
    pts, per_set = generate(pool, name, n, count, seed, max(1, count // 8))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, pts=pts, per_set=per_set)
    tmp.replace(path)
    return pts, per_set, False


def example_reference(name: str, n: int, seed: int) -> np.ndarray:
    """One reference set of sampler ``name`` at ``n`` for a plot: the first set of the first
    cached reference file of that size (by name), else a fresh draw from ``seed``. The slow
    samplers take minutes a set at n = 4096, and an example needs no set of its own."""
    files = sorted(f for f in (cache_dir() / "reference").glob(f"{name}_n{n}_c*_s*.npz")
                   if "_stats" not in f.name and not f.name.endswith(".tmp.npz"))
    for f in files:
        with np.load(f) as z:
            pts = z["pts"]  # read once: each access of an npz member reads it anew
        if len(pts):
            return pts[0]
    return sample(name, n, count=1, seed=seed)[0]


def save_png(fig, path: Path, dpi: int = 70) -> None:
    """A matplotlib figure as a 256-colour PNG: a fraction of the full-colour file's size
    for plots of points and curves, so that the results folder stays small."""
    import io

    from PIL import Image
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    Image.open(buf).convert("RGB").quantize(256).save(path, optimize=True)
