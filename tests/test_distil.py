"""Warm start from ONNX and few-step distillation (trainer.warm_start, trainer.distil)."""
import json
import warnings

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

import diffsampler_rt  # noqa: E402
from trainer import zoo  # noqa: E402
from diffsampler_rt.schedule import alphas_cumprod, timesteps  # noqa: E402
from diffsampler_rt.solvers import ddim, solve  # noqa: E402
from trainer.distil import (DistilConfig, Distiller, hop_loss, hop_times,  # noqa: E402
                            teacher_trajectories)
from trainer.warm_start import net_from_onnx  # noqa: E402

from .conftest import TINY_ONNX_UNET, TINY_UNET, recipe_stage, tiny_config  # noqa: E402

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow


def tiny_distil(teacher, **changes) -> DistilConfig:
    """A distillation of a tiny teacher small enough for a test (a few seconds)."""
    return DistilConfig(**{"teacher": str(teacher), "name": "tiny_fast", "student_steps": 2,
                           "teacher_steps": 4, "teacher_solver": "ddim", "sizes": (4, 8),
                           "trajectories": (6, 4), "batch_sizes": (3, 2), "steps": 2,
                           "warmup_steps": 1, "attention_window": 2, "lr": 1e-3, **changes})


def student_denoiser(d: Distiller):
    """The student's noise prediction as a numpy denoiser, for the runtime's solvers."""
    def eps_fn(xn, t):
        with torch.no_grad():
            return d.model(torch.tensor(xn, dtype=torch.float32),
                           torch.full((len(xn),), float(t))).numpy()
    return eps_fn


def export_untrained_student(d: Distiller, path):
    """Export a student after a few steps: its still-equal (untrained) tensors, which the
    exporter stores once and net_from_onnx could not read back, made to differ first, as
    training does."""
    from export.onnx_export import export_checkpoint
    from trainer.train import save_run

    with torch.no_grad():
        for p in d.ema.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return export_checkpoint(save_run(d), path, parity_sides=(8,))[0]


def test_net_from_onnx_reads_untrained_group_norms(tmp_path):
    """A fresh net's GroupNorm constants are all equal (weights 1, biases 0): the exporter
    stores each once for several layers, and every layer's use is read back (fit --fast on
    a barely trained teacher failed on it)."""
    from export.onnx_export import export_model, model_card
    from trainer.unet import UNet
    torch.manual_seed(0)
    cfg = tiny_config()
    net = UNet(cfg.unet).eval()
    with torch.no_grad():  # every other tensor made distinct (zero-initialised biases too)
        for name, p in net.named_parameters():
            if "norm" not in name:
                p.add_(0.05 * torch.randn_like(p))
    assert all(torch.equal(p, torch.ones_like(p)) for n, p in net.named_parameters()
               if "norm" in n and n.endswith("weight"))
    path = tmp_path / "fresh.onnx"
    export_model(net, model_card(cfg, training_steps=0), path, fp16_weights=False)
    got = net_from_onnx(path)[0].state_dict()
    for name, value in net.state_dict().items():
        assert torch.equal(got[name], value), name
    # an untouched net's zero biases are stored once too: refused with a typed error, which
    # fit --fast turns into "fit longer"
    from trainer.warm_start import MissingWeightsError
    export_model(UNet(cfg.unet).eval(), model_card(cfg, training_steps=0),
                 tmp_path / "untouched.onnx", fp16_weights=False)
    with pytest.raises(MissingWeightsError, match="weights missing"):
        net_from_onnx(tmp_path / "untouched.onnx")


def test_net_from_onnx_recovers_every_weight(tiny_onnx):
    # the fixture keeps the exported net's state dict next to the file
    ref = torch.load(tiny_onnx.with_suffix(".state"))
    net, cfg, card = net_from_onnx(tiny_onnx)
    assert cfg.unet == tiny_config(**TINY_ONNX_UNET).unet
    assert card["name"] == "tiny"
    got = net.state_dict()
    assert set(got) == set(ref)
    for name, value in ref.items():  # GroupNorm weights included (folded by the exporter)
        assert torch.equal(got[name], value), name
    m = diffsampler_rt.Model(tiny_onnx)
    x = np.random.default_rng(0).standard_normal((2, 2, 9, 9))
    with torch.no_grad():
        eps = net(torch.tensor(x, dtype=torch.float32), torch.full((2,), 30.0)).numpy()
    np.testing.assert_allclose(eps, m.denoise(x, 30), atol=1e-5)


class _Oracle(torch.nn.Module):
    """A 'net' that returns a fixed eps, whatever its input."""

    def __init__(self, eps):
        super().__init__()
        self.eps = eps

    def forward(self, x, t):
        return self.eps


@pytest.mark.parametrize("weighting", ["snr", "truncated_snr"])
@pytest.mark.parametrize("last", [False, True])
def test_hop_loss_is_zero_exactly_when_ddim_lands_on_the_target(last, weighting):
    ab = alphas_cumprod({"kind": "linear", "beta_start": 1e-4, "beta_end": 0.02,
                         "num_steps": 1000})
    rng = np.random.default_rng(3)
    x_t = rng.standard_normal((3, 2, 5, 5))
    eps = rng.standard_normal((3, 2, 5, 5))
    t, t_next = 874, (-1 if last else 749)
    # DDIM's own hop from t to t_next with this eps (ts ending at t: the step goes to clean)
    x_next = ddim(lambda x, s: eps, x_t, ab, [t] if last else [t, t_next])
    if not last:  # ddim ran on to clean data; redo only the first hop
        x0 = (x_t - np.sqrt(1 - ab[t]) * eps) / np.sqrt(ab[t])
        x_next = np.sqrt(ab[t_next]) * x0 + np.sqrt(1 - ab[t_next]) * eps
    f = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    args = (f(x_t), f(x_next), torch.full((3,), t), torch.full((3,), t_next),
            torch.tensor(ab, dtype=torch.float32))
    assert hop_loss(_Oracle(f(eps)), *args, weighting).item() < 1e-6
    assert hop_loss(_Oracle(f(eps) + 0.1), *args, weighting).item() > 1e-3
    if weighting == "snr":  # = the squared error of the implied noise
        assert hop_loss(_Oracle(f(eps) + 0.1), *args, weighting).item() == pytest.approx(0.01)


def test_hop_times_end_in_clean_data():
    assert list(hop_times(1000, 4)) == [999, 749, 499, 249, -1]


def test_teacher_trajectory_rows_are_the_solver_states(tiny_onnx):
    m = diffsampler_rt.Model(tiny_onnx)
    T = len(m.alpha_bar)
    tr = teacher_trajectories(m, 6, 5, teacher_steps=4, student_steps=2, solver="ddim",
                              seed=7, batch=3)
    assert tr.shape == (3, 5, 2, 6, 6) and tr.dtype == np.float32
    x = np.random.default_rng([7, 6]).standard_normal((3, 2, 6, 6))  # first batch
    np.testing.assert_allclose(tr[0, :3], x, atol=1e-6)
    ts = timesteps(T, 4)
    states = []  # the states the solver visits, one per teacher step
    solve("ddim", lambda y, t: (states.append(y.copy()), m.denoise(y, t))[1], x,
          m.alpha_bar, ts)
    np.testing.assert_allclose(tr[1, :3], states[2], atol=1e-5)
    np.testing.assert_allclose(tr[2, :3], solve("ddim", m.denoise, x, m.alpha_bar, ts),
                               atol=1e-5)
    with pytest.raises(ValueError, match="not part of"):
        teacher_trajectories(m, 6, 1, teacher_steps=3, student_steps=2, solver="ddim", seed=0)


def test_guided_teacher_trajectories_follow_its_card_guide(tiny_onnx, tmp_path, monkeypatch):
    """With teacher_guidance the trajectories are the guided teacher's, at the card's weight
    per grid size (0 at k = 4 here: the plain teacher's), and are cached apart."""
    import shutil

    from diffsampler_rt.finish.pipeline import find
    from diffsampler_rt.guidance import guided
    from export.__main__ import main as export_main
    from export.onnx_export import export_model, model_card
    from trainer.distil import cached_trajectories
    from trainer.unet import UNet
    from .conftest import tiny_config
    torch.manual_seed(1)  # another random net of the same schedule and embedding: the guide
    cfg = tiny_config(**TINY_ONNX_UNET)
    net = UNet(cfg.unet).eval()
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    export_model(net, model_card(cfg, training_steps=0), tmp_path / "weak.onnx")
    teacher = tmp_path / "tiny.onnx"
    shutil.copy(tiny_onnx, teacher)
    assert export_main(["pipeline", str(teacher), "--add", "guide", "--model", "weak",
                        "--weight", "16:0,64:1", "--at", "0"]) == 0
    m = diffsampler_rt.Model(teacher)
    spec = find(m.card["pipeline"], "guide")
    assert (spec["model"], spec["weight"]) == ("weak", {"n": [16, 64], "values": [0, 1]})
    kw = dict(teacher_steps=4, student_steps=2, solver="ddim", seed=7)
    plain8, plain4 = (teacher_trajectories(m, k, 3, **kw) for k in (8, 4))
    guided8 = teacher_trajectories(m, 8, 3, guidance=True, **kw)
    x = np.random.default_rng([7, 8]).standard_normal((3, 2, 8, 8))
    ts = timesteps(len(m.alpha_bar), 4)
    np.testing.assert_allclose(guided8[-1], solve("ddim", guided(m.denoise, m.guide(spec).denoise,
                                                                 1.0), x, m.alpha_bar, ts),
                               atol=1e-5)
    assert np.abs(guided8[-1] - plain8[-1]).max() > 1e-3
    np.testing.assert_array_equal(teacher_trajectories(m, 4, 3, guidance=True, **kw), plain4)
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    for guidance in (False, True):
        dc = tiny_distil(teacher, teacher_guidance=guidance, seed=7)
        tr = cached_trajectories(dc, m, "sha", 8, 3)
        np.testing.assert_array_equal(tr, guided8 if guidance else plain8)
    assert len(list((tmp_path / "cache").glob("traj_*.npy"))) == 2


def test_config_rejects_steps_that_do_not_nest():
    with pytest.raises(ValueError, match="multiple"):
        DistilConfig(teacher="gbn", name="x", student_steps=8, teacher_steps=20)
    with pytest.raises(ValueError, match="deterministic"):
        DistilConfig(teacher="gbn", name="x", teacher_solver="ddpm")
    with pytest.raises(ValueError, match="loss_weighting"):
        DistilConfig(teacher="gbn", name="x", loss_weighting="uniform")


def test_distil_run_exports_a_student_with_its_record(tiny_onnx, tmp_path, monkeypatch):
    from export.onnx_export import export_checkpoint

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx, steps=3, log_every=1)
    d = Distiller(cfg, tmp_path / "run", progress=False)
    # the card's training figures are the teacher's: say it trained on a GPU
    d.teacher_card = {**d.teacher_card, "train_seconds": 60, "train_devices": ["cuda"]}
    before = {k: v.clone() for k, v in d.model.state_dict().items()}
    ckpt = d.run()
    assert d.step == 3
    assert any(not torch.equal(before[k], v) for k, v in d.model.state_dict().items())
    assert len((tmp_path / "run" / "log.csv").read_text().splitlines()) == 4
    # resumes exactly where it stopped, and remembers where the student trained before
    from trainer.train import load_checkpoint, save_checkpoint
    st = load_checkpoint(ckpt)
    assert st["student_devices"] == ["cpu"]
    (tmp_path / "moved").mkdir()
    save_checkpoint(tmp_path / "moved" / ckpt.name, {**st, "student_devices": ["cuda"]})
    assert Distiller(cfg, tmp_path / "run", progress=False).step == 3
    moved = Distiller(cfg, tmp_path / "moved", progress=False)
    assert moved.step == 3 and "min on CPU and GPU" in moved.state()["card_extra"]["provenance"]
    out, _ = export_checkpoint(ckpt, tmp_path / "tiny_fast.onnx", parity_sides=(8,))
    m = diffsampler_rt.Model(out)
    assert m.card["name"] == "tiny_fast"
    assert (m.card["default_solver"], m.card["default_steps"]) == ("ddim", 2)
    assert m.card["distillation"]["teacher"] == "tiny"
    assert m.card["distillation"]["steps"] == 3
    assert m.card["distillation"]["devices"] == ["cpu"]  # where the student trained
    assert (m.card["train_seconds"], m.card["train_devices"]) == (60, ["cuda"])
    assert "min on CPU" in m.card["provenance"]  # the student's own run
    assert m.card["config"]["unet"]["attention_window"] == 2
    assert json.dumps(m.card["distillation"]["config"])  # JSON all the way down
    pts = m.generate(64, 2, seed=0)
    assert pts.shape == (2, 64, 2) and ((pts >= 0) & (pts < 1)).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m.generate(16, seed=0)  # its own setting: no warning
    with pytest.warns(UserWarning, match="distilled for ddim with 2 steps"):
        m.generate(16, seed=0, steps=5)


def test_a_non_uniform_teachers_student_maps_its_sets_with_the_teachers_table(
        tiny_onnx, tmp_path, monkeypatch):
    import shutil

    from export.defaults import edit_card
    from export.onnx_export import export_checkpoint
    from trainer.density import fit_density

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    teacher = tmp_path / "tiny_ramp.onnx"
    shutil.copy(tiny_onnx, teacher)
    ramp = np.sqrt(np.random.default_rng(0).random((4000, 2)))  # density 4xy
    table = fit_density(ramp, 8, floor=1e-6)

    def non_uniform(card: dict) -> None:  # as after `python -m export density-floor`
        card.update(density=table, density_floor=1e-6)

    edit_card(teacher, non_uniform)
    cfg = tiny_distil(teacher, name="tiny_ramp_fast", steps=1)
    out, _ = export_checkpoint(Distiller(cfg, tmp_path / "run", progress=False).run(),
                               tmp_path / "tiny_ramp_fast.onnx", parity_sides=(8,))
    card = diffsampler_rt.Model(out).card
    assert card["density"] == table and card["density_floor"] == 1e-6
    assert card["config"]["data"]["density_floor"] == 1e-6
    pts = diffsampler_rt.generate(out, 1024, seed=0)
    # mapped to the density 4xy (mean 2/3 on each axis), not left uniform (mean 1/2)
    assert np.all(np.abs(pts.mean(axis=0) - 2 / 3) < 0.05)
    # a uniform teacher's student has no table
    plain = tiny_distil(tiny_onnx, steps=1)
    assert Distiller(plain, tmp_path / "plain", progress=False).state()["density"] is None


def test_a_later_stage_starts_from_the_earlier_student(tiny_onnx, tmp_path, monkeypatch):
    from dataclasses import replace
    from export.onnx_export import export_checkpoint

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx)
    first, _ = export_checkpoint(Distiller(cfg, tmp_path / "one", progress=False).run(),
                                 tmp_path / "one.onnx", parity_sides=(8,))
    later = replace(cfg, init_from=str(first), steps=1, seed=1)
    d = Distiller(later, tmp_path / "two", progress=False)
    start = net_from_onnx(first)[0].state_dict()
    assert all(torch.equal(v, start[k]) for k, v in d.model.state_dict().items())
    d.run()
    record = d.state()["card_extra"]
    assert (record["distillation"]["steps"], record["distillation"]["earlier_steps"]) == (1, 2)
    assert "after 2 steps" in record["provenance"]
    with pytest.raises(ValueError, match="is not a student of"):
        Distiller(replace(cfg, init_from=str(tiny_onnx)), tmp_path / "three", progress=False)
    with pytest.raises(ValueError, match="has architecture"):
        Distiller(replace(later, attention_window=None), tmp_path / "four", progress=False)
    with pytest.raises(FileNotFoundError, match="existing .onnx"):
        Distiller(replace(cfg, init_from=str(tmp_path / "none.onnx")), tmp_path / "five",
                  progress=False)


def test_a_student_of_its_own_architecture_starts_from_fresh_weights(tiny_onnx, tmp_path,
                                                                    monkeypatch):
    from dataclasses import replace

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx, student_unet={"base_channels": 4, "num_heads": 1})
    d = Distiller(cfg, tmp_path / "one", progress=False)
    teacher = net_from_onnx(tiny_onnx)[0]
    assert (sum(p.numel() for p in d.model.parameters())
            < sum(p.numel() for p in teacher.parameters()) / 2)
    # seeded: the same config starts from the same weights
    again = Distiller(cfg, tmp_path / "again", progress=False).model.state_dict()
    assert all(torch.equal(v, again[k]) for k, v in d.model.state_dict().items())
    d.run()
    out = export_untrained_student(d, tmp_path / "small.onnx")
    card = diffsampler_rt.Model(out).card
    unet = card["config"]["unet"]
    assert (unet["base_channels"], unet["num_heads"]) == (4, 1)
    assert unet["coord_bits"] == TINY_ONNX_UNET["coord_bits"]  # the rest is the teacher's
    assert card["parameters"] == sum(p.numel() for p in d.model.parameters())
    assert "in a net of its own (base_channels 4, num_heads 1)" in card["provenance"]
    assert diffsampler_rt.generate(out, 64, seed=0).shape == (64, 2)
    # a later stage of it starts from it
    later = Distiller(replace(cfg, init_from=str(out), steps=1), tmp_path / "two",
                      progress=False)
    start = net_from_onnx(out)[0].state_dict()
    assert all(torch.equal(v, start[k]) for k, v in later.model.state_dict().items())
    with pytest.raises(ValueError, match=r"unknown student_unet keys \['width'\]"):
        tiny_distil(tiny_onnx, student_unet={"width": 4})
    with pytest.raises(ValueError, match="may not set attention_window"):
        tiny_distil(tiny_onnx, student_unet={"attention_window": 4})


def test_a_student_with_fewer_res_blocks_starts_from_an_earlier_student_cut_down(
        tiny_onnx, tmp_path, monkeypatch):
    from dataclasses import replace
    from trainer.drop_blocks import drop_res_blocks

    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx, student_unet={"num_res_blocks": 2})
    d = Distiller(cfg, tmp_path / "two_blocks", progress=False)
    d.run()
    wide = export_untrained_student(d, tmp_path / "wide.onnx")
    cut_cfg = replace(cfg, student_unet={"num_res_blocks": 1}, init_from=str(wide), steps=1)
    cut = Distiller(cut_cfg, tmp_path / "one_block", progress=False)
    start = drop_res_blocks(net_from_onnx(wide)[0], 1).state_dict()
    assert all(torch.equal(v, start[k]) for k, v in cut.model.state_dict().items())
    cut.run()
    record = cut.state()["card_extra"]
    assert record["distillation"]["earlier_res_blocks"] == 2
    assert "in earlier stages, cut down from 2 res blocks a level" in record["provenance"]
    # a student cannot grow blocks, nor change anything else, from an earlier one
    with pytest.raises(ValueError, match="has architecture"):
        Distiller(replace(cut_cfg, student_unet={"num_res_blocks": 3}), tmp_path / "grow",
                  progress=False)
    with pytest.raises(ValueError, match="has architecture"):
        Distiller(replace(cut_cfg, student_unet={"num_res_blocks": 1, "base_channels": 4}),
                  tmp_path / "other", progress=False)


def test_cutting_res_blocks_keeps_the_first_of_each_level_and_the_upsampling_ones():
    import doctest

    from trainer import drop_blocks
    from trainer.drop_blocks import drop_res_blocks, kept_blocks
    from trainer.unet import UNet, UNetConfig

    assert doctest.testmod(drop_blocks).failed == 0
    down, up = kept_blocks(3, 2, 1)
    # down: [b, b, conv, b, b, conv, b, b] -> [b, conv, b, conv, b]
    assert down == {0: 0, 1: 2, 2: 3, 3: 5, 4: 6}
    # up: 3 blocks a level, the last reading the downsampling's skip -> 2
    assert up == {0: 0, 1: 2, 2: 3, 3: 5, 4: 6, 5: 8}
    assert kept_blocks(2, 3, 3) == ({i: i for i in range(7)}, {i: i for i in range(8)})
    with pytest.raises(ValueError, match="1 to 2 res blocks a level, not 3"):
        kept_blocks(3, 2, 3)
    torch.manual_seed(0)
    full = UNet(UNetConfig(**{**TINY_UNET, "num_res_blocks": 2}))
    same = drop_res_blocks(full, 2)
    x, t = torch.randn(2, 2, 8, 8), torch.tensor([10, 500])
    with torch.no_grad():
        assert torch.equal(same(x, t), full(x, t))
        assert drop_res_blocks(full, 1)(x, t).shape == x.shape


def test_difference_term_charges_cell_to_cell_error_only():
    ab = torch.tensor(alphas_cumprod({"kind": "linear", "beta_start": 1e-4, "beta_end": 0.02,
                                      "num_steps": 1000}), dtype=torch.float32)
    x_t = torch.randn(2, 2, 6, 6)
    t, t_next = torch.full((2,), 124), torch.full((2,), -1)
    a, s = ab[124].sqrt(), (1 - ab[124]).sqrt()
    eps = torch.randn(2, 2, 6, 6)
    x0 = (x_t - s * eps) / a  # the clean target this eps implies
    smooth = _Oracle(eps + 0.1)  # the same error in every cell
    checker = _Oracle(eps + 0.1 * (-1.0) ** torch.arange(6).add(torch.arange(6)[:, None]))
    plain = [hop_loss(o, x_t, x0, t, t_next, ab).item() for o in (smooth, checker)]
    assert plain[0] == pytest.approx(plain[1], rel=1e-4)  # same size of error
    diff = [hop_loss(o, x_t, x0, t, t_next, ab, difference_weight=1.0).item()
            for o in (smooth, checker)]
    assert diff[0] == pytest.approx(plain[0], rel=1e-4)
    assert diff[1] > 5 * plain[1]  # neighbours differ by 0.2 everywhere: (1 + 2 * 4 * 5/6) x


def test_bundled_students_were_distilled_from_the_bundled_teachers():
    # `python -m trainer distil trainer/configs/distil/NAME.json` distils from the bundled
    # teacher, so a student must have been made from exactly that file to be reproducible
    from trainer.distil import network_hash
    for name in zoo.networks():
        card = diffsampler_rt.load(name).card
        if "distillation" not in card:
            continue
        d = card["distillation"]
        teacher = diffsampler_rt.load(d["teacher"])
        if d["teacher_sha1"] != network_hash(teacher.path):
            # allowed only for a teacher re-exported with attention windows at least as wide as
            # its attention level at every trained side (k / 4 cells): the same function there,
            # so distilling from it again makes the same trajectories up to float rounding
            window = teacher.card["config"]["unet"].get("attention_window")
            assert "re-exported" in teacher.card["provenance"] and window, (name, d["teacher"])
            assert max(teacher.card["trained_sizes"]) <= (4 * window) ** 2, (name, window)


def test_distillation_recipes_load_and_later_stages_chain():
    # every bundled student's recipe loads; a later stage (NAME_stageN.json) starts from the
    # previous stage's export in that stage's run directory, as the training recipes do, and
    # the last stage of each student gives the bundled file's step count
    from pathlib import Path
    last: dict[str, tuple[int, DistilConfig]] = {}
    for path in sorted(Path("trainer/configs/distil").glob("*.json")):
        cfg = DistilConfig.load(path)
        stem, number, previous = recipe_stage(path)
        assert cfg.name == stem, path
        if previous:
            assert cfg.init_from == f"runs/{previous}/{cfg.name}.onnx", path
            assert DistilConfig.load(path.with_name(f"{previous}.json")).teacher == cfg.teacher
        if cfg.name not in last or number > last[cfg.name][0]:
            last[cfg.name] = (number, cfg)
    for name, (_, cfg) in last.items():
        card = diffsampler_rt.load(name).card
        assert card["default_steps"] == cfg.student_steps, name
        assert card["distillation"]["config"]["student_steps"] == cfg.student_steps, name


@pytest.mark.parametrize("settings, message", [
    (dict(spectrum_weight=-1.0), "spectrum_weight"),
    (dict(spectrum_weight=1.0, spectrum_sizes=(64,)), r"spectrum_sizes \(64,\)"),
    (dict(spectrum_sets=0), "spectrum_sets"),
    (dict(spectrum_radius=6.0), "spectrum_radius"),
    (dict(spectrum_target="sampler"), "'sampler'"),
    (dict(spectrum_examples=0), "spectrum_examples must be >= 1, got 0"),
    (dict(projection_weight=-1.0), "projection_weight must be >= 0, got -1.0"),
    (dict(projection_weight=1.0, projection_sizes=(64,)), r"projection_sizes \(64,\)"),
    (dict(projection_sets=3), "projection_sets must be even and >= 2, got 3"),
])
def test_config_rejects_bad_spectrum_and_projection_settings(settings, message):
    with pytest.raises(ValueError, match=message):
        DistilConfig(teacher="gbn", name="x", **settings)


def test_projection_loss_scores_two_halves_and_logs_its_column(tiny_onnx, tmp_path,
                                                               monkeypatch):
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx, steps=2, log_every=1, projection_weight=10.0,
                      projection_sizes=(8,), projection_sets=4, spectrum_radius=2.0)
    d = Distiller(cfg, tmp_path / "run", progress=False)
    figure, target = d.projections[8]
    assert target.shape == (16,) and not d.spectra  # 2 sqrt(n) frequencies; no radial loss
    # the target: the teacher's sets' mean axis spectrum
    from diffsampler_rt.grid import decode
    final = d.trajectories[8][-1].numpy() / float(d.teacher_card["offset_scale"])
    pts = decode(final, stratified=d.teacher_card["embedding"] == "stratified")
    np.testing.assert_allclose(target.numpy(), figure(torch.tensor(pts).float()).numpy(),
                               rtol=1e-4, atol=1e-6)
    d.teacher_card = {**d.teacher_card, "offset_scale": 1e4}  # as in the spectrum test
    # the loss is the product of the two halves' differences from the target
    state = d.gen.get_state()
    with torch.no_grad():
        sets = d._rollout_points(8, 4)
        want = 10.0 * torch.mean((figure(sets[:2]) - target) * (figure(sets[2:]) - target))
    d.gen.set_state(state)
    loss = d.projection_loss(8)
    assert torch.allclose(loss, want)
    loss.backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in d.model.parameters())
    d.model.zero_grad(set_to_none=True)
    d.run()
    header = (tmp_path / "run" / "log.csv").read_text().splitlines()[0].split(",")
    assert header[-3:] == ["loss_k4", "loss_k8", "projection_k8"]


def test_the_rollout_is_the_runtimes_ddim(tiny_onnx, tmp_path, monkeypatch):
    # the spectrum loss differentiates the student's own sets: the rollout must be what the
    # runtime makes from the same starting noise with the same weights
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    d = Distiller(tiny_distil(tiny_onnx), tmp_path / "run", progress=False)
    x = torch.randn(3, 2, 8, 8, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        got = d.rollout(x).numpy()
    eps_fn = student_denoiser(d)

    ts = timesteps(len(d.teacher.alpha_bar), 2)
    want = ddim(eps_fn, x.numpy(), d.teacher.alpha_bar, ts)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=2e-5)  # float32 against float64


def test_spectrum_loss_trains_and_logs_its_column(tiny_onnx, tmp_path, monkeypatch):
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx, steps=2, log_every=1, spectrum_weight=10.0,
                      spectrum_sizes=(8,), spectrum_sets=2, spectrum_radius=2.0)
    d = Distiller(cfg, tmp_path / "run", progress=False)
    figure, target = d.spectra[8]
    assert target.shape == (32,) and torch.isfinite(target).all()
    # the target is the teacher's sets' mean spectrum as the runtime's figure has it
    from diffsampler_rt.grid import decode
    from diffsampler_rt.spectrum import radial_spectrum
    final = d.trajectories[8][-1].numpy() / float(d.teacher_card["offset_scale"])
    pts = decode(final, stratified=d.teacher_card["embedding"] == "stratified")
    np.testing.assert_allclose(target.numpy(), radial_spectrum(pts)[1][:32], rtol=1e-4,
                               atol=1e-6)
    # the untrained tiny student's sets lie outside their cells, where the clamp has no
    # gradient: read its offsets at a scale that keeps them inside
    d.teacher_card = {**d.teacher_card, "offset_scale": 1e4}
    loss = d.spectrum_loss(8)
    loss.backward()
    assert loss.item() > 0
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in d.model.parameters())
    d.model.zero_grad(set_to_none=True)
    d.run()
    header = (tmp_path / "run" / "log.csv").read_text().splitlines()[0].split(",")
    assert header[-3:] == ["loss_k4", "loss_k8", "spectrum_k8"]


def test_examples_target_is_the_samplers_own_sets_spectrum(tiny_onnx, tmp_path, monkeypatch):
    # the tiny teacher learned fresh Sobol'+Owen sets: the target is the mean spectrum of
    # spectrum_examples such sets, drawn from the distillation's seed
    from diffsampler_rt.spectrum import radial_spectrum
    from trainer.samplers import sample
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    cfg = tiny_distil(tiny_onnx, spectrum_weight=1.0, spectrum_sizes=(8,), spectrum_radius=2.0,
                      spectrum_target="examples", spectrum_examples=5, seed=3)
    _, target = Distiller(cfg, tmp_path / "run", progress=False).spectra[8]
    sets = sample("sobol_owen", 64, count=5, seed=np.random.default_rng([3, 8]))
    np.testing.assert_allclose(target.numpy(), radial_spectrum(sets)[1][:32], rtol=1e-5,
                               atol=1e-7)


def test_the_card_rollout_is_the_runtimes_structure_guided_generation(tiny_onnx, tmp_path,
                                                                      monkeypatch):
    # with spectrum_card the rollout follows the card: noise shaped by its coarse-noise
    # gain and structure temperature, the structure imposed on the clean-set prediction of
    # its last structure_guidance steps and on the decoded set, as the runtime does
    from diffsampler_rt.coarse_noise import shape_noise
    from diffsampler_rt.grid import decode, encode_stratified
    from diffsampler_rt.solvers import project_x0
    from diffsampler_rt.structure import impose_n_rooks
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    coarse = {"step": "coarse_noise", "gain": {"n": [16, 64], "values": [1.5, 1.5]},
              "cut": 0.25}
    pipeline = [{**coarse, "where": "unstructured"},
                {**coarse, "temperature": 0.9, "where": "structured"},
                {"step": "structure_guidance", "steps": 2}, {"step": "n_rooks"},
                {"step": "thin", "drop": "random"}]
    spectrum = dict(student_steps=4, teacher_steps=4, spectrum_weight=1.0,
                    spectrum_sizes=(8,), spectrum_sets=2, spectrum_radius=2.0)
    cfg = tiny_distil(tiny_onnx, spectrum_card={"pipeline": pipeline}, **spectrum)
    d = Distiller(cfg, tmp_path / "run", progress=False)
    assert d.rollout_card == {**d.teacher_card, "pipeline": pipeline}
    # the same settings as format-1 card fields: converted to that pipeline
    settings = {"structure": "n_rooks", "structure_guidance": 2, "structure_temperature": 0.9,
                "coarse_noise": {"gain": [1.5, 1.5], "n": [16, 64], "cut": 0.25}}
    old = Distiller(tiny_distil(tiny_onnx, spectrum_card=settings, **spectrum),
                    tmp_path / "old", progress=False)
    assert old.rollout_card == d.rollout_card
    # offsets read at a scale that keeps the untrained net's points inside their cells
    scale = 1e3
    d.teacher_card = {**d.teacher_card, "offset_scale": scale}
    state = d.gen.get_state()
    x = d._start_noise(8, 2)
    d.gen.set_state(state)
    raw = torch.randn((2, 2, 8, 8), generator=d.gen, dtype=torch.float64).numpy()
    np.testing.assert_allclose(x.numpy(), shape_noise(raw, 1.5, 0.25, 0.9), rtol=1e-6)
    with torch.no_grad():
        got = d.rollout(x).numpy()
    eps_fn = student_denoiser(d)

    def project(x0):
        return encode_stratified(impose_n_rooks(decode(x0 / scale, stratified=True), 8),
                                 8) * scale

    ts = timesteps(len(d.teacher.alpha_bar), 4)
    guided_eps = project_x0(eps_fn, d.teacher.alpha_bar, project, ts[2:])
    want = ddim(guided_eps, x.numpy(), d.teacher.alpha_bar, ts)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)  # float32, offsets x 1e3
    # the loss scores the imposed set, and its gradient passes the imposition
    d.gen.set_state(state)
    loss = d.spectrum_loss(8)
    figure, target = d.spectra[8]
    imposed = torch.from_numpy(impose_n_rooks(decode(want / scale, stratified=True), 8))
    np.testing.assert_allclose(loss.item(), torch.mean((figure(imposed.float()) - target) ** 2)
                               .item(), rtol=1e-3)
    loss.backward()
    assert loss.item() > 0
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in d.model.parameters())


def test_spectrum_card_is_a_model_or_valid_card_entries(tiny_onnx, tmp_path, monkeypatch):
    from diffsampler_rt.errors import ModelFormatError
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path / "cache"))
    spectrum = dict(spectrum_weight=1.0, spectrum_sizes=(8,), spectrum_sets=2)
    d = Distiller(tiny_distil(tiny_onnx, spectrum_card=str(tiny_onnx), **spectrum),
                  tmp_path / "a", progress=False)
    assert d.rollout_card == diffsampler_rt.load(tiny_onnx).card
    with pytest.raises(ModelFormatError, match="structure_guidance"):
        Distiller(tiny_distil(tiny_onnx, spectrum_card={"structure_guidance": -1}, **spectrum),
                  tmp_path / "b", progress=False)
    bad = [{"step": "structure_guidance", "steps": -1}, {"step": "n_rooks"}, {"step": "thin"}]
    with pytest.raises(ModelFormatError, match="step 'structure_guidance': 'steps' must be"):
        Distiller(tiny_distil(tiny_onnx, spectrum_card={"pipeline": bad}, **spectrum),
                  tmp_path / "c", progress=False)
    with pytest.raises(ModelFormatError, match="needs a structure step"):  # none to steer by
        Distiller(tiny_distil(tiny_onnx, spectrum_card={"pipeline": [
            {"step": "structure_guidance", "steps": 2}, {"step": "thin"}]}, **spectrum),
            tmp_path / "d", progress=False)
