"""The finishing-step contract (diffsampler_rt.finish): every registered step is tested by a
subclass of StepContract (parameters refused with the field named, a one-line description,
output in [0, 1)^2 with the shape kept, the same sets from the same streams, no change at
its identity setting), as scipy.stats.qmc's engine tests share one base class."""
from __future__ import annotations

import re

import numpy as np
import pytest

from diffsampler_rt.finish import STEPS, Context
from diffsampler_rt.finish.pipeline import (describe, entry_problem, params_of, pipeline_problem,
                                            plan)
from diffsampler_rt.grid import cell_centres
from trainer import zoo


def stratified(k: int, sets: int, seed: int) -> np.ndarray:
    """Jittered k x k sets, one point per cell in row-major order (a stratified decode)."""
    rng = np.random.default_rng(seed)
    return cell_centres(k)[None] + rng.uniform(-0.5, 0.5, (sets, k * k, 2)) / k


def streams(sets: int, seed: int = 1) -> list[np.random.Generator]:
    return np.random.default_rng(seed).spawn(sets)


class StepContract:
    """Subclasses set ``name``, ``valid`` (parameters it accepts), ``invalid`` (parameters
    and the field the message must name), ``identity`` (parameters that change nothing, or
    None) and, for point steps, ``n`` / ``k`` of the sets it gets."""
    name = ""
    valid: dict = {}
    invalid: list[tuple[dict, str]] = []
    identity: dict | None = None
    n, k = 256, 16

    @property
    def step(self):
        return STEPS[self.name]

    def test_registered_with_its_own_name(self):
        assert self.step.name == self.name and self.step.phase in ("noise", "denoiser", "points")

    def test_valid_parameters_accepted(self):
        assert entry_problem({"step": self.name, **self.valid}) is None

    def test_bad_parameters_refused_naming_the_field(self):
        for params, field in self.invalid + [({**self.valid, "no_such": 1}, "no_such")]:
            problem = entry_problem({"step": self.name, **params})
            assert problem and self.name in problem and field in problem, (params, problem)

    def test_described_in_one_line(self):
        text = self.step.describe(self.valid)
        assert text and "\n" not in text

    def run(self, params: dict, x: np.ndarray, seed: int = 1) -> np.ndarray:
        ctx = Context(n=self.n, k=self.k, rngs=streams(len(x), seed), structured=True)
        if self.step.phase == "noise":
            return self.step.shape(params, x, ctx)
        return self.step.apply(params, x, ctx)

    def sets(self, seed: int = 0) -> np.ndarray:
        if self.step.phase == "noise":
            return np.random.default_rng(seed).standard_normal((3, 2, self.k, self.k))
        return stratified(self.k, 3, seed)

    def test_shape_range_and_determinism(self):
        if self.step.phase == "denoiser":
            pytest.skip("a denoiser step wraps a function: tests/test_guidance.py, test_structure.py")
        x = self.sets()
        out = self.run(self.valid, x.copy())
        again = self.run(self.valid, x.copy())
        np.testing.assert_array_equal(out, again)
        if self.step.phase == "points":
            assert out.shape[:-2] == x.shape[:-2] and out.shape[-2] >= self.n
            assert np.all((out >= 0) & (out < 1)) and np.isfinite(out).all()
        else:
            assert out.shape == x.shape

    def test_identity_setting_changes_nothing(self):
        if self.identity is None or self.step.phase == "denoiser":
            pytest.skip("no identity setting")
        x = self.sets()
        np.testing.assert_array_equal(self.run(self.identity, x.copy()), x)


class TestCoarseNoise(StepContract):
    name = "coarse_noise"
    valid = {"gain": {"n": [64, 1024], "values": [1.5, 1.2]}, "cut": 0.25, "temperature": 0.9}
    invalid = [({"gain": 0}, "gain"), ({"gain": 1.2, "cut": 1.5}, "cut"),
               ({"temperature": 3}, "temperature"),
               ({"gain": {"n": [64], "values": [1, 2]}}, "gain")]
    identity = {"gain": 1.0, "cut": 0.5}


class TestGuide(StepContract):
    name = "guide"
    valid = {"model": "sot_32_guide", "weight": 1.0}
    invalid = [({"model": "a/b", "weight": 1}, "model"), ({"model": "x", "weight": 9}, "weight"),
               ({"model": "x"}, "weight"),
               ({"model": "x", "weight": 1, "network_sha256": "xyz"}, "digest")]


class TestStructureGuidance(StepContract):
    name = "structure_guidance"
    valid = {"steps": 3}
    invalid = [({"steps": -1}, "steps"), ({"steps": 1.5}, "steps"),
               ({"steps": {"n": [256, 64], "values": [1, 2]}}, "steps")]


class TestMinSpacing(StepContract):
    name = "min_spacing"
    valid = {"c": 0.7}
    invalid = [({"c": 1.2}, "'c'"), ({}, "'c'"), ({"c": {"n": [64, 32], "values": [1, 1]}}, "'c'")]
    identity = {"c": 1e-9}


class TestEvenOut(StepContract):
    name = "even_out"
    valid = {"gain": 0.3, "cut": 0.5}
    invalid = [({"gain": 2, "cut": 0.5}, "gain"), ({"gain": 0.2, "cut": 0}, "cut")]
    identity = {"gain": 0.0, "cut": 0.5}


class TestProjectionGain(StepContract):
    name = "projection_gain"
    valid = {"gain": {"n": [64, 256], "values": [1.0, 1.1]}}
    invalid = [({"gain": 2}, "gain"), ({"gain": "x"}, "gain")]
    identity = {"gain": 1.0}


class TestSlicedOT(StepContract):
    name = "sliced_ot"
    valid = {"directions": 32, "iterations": 2, "step_size": 1.5}
    invalid = [({"directions": 0, "iterations": 2}, "directions"),
               ({"directions": 8, "iterations": -1}, "iterations"),
               ({"directions": 8, "iterations": 1, "step_size": 3}, "step_size")]
    identity = {"directions": 32, "iterations": 0}


class TestThin(StepContract):
    name = "thin"
    n = 200
    valid = {"drop": "crowded", "restore_cut": 1.0}
    invalid = [({"drop": "oldest"}, "drop"), ({"restore_cut": 0}, "restore_cut")]

    def test_thins_to_n_and_keeps_square_sets(self):
        x = self.sets()
        assert self.run({"drop": "random"}, x).shape == (3, 200, 2)
        self.n = 256
        np.testing.assert_array_equal(self.run(self.valid, x), x)


class TestDyadicNet(StepContract):
    name = "dyadic_net"
    valid = {"prefix": True, "min_side": 4}
    invalid = [({"prefix": "yes"}, "prefix"), ({"min_side": 0}, "min_side"),
               ({"sides": [16, 8]}, "sides")]
    identity = {"sides": [8]}


class TestNRooks(StepContract):
    name = "n_rooks"
    valid = {"min_side": 16, "block": {"sides": [64], "block": [32]}, "runs": 16}
    invalid = [({"block": 3}, "block"), ({"runs": 1}, "runs")]
    identity = {"min_side": 32}


class TestRank1Lattice(StepContract):
    name = "rank1_lattice"
    valid = {"sides": [8, 16]}
    invalid = [({"sides": "8"}, "sides")]
    identity = {"sides": [8]}


def test_every_registered_step_has_a_contract_test():
    tested = {cls.name for cls in StepContract.__subclasses__()}
    assert tested == set(STEPS)


def test_the_pipeline_runs_in_the_listed_order():
    x = stratified(16, 2, 3)
    first = [{"step": "even_out", "gain": 0.5, "cut": 1.0}, {"step": "projection_gain", "gain": 1.3}]
    a = plan(first, 256).finish(x, Context(n=256, k=16, rngs=streams(2)))
    b = plan(first[::-1], 256).finish(x, Context(n=256, k=16, rngs=streams(2)))
    assert not np.array_equal(a, b)
    ctx = Context(n=256, k=16, rngs=streams(2))
    by_hand = STEPS["projection_gain"].apply({"gain": 1.3}, STEPS["even_out"].apply(
        {"gain": 0.5, "cut": 1.0}, x, ctx), ctx)
    np.testing.assert_array_equal(a, by_hand)


def test_where_entries_follow_the_structure_step():
    pipe = [{"step": "min_spacing", "c": 0.5, "where": "structured"},
            {"step": "n_rooks", "min_side": 16},
            {"step": "thin"},
            {"step": "min_spacing", "c": 0.6, "where": "unstructured"}]
    assert pipeline_problem(pipe) is None
    at_256, at_64 = plan(pipe, 256), plan(pipe, 64)
    assert at_256.structured and not at_64.structured
    assert [p.get("c") for _, p in at_256.steps["points"]] == [0.5, None, None]
    assert [p.get("c") for _, p in at_64.steps["points"]] == [None, None, 0.6]


def test_structure_false_keeps_only_plain_thinning():
    pipe = [{"step": "coarse_noise", "gain": 1.3}, {"step": "min_spacing", "c": 0.6},
            {"step": "thin", "drop": "crowded", "restore_cut": 1.0}]
    p = plan(pipe, 200, structure=False)
    assert p.steps["noise"] == [] and p.steps["denoiser"] == []
    assert [(s.name, params) for s, params in p.steps["points"]] == [("thin", {"drop": "crowded"})]


def test_a_prefix_structure_picks_the_grid_side():
    pipe = [{"step": "dyadic_net", "prefix": True}, {"step": "thin"}]
    assert plan(pipe, 300).k == 32 and plan(pipe, 300, structure=False).k == 18
    assert plan(pipe, 256).k == 16


THIN = {"step": "thin"}


@pytest.mark.parametrize("pipe, message", [
    ("x", "must be a list"),
    ([{"step": "nope"}], "unknown step 'nope'"),
    ([{"step": "thin", "where": "sometimes"}], "'where'"),
    ([{"step": "thin", "where": "structured"}], "needs a structure step"),
    ([{"step": "structure_guidance", "steps": 2}, THIN], "needs a structure step"),
    ([{"step": "rank1_lattice"}, {"step": "structure_guidance", "steps": 2}, THIN],
     "cannot steer"),
    ([{"step": "n_rooks"}, {"step": "dyadic_net"}, THIN], "at most one structure"),
    ([{"step": "min_spacing", "c": 0.5}], "needs a 'thin' step"),
])
def test_bad_pipelines_refused(pipe, message):
    assert re.search(message, pipeline_problem(pipe))


def test_format_1_cards_convert_to_the_same_steps():
    from diffsampler_rt.finish.legacy import convert
    old = {"format_version": 1, "structure": "n_rooks", "structure_min_side": 16,
           "structure_temperature": 0.9, "structure_guidance": 3,
           "coarse_noise": {"cut": 0.25, "n": [64, 1024], "gain": [1.4, 1.5]},
           "min_spacing": {"n": [64, 1024], "c": [0.75, 0.7]}, "restore_cut": 1.0}
    new = convert(old)
    assert new["format_version"] == 2 and "structure" not in new and "min_spacing" not in new
    assert [(e["step"], e.get("where")) for e in new["pipeline"]] == [
        ("coarse_noise", "unstructured"), ("coarse_noise", "structured"),
        ("structure_guidance", None), ("min_spacing", "structured"), ("n_rooks", None),
        ("thin", None), ("min_spacing", "unstructured")]
    assert new["pipeline"][1]["temperature"] == 0.9
    assert new["pipeline"][3]["c"] == {"n": [64, 1024], "values": [0.75, 0.7]}
    assert params_of(new["pipeline"][5]) == {"drop": "crowded", "restore_cut": 1.0}
    assert pipeline_problem(new["pipeline"]) is None


def test_a_format_1_file_loads_and_makes_the_same_sets(tmp_path):
    # every bundled file is format 2; a format-1 card (its steps as top-level keys) must
    # read as the format-2 pipeline it stands for and give the same sets
    import json

    import onnx

    import diffsampler_rt
    from diffsampler_rt.card import CARD_KEY
    model = onnx.load(str(diffsampler_rt.load("sot_fast").path))
    card = json.loads(next(p.value for p in model.metadata_props if p.key == CARD_KEY))
    table = lambda n, v: {"n": n, "values": v}
    new = {**card, "pipeline": [
        {"step": "thin", "drop": "crowded", "restore_cut": 0.4},
        {"step": "sliced_ot", "directions": 128, "step_size": 1.5,
         "iterations": table([256, 1024, 4096], [4, 12, 20])},
        {"step": "even_out", "cut": table([256, 576, 1024, 4096], [0.5] * 4),
         "gain": table([256, 576, 1024, 4096], [0.25, 0.3, 0.27, 0.1])},
        {"step": "min_spacing", "c": table([64, 256, 1024], [0.6625, 0.6211, 0.5777])}]}
    old = {k: v for k, v in card.items() if k != "pipeline"}
    old.update(format_version=1, min_spacing={"n": [64, 256, 1024], "c": [0.6625, 0.6211, 0.5777]},
               even_out={"cut": [0.5] * 4, "gain": [0.25, 0.3, 0.27, 0.1], "n": [256, 576, 1024, 4096]},
               restore_cut=0.4, sliced_ot={"directions": 128, "iterations": [4, 12, 20],
                                           "n": [256, 1024, 4096], "step": 1.5})
    models = {}
    for name, c in (("new", new), ("old", old)):
        for p in model.metadata_props:
            if p.key == CARD_KEY:
                p.value = json.dumps(c)
        onnx.save(model, str(tmp_path / f"{name}.onnx"))
        models[name] = diffsampler_rt.Model(tmp_path / f"{name}.onnx")
    assert models["old"].card["pipeline"] == models["new"].card["pipeline"]
    np.testing.assert_array_equal(models["old"].generate(200, 2, seed=4),
                                  models["new"].generate(200, 2, seed=4))


def test_every_bundled_card_is_format_2_and_describes_its_steps():
    import diffsampler_rt
    for name in zoo.networks():
        card = diffsampler_rt.load(name).card
        assert card["format_version"] == 2
        lines = describe(card["pipeline"])
        assert len(lines) == len(card["pipeline"]) and all("\n" not in t for t in lines)


def test_generation_checks_points_once_and_steps_trust_them(monkeypatch):
    import diffsampler_rt
    from diffsampler_rt import _validate, spacing
    seen = []
    real = spacing.unit_points

    def spy(*args, **kwargs):
        seen.append(getattr(_validate._TRUST, "on", False))
        return real(*args, **kwargs)

    monkeypatch.setattr(spacing, "unit_points", spy)
    diffsampler_rt.generate("gbn_fast", 200, 2, seed=0)
    assert seen and all(seen)  # inside the generation path: trusted
    with pytest.raises(ValueError, match="non-finite"):  # called directly: checked
        spacing.enforce_min_spacing(np.full((1, 16, 2), np.nan), 0.1)


def test_structure_guidance_leaves_a_structure_without_a_projection_alone(tiny_onnx):
    """A rank-1 lattice replaces the set; there is no imposition on a predicted set to
    guide by, so the guidance is a no-op there rather than an error."""
    import diffsampler_rt
    model = diffsampler_rt.Model(tiny_onnx)
    lattice = [{"step": "rank1_lattice", "sides": [8]}, {"step": "thin", "drop": "random"}]
    model.card = {**model.card, "pipeline": lattice}
    plain = model.generate(64, 2, seed=3, steps=3)
    model.card = {**model.card, "pipeline": [{"step": "structure_guidance", "steps": 2}]
                  + lattice}
    np.testing.assert_array_equal(model.generate(64, 2, seed=3, steps=3), plain)


def test_structure_guidance_steps_may_differ_by_size(tiny_onnx):
    """Calibration chooses the guided steps size by size: a table whose value is 0 at a
    size leaves that size's sets as they are, and guides at the others."""
    import diffsampler_rt
    model = diffsampler_rt.Model(tiny_onnx)
    net = [{"step": "dyadic_net", "min_side": 4}, {"step": "thin", "drop": "random"}]

    def sets(guide: list[dict], n: int) -> np.ndarray:
        model.card = {**model.card, "pipeline": guide + net}
        return model.generate(n, 2, seed=3, steps=3)

    table = [{"step": "structure_guidance", "steps": {"n": [16, 64], "values": [0, 2]}}]
    np.testing.assert_array_equal(sets(table, 16), sets([], 16))
    np.testing.assert_array_equal(sets(table, 64), sets([{"step": "structure_guidance",
                                                           "steps": 2}], 64))
    assert not np.array_equal(sets(table, 64), sets([], 64))
    assert "0 / 2 at n = 16 / 64" in "\n".join(diffsampler_rt.finish.pipeline.describe(table))
