"""Loading diffsampler ONNX models and generating point sets with them."""
from __future__ import annotations

import os
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from . import _validate
from ._progress import Progress
from .card import CARD_KEY, parse_card
from .coarse_noise import shape_noise, shaping
from .density import warp
from .elimination import eliminate, thin
from .errors import ModelFormatError, ModelNotFoundError, UnknownModelError
from .grid import decode, encode_stratified, wrap
from .guidance import check_compatible, guide_path, guided, weight_at
from .lattice import nearest_rank1_lattice
from .low_frequencies import RESTORE_CUT, even_out
from .metadata import WireFormatError, read_metadata
from .per_size import cut_at, gain_at
from .projections import gain_at as projection_gain_at
from .projections import spread_projections
from .schedule import alphas_cumprod, timesteps
from .shards import Shards, layout, usable_cores
from .solvers import SOLVERS, project_x0, solve
from .sliced_ot import iterations_at, polish
from .spacing import enforce_min_spacing, radius
from .sobol_orbit import _orbit as impose_sobol_unchecked
from .sobol_orbit import first_points
from .structure import _impose as impose_unchecked
from .structure import applies, block_at

MODELS_DIR = Path(__file__).parent / "models"
#: points evaluated per onnxruntime call when generating many sets
POINTS_PER_BATCH = 32 * 1024


def bundled_models() -> list[str]:
    """Names of the models shipped with the package (``diffsampler_rt/models/*.onnx``)."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.onnx"))


def resolve(model: str | os.PathLike) -> Path:
    """A bundled model name or a path to an ``.onnx`` file -> an existing path."""
    if not isinstance(model, (str, os.PathLike)):
        raise TypeError(f"model must be a bundled model name or a path, got {model!r}")
    text = os.fspath(model)
    path = Path(text)
    if path.is_file():
        return path.resolve()
    if text in bundled_models():
        return MODELS_DIR / f"{text}.onnx"
    if path.suffix == ".onnx" or os.sep in text or "/" in text:
        raise ModelNotFoundError(f"model file {text!r} does not exist")
    raise UnknownModelError(f"unknown model {text!r}; bundled models: "
                            f"{', '.join(bundled_models()) or '(none)'}, or give a path to an "
                            ".onnx file")


class Model:
    """A loaded diffsampler model: an onnxruntime session plus its model card.

    Parameters
    ----------
    model : str or path-like
        A bundled model name (see :func:`diffsampler_rt.list_models`) or an ``.onnx`` path.
    threads : int, optional
        Cores to use (default: every core this process may run on). A batch of at least
        one set per core is split between single-thread onnxruntime sessions, one per core,
        run side by side (beyond 8 cores, 8 sessions sharing the cores;
        :mod:`diffsampler_rt.shards`); a smaller batch, a single set included, runs on one
        session with that many intra-op threads (default: onnxruntime's choice). The sets
        are the same either way, bit for bit.

    Notes
    -----
    A model whose card asks for a sliced-OT polish or a guide (and the guide itself) runs
    onnxruntime without spinning idle workers, so the polish's threads and the other
    network get the cores (the card is read from the file before
    the session is made: :mod:`diffsampler_rt.metadata`).

    Examples
    --------
    >>> import diffsampler_rt
    >>> m = diffsampler_rt.load("rank1")
    >>> m.card["embedding"]
    'ot'
    >>> m.generate(64, count=2, seed=0).shape
    (2, 64, 2)
    """

    def __init__(self, model: str | os.PathLike, *, threads: int | None = None,
                 _quiet: bool = False):
        self.path = resolve(model)
        threads = None if threads is None else _validate.integer("threads", threads)
        if threads is not None and threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        try:  # the card first: the session's options depend on it
            meta = read_metadata(self.path)
        except (OSError, WireFormatError):
            meta = {}
        session = None
        if CARD_KEY not in meta:  # onnxruntime has the last word (and the error message)
            session = self._session(session_options(threads))
            meta = session.get_modelmeta().custom_metadata_map
        self.card: dict[str, Any] = parse_card(meta, str(self.path))
        # the polish sorts on every core right after the network; onnxruntime's idle
        # workers spin for a while after each run and would take those cores (sot_fast,
        # n = 1024, batch of 32: 33-34 ms a set without spinning, 34-52 ms with it); a
        # guided model's network takes turns with its guide's in the same way
        quiet = _quiet or _alternates(self.card)  # _quiet: a guide (_cached_guide)
        if session is None or quiet:
            session = self._session(session_options(threads, spinning=not quiet))
        self.session = session
        names = {i.name for i in self.session.get_inputs()}
        if names != {"x", "t"}:
            raise ModelFormatError(f"{self.path}: expected inputs x and t, found {sorted(names)}")
        self.alpha_bar = alphas_cumprod(self.card["schedule"])
        self._threads = threads
        shards, each = layout(usable_cores() if threads is None else threads)
        self._shards = (Shards(lambda: self._session(session_options(each, spinning=not quiet)),
                               shards) if shards >= 2 else None)
        self._guide: Model | None = None

    def guide(self) -> "Model | None":
        """The model this one's card is guided by (``"guide"``, loaded on first use;
        :mod:`diffsampler_rt.guidance`), or None."""
        spec = self.card.get("guide")
        if spec is None:
            return None
        if self._guide is None:
            path = guide_path(spec, self.path, MODELS_DIR)
            guide = _cached_guide(str(path), path.stat().st_mtime, self._threads)
            check_compatible(self.card, guide.card, str(self.path))
            self._guide = guide
        return self._guide

    def _session(self, opts: "ort.SessionOptions") -> "ort.InferenceSession":
        try:
            return ort.InferenceSession(str(self.path), sess_options=opts,
                                        providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own non-standard exception types
            raise ModelFormatError(f"{self.path} is not a readable ONNX model: "
                                   f"{str(exc).splitlines()[0][:200]}") from None

    @property
    def name(self) -> str:
        return self.card["name"]

    def __repr__(self) -> str:
        return (f"Model({self.name!r}, sampler={self.card['sampler']!r}, "
                f"trained_sizes={self.card['trained_sizes']})")

    def denoise(self, x: np.ndarray, t: int) -> np.ndarray:
        """eps prediction for a batch x (B, 2, k, k) at timestep index t (float64 out)."""
        tt = np.full(x.shape[0], float(t), dtype=np.float32)
        x = x.astype(np.float32)
        if self._shards is not None and len(x) >= self._shards.count:
            eps = self._shards.run(x, tt)
        else:
            eps = self.session.run(["eps"], {"x": x, "t": tt})[0]
        return eps.astype(np.float64)

    def generate(self, n: int, count: int | None = None, *,
                 seed: int | np.random.Generator | None = None, steps: int | None = None,
                 solver: str | None = None, progress: bool = False,
                 structure: bool = True) -> np.ndarray:
        """Generate point sets of ``n`` points with this model.

        Parameters
        ----------
        n : int
            Points per set, 16 <= n <= 512*512. The net makes k*k points on a k x k grid;
            for an n that is not a square, k = ceil(sqrt n) and k*k - n points are removed
            (:mod:`diffsampler_rt.elimination`): a blue-noise model's (a card with a
            minimum spacing) most crowded first, any other's at random, the set's large
            scales then restored; the polish (three times as long) and the spacing follow,
            at n. A lattice model's thinned set is replaced by its nearest rank-1 lattice
            of n points instead (with ``structure``).
        count : int, optional
            Number of sets. ``None`` returns one set of shape (n, 2).
        seed : int or numpy.random.Generator, optional
            The same seed gives the same sets.
        steps : int, optional
            Denoiser evaluations (default: the model card's ``default_steps``). A distilled
            model (its card has a ``distillation`` record) learned only its default solver
            and steps; other settings warn.
        solver : {"ddim", "ddpm", "dpmpp_2m"}, optional
            Deterministic DDIM, ancestral DDPM on the same step grid, or the deterministic
            second-order multistep DPM-Solver++(2M) (one evaluation per step too).
            Default: the model card's ``default_solver``.
        progress : bool
            Show a progress bar on stderr.
        structure : bool
            Restore what the sampler has by construction, as the model card says:
            ``"structure": "dyadic_net"`` (sobol_owen: every set of 2^m points, k a power
            of two, made a (0, m, 2)-net without moving any point out of its grid cell;
            :mod:`diffsampler_rt.structure`; with ``"structure_prefix"``, a set of n points,
            n not a power of four, is the first n points in Sobol' order of a net of the
            next power-of-four size imposed onto the Owen-scrambled Sobol' nets, as the
            first n points of the sequence are; :mod:`diffsampler_rt.sobol_orbit`),
            ``"structure": "n_rooks"`` (ldbn: both 1-d projections stratified at
            power-of-two k >= 16, also imposed on the clean-set prediction of the last
            ``"structure_guidance"`` solver steps so that the net arranges its sets
            around it; with ``"structure_block"``, at k = 64 and 128 the
            aligned halves of every column and row, and their halves down to 32 cells,
            stratified at their own sub-strip widths too, as LDBN's are; with
            ``"structure_runs"``, at sides that are not powers of two, every run of that
            many cells of a column and row in distinct sub-strips of its own width),
            ``"structure": "rank1_lattice"`` (lattice models: each set replaced by the
            rank-1 lattice it is closest to, read off its power spectrum, under a uniformly
            random shift, at the grid sides in
            ``"structure_sides"``;
            :mod:`diffsampler_rt.lattice`), ``"sliced_ot"`` (SOT models: a few of the
            sampler's own sliced-OT iterations from the network's set, which take out its
            excess low-frequency power at large n; :mod:`diffsampler_rt.sliced_ot`),
            ``"even_out"`` (GBN, SOT students, at n = 4096 Poisson-disk models and beyond
            4096 ldbn(_fast): their sets' density deviations at large scales shrunk, or
            amplified, by a smooth move; :mod:`diffsampler_rt.low_frequencies`),
            ``"projection_gain"`` (sot_32_fast at 256: the deviations of each axis's
            sorted coordinates from evenly spread positions scaled, so that the x and y
            projections are as uneven as the sampler's; not where a structure is imposed;
            :mod:`diffsampler_rt.projections`),
            ``"restore_cut"`` (GBN models 1, sot /
            sot_fast 0.4: where n is not a square, the thinned set's density restored from
            the full set's up to that many sqrt(n) instead of the runtime's 0.25) and
            ``"min_spacing": c`` (blue noise: pairs closer than c / sqrt(n) pushed apart,
            every other point kept; :mod:`diffsampler_rt.spacing`), in that order, except
            that where a structure is imposed the spacing and the evening come before it,
            so that the structure holds exactly (ldbn: the n-rooks projection then puts
            every point back in a strip of its own cell, which keeps most of the spacing
            and of the evened large scales).
            Before all that, ``"coarse_noise"`` (ldbn, sobol_owen) scales the coarse Fourier modes
            of the solver's starting noise, so that the sets vary at large scales as
            much as the sampler's (:mod:`diffsampler_rt.coarse_noise`; where the structure
            is imposed, ``"structure_temperature"`` scales every other mode: ldbn_fast
            0.9), and ``"guide"``
            (sot) steers every solver step away from a weaker model of the same sampler
            (autoguidance, two network evaluations a step;
            :mod:`diffsampler_rt.guidance`).
            ``False`` returns the network's sets as decoded, unguided, from white noise
            (thinned to n points where n is not a square, restored below 0.25 sqrt(n)).
            A non-uniform model's density (card field ``"density"``) is part of the model,
            not a repair: its sets are mapped to it either way (:mod:`diffsampler_rt.density`).
            So is a toroidal model's shift: a net with circular padding (``"padding":
            "circular"``) makes its sets on the torus; they are decoded modulo 1 and each
            shifted by a uniform random vector, as a toroidal sampler's sets may be, and
            its minimum spacing is kept on the torus (across the seam too).

        Returns
        -------
        numpy.ndarray
            float64, shape (n, 2) or (count, n, 2), every point in [0, 1)^2.
        """
        _validate.num_points(n)
        c = 1 if count is None else _validate.count(count)
        out = np.empty((c, n, 2))
        start = 0
        for block in self.iter_sets(n, c, seed=seed, steps=steps, solver=solver,
                                    progress=progress, structure=structure):
            out[start:start + len(block)] = block
            start += len(block)
        return out[0] if count is None else out

    def iter_sets(self, n: int, count: int, *, batch: int | None = None,
                  seed: int | np.random.Generator | None = None, steps: int | None = None,
                  solver: str | None = None, progress: bool = False, structure: bool = True):
        """Generate ``count`` sets lazily, ``batch`` sets at a time (a generator).

        For counts too large to hold at once: each yielded block has shape
        (b, n, 2) with b <= ``batch`` (default: about 32 k points per block), and the
        blocks concatenated equal ``generate(n, count, seed=seed, ...)``.

        Examples
        --------
        >>> import diffsampler_rt
        >>> m = diffsampler_rt.load("rank1")
        >>> sum(len(b) for b in m.iter_sets(64, 10, batch=4, seed=0))
        10
        """
        k = _validate.num_points(n)
        c = _validate.count(count)
        T = len(self.alpha_bar)
        s = self.card["default_steps"] if steps is None else _validate.steps(steps, T)
        solver = self.card["default_solver"] if solver is None else solver
        if solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}; choose one of {list(SOLVERS)}")
        distilled = self.card.get("distillation")
        if distilled and (s, solver) != (self.card["default_steps"], self.card["default_solver"]):
            warnings.warn(f"model {self.name!r} was distilled for {self.card['default_solver']} "
                          f"with {self.card['default_steps']} steps; {solver} with {s} steps "
                          "is outside what it learned and gives poorer sets", stacklevel=3)
        rng = _validate.rng(seed)
        structure = _validate.flag("structure", structure)
        progress = _validate.flag("progress", progress)
        sequence = False
        if structure and self.card.get("structure_prefix"):
            # n not 4^h: the first n points, in Sobol' order, of a net of the next 4^h
            side = 1 << (k - 1).bit_length()
            sequence = side * side != n and applies(self.card, side)
            k = side if sequence else k
        if batch is None:
            per_batch = max(1, POINTS_PER_BATCH // (k * k))
        else:
            per_batch = _validate.integer("batch", batch)
            if per_batch < 1:
                raise ValueError(f"batch must be >= 1, got {per_batch}")
        # validated now; the sets are made as the caller iterates
        # a structure belongs to the k x k set, except a lattice (one per n: at an n that is
        # not a square, the thinned set is replaced by its nearest lattice of n points); the
        # per-size settings go by the n kept
        lattice = self.card.get("structure") == "rank1_lattice"
        imposed = bool(structure) and applies(self.card, k) and (n == k * k or not lattice)
        relattice = bool(structure) and lattice and n < k * k
        spacing = radius(self.card, n) if structure else None
        polishing = self.card.get("sliced_ot") if structure else None
        sliced = iterations_at(polishing, n, thinned=n < k * k) if polishing else 0
        coarse = self.card.get("coarse_noise") if structure else None
        # where the structure is imposed, every mode but the coarse ones at a temperature
        hot = self.card.get("structure_temperature", 1.0) if imposed else 1.0
        noise_shape = shaping(coarse, k * k, hot)
        even = self.card.get("even_out") if structure else None
        # where a structure is imposed the evening comes before it, on the full k x k set
        evened = k * k if imposed else n
        evening = (gain_at(even, evened), cut_at(even, evened)) if even else None
        spread = (self.card.get("projection_gain") if structure and not (imposed or relattice)
                  else None)
        projection_gain = projection_gain_at(spread, n) if spread is not None else 1.0
        # a thinned set's large scales restored from its full one up to this (a card's own
        # cut is a tuning like the ones above; without them the runtime's default)
        restore = self.card.get("restore_cut", RESTORE_CUT) if structure else RESTORE_CUT
        guide = self.card.get("guide") if structure else None
        weight = weight_at(guide, k * k) if guide else 0.0
        if weight:
            self.guide()  # a missing or mismatched guide fails here, before any work
        return self._blocks(k, n, c, per_batch, rng, timesteps(T, min(s, T)), solver, progress,
                            imposed, relattice, spacing, sliced, noise_shape, evening, restore,
                            weight, sequence, projection_gain)

    def _blocks(self, k: int, n: int, c: int, per_batch: int, rng: np.random.Generator,
                ts: np.ndarray, solver: str, progress: bool, imposed: bool, relattice: bool,
                spacing: float | None, sliced: int,
                noise_shape: tuple[float, float, float] | None,
                evening: tuple[float, float] | None, restore: float, weight: float,
                sequence: bool, projection_gain: float = 1.0):
        # one child stream per set: results do not depend on how sets are batched
        streams = rng.spawn(c)
        bar = Progress(c, f"{self.name} n={n}", enabled=progress)
        density = self.card.get("density")
        crowded_first = "min_spacing" in self.card  # a blue-noise card: thin by elimination
        # a net with circular padding makes sets on the torus: decoded modulo 1 and shifted
        # by a uniform random vector, so the set's seam is anywhere, as for the sampler
        toroidal = self.card.get("padding") == "circular"
        scale = float(self.card["offset_scale"])
        eps_fn = self.denoise
        if weight:  # autoguidance by the card's weaker model
            eps_fn = guided(self.denoise, self.guide().denoise, weight)
        guided_steps = self.card.get("structure_guidance", 0) if imposed else 0
        block = block_at(self.card, k)  # n-rooks' smallest stratified block at this side
        if guided_steps:
            def project(x0: np.ndarray) -> np.ndarray:
                pts = impose_unchecked(decode(x0 / scale, stratified=True), k,
                                       self.card["structure"], block=block)
                return encode_stratified(pts, k) * scale

            eps_fn = project_x0(eps_fn, self.alpha_bar, project,
                                ts[max(0, len(ts) - guided_steps):])
        for start in range(0, c, per_batch):
            sub = streams[start:start + per_batch]
            x = np.stack([g.standard_normal((2, k, k)) for g in sub])
            if noise_shape is not None:  # (gain, cut) of the card's "coarse_noise", temperature
                x = shape_noise(x, *noise_shape)

            def noise(shape: tuple[int, ...], sub=sub) -> np.ndarray:
                return np.stack([g.standard_normal(shape[1:]) for g in sub])

            x = solve(solver, eps_fn, x, self.alpha_bar, ts, noise)
            grid = x / scale
            bar.update(len(sub))
            pts = decode(grid, stratified=self.card["embedding"] == "stratified",
                         toroidal=toroidal)
            if toroidal:  # after the solver's draws, like a lattice's shift
                pts = wrap(pts + np.stack([g.random(2) for g in sub])[:, None, :])
            # an imposed structure must hold exactly, so the spacing and the evening go
            # before it (the structure puts every point back in a strip of its own cell, a
            # small move that keeps most of the spacing and the evened large scales)
            if spacing is not None and imposed:
                pts = enforce_min_spacing(pts, spacing, torus=toroidal)
            if evening is not None and imposed:
                pts = even_out(pts, evening[0], cut=evening[1], torus=toroidal)
            if sequence:  # the column and row scrambles come after the solver's draws
                pts = first_points(*impose_sobol_unchecked(pts, k, sub), n)
            elif imposed:  # a lattice's random shift comes after the solver's draws
                pts = impose_unchecked(pts, k, self.card["structure"], sub, block)
            if relattice:  # n not a square: the thinned set's nearest lattice of n points
                pts = nearest_rank1_lattice(eliminate(pts, n, torus=toroidal), sub)
            elif n < pts.shape[-2]:  # blue noise: the most crowded points go; else at random
                pts = thin(pts, n, torus=toroidal, rngs=None if crowded_first else sub,
                           cut=restore)
            if sliced:
                pts = polish(pts, sliced, self.card["sliced_ot"]["directions"], sub,
                             step=self.card["sliced_ot"].get("step", 1.0))
            if evening is not None and not imposed:  # (gain, cut) of the card's "even_out"
                pts = even_out(pts, evening[0], cut=evening[1], torus=toroidal)
            if projection_gain != 1.0:  # the card's "projection_gain" (no structure here)
                pts = spread_projections(pts, projection_gain)
            if spacing is not None and not imposed:
                pts = enforce_min_spacing(pts, spacing, torus=toroidal)
            # a non-uniform model's net makes the sets in the uniform square
            yield pts if density is None else warp(pts, density)


#: onnxruntime session option: exact 8-bit products on x86 CPUs without VNNI
X64_QUANT_PRECISION = "session.x64quantprecision"
#: /proc/cpuinfo flags of x86 dot-product instructions that add 8-bit products in 32 bits
VNNI_FLAGS = frozenset({"avx512_vnni", "avx_vnni"})


def needs_exact_8bit(cpuinfo: str | None = None) -> bool:
    """Whether sessions here should set :data:`X64_QUANT_PRECISION`: True unless the CPU is
    known to have VNNI (a ``flags`` line of Linux's /proc/cpuinfo, or ``cpuinfo``'s text,
    naming one of :data:`VNNI_FLAGS`); unknown CPUs get the exact products.

    With VNNI, onnxruntime's fast 8-bit kernel sums in 32 bits and is exact already, and the
    option only makes it rewrite the weights to unsigned and take a slower kernel: on a
    2-core Intel Xeon with AVX512-VNNI the 8-bit networks' outputs were bit for bit the same
    with and without it (tests/test_quantize.py checks it on such hosts) and one evaluation
    of sot_fast at n = 1024 in a batch of 32 on two single-thread sessions took 2.2-2.3 ms a
    set without it, 4.6-4.9 with it (2026-12-06). AVX-VNNI without AVX-512 is trusted on
    the same grounds (onnxruntime's kernel there also sums in 32 bits), not measured.

    Examples
    --------
    >>> from diffsampler_rt.model import needs_exact_8bit
    >>> needs_exact_8bit("flags : fpu sse2 avx2 avx512f avx512_vnni")
    False
    >>> needs_exact_8bit("flags : fpu sse2 avx2")
    True
    """
    if cpuinfo is None:
        return _exact_8bit_here()
    for line in cpuinfo.splitlines():
        name, _, value = line.partition(":")
        if name.strip() == "flags":
            return not (VNNI_FLAGS & set(value.split()))
    return True


@lru_cache(maxsize=1)
def _exact_8bit_here() -> bool:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            return needs_exact_8bit(f.read())
    except OSError:  # not Linux: exact products (harmless on CPUs that are not x86)
        return True


def session_options(threads: int | None = None, *,
                    spinning: bool = True) -> "ort.SessionOptions":
    """The onnxruntime session options every :class:`Model` uses (benchmarks reuse them).

    All graph optimisations; one inter-op thread (the U-Net is one chain of operators run
    sequentially, so the cores go to intra-op parallelism); ``threads`` intra-op threads
    (default: onnxruntime's, one per physical core). ``spinning=False`` makes idle workers
    sleep at once instead of spinning: one set alone gets slower (gbn_fast at n = 1024:
    ~45 instead of ~36 ms), batches do not, and work that follows a run gets the cores.

    The 8-bit (``_fast``) files' convolutions are computed exactly on every x86 CPU:
    without VNNI (AVX2-only CPUs, e.g. many AMD EPYC / Ryzen and older Intel parts)
    onnxruntime's fast unsigned x signed byte product saturates its 16-bit sums, which
    doubled gbn_fast's noise-prediction error on such a host (2.0 % instead of 0.9 % of
    its RMS); ``session.x64quantprecision`` makes it use the exact kernel there (a little
    slower). It is set unless the CPU is known to have VNNI (:func:`needs_exact_8bit`):
    there the fast kernel is exact and the option only halves the 8-bit networks' speed.
    It applies to 8-bit operators only; float models are untouched either way.
    """
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.inter_op_num_threads = 1
    if needs_exact_8bit():
        opts.add_session_config_entry(X64_QUANT_PRECISION, "1")
    if threads is not None:
        opts.intra_op_num_threads = threads
    if not spinning:
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return opts


@lru_cache(maxsize=16)
def _cached(path: str, mtime: float) -> Model:
    return Model(path)


def _alternates(card: dict) -> bool:
    """Whether a model's network runs take turns with other work on the same cores (a
    sliced-OT polish, or a guide's network): then its session must not spin."""
    return bool(card.get("sliced_ot") or card.get("guide"))


@lru_cache(maxsize=8)
def _cached_guide(path: str, mtime: float, threads: int | None) -> Model:
    """A guide, loaded once per file and thread count, with a session that does not spin:
    it takes turns with the guided model's (sot_32 at n = 1024, batch of 32: 232-242 ms a
    set with the guide's workers spinning, 193-198 ms without)."""
    return Model(path, threads=threads, _quiet=True)


def load(model: str | os.PathLike | Model) -> Model:
    """Load (and cache) a model by bundled name or ``.onnx`` path.

    Examples
    --------
    >>> import diffsampler_rt
    >>> diffsampler_rt.load("sobol_owen").card["sampler"]
    'sobol_owen'
    """
    if isinstance(model, Model):
        return model
    path = resolve(model)
    return _cached(str(path), path.stat().st_mtime)


def generate(model: str | os.PathLike | Model, n: int, count: int | None = None, *,
             seed: int | np.random.Generator | None = None, steps: int | None = None,
             solver: str | None = None, progress: bool = False,
             structure: bool = True) -> np.ndarray:
    """Generate ``count`` point sets of ``n`` points from a learned sampler.

    Parameters
    ----------
    model : str, path-like or Model
        A bundled model name (``diffsampler_rt.list_models()``) or a path to an ``.onnx``
        file exported by diffsampler.
    n, count, seed, steps, solver, progress, structure
        See :meth:`Model.generate`.

    Returns
    -------
    numpy.ndarray
        float64 array (n, 2), or (count, n, 2) when ``count`` is given, in [0, 1)^2.

    Examples
    --------
    >>> import diffsampler_rt
    >>> pts = diffsampler_rt.generate("rank1", 576, seed=1)
    >>> pts.shape, bool(((pts >= 0) & (pts < 1)).all())
    ((576, 2), True)
    """
    return load(model).generate(n, count, seed=seed, steps=steps, solver=solver,
                                progress=progress, structure=structure)
