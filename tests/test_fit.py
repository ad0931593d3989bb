"""Learning a sampler from example files (trainer.fitting, `python -m trainer fit`):
reading and checking the examples, the analysis, the held-out split, calibration, exact
resumption, data-parallel training, and one small fit end to end."""
from __future__ import annotations

import functools
import json
import math
import re

import numpy as np
import pytest

from trainer.fitting.analysis import analyse, describe
from trainer.fitting.calibrate import SEARCHES
from trainer.fitting.data import split
from trainer.fitting.examples import ExampleError, read_examples
from trainer.samplers import sample


@functools.lru_cache(maxsize=None)
def drawn(name: str, n: int, count: int, seed: int) -> np.ndarray:
    """A built-in sampler's sets (the slow ones drawn once for every test here)."""
    return sample(name, n, count=count, seed=seed)


def jittered(n: int, count: int, seed: int) -> np.ndarray:
    from diffsampler_rt.grid import cell_centres
    k = int(np.sqrt(n))
    rng = np.random.default_rng(seed)
    return cell_centres(k)[None] + rng.uniform(-0.5, 0.5, (count, n, 2)) / k


# ---- reading ------------------------------------------------------------------------------

def test_every_accepted_format_reads_the_same_sets(tmp_path):
    sets = jittered(16, 3, 0)
    np.save(tmp_path / "a.npy", sets)
    np.save(tmp_path / "one.npy", sets[0])
    with open(tmp_path / "b.txt", "w") as fh:  # diffsampler generate's txt: blank lines
        fh.write("\n\n".join("\n".join(f"{x!r} {y!r}" for x, y in s.tolist()) for s in sets) + "\n")
    with open(tmp_path / "c.csv", "w") as fh:
        fh.write("set,x,y\n" + "".join(f"{i},{x!r},{y!r}\n" for i, s in enumerate(sets)
                                       for x, y in s.tolist()))
    with open(tmp_path / "d.dat", "w") as fh:  # UTK-style: a comment, one set per file
        fh.write("# 16 points\n" + "".join(f"{x!r}\t{y!r}\n" for x, y in sets[1].tolist()))
    for name, want in (("a.npy", sets), ("one.npy", sets[:1]), ("b.txt", sets),
                       ("c.csv", sets), ("d.dat", sets[1:2])):
        ex = read_examples(tmp_path / name)
        assert ex.sizes == [16]
        np.testing.assert_array_equal(np.concatenate(list(ex.iter_sets(16))), want)
    folder = read_examples([tmp_path, jittered(64, 2, 1)])  # a folder and an array
    assert folder.sizes == [16, 64] and folder.count(16) == 3 + 1 + 3 + 3 + 1
    np.testing.assert_array_equal(folder.take(16, np.array([4, 0])), np.stack([sets[1], sets[0]]))


BAD = [
    ("empty.txt", "", "empty file"),
    ("nan.npy", np.full((2, 16, 2), np.nan), "set 0 holds NaN"),
    ("inf.txt", "0.1 0.2\n" * 15 + "inf 0.3\n", "NaN or infinite"),
    ("outside.npy", np.full((3, 16, 2), 0.5) + [[[0, 0]], [[0, 0]], [[0.6, 0]]],
     "set 2 has points outside"),
    ("ragged.txt", "0.1 0.2\n" * 16 + "\n" + "0.1 0.2\n" * 9, "different sizes"),
    ("one.txt", "0.5 0.5\n", "n = 1"),
    ("columns.txt", "0.1 0.2 0.3\n", "line 1 has 3 columns"),
    ("words.txt", "0.1 abc\n", "line 1 is not numbers"),
    ("shape.npy", np.zeros((2, 16, 3)), "shape (2, 16, 3)"),
    ("square.npy", np.full((2, 50, 2), 0.5), "nearest squares 49 or 64"),
    ("binary.txt", bytes(range(256)) * 4, "binary file"),
    ("csv.csv", "set,x,y\n0,0.1,0.2\n2,0.3,0.4\n", "set 2 follows set 0"),
]


@pytest.mark.parametrize("name, content, message", BAD, ids=[b[0] for b in BAD])
def test_bad_examples_are_refused_naming_the_file(tmp_path, name, content, message):
    path = tmp_path / name
    if isinstance(content, np.ndarray):
        np.save(path, content)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(ExampleError, match=re.escape(message)) as err:
        read_examples(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_the_cli_refuses_bad_examples_in_one_line_before_any_work(tmp_path, capsys):
    from trainer.__main__ import main
    np.save(tmp_path / "nan.npy", np.full((20, 16, 2), np.nan))
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "nan.npy"), "--name", "x", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "nan.npy" in err and len(err.splitlines()) == 1
    assert not out.exists()  # nothing written
    np.save(tmp_path / "few.npy", jittered(16, 10, 0))
    assert main(["fit", str(tmp_path / "few.npy"), "--name", "x", "-o", str(out)]) == 2
    assert "10 example sets; a fit needs at least 12" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "few.npy"), "--name", "a/b"]) == 2
    assert main(["fit", str(tmp_path / "few.npy"), "--name", "x", "--symmetries", "9"]) == 2


def test_a_large_file_is_read_in_chunks_not_whole(tmp_path):
    np.save(tmp_path / "big.npy", jittered(64, 600, 2))
    ex = read_examples(tmp_path / "big.npy")
    chunks = list(ex.iter_sets(64, chunk=256))
    assert [len(c) for c in chunks] == [256, 256, 88]
    assert isinstance(np.load(tmp_path / "big.npy", mmap_mode="r"), np.memmap)


# ---- analysis and split -------------------------------------------------------------------

def thomas(count: int, n: int, seed: int) -> np.ndarray:
    """A clustered but uniform process (parents uniform, children Gaussian around them on
    the torus), n points a set."""
    rng = np.random.default_rng(seed)
    parents = rng.random((count, n // 8, 1, 2))
    kids = (parents + rng.normal(0, 0.02, (count, n // 8, 8, 2))) % 1.0
    return np.where(kids >= 1, 0, kids).reshape(count, n, 2)


@pytest.mark.slow
def test_analysis_finds_embedding_uniformity_and_structure():
    nets = analyse(read_examples([sample("sobol_owen", 256, count=24, seed=1)]))
    assert (nets.embedding, nets.uniform, nets.structure) == ("stratified", True, "dyadic_net")
    blue = analyse(read_examples([drawn("poisson_disk", 64, 32, 2)]))
    assert (blue.embedding, blue.uniform, blue.structure) == ("ot", True, None)
    clustered = analyse(read_examples([thomas(48, 256, 3)]))
    assert clustered.uniform  # over-dispersed counts are not a density
    ramp = analyse(read_examples([drawn("sot_ramp", 64, 32, 2)]))
    assert not ramp.uniform and "NOT uniform" in " ".join(describe(ramp))

def test_a_structure_that_starts_at_some_size_is_found_from_there():
    """LDBN's sets have stratified projections from k = 16 on, not at k = 8."""
    from trainer.fitting.analysis import common_structure
    ldbn = read_examples([sample("ldbn", 64, count=8, seed=1), sample("ldbn", 256, count=8, seed=1)])
    assert common_structure(ldbn, True) == ("n_rooks", [256])
    # a structure only at a smaller size than some other example size is none
    mixed = read_examples([sample("ldbn", 256, count=8, seed=1),
                           np.random.default_rng(0).random((8, 1024, 2))])
    assert common_structure(mixed, True) == (None, [])


@pytest.mark.slow
def test_asserted_invariances_are_checked_against_the_examples():
    ramp = read_examples([drawn("sot_ramp", 64, 32, 2)])
    warned = analyse(ramp, symmetries=[1, 2])
    assert any("symmetry" in w for w in warned.warnings)
    fine = analyse(read_examples([drawn("poisson_disk", 64, 32, 2)]),
                   symmetries=list(range(8)))
    assert fine.warnings == []
    # a square's edges that the sets avoid: not toroidal
    inner = 0.1 + 0.8 * jittered(256, 40, 5)
    assert any("edges" in w for w in analyse(read_examples([inner]), toroidal=True).warnings)


def test_the_split_holds_out_sets_of_every_size_and_is_seeded():
    ex = read_examples([jittered(16, 40, 0), jittered(64, 12, 1)])
    a, b = split(ex, 3), split(ex, 3)
    assert {n: len(v) for n, v in a.held_out.items()} == {16: 8, 64: 8}
    assert {n: len(v) for n, v in a.held_in.items()} == {16: 32, 64: 4}
    for n in (16, 64):
        np.testing.assert_array_equal(a.held_out[n], b.held_out[n])
        assert not set(a.held_in[n]) & set(a.held_out[n])


# ---- calibration --------------------------------------------------------------------------

def test_spacing_is_calibrated_from_the_examples_smallest_distances():
    from trainer.fitting.calibrate import base_pipeline, spacing
    from trainer.stats.distance import spacing_coefficient
    blue = {64: drawn("poisson_disk", 64, 32, 2)}
    cs, is_blue, _ = spacing(blue)
    assert is_blue and cs[64] == round(spacing_coefficient(blue[64], 5.0), 4)
    assert base_pipeline(None, cs, True) == [{"step": "thin", "drop": "crowded"},
                                             {"step": "min_spacing", "c": round(cs[64], 4)}]
    white = {256: np.random.default_rng(0).random((40, 256, 2))}
    cs, is_blue, _ = spacing(white)
    # not blue noise: random thinning, and the examples' floor, far below their spacing
    assert not is_blue and base_pipeline(None, cs, False) == [
        {"step": "thin", "drop": "random"}, {"step": "min_spacing", "c": round(cs[256], 4)}]
    assert cs[256] < 0.1
    twins = white[256].copy()
    twins[:, 1] = twins[:, 0]  # coinciding points: no floor to keep
    cs, is_blue, _ = spacing({256: twins})
    assert cs[256] == 0 and base_pipeline(None, cs, False) == [{"step": "thin", "drop": "random"}]
    assert not spacing({1024: thomas(8, 1024, 1)})[1]
    seam = np.array([[[0.01, 0.5], [0.99, 0.5], [0.5, 0.2], [0.5, 0.8]]])  # close across x = 0
    assert spacing({4: seam}, toroidal=True)[0][4] == pytest.approx(0.02 * 2)
    # 0.49 apart in the square: c = 1.149, above what the runtime can keep, so capped
    assert np.hypot(0.49, 0.3) * 2 > 1.07 and spacing({4: seam})[0][4] == 1.069
    assert not spacing({256: jittered(256, 40, 1)})[1]
    # with a structure the spacing comes before it where it holds, after thinning elsewhere
    pipe = base_pipeline({"step": "n_rooks", "min_side": 16}, {256: 0.7}, True)
    assert [(e["step"], e.get("where")) for e in pipe] == [
        ("min_spacing", "structured"), ("n_rooks", None), ("thin", None),
        ("min_spacing", "unstructured")]
    # a lattice replaces the set: no spacing before it
    pipe = base_pipeline({"step": "rank1_lattice", "sides": [8]}, {64: 0.95}, True)
    assert [(e["step"], e.get("where")) for e in pipe] == [
        ("rank1_lattice", None), ("thin", None), ("min_spacing", "unstructured")]


def test_a_soft_core_is_blue_noise_at_every_size():
    """A lattice with Gaussian jitter: its smallest distance per set sinks with n (c below
    0.3 at 1024, where 0.3 at 64), its points' nearest-neighbour distances do not."""
    from trainer.fitting.calibrate import spacing

    def perturbed(n: int, count: int) -> np.ndarray:
        k, rng = math.isqrt(n), np.random.default_rng(n)
        i, j = np.meshgrid(np.arange(k), np.arange(k))
        rows = np.stack([(i + 0.5 * (j % 2)) / k, j / k], -1).reshape(-1, 2)
        pts = (rows + rng.random((count, 1, 2)) + rng.normal(0, 0.15 / k, (count, n, 2))) % 1
        return np.where(pts >= 1, 0, pts)

    cs, is_blue, core = spacing({n: perturbed(n, 24) for n in (64, 1024)})
    assert cs[1024] < 0.3 < cs[64] and is_blue
    assert all(0.4 < v < 0.55 for v in core.values())


def test_evening_gain_is_the_one_whose_spectrum_comes_closest():
    from diffsampler_rt.low_frequencies import even_out
    from trainer.fitting.calibrate import EVEN_GAINS, evening
    examples = {64: drawn("poisson_disk", 64, 32, 2)}
    # sets whose spectrum does not depend on the gain: no evening
    same, _ = evening(lambda gain: lambda n, c: drawn("poisson_disk", n, 64, 7)[:c], examples)
    assert same == {64: 0.0}
    # white noise evened towards blue noise: the gain that takes out most large-scale power
    white = np.random.default_rng(1).random((64, 64, 2))
    gains, figures = evening(
        lambda gain: lambda n, c: even_out(white[:c], gain, cut=0.5) if gain else white[:c],
        examples)
    maes = figures[64]["difference"]
    assert set(maes) == {f"{g:g}" for g in EVEN_GAINS}
    assert gains[64] > 0 and maes[f"{gains[64]:g}"] == min(maes.values())


def test_a_searched_step_runs_where_its_phase_does_and_only_where_it_helps():
    from trainer.fitting.calibrate import _insert
    from trainer.fitting.choice import choose
    pipe = [{"step": "thin", "drop": "crowded"}, {"step": "min_spacing", "c": 0.7}]
    assert _insert(pipe, {"step": "coarse_noise", "gain": 1.2}, "noise")[0]["step"] == \
        "coarse_noise"
    assert [e["step"] for e in _insert(pipe, {"step": "even_out", "gain": 0.5}, "points")] == [
        "thin", "even_out", "min_spacing"]  # the spacing stays last
    examples = {64: drawn("poisson_disk", 64, 32, 2)}
    same = lambda v: lambda n, c: drawn("poisson_disk", n, 64, 7)[:c]  # noqa: E731
    chosen, figures = choose((2, 5), 0, same, examples)
    assert chosen == {64: 0} and set(figures[64]["difference"]) == {"0", "2", "5"}


@pytest.mark.slow
def test_a_density_model_is_calibrated_in_the_square(tiny_onnx, tmp_path):
    """The held-in sets are unwarped by the model's map, so the spacing is the square's."""
    import shutil

    import diffsampler_rt
    from diffsampler_rt.density import warp
    from export.defaults import edit_card
    from trainer.fitting.calibrate import calibrate
    from trainer.stats.distance import spacing_coefficient
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    ramp = {"x_cdf": list(np.linspace(0, 1, 9) ** 2), "y_cdf": [list(np.linspace(0, 1, 9))] * 8}
    edit_card(path, lambda card: card.update(density=ramp))
    square = drawn("poisson_disk", 64, 32, 2)
    card = calibrate(path, {64: warp(square, ramp)}, None, [], searches=(), log=lambda _: None)
    c = next(e["c"] for e in card["pipeline"] if e["step"] == "min_spacing")
    assert c == pytest.approx(spacing_coefficient(square, 5.0), abs=2e-3)
    assert diffsampler_rt.Model(path).card["density"] == ramp


# ---- training: resumption and data parallelism ---------------------------------------------

def tiny_fit_trainer(run_dir, pools, seed=0, bf16=False):
    from dataclasses import replace

    from trainer.fitting.data import ExampleBatches
    from trainer.train import Trainer

    from .conftest import tiny_config
    cfg = replace(tiny_config(sampler="examples:t"), bf16=bf16)
    batches = ExampleBatches(pools, {4: 4, 8: 2}, 2.0, (0, 1))
    return Trainer(cfg, run_dir, progress=False, batches=batches)


@pytest.mark.parametrize("bf16", [False, True])
def test_a_restarted_fit_resumes_to_the_same_weights(tmp_path, bf16):
    torch = pytest.importorskip("torch")
    from trainer.embedding import embed
    from trainer.train import native_bf16
    if bf16 and not native_bf16(torch.device("cpu")):
        pytest.skip("bf16 autocast is emulated on this CPU (fit trains in float32 here)")
    pools = {4: embed(jittered(16, 10, 0), "stratified").astype(np.float32),
             8: embed(jittered(64, 10, 1), "stratified").astype(np.float32)}
    whole = tiny_fit_trainer(tmp_path / "a", pools, bf16=bf16)
    whole.run(until_step=6)
    first = tiny_fit_trainer(tmp_path / "b", pools, bf16=bf16)
    first.run(until_step=3)  # "killed" after its checkpoint at step 3
    again = tiny_fit_trainer(tmp_path / "b", pools, bf16=bf16)
    assert again.step == 3
    again.run(until_step=6)
    for (k, a), b in zip(whole.model.state_dict().items(), again.model.state_dict().values()):
        assert torch.equal(a, b), k


def test_a_fit_trains_in_bf16_only_where_the_device_computes_it_natively():
    torch = pytest.importorskip("torch")
    from trainer.fitting.run import uses_bf16
    from trainer.train import native_bf16
    assert uses_bf16(None, "cpu") is native_bf16(torch.device("cpu"))
    assert uses_bf16(False, "cpu") is False and uses_bf16(True, "cpu") is True


def _ddp_worker(rank: int, world: int, init: str, out: str) -> None:
    import torch
    import torch.distributed as dist

    from trainer.embedding import embed
    dist.init_process_group("gloo", init_method=init, rank=rank, world_size=world)
    # each process its own shard of the examples, so different batches
    pools = {4: embed(jittered(16, 8, 10 + rank), "stratified").astype(np.float32),
             8: embed(jittered(64, 8, 20 + rank), "stratified").astype(np.float32)}
    tr = tiny_fit_trainer(f"{out}/rank{rank}", pools)
    sums = []
    for _ in range(3):
        tr.train_step()
        flat = torch.cat([p.detach().reshape(-1) for p in tr.model.parameters()])
        gathered = [torch.empty_like(flat) for _ in range(world)]
        dist.all_gather(gathered, flat)
        sums.append(all(torch.equal(gathered[0], g) for g in gathered))
    torch.save(sums, f"{out}/ok{rank}.pt")
    dist.destroy_process_group()


@pytest.mark.slow
def test_two_gloo_processes_hold_identical_weights_after_each_step(tmp_path):
    torch = pytest.importorskip("torch")
    import torch.multiprocessing as mp
    init = f"file://{tmp_path / 'rendezvous'}"
    mp.spawn(_ddp_worker, args=(2, init, str(tmp_path)), nprocs=2, join=True)
    for rank in range(2):
        assert torch.load(tmp_path / f"ok{rank}.pt") == [True, True, True]


# ---- end to end ---------------------------------------------------------------------------

@pytest.mark.slow
def test_a_small_fit_end_to_end(tmp_path, capsys):
    import diffsampler_rt
    from trainer.__main__ import main
    np.save(tmp_path / "ex64.npy", sample("sobol_owen", 64, count=20, seed=3))
    with open(tmp_path / "ex16.txt", "w") as fh:
        for s in sample("sobol_owen", 16, count=20, seed=4):
            fh.write("".join(f"{x!r} {y!r}\n" for x, y in s.tolist()) + "\n")
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "ex64.npy"), str(tmp_path / "ex16.txt"), "--name",
                 "mine", "-o", str(out), "--minutes", "0.1", "--net", "small",
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "structure every set has: dyadic_net" in printed
    model = diffsampler_rt.load(out / "mine.onnx")
    steps = [e["step"] for e in model.card["pipeline"]]
    # the examples' spacing floor, then the structure (which keeps points in their cells);
    # noise steps may come first, as the briefly trained network's calibration finds them
    from diffsampler_rt.finish import STEPS
    assert [s for s in steps if STEPS[s].phase == "points"][:3] == [
        "min_spacing", "dyadic_net", "thin"]
    assert model.card["fit"]["examples"]["64"] == {"sets": 20, "held_out": 8}
    from trainer.fitting.run import uses_bf16
    saved = json.loads((out / "mine.run" / "fit_config.json").read_text())
    assert saved["bf16"] is uses_bf16(None, "cpu")
    pts = diffsampler_rt.generate(out / "mine.onnx", 100, 3, seed=1)
    assert pts.shape == (3, 100, 2) and np.all((pts >= 0) & (pts < 1))
    report = (out / "mine.report.md").read_text()
    for figure in ("radial spectrum", "pair correlation", "star L2", "n = 256"):
        assert figure in report
    assert (out / "mine.report.png").stat().st_size > 0
    assert not list(out.glob("*.partial*"))


@pytest.mark.slow
def test_calibrate_writes_the_finishing_steps_from_example_sets(tiny_onnx, tmp_path, capsys):
    import shutil

    import diffsampler_rt
    from trainer.__main__ import main
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    np.save(tmp_path / "blue.npy", drawn("poisson_disk", 64, 32, 2))
    assert main(["calibrate", str(path), str(tmp_path / "blue.npy")]) == 0
    card = diffsampler_rt.Model(path).card
    steps = [e["step"] for e in card["pipeline"]]
    thin = steps.index("thin")  # the points' first step; only noise steps come before it
    assert card["pipeline"][thin]["drop"] == "crowded"
    assert set(steps[:thin]) <= {"coarse_noise"}
    assert "min_spacing" in steps and {c["step"] for c in card["calibration"]} >= {
        "min_spacing", "coarse_noise", "sliced_ot", "even_out"}  # each search has its note
    searched = [c["how"].split(":")[0] for c in card["calibration"] if c["step"] == "coarse_noise"]
    assert searched == [s.what for s in SEARCHES[:2]]  # temperature, then the coarse modes
    assert "structure_guidance" not in {c["step"] for c in card["calibration"]}  # no structure
    assert "min_spacing" in capsys.readouterr().out
    # nets: the structure, its guidance searched, the point steps not (they would break it)
    np.save(tmp_path / "nets.npy", sample("sobol_owen", 64, count=32, seed=2))
    assert main(["calibrate", str(path), str(tmp_path / "nets.npy")]) == 0
    card = diffsampler_rt.Model(path).card
    assert [e["step"] for e in card["pipeline"]][-4:] == [
        "min_spacing", "dyadic_net", "thin", "min_spacing"]
    assert card["pipeline"][-3:-1] == [{"step": "dyadic_net", "min_side": 8, "prefix": True},
                                       {"step": "thin", "drop": "random"}]
    assert {c["step"] for c in card["calibration"]} == {
        "thin", "min_spacing", "dyadic_net", "coarse_noise", "structure_guidance"}
    assert main(["calibrate", str(tmp_path / "nope.onnx"), str(tmp_path / "blue.npy")]) == 2


def test_a_net_listed_in_sequence_order_gets_the_prefix():
    """Owen-scrambled Sobol' sets list their points as a (0, 2)-sequence does: their first
    points are smaller nets, so other n take the first points of the next net; the same
    sets shuffled are still nets but their order says nothing."""
    from trainer.fitting.calibrate import in_sequence_order, structure_entry
    nets = sample("sobol_owen", 256, count=6, seed=2)
    assert in_sequence_order(nets)
    assert structure_entry("dyadic_net", [64, 256], {64: sample("sobol_owen", 64, count=6,
                                                                seed=2), 256: nets}) == \
        {"step": "dyadic_net", "min_side": 8, "prefix": True}
    shuffled = np.stack([s[np.random.default_rng(i).permutation(256)] for i, s in
                         enumerate(nets)])
    assert not in_sequence_order(shuffled)
    assert structure_entry("dyadic_net", [256], {256: shuffled}) == \
        {"step": "dyadic_net", "min_side": 16}


def test_blue_noise_is_told_apart_on_processes_the_project_does_not_know():
    """The foreign-process benchmark's processes (benchmarks/foreign.py): hard-core, relaxed
    and lattice-like sets are blue noise at every size; jittered, clustered ones are not."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from foreign import PROCESSES

    from trainer.fitting.calibrate import spacing
    for name, blue in (("jittered", False), ("thomas", False), ("trees", False),
                       ("dart", True), ("lloyd", True), ("hex", True)):
        rng = np.random.default_rng(5)
        sets = {n: np.stack([PROCESSES[name](n, rng) for _ in range(6)]) for n in (64, 256)}
        assert spacing(sets)[1] == blue, name


def test_star_l2_vetoes_only_beyond_its_tolerance_and_mends_a_miss_the_spectrum_cannot_see():
    from trainer.fitting.choice import TOLERANCE, Measured, Target, decide
    rng = np.random.default_rng(0)

    def cand(difference: float, l2: float) -> Measured:
        folds = difference + rng.normal(0, 1e-4, 8)
        return Measured(float(folds.mean()), folds, l2 * (1 + rng.normal(0, 1e-3, 64)),
                        np.full(64, 0.7))

    ref = Target(np.ones(79), [np.ones(79)] * 8, 1.0, 0.7)
    # a clearly closer spectrum, its star L2 3 % off (significant, inside the tolerance)
    value, f = decide({0: cand(0.10, 1.0), 1: cand(0.05, 1.03)}, 0, ref)
    assert value == 1 and f["by"] == "spectrum"
    # 10 % off: not taken, however close its spectrum
    value, f = decide({0: cand(0.10, 1.0), 1: cand(0.05, 1.0 + 2 * TOLERANCE)}, 0, ref)
    assert value == 0 and f["best"] == 0
    # off misses by 6 %: a value 2 % further is taken, one 6 % further is not
    assert decide({0: cand(0.10, 0.94), 1: cand(0.05, 0.92)}, 0, ref)[0] == 1
    assert decide({0: cand(0.10, 0.94), 1: cand(0.05, 0.88)}, 0, ref)[0] == 0
    # the spectrum cannot tell them apart; off misses the star L2 by 20 %: mended
    value, f = decide({0: cand(0.10, 0.8), 1: cand(0.10, 0.9), 2: cand(0.10, 0.99)}, 0, ref)
    assert value == 2 and f["by"] == "star L2"
    # ... but not by a value whose spectrum is further off, nor where off is within 5 %
    assert decide({0: cand(0.10, 0.8), 1: cand(0.2, 0.99)}, 0, ref)[0] == 0
    assert decide({0: cand(0.10, 0.97), 1: cand(0.10, 1.0)}, 0, ref)[0] == 0


def _gauss_candidates(seed: int, noise: float):
    """``cand(difference, gauss)``: a candidate's measurements with that spectrum
    difference and mean Gaussian integration error (per-set relative noise ``noise``)."""
    from trainer.fitting.choice import Measured
    rng = np.random.default_rng(seed)

    def cand(difference: float, gauss: float) -> Measured:
        folds = difference + rng.normal(0, 1e-4, 8)
        return Measured(float(folds.mean()), folds, 1 + rng.normal(0, 1e-3, 64),
                        np.full(64, 0.7), gauss * (1 + rng.normal(0, noise, 64)))
    return cand


def _gauss_target(gauss_se: float):
    """Held-in sets whose figures are all 1 (smallest distance 0.7), the Gaussian
    integration error's mean known to ``gauss_se``."""
    from trainer.fitting.choice import Target
    return Target(np.ones(79), [np.ones(79)] * 8, 1.0, 0.7, gauss=1.0,
                  se={"l2": 0.01, "gauss": gauss_se})


def test_gaussian_integration_vetoes_a_spectrum_gain_and_mends_a_miss_like_star_l2():
    """The smooth integrands' error is held to the held-in sets' as the star L2 is: a
    closer spectrum that integrates Gaussians 20 % worse than without the step is not
    taken; where the spectrum cannot tell values apart, the one that mends a miss is,
    unless the miss is within the noise of the held-in sets' own mean."""
    from trainer.fitting.choice import Target, decide
    cand, ref = _gauss_candidates(2, 1e-3), _gauss_target(0.01)
    value, f = decide({0: cand(0.10, 1.0), 1: cand(0.05, 1.2)}, 0, ref)
    assert value == 0 and f["best"] == 0 and f["gauss_mse"]["1"] == pytest.approx(0.2, abs=0.01)
    assert decide({0: cand(0.10, 1.0), 1: cand(0.05, 1.03)}, 0, ref)[0] == 1
    value, f = decide({0: cand(0.10, 1.3), 1: cand(0.10, 1.02)}, 0, ref)
    assert value == 1 and f["by"] == "Gaussian integration"
    assert decide({0: cand(0.10, 1.3), 1: cand(0.10, 1.02)}, 0, _gauss_target(0.2))[0] == 0
    # without the figure (not measured) the closer spectrum is taken
    assert decide({0: cand(0.10, 1.0), 1: cand(0.05, 1.2)}, 0,
                  Target(np.ones(79), [np.ones(79)] * 8, 1.0, 0.7))[0] == 1


def test_a_gross_integration_miss_is_mended_first_even_at_a_cost_to_the_spectrum():
    """Sets that integrate Gaussians ten times worse than the examples (power at scales
    below the spectrum's first bin) take the value that brings it within a factor 2 and
    closest, though their spectrum is further off; not a value still beyond the factor,
    nor where the spectrum's own choice is within it."""
    from trainer.fitting.choice import decide
    cand, ref = _gauss_candidates(4, 1e-2), _gauss_target(0.01)
    value, f = decide({0: cand(0.08, 10.0), 5: cand(0.09, 1.8), 12: cand(0.10, 0.78),
                       24: cand(0.12, 0.46)}, 0, ref)
    assert value == 12 and f["by"] == "Gaussian integration, missed beyond a factor 2"
    assert decide({0: cand(0.08, 10.0), 5: cand(0.09, 3.0)}, 0, ref)[0] == 0
    value, f = decide({0: cand(0.10, 10.0), 24: cand(0.05, 1.1), 12: cand(0.09, 1.0)}, 0, ref)
    assert value == 24 and f["by"] == "spectrum"


def test_the_spacing_floor_is_what_a_card_can_hold(tiny_onnx, tmp_path):
    """Rounded as the card holds it (a floor that rounds to 0 is none), under the runtime's
    limit (a hexagonal lattice's smallest distance is above it), and two sets at least."""
    import shutil

    from trainer.fitting.calibrate import base_pipeline, calibrate, floor_c, spacing
    close = np.random.default_rng(3).random((12, 1024, 2))
    close[:, 1] = close[:, 0] + 1e-6  # one pair per set a millionth apart
    cs, _, _ = spacing({1024: close})
    assert cs[1024] == 0 and base_pipeline(None, cs, False) == [{"step": "thin",
                                                                 "drop": "random"}]
    k = 16
    i, j = np.meshgrid(np.arange(k), np.arange(k))
    hexa = np.stack([(i + 0.5 * (j % 2) + 0.25) / k, (j + 0.5) * np.sqrt(3) / 2 / k], -1)
    assert floor_c(hexa.reshape(1, -1, 2) * [1, 2 / np.sqrt(3)], 5.0) < 1.07
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    with pytest.raises(ValueError, match="at least 2 example sets at each size, got 1 at n = 64"):
        calibrate(path, {64: close[:1, :64], 256: close[:3, :256]}, None, [])


def test_the_spacing_rises_to_the_percentile_that_matches_the_examples_smallest_distance():
    from trainer.fitting.choice import Measured, Target, decide_spacing
    rng = np.random.default_rng(1)

    def cand(smallest: float, difference: float = 0.1) -> Measured:
        folds = difference + rng.normal(0, 1e-4, 8)
        return Measured(float(folds.mean()), folds, np.full(64, 1.0) + rng.normal(0, 1e-3, 64),
                        smallest + rng.normal(0, 0.01, 64))

    goal = Target(np.ones(79), [np.ones(79)] * 8, 1.0, 0.7)
    # the floor leaves the sets' smallest distance 29 % short; the 30th percentile meets it
    value, f = decide_spacing({5: cand(0.5), 15: cand(0.6), 30: cand(0.69), 50: cand(0.8)}, 5,
                              goal)
    assert value == 30 and f["smallest"]["5"] == pytest.approx(-0.29, abs=0.01)
    # not where its spectrum is further off, nor where the floor already meets it
    assert decide_spacing({5: cand(0.5), 30: cand(0.7, difference=0.3)}, 5, goal)[0] == 5
    assert decide_spacing({5: cand(0.7), 30: cand(0.7)}, 5, goal)[0] == 5


def test_a_search_does_not_take_the_generated_sets_own_noise_for_a_gain():
    """Held-in lattices all have one spectrum (no noise of their own); candidates that only
    draw other random sets must not beat 'off' by that noise: the folds see it."""
    from trainer.fitting.choice import choose
    k = np.arange(64)
    lattice = np.stack([np.stack([k / 64, (k * 19 / 64) % 1], -1) + r for r in
                        np.random.default_rng(0).random((16, 1, 2))]) % 1
    taken = 0
    for seed in range(20):
        def noisy(v, seed=seed):
            return lambda n, c: np.random.default_rng([seed, int(10 * v)]).random((c, n, 2))
        chosen, figures = choose((1, 2, 3, 4, 5), 0, noisy, {64: lattice})
        taken += chosen[64] != 0
    assert taken <= 1  # about 1 search in 100 takes such a value (choice.GAIN_SE)


def test_report_verdicts_name_the_miss_against_the_floor():
    from trainer.fitting.report import Figure
    assert Figure("s", 0.01, 0.0, 0.006, "curve").verdict() == "within noise"
    assert Figure("s", 0.03, 0.0, 0.01, "curve").verdict() == "off by 3.0x the floor"
    assert Figure("s", 0.1, 0.0, 0.0, "curve").verdict() == "off by 0.1000 (floor 0)"  # lattices
    assert Figure("m", 1.1, 1.0, 0.02, "mean").verdict() == "off by +10.0 %"
