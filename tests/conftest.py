from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from trainer import zoo

# model names in the tests are the repository's networks (models/NAME.onnx); the tests of the
# wheel's own one-per-sampler models name diffsampler_rt.model.MODELS_DIR or clear this
zoo.use()

SHARED = Path(__file__).resolve().parents[2] / "shared"
REFERENCE_CSV = SHARED / "reference" / "radial_spectra_original_n1024.csv"

TINY_UNET = dict(base_channels=8, channel_mult=(1, 2), num_res_blocks=1, attention_levels=(1,),
                 middle_attention=True, num_heads=2, groups=4)


#: the tiny_onnx fixture's extra U-Net settings (every input and attention kind)
TINY_ONNX_UNET = dict(coord_bits=2, axial_levels=(0,))


def tiny_config(name: str = "tiny", sampler: str = "sobol_owen", embedding: str = "stratified",
                **unet):
    from trainer.config import DataConfig, TrainConfig
    from trainer.unet import UNetConfig

    return TrainConfig(
        name=name,
        data=DataConfig(sampler=sampler, embedding=embedding, sizes=(4, 8), batch_sizes=(4, 2),
                        pool_sizes=(0, 0)),
        unet=UNetConfig(**{**TINY_UNET, **unet}), steps=6, warmup_steps=2,
        checkpoint_every_s=1e9, log_every=1, default_sample_steps=5,
        default_solver="ddim")


@pytest.fixture
def bundled_copy(tmp_path):
    """A function: a bundled model's file copied to tmp_path / "m.onnx" (its card free to
    edit with set-defaults); returns the copy's path."""
    def copy(name: str) -> Path:
        import diffsampler_rt
        path = tmp_path / "m.onnx"
        shutil.copy(diffsampler_rt.model.resolve(name), path)
        return path
    return copy


#: what the tiny_onnx fixture's file depends on: a change to any of them makes it anew
TINY_ONNX_SOURCES = ("trainer/unet.py", "trainer/config.py", "export/onnx_export.py",
                     "diffsampler_rt/card.py", "tests/conftest.py")


def _tiny_onnx_key() -> str:
    import hashlib

    import torch
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(torch.__version__.encode())
    for name in TINY_ONNX_SOURCES:
        h.update((root / name).read_bytes())
    return h.hexdigest()[:16]


@pytest.fixture(scope="session")
def tiny_onnx(tmp_path_factory) -> Path:
    """A small random U-Net (all attention kinds) exported with a valid model card (fp16
    weights). The export takes ~20 s, so the file is kept in the cache
    (``$DIFFSAMPLER_CACHE/test_fixtures``) under a digest of the code that makes it."""
    torch = pytest.importorskip("torch")
    from trainer.data import cache_dir
    path = tmp_path_factory.mktemp("onnx") / "tiny.onnx"
    kept = cache_dir() / "test_fixtures" / f"tiny-{_tiny_onnx_key()}.onnx"
    if kept.exists() and kept.with_suffix(".state").exists():
        shutil.copy(kept, path)
        shutil.copy(kept.with_suffix(".state"), path.with_suffix(".state"))
        return path
    from export.onnx_export import export_model, model_card, round_to_fp16
    from trainer.unet import UNet

    torch.manual_seed(0)
    cfg = tiny_config(**TINY_ONNX_UNET)
    net = UNet(cfg.unet).eval()
    with torch.no_grad():  # the U-Net zero-initialises its output layers: make it non-trivial
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    round_to_fp16(net)
    export_model(net, model_card(cfg, training_steps=0), path, fp16_weights=True)
    torch.save(net.state_dict(), path.with_suffix(".state"))
    kept.parent.mkdir(parents=True, exist_ok=True)
    for src, dst in ((path, kept), (path.with_suffix(".state"), kept.with_suffix(".state"))):
        part = dst.with_name(dst.name + ".partial")  # never a half-written file in the cache
        shutil.copy(src, part)
        part.replace(dst)
    return path


def recipe_stage(path: Path) -> tuple[str, int, str | None]:
    """A recipe file's model name, its stage (1 for NAME.json, N for NAME_stageN.json) and
    the stem of the recipe before it (None for a first stage): a later stage starts from the
    previous stage's export in that stage's run directory, runs/<previous>/<NAME>.onnx."""
    stem, _, stage = path.stem.partition("_stage")
    if not stage:
        return stem, 1, None
    return stem, int(stage), stem if stage == "2" else f"{stem}_stage{int(stage) - 1}"


def changed_card_error(model: str, change: dict, key: str) -> str:
    """The message of the ModelFormatError naming ``key`` that parse_card raises on bundled
    ``model``'s card with ``change`` applied (a None value removes that entry)."""
    import json

    import diffsampler_rt
    from diffsampler_rt.card import CARD_KEY, parse_card
    from diffsampler_rt.errors import ModelFormatError
    card = {**diffsampler_rt.load(model).card, **change}
    card = {k: v for k, v in card.items() if v is not None}
    with pytest.raises(ModelFormatError, match=key) as err:
        parse_card({CARD_KEY: json.dumps(card)}, "m")
    return str(err.value)


def session_entry(opts, key: str) -> str | None:
    """An onnxruntime SessionOptions' config entry, or None where it was never set (the
    Python API raises instead and has no query for it)."""
    try:
        return opts.get_session_config_entry(key)
    except RuntimeError:
        return None


def changed_pipeline_error(model: str, edit, key: str) -> str:
    """The message of the ModelFormatError matching ``key`` that parse_card raises on bundled
    ``model``'s card after ``edit`` (a function changing a deep copy of its "pipeline" list
    in place, or returning a new list)."""
    import copy
    import json

    import diffsampler_rt
    from diffsampler_rt.card import CARD_KEY, parse_card
    from diffsampler_rt.errors import ModelFormatError
    card = copy.deepcopy(diffsampler_rt.load(model).card)
    changed = edit(card["pipeline"])
    if changed is not None:
        card["pipeline"] = changed
    with pytest.raises(ModelFormatError, match=key) as err:
        parse_card({CARD_KEY: json.dumps(card)}, "m")
    return str(err.value)


def pipeline_card_error(model: str, pipeline: list, text: str) -> str:
    """The message of the ModelFormatError that parse_card raises on bundled ``model``'s
    card with its ``"pipeline"`` replaced by ``pipeline``; checked to contain ``text``
    (plain text, not a pattern)."""
    import copy
    import json

    import diffsampler_rt
    from diffsampler_rt.card import CARD_KEY, parse_card
    from diffsampler_rt.errors import ModelFormatError
    card = {**copy.deepcopy(diffsampler_rt.load(model).card), "pipeline": pipeline}
    with pytest.raises(ModelFormatError) as err:
        parse_card({CARD_KEY: json.dumps(card)}, "m")
    assert text in str(err.value), (text, str(err.value))
    return str(err.value)


def pipeline_refused(path, argv, capsys, *texts) -> None:
    """``python -m export pipeline PATH ARGV`` exits 2 with a one-line error holding every
    text, and leaves the file as it was."""
    from export.__main__ import main as export_main
    before = path.read_bytes()
    capsys.readouterr()
    assert export_main(["pipeline", str(path), *argv]) == 2
    out, err = capsys.readouterr()
    assert err.startswith("error: ") and err.count("\n") == 1 and not out
    for text in texts:
        assert text in err, (text, err)
    assert path.read_bytes() == before
