"""The (0, m, 2)-net structure the runtime imposes on decoded sets (diffsampler_rt.structure)."""
import doctest
import shutil

import numpy as np
import pytest

import diffsampler_rt
from diffsampler_rt import structure
from diffsampler_rt.structure import impose_dyadic_net, impose_n_rooks
from trainer.stats import empty_elementary_fraction, t_value
from trainer.stats.structure import stratified_projections

from .conftest import changed_pipeline_error, pipeline_card_error


def _export_pipeline(path, *args) -> int:
    """``python -m export pipeline PATH ARGS...`` (the CLI's main): its exit status."""
    from export.__main__ import main as export_main
    return export_main(["pipeline", str(path), *map(str, args)])


def _entry(path, step: str) -> dict | None:
    """The parameters of the card's ``step`` entry in the model at ``path``, or None."""
    from diffsampler_rt.finish.pipeline import find
    return find(diffsampler_rt.Model(path).card["pipeline"], step)


def jittered(k: int, count: int, seed: int = 0) -> np.ndarray:
    """One uniform point per cell, row-major cell order (what a stratified decode gives)."""
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
    return (cells + np.random.default_rng(seed).random((count, k * k, 2))) / k


@pytest.mark.parametrize("k", [2, 4, 8, 32])
def test_imposed_sets_are_nets_and_keep_their_cells(k):
    pts = jittered(k, 6)
    if k >= 8:  # jittered sets are far from nets
        assert empty_elementary_fraction(pts).mean() > 0.1
    out = impose_dyadic_net(pts, k)
    assert out.shape == pts.shape and out.dtype == np.float64
    assert np.all((out >= 0) & (out < 1))
    assert np.all(t_value(out) == 0)  # every elementary interval holds exactly one point
    np.testing.assert_array_equal(np.floor(out * k), np.floor(pts * k))
    # moves stay inside the cell: at most one cell width, mostly far less
    assert np.abs(out - pts).max() < 1 / k and np.abs(out - pts).mean() < 0.25 / k


def test_nets_are_left_unchanged():
    from trainer.samplers import sample
    ref = sample("sobol_owen", 256, count=4, seed=3)
    k = 16
    # the runtime's sets come in row-major cell order
    cell = (np.floor(ref[..., 1] * k) * k + np.floor(ref[..., 0] * k)).astype(int)
    ordered = np.take_along_axis(ref, np.argsort(cell, axis=1)[..., None], axis=1)
    np.testing.assert_array_equal(impose_dyadic_net(ordered, k), ordered)
    out = impose_dyadic_net(jittered(k, 2), k)
    np.testing.assert_array_equal(impose_dyadic_net(out, k), out)  # idempotent


def test_bad_sides_are_refused():
    with pytest.raises(ValueError, match="power-of-two grid side, got k=24"):
        impose_dyadic_net(jittered(24, 1), 24)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 64, 2\)"):
        impose_dyadic_net(np.zeros((1, 60, 2)), 8)
    with pytest.raises(ValueError, match="one per grid cell in row-major cell order"):
        impose_dyadic_net(jittered(8, 1)[:, ::-1], 8)


def test_card_structure_is_applied_at_power_of_two_sides(tiny_onnx, tmp_path):
    from export.pipeline_edit import edit_pipeline
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    plain = {n: diffsampler_rt.Model(path).generate(n, 3, seed=5) for n in (64, 144)}
    card = edit_pipeline(path, add="dyadic_net", at=0)  # before the thinning
    assert [e["step"] for e in card["pipeline"]] == ["dyadic_net", "thin"]
    m = diffsampler_rt.Model(path)
    net = m.generate(64, 3, seed=5)
    assert np.all(t_value(net) == 0) and not np.all(t_value(plain[64]) == 0)
    np.testing.assert_array_equal(net, impose_dyadic_net(plain[64], 8))
    np.testing.assert_array_equal(m.generate(64, 3, seed=5, structure=False), plain[64])
    blocks = np.concatenate(list(m.iter_sets(64, 3, batch=2, seed=5)))
    np.testing.assert_array_equal(blocks, net)
    np.testing.assert_array_equal(m.generate(144, 3, seed=5), plain[144])  # k = 12: no net
    card = edit_pipeline(path, remove="dyadic_net")
    assert [e["step"] for e in card["pipeline"]] == ["thin"]
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(64, 3, seed=5), plain[64])
    with pytest.raises(ValueError, match="unknown step 'lattice'"):
        edit_pipeline(path, add="lattice", at=0)


def test_card_structure_is_validated():
    def grid(pipe):
        pipe[[e["step"] for e in pipe].index("dyadic_net")] = {"step": "grid"}

    assert "unknown step 'grid'" in changed_pipeline_error("sobol_owen", grid, "unknown step")
    assert diffsampler_rt.load("rank1").card["embedding"] == "ot"
    pipeline_card_error("rank1", [{"step": "dyadic_net"}, {"step": "thin"}],
                        "step 'dyadic_net' needs the stratified embedding")


@pytest.mark.parametrize("k", [3, 8, 16])
def test_n_rooks_stratifies_both_projections_and_keeps_cells(k):
    pts = jittered(k, 6)
    assert not stratified_projections(pts).any()
    out = impose_n_rooks(pts, k)
    assert out.shape == pts.shape and np.all((out >= 0) & (out < 1))
    assert stratified_projections(out).all()
    np.testing.assert_array_equal(np.floor(out * k), np.floor(pts * k))
    # each coordinate goes to the nearest point of its new 1/n strip, a few strips at most
    assert np.abs(out - pts).max() < 1 / k
    np.testing.assert_array_equal(impose_n_rooks(out, k), out)  # idempotent
    kept = np.floor(out * (k * k)) == np.floor(pts * (k * k))
    np.testing.assert_array_equal(out[kept], pts[kept])  # a point in its strip is not moved


def test_n_rooks_leaves_ldbn_sets_unchanged():
    from trainer.samplers import sample
    k = 16
    ref = sample("ldbn", k * k, count=3, seed=2)
    cell = (np.floor(ref[..., 1] * k) * k + np.floor(ref[..., 0] * k)).astype(int)
    ordered = np.take_along_axis(ref, np.argsort(cell, axis=1)[..., None], axis=1)
    np.testing.assert_array_equal(impose_n_rooks(ordered, k), ordered)
    with pytest.raises(ValueError, match="one per grid cell"):
        impose_n_rooks(ordered[:, ::-1], k)


def _block_strata(pts: np.ndarray, k: int, block: int) -> bool:
    """Whether every aligned block of B = block, 2 block, ... k cells of each column (row)
    puts its B points in B distinct sub-columns (sub-rows) of width 1/(k B)."""
    grid = pts.reshape(-1, k, k, 2)
    for axis, coord in ((1, grid[..., 0]), (2, grid[..., 1])):  # x down columns, y along rows
        along = np.moveaxis(coord, axis, -1)  # (set, other index, k cells of the run)
        b = block
        while b <= k:
            sub = np.floor(along * k * b).astype(int) % b  # sub-strip of width 1/(k b) in cell
            runs = np.sort(sub.reshape(*sub.shape[:-1], k // b, b), axis=-1)
            if not np.array_equal(runs, np.broadcast_to(np.arange(b), runs.shape)):
                return False
            b *= 2
    return True


@pytest.mark.parametrize("k, block", [(32, 16), (64, 32), (64, 4), (16, 16)])
def test_n_rooks_blocks_stratify_every_block_from_b_up(k, block):
    pts = jittered(k, 3)
    out = impose_n_rooks(pts, k, block=block)
    assert stratified_projections(out).all() and _block_strata(out, k, block)
    assert not _block_strata(impose_n_rooks(pts, k), k, block) or block >= k
    np.testing.assert_array_equal(np.floor(out * k), np.floor(pts * k))  # cells kept
    np.testing.assert_array_equal(impose_n_rooks(out, k, block=block), out)  # idempotent
    if block >= k:  # plain n-rooks
        np.testing.assert_array_equal(out, impose_n_rooks(pts, k))


@pytest.mark.parametrize("k", [32, 64])
def test_ldbn_sets_have_the_blocks_from_16_and_keep_them(k):
    """LDBN's offsets are radical inverses of 16 consecutive integers per aligned block of 16
    cells: its sets are stratified in blocks of 16 and up (not 8) and impose_n_rooks with
    block 16 leaves them as they are."""
    from trainer.samplers import sample
    ref = sample("ldbn", k * k, count=3, seed=5)
    cell = (np.floor(ref[..., 1] * k) * k + np.floor(ref[..., 0] * k)).astype(int)
    ordered = np.take_along_axis(ref, np.argsort(cell, axis=1)[..., None], axis=1)
    assert _block_strata(ordered, k, 16) and not _block_strata(ordered, k, 8)
    np.testing.assert_array_equal(impose_n_rooks(ordered, k, block=16), ordered)


@pytest.mark.parametrize("k, block, message", [
    (32, 3, "power of two >= 1, got 3"), (32, 0, "got 0"), (32, True, "got True"),
    (24, 8, "power-of-two grid side, got k=24"),
])
def test_n_rooks_block_is_validated(k, block, message):
    with pytest.raises(ValueError, match="block") as err:
        impose_n_rooks(jittered(k, 1), k, block=block)
    assert message in str(err.value)
    impose_n_rooks(jittered(24, 1), 24, block=32)  # a block of k or more: plain n-rooks


def _changed(step: str, **params):
    """A pipeline edit: the ``step`` entry's parameters changed (None removes one)."""
    def edit(pipe):
        entry = next(e for e in pipe if e["step"] == step)
        entry.update(params)
        for key in [k for k, v in entry.items() if v is None]:
            del entry[key]
    return edit


def _n_rooks_changed(**params):
    return _changed("n_rooks", **params)


def _n_rooks_replaced(entry: dict):
    """A pipeline edit: the n_rooks entry replaced by ``entry``."""
    def edit(pipe):
        pipe[next(i for i, e in enumerate(pipe) if e["step"] == "n_rooks")] = entry
    return edit


@pytest.mark.parametrize("edit, message", [
    (_n_rooks_replaced({"step": "dyadic_net", "block": 32}),
     "step 'dyadic_net' has no parameter 'block'"),
    (_n_rooks_changed(block=24), "got 24"),
    (_n_rooks_changed(block=32.0), "got 32.0"),
    (_n_rooks_changed(block={"sides": [128, 64], "block": [64, 32]}), "increasing"),
    (_n_rooks_changed(block={"sides": [64], "block": [32, 64]}), "got {"),
    (_n_rooks_changed(block={"sides": [64], "blocks": [32]}), "got {"),
    (_changed("thin", block=32), "step 'thin' has no parameter 'block'"),
])
def test_card_structure_block_is_validated(edit, message):
    assert message in changed_pipeline_error("ldbn_fast", edit, "block")


def _refused(path, capsys, args, *texts) -> None:
    """``python -m export pipeline PATH ARGS`` exits 2 with one "error: ..." line holding
    every text, and leaves the file as it was."""
    before = path.read_bytes()
    capsys.readouterr()
    assert _export_pipeline(path, *args) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), captured.err
    assert all(text in err[0] for text in texts), (texts, err[0])
    assert captured.out == ""
    assert path.read_bytes() == before


def test_card_structure_block_applies_in_the_solver_and_on_the_sets(tiny_onnx, tmp_path,
                                                                    capsys):
    """pipeline --update n_rooks --block writes it; at k = 32 the runtime's sets then have
    the blocks of 16 and the guided steps project onto them too; --block none removes it."""
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    assert _export_pipeline(path, "--add", "n_rooks", "--min-side", "16", "--at", "0") == 0
    plain = diffsampler_rt.Model(path).generate(1024, 2, seed=4)
    assert not _block_strata(plain, 32, 16)
    capsys.readouterr()
    assert _export_pipeline(path, "--update", "n_rooks", "--block", "16") == 0
    assert "0. n_rooks: n-rooks projections imposed at k >= 16, blocks of 16 cells and up" \
        in capsys.readouterr().out
    m = diffsampler_rt.Model(path)
    out = m.generate(1024, 2, seed=4)
    assert _block_strata(out, 32, 16)
    np.testing.assert_array_equal(m.generate(256, 2, seed=4),  # k = 16: plain n-rooks
                                  diffsampler_rt.Model(path).generate(256, 2, seed=4))
    assert _export_pipeline(path, "--add", "structure_guidance", "--steps", "2", "--at",
                            "0") == 0
    guided = diffsampler_rt.Model(path).generate(1024, 2, seed=4)
    assert _block_strata(guided, 32, 16) and not np.array_equal(guided, out)
    _refused(path, capsys, ["--update", "n_rooks", "--block", "x"],
             "step 'n_rooks': 'block' must be a power of two", "got 'x'")
    # per grid side: blocks of 16 at k = 32 only, plain n-rooks at the sides not listed
    assert _export_pipeline(path, "--update", "n_rooks", "--block",
                            '{"sides": [32, 64], "block": [16, 32]}') == 0
    assert "blocks of 16 cells and up at k = 32, 32 cells and up at k = 64" in \
        capsys.readouterr().out
    assert _entry(path, "n_rooks")["block"] == {"sides": [32, 64], "block": [16, 32]}
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(1024, 2, seed=4), guided)
    assert _export_pipeline(path, "--update", "n_rooks", "--block",
                            '{"sides": [64], "block": [16]}') == 0
    assert not _block_strata(diffsampler_rt.Model(path).generate(1024, 2, seed=4), 32, 16)
    for bad in ("64:16:2", "12", "32:16,64:32"):  # a per-size table is not a block table
        _refused(path, capsys, ["--update", "n_rooks", "--block", bad], "'block'")
    assert _export_pipeline(path, "--update", "n_rooks", "--block", "none") == 0
    assert "block" not in _entry(path, "n_rooks")
    assert _export_pipeline(path, "--update", "n_rooks", "--block", "16") == 0
    # the guidance needs the structure: it goes first, then the structure with its block
    _refused(path, capsys, ["--remove", "n_rooks"], "'structure_guidance'",
             "needs a structure step")
    assert _export_pipeline(path, "--remove", "structure_guidance") == 0
    assert _export_pipeline(path, "--remove", "n_rooks") == 0
    assert [e["step"] for e in diffsampler_rt.Model(path).card["pipeline"]] == ["thin"]
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(1024, 2, seed=4),
                                  diffsampler_rt.Model(tiny_onnx).generate(1024, 2, seed=4))


def test_n_rooks_card_min_side_and_guidance(tiny_onnx, tmp_path):
    from diffsampler_rt.finish.pipeline import find
    from export.pipeline_edit import edit_pipeline
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    plain = {n: diffsampler_rt.Model(path).generate(n, 2, seed=4) for n in (64, 256)}
    edit_pipeline(path, add="n_rooks", at=0, params={"min_side": 16})
    m = diffsampler_rt.Model(path)
    np.testing.assert_array_equal(m.generate(64, 2, seed=4), plain[64])  # k = 8 < 16
    rooks = m.generate(256, 2, seed=4)
    np.testing.assert_array_equal(rooks, impose_n_rooks(plain[256], 16))
    card = edit_pipeline(path, add="structure_guidance", at=0, params={"steps": 3})
    assert (find(card["pipeline"], "n_rooks"), find(card["pipeline"], "structure_guidance")) \
        == ({"min_side": 16}, {"steps": 3})
    m = diffsampler_rt.Model(path)
    guided = m.generate(256, 2, seed=4)
    assert stratified_projections(guided).all() and not np.array_equal(guided, rooks)
    np.testing.assert_array_equal(m.generate(256, 2, seed=4, structure=False), plain[256])
    np.testing.assert_array_equal(np.concatenate(list(m.iter_sets(256, 2, batch=1, seed=4))),
                                  guided)
    edit_pipeline(path, remove="structure_guidance")
    card = edit_pipeline(path, remove="n_rooks")
    assert [e["step"] for e in card["pipeline"]] == ["thin"]


def _spaced(points: np.ndarray, k: int) -> np.ndarray:
    from diffsampler_rt.spacing import enforce_min_spacing
    return enforce_min_spacing(points, 0.7 / k)


def _evened(points: np.ndarray, k: int) -> np.ndarray:
    from diffsampler_rt.low_frequencies import even_out
    return even_out(points, 0.6, cut=0.5)


@pytest.mark.parametrize("setting, move", [
    ({"step": "min_spacing", "c": 0.7}, _spaced),
    ({"step": "even_out", "cut": 0.5, "gain": 0.6}, _evened),
])
def test_moves_go_before_an_imposed_structure(tiny_onnx, tmp_path, setting, move):
    """The structure must hold exactly, so a card's spacing and evening move the decoded set
    before it (after it, the moves would take points out of their strips); where none is
    imposed, after: the pipeline lists the move before the structure where it holds, and
    after the thinning where it does not."""
    from export.defaults import edit_card
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    plain = {n: diffsampler_rt.Model(path).generate(n, 3, seed=6) for n in (64, 256)}

    def moves_around_the_structure(card):
        assert [e["step"] for e in card["pipeline"]] == ["thin"]
        card["pipeline"] = [{**setting, "where": "structured"},
                            {"step": "n_rooks", "min_side": 16}, *card["pipeline"],
                            {**setting, "where": "unstructured"}]

    edit_card(path, moves_around_the_structure)
    m = diffsampler_rt.Model(path)
    both = m.generate(256, 3, seed=6)
    # a move may cross a cell border; the structure puts the point back in a strip of its
    # own cell (so the checked impose_n_rooks would refuse the moved set)
    np.testing.assert_array_equal(both, structure.impose(move(plain[256], 16), 16, "n_rooks"))
    assert stratified_projections(both).all()
    cells = np.stack(np.meshgrid(np.arange(16), np.arange(16)), -1).reshape(-1, 2)
    assert np.array_equal(np.floor(both * 16), np.broadcast_to(cells, both.shape))
    np.testing.assert_array_equal(m.generate(64, 3, seed=6),  # k = 8 < 16: the move only
                                  move(plain[64], 8))
    # after the structure, the move would break it
    assert not stratified_projections(move(both, 16)).all()


@pytest.mark.parametrize("name", ["ldbn", "ldbn_fast"])
def test_bundled_cards_move_before_their_structure(name):
    """ldbn's cards space (and even) their sets before imposing n-rooks where it holds, and
    after thinning where it does not."""
    pipe = diffsampler_rt.load(name).card["pipeline"]
    steps = [(e["step"], e.get("where")) for e in pipe]
    structure_at, thin_at = steps.index(("n_rooks", None)), steps.index(("thin", None))
    assert structure_at < thin_at
    for move in ("min_spacing", "even_out"):
        assert steps.index((move, "structured")) < structure_at
        assert steps.index((move, "unstructured")) > thin_at


@pytest.mark.parametrize("pipeline, message", [
    ([{"step": "structure_guidance", "steps": 2}, {"step": "thin"}],
     "pipeline entry 0 ('structure_guidance') needs a structure step in the pipeline"),
    ([{"step": "min_spacing", "c": 0.7, "where": "structured"}, {"step": "thin"}],
     "pipeline entry 0 ('min_spacing') needs a structure step in the pipeline"),
    ([{"step": "thin", "min_side": 16}], "step 'thin' has no parameter 'min_side'"),
    ([{"step": "n_rooks", "min_side": 0}, {"step": "thin"}],
     "pipeline entry 0: step 'n_rooks': 'min_side' must be an integer in [1, inf], got 0"),
    ([{"step": "structure_guidance", "steps": -1}, {"step": "n_rooks"}, {"step": "thin"}],
     "pipeline entry 0: step 'structure_guidance': 'steps' must be an integer in [0, inf] "
     "or a per-size table"),
    ([{"step": "structure_guidance", "steps": 1.5}, {"step": "n_rooks"}, {"step": "thin"}],
     "got 1.5"),
    ([{"step": "structure_guidance", "steps": True}, {"step": "n_rooks"}, {"step": "thin"}],
     "got True"),
    ([{"step": "structure_guidance", "steps": 2.5}, {"step": "n_rooks"}, {"step": "thin"}],
     "got 2.5"),
    ([{"step": "n_rooks"}, {"step": "dyadic_net"}, {"step": "thin"}],
     "a pipeline holds at most one structure step, got ['n_rooks', 'dyadic_net']"),
])
def test_structure_settings_are_validated(pipeline, message):
    pipeline_card_error("sobol_owen", pipeline, message)


def test_docstring_examples():
    assert doctest.testmod(structure).failed == 0


def test_bundled_sobol_owen_fast_makes_nets_at_its_6_step_default():
    m = diffsampler_rt.load("sobol_owen_fast")
    assert (m.card["default_solver"], m.card["default_steps"]) == ("ddim", 6)
    assert m.card["distillation"]["teacher"] == "sobol_owen"
    pts = m.generate(256, 2, seed=0)
    assert np.all(empty_elementary_fraction(pts) == 0)
    assert np.any(empty_elementary_fraction(m.generate(256, 2, seed=0, structure=False)) > 0)


def _runs_strata(pts: np.ndarray, k: int, run: int) -> np.ndarray:
    """Per set and axis (sets, 2): the alignment (0: first cell, 1: last) whose full runs of
    ``run`` cells of every column (row) hold ``run`` distinct sub-strips of width
    1/(k run), and whose partial run distinct ones too, or -1 where neither does."""
    grid = pts.reshape(-1, k, k, 2)
    out = -np.ones((len(grid), 2), dtype=int)
    full = k // run * run
    for c, (axis, coord) in enumerate(((1, grid[..., 0]), (2, grid[..., 1]))):
        along = np.moveaxis(coord, axis, -1)
        sub = np.floor(along * k * run).astype(int) % run
        for a, start in reversed(list(enumerate((0, k - full)))):
            part = np.sort(sub[..., start:start + full].reshape(*sub.shape[:-1], -1, run), -1)
            ok = np.all(part == np.arange(run), axis=(1, 2, 3))
            rest = np.sort(np.concatenate([sub[..., :start], sub[..., start + full:]], -1), -1)
            ok &= np.all(np.diff(rest, axis=-1) > 0, axis=(1, 2))  # the partial run's
            out[ok, c] = a
    return out


@pytest.mark.parametrize("k, run", [(24, 16), (20, 16), (48, 16), (12, 4)])
def test_runs_stratify_every_full_run_and_keep_cells(k, run):
    pts = jittered(k, 4)
    assert np.all(_runs_strata(pts, k, run) == -1)
    out = structure.impose_runs(pts, k, run)
    assert np.all(_runs_strata(out, k, run) >= 0)
    np.testing.assert_array_equal(np.floor(out * k), np.floor(pts * k))  # cells kept
    assert np.abs(out - pts).max() < 1 / k
    np.testing.assert_array_equal(structure.impose_runs(out, k, run), out)  # idempotent
    if k % run == 0:  # one alignment: every run full
        assert np.all(_runs_strata(out, k, run) == 0)


def test_runs_leave_ldbn_sets_at_other_sides_unchanged():
    """LDBN's sets at k = 24 have one full run of 16 stratified cells per column and row,
    aligned with either end (its mirror images), and the partial run's 8 points in
    distinct sub-strips; imposing runs of 16 leaves them as they are."""
    from trainer.samplers import sample
    k = 24
    ref = sample("ldbn", k * k, count=8, seed=6)
    cell = (np.floor(ref[..., 1] * k) * k + np.floor(ref[..., 0] * k)).astype(int)
    ordered = np.take_along_axis(ref, np.argsort(cell, axis=1)[..., None], axis=1)
    aligned = _runs_strata(ordered, k, 16)
    assert np.all(aligned >= 0) and len(np.unique(aligned)) == 2  # both alignments occur
    np.testing.assert_array_equal(structure.impose_runs(ordered, k, 16), ordered)
    assert not stratified_projections(ordered).any()  # no n-rooks at 24 in LDBN either


@pytest.mark.parametrize("run", [1, 25, 2.0, True])
def test_runs_are_validated(run):
    with pytest.raises(ValueError, match=r"run must be an integer in \[2, k=24\], got"):
        structure.impose_runs(jittered(24, 1), 24, run)


@pytest.mark.parametrize("edit, message", [
    (_n_rooks_changed(runs=1), "step 'n_rooks': 'runs' must be an integer in [2, inf], got 1"),
    (_n_rooks_changed(runs=16.0), "got 16.0"),
    (_n_rooks_changed(runs=True), "got True"),
    (_n_rooks_replaced({"step": "dyadic_net", "runs": 16}),
     "step 'dyadic_net' has no parameter 'runs'"),
])
def test_card_structure_runs_is_validated(edit, message):
    assert message in changed_pipeline_error("ldbn_fast", edit, "runs")


def test_card_structure_runs_apply_at_other_sides_only(tiny_onnx, tmp_path, capsys):
    """pipeline --update n_rooks --runs 16: at k = 24 (not a power of two) the sets' full
    runs are stratified, projected in the guided steps too; power-of-two sides are as
    before."""
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_onnx, path)
    assert _export_pipeline(path, "--add", "n_rooks", "--min-side", "16", "--at", "0") == 0
    plain = diffsampler_rt.Model(path)
    assert np.all(_runs_strata(plain.generate(576, 2, seed=4), 24, 16) == -1)
    capsys.readouterr()
    assert _export_pipeline(path, "--update", "n_rooks", "--runs", "16") == 0
    assert "0. n_rooks: n-rooks projections imposed at k >= 16, runs of 16 at other sides" \
        in capsys.readouterr().out
    m = diffsampler_rt.Model(path)
    out = m.generate(576, 2, seed=4)
    assert np.all(_runs_strata(out, 24, 16) >= 0)
    for n in (256, 1024, 144):  # powers of two as before; k = 12 < 16: no structure
        np.testing.assert_array_equal(m.generate(n, 2, seed=4), plain.generate(n, 2, seed=4))
    assert _export_pipeline(path, "--add", "structure_guidance", "--steps", "2", "--at",
                            "0") == 0
    guided = diffsampler_rt.Model(path).generate(576, 2, seed=4)
    assert np.all(_runs_strata(guided, 24, 16) >= 0) and not np.array_equal(guided, out)
    _refused(path, capsys, ["--update", "n_rooks", "--runs", "1"],
             "step 'n_rooks': 'runs' must be an integer in [2, inf], got 1")
    assert _export_pipeline(path, "--update", "n_rooks", "--runs", "none") == 0
    assert "runs" not in _entry(path, "n_rooks")
    np.testing.assert_array_equal(diffsampler_rt.Model(path).generate(576, 2, seed=4),
                                  diffsampler_rt.Model(path).generate(576, 2, seed=4,
                                                                      structure=False))
