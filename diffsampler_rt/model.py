"""Loading diffsampler ONNX models and generating point sets with them."""
from __future__ import annotations

import difflib
import json
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
from .density import warp
from .errors import ModelFormatError, ModelNotFoundError, UnknownModelError
from .finish import pipeline as finishing
from .grid import decode, wrap
from .guidance import check_compatible, guide_path
from .metadata import WireFormatError, read_metadata
from .schedule import alphas_cumprod, timesteps
from .shards import Shards, layout, usable_cores
from .solvers import SOLVERS, solve

MODELS_DIR = Path(__file__).parent / "models"
#: folders searched for a model given by bare name, before the bundled models
MODELS_ENV = "DIFFSAMPLER_MODELS"
#: points evaluated per onnxruntime call when generating many sets
POINTS_PER_BATCH = 32 * 1024


def bundled_models() -> list[str]:
    """Names of the models shipped with the package (``diffsampler_rt/models/*.onnx``)."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.onnx"))


def search_path() -> list[Path]:
    """The folders of ``DIFFSAMPLER_MODELS`` (separated like ``PATH``), in order: a bare
    name is looked up there before the bundled models, so a folder of your own models is
    called by name."""
    text = os.environ.get(MODELS_ENV, "")
    return [Path(part).expanduser() for part in text.split(os.pathsep) if part]


def listed_models() -> dict[str, Path]:
    """Every name a bare model name can be: the ``DIFFSAMPLER_MODELS`` folders' models and
    the bundled ones, name -> the file it resolves to."""
    names = {p.stem for folder in search_path() for p in folder.glob("*.onnx")}
    return {name: _by_name(name) for name in sorted(names | set(bundled_models()))}


def catalogue() -> dict[str, dict]:
    """The bundled models' catalogue (``models/catalogue.json``, generated from their cards
    and the speed and fidelity reports): name -> what it imitates, its network, sampling and
    figures at n = 1024; empty where the file is missing."""
    path = MODELS_DIR / "catalogue.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def _by_name(name: str) -> Path | None:
    for folder in search_path():
        if (folder / f"{name}.onnx").is_file():
            return (folder / f"{name}.onnx").resolve()
    return MODELS_DIR / f"{name}.onnx" if name in bundled_models() else None


def resolve(model: str | os.PathLike) -> Path:
    """A model name or a path to an ``.onnx`` file -> an existing path.

    A bare name (``"gbn"``) is ``NAME.onnx`` in the first ``DIFFSAMPLER_MODELS`` folder
    holding it, else the bundled model, even beside a local file of that name (write
    ``"./gbn"`` for the file). Any other existing file wins; a path that does not exist but
    names a bundled model (``"gbn.onnx"``, ``"models/gbn.onnx"``) is that bundled model; a
    folder is refused.
    """
    if not isinstance(model, (str, os.PathLike)):
        raise TypeError(f"model must be a bundled model name or a path, got {model!r}")
    text = os.fspath(model)
    path = Path(text)
    if isinstance(model, str) and os.sep not in text and "/" not in text \
            and (found := _by_name(text)) is not None:
        return found
    if path.is_file():
        return path.resolve()
    if path.is_dir():
        raise ModelNotFoundError(f"model {text!r} is a folder, not an .onnx file")
    names = bundled_models()
    stem = path.stem if path.suffix == ".onnx" else path.name
    if text in names or (path.suffix == ".onnx" and stem in names):
        return MODELS_DIR / f"{stem}.onnx"
    if path.suffix == ".onnx" or os.sep in text or "/" in text:
        raise ModelNotFoundError(f"model file {text!r} does not exist (nor is {stem!r} a "
                                 "bundled model)")
    close = difflib.get_close_matches(text, names, n=3, cutoff=0.5)
    hint = f"did you mean {', '.join(close)}? " if close else ""
    raise UnknownModelError(f"unknown model {text!r}; {hint}bundled models: "
                            f"{', '.join(names) or '(none)'}, or give a path to an .onnx file")


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
        are the same either way, bit for bit. More threads than usable cores are capped,
        with a warning.
    providers : list, optional
        onnxruntime execution providers for the network, as ``onnxruntime.InferenceSession``
        takes them (``["CUDAExecutionProvider", "CPUExecutionProvider"]``, DirectML,
        CoreML, ...); default the CPU. Other hardware rounds differently: the sets agree
        with the CPU's to float32 rounding of the network's output, not bit for bit.

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
                 providers: list | None = None, _quiet: bool = False):
        self.path = resolve(model)
        threads = _usable_threads(threads)
        self.providers = _validate_providers(providers)
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
        quiet = _quiet or finishing.shares_cores(self.card["pipeline"])  # _quiet: a guide (_cached_guide)
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

    def guide(self, spec: dict) -> "Model":
        """The model a ``guide`` step names (loaded once per file; checked to share this
        model's schedule and embedding; :mod:`diffsampler_rt.guidance`)."""
        path = guide_path(spec, self.path, MODELS_DIR)
        guide = _cached_guide(str(path), path.stat().st_mtime, self._threads)
        check_compatible(self.card, guide.card, str(self.path))
        return guide

    def _session(self, opts: "ort.SessionOptions") -> "ort.InferenceSession":
        try:
            return ort.InferenceSession(str(self.path), sess_options=opts,
                                        providers=self.providers)
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
            Run the finishing steps the model card's ``"pipeline"`` lists, in its order
            (``diffsampler info MODEL`` prints them; :mod:`diffsampler_rt.finish`): noise
            shaping, guidance, imposed structures, thinning, polish, evening, spacing.
            ``False`` skips every step but thinning (which an n that is not a square
            needs; it then restores the large scales below the default 0.25 sqrt(n)), so
            the network's own sets come out, decoded, unguided, from white noise. The
            model's density map (card field ``"density"``) and a toroidal model's random
            shift (``"padding": "circular"``) are part of the model and apply either way.

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
        _validate.num_points(n)
        c = _validate.count(count)
        T = len(self.alpha_bar)
        s = self.card["default_steps"] if steps is None else _validate.steps(steps, T)
        solver = self.card["default_solver"] if solver is None else solver
        if not isinstance(solver, str):
            raise TypeError(f"solver must be a solver name, got {solver!r}")
        if solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}; choose one of {list(SOLVERS)}")
        self._warn_if_undistilled(s, solver)
        rng = _validate.rng(seed)
        structure = _validate.flag("structure", structure)
        progress = _validate.flag("progress", progress)
        plan = finishing.plan(self.card["pipeline"], n, structure=structure)
        per_batch = self._per_batch(batch, plan.k)
        ts = timesteps(T, min(s, T))
        # built now, so that a missing or mismatched guide fails before any work
        eps_fn = plan.denoiser(self.denoise, plan.context(n, model=self, timesteps=ts))

        def run(x: np.ndarray, noise) -> np.ndarray:  # the solver, from x to clean offsets
            return solve(solver, eps_fn, x, self.alpha_bar, ts, noise)

        return self._blocks(plan, n, c, per_batch, rng, run, progress)

    def _warn_if_undistilled(self, steps: int, solver: str) -> None:
        card = self.card
        if card.get("distillation") and (steps, solver) != (card["default_steps"],
                                                            card["default_solver"]):
            warnings.warn(f"model {self.name!r} was distilled for {card['default_solver']} "
                          f"with {card['default_steps']} steps; {solver} with {steps} steps "
                          "is outside what it learned and gives poorer sets", stacklevel=4)

    @staticmethod
    def _per_batch(batch: int | None, k: int) -> int:
        if batch is None:
            return max(1, POINTS_PER_BATCH // (k * k))
        per_batch = _validate.integer("batch", batch)
        if per_batch < 1:
            raise ValueError(f"batch must be >= 1, got {per_batch}")
        return per_batch

    def _blocks(self, plan: finishing.Plan, n: int, c: int, per_batch: int,
                rng: np.random.Generator, run, progress: bool):
        """noise -> solver -> decode -> point steps -> density map, a batch at a time."""
        streams = rng.spawn(c)  # one per set: results do not depend on the batching
        bar = Progress(c, f"{self.name} n={n}", enabled=progress)
        k, density = plan.k, self.card.get("density")
        toroidal = self.card.get("padding") == "circular"
        for start in range(0, c, per_batch):
            sub = streams[start:start + per_batch]
            ctx = plan.context(n, torus=toroidal, rngs=sub)
            x = plan.shape_noise(np.stack([g.standard_normal((2, k, k)) for g in sub]), ctx)

            def noise(shape: tuple[int, ...], sub=sub) -> np.ndarray:
                return np.stack([g.standard_normal(shape[1:]) for g in sub])

            x = run(x, noise)
            bar.update(len(sub))
            pts = decode(x / float(self.card["offset_scale"]),
                         stratified=self.card["embedding"] == "stratified", toroidal=toroidal)
            if toroidal:  # the set's seam anywhere, as for a toroidal sampler
                pts = wrap(pts + np.stack([g.random(2) for g in sub])[:, None, :])
            with _validate.trusted():  # the steps' public functions skip their checks
                pts = plan.finish(pts, ctx)
                # a non-uniform model's net makes its sets in the uniform square
                pts = pts if density is None else warp(pts, density)
            yield pts


#: onnxruntime session option: exact 8-bit products on x86 CPUs without VNNI
X64_QUANT_PRECISION = "session.x64quantprecision"
#: /proc/cpuinfo flags of x86 dot-product instructions that add 8-bit products in 32 bits
VNNI_FLAGS = frozenset({"avx512_vnni", "avx_vnni"})


def needs_exact_8bit(cpuinfo: str | None = None) -> bool:
    """Whether sessions here should set :data:`X64_QUANT_PRECISION`: True unless the CPU is
    known to have VNNI (a ``flags`` line of Linux's /proc/cpuinfo, or ``cpuinfo``'s text,
    naming one of :data:`VNNI_FLAGS`); unknown CPUs get the exact products.

    With VNNI, onnxruntime's fast 8-bit kernel sums in 32 bits and is exact already, and the
    option only makes it rewrite the weights to unsigned and take a slower kernel, about
    twice as slow for the same outputs bit for bit (tests/test_quantize.py checks the
    outputs on such CPUs). AVX-VNNI without AVX-512 is trusted on the same grounds
    (onnxruntime's kernel there also sums in 32 bits).

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
    without VNNI (AVX2-only CPUs)
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


def _usable_threads(threads: int | None) -> int | None:
    """``threads`` checked; above the cores this process may use, capped with a warning
    (more onnxruntime threads than cores wait on each other: 10x slower on 2 cores)."""
    if threads is None:
        return None
    threads = _validate.integer("threads", threads)
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    cores = usable_cores()
    if threads > cores:
        warnings.warn(f"threads={threads} is more than the {cores} cores this process may "
                      f"use; using {cores}", stacklevel=3)
        return cores
    return threads


def _validate_providers(providers: list | None) -> list:
    """onnxruntime execution providers (names, or (name, options) pairs), as
    ``onnxruntime.InferenceSession`` takes them; default: the CPU's."""
    if providers is None:
        return ["CPUExecutionProvider"]
    if isinstance(providers, (str, bytes)) or not isinstance(providers, (list, tuple)):
        raise TypeError(f"providers must be a list of onnxruntime execution providers, got "
                        f"{providers!r}")
    available = ort.get_available_providers()
    for p in providers:
        name = p[0] if isinstance(p, tuple) else p
        if not isinstance(name, str):
            raise TypeError(f"a provider must be a name or a (name, options) pair, got {p!r}")
        if name not in available:
            raise ValueError(f"execution provider {name!r} is not available in this "
                             f"onnxruntime; available: {', '.join(available)}")
    return list(providers)


@lru_cache(maxsize=16)
def _cached(path: str, mtime: float) -> Model:
    return Model(path)


@lru_cache(maxsize=8)
def _cached_guide(path: str, mtime: float, threads: int | None) -> Model:
    """A guide, loaded once per file and thread count, with a session that does not spin:
    it takes turns with the guided model's (sot_32 at n = 1024, batch of 32: 232-242 ms a
    set with the guide's workers spinning, 193-198 ms without)."""
    return Model(path, threads=threads, _quiet=True)


def load(model: str | os.PathLike | Model, *, providers: list | None = None) -> Model:
    """Load (and cache) a model by bundled name or ``.onnx`` path.

    ``providers``: onnxruntime execution providers to run the network on, e.g.
    ``["CUDAExecutionProvider", "CPUExecutionProvider"]`` (default: the CPU); a model with
    providers is not cached.

    Examples
    --------
    >>> import diffsampler_rt
    >>> diffsampler_rt.load("sobol_owen").card["sampler"]
    'sobol_owen'
    """
    if isinstance(model, Model):
        return model
    if providers is not None:
        return Model(model, providers=providers)
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
