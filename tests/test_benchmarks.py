"""The benchmark scripts run end to end (tiny sizes)."""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# minutes in all: run by the full suite, not by `pytest -m "not slow"`
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


def test_fidelity_report_runs(tmp_path):
    env = {**__import__("os").environ, "DIFFSAMPLER_CACHE": str(tmp_path / "cache")}
    res = subprocess.run([sys.executable, "benchmarks/fidelity.py", "--models", "sobol_owen",
                          "--sizes", "64", "--sets", "3", "--workers", "1",
                          "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "| 64 | 3 |" in md and "empty el. intervals" in md
    assert (tmp_path / "out" / "fidelity.json").exists()
    # the kept per-model result feeds the report again and the violin plots
    res = subprocess.run([sys.executable, "benchmarks/fidelity.py", "--report-only",
                          "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    assert "| 64 | 3 |" in (tmp_path / "out" / "fidelity.md").read_text()
    # --merge measures 256 now and keeps the 64 row, which the same file reproduces
    merge = [sys.executable, "benchmarks/fidelity.py", "--models", "sobol_owen", "--sizes", "256",
             "--sets", "3", "--workers", "1", "--merge", "--out", str(tmp_path / "out")]
    res = subprocess.run(merge, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "| 64 | 3 |" in md and "| 256 | 3 |" in md and "n = 64 in an earlier run on " in md
    # no size given: every kept row re-checked and kept (after a card change that no square
    # size's sets show), the plot's examples made anew; without --merge that is refused
    res = subprocess.run(merge[:4] + ["--sizes"] + merge[6:], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "| 64 | 3 |" in md and "| 256 | 3 |" in md
    assert "Measured: n = 64, 256 in an earlier run on " in md and "n =  " not in md
    res = subprocess.run(merge[:4] + ["--sizes", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 2 and "no size given" in res.stderr
    res = subprocess.run(merge[:4] + ["--sizes", "--merge", "--out", str(tmp_path / "none")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 1 and "sobol_owen: no kept result to keep" in res.stderr
    # a kept row the current file does not reproduce is refused, not merged
    kept = tmp_path / "out" / "fidelity" / "sobol_owen.json"
    r = json.loads(kept.read_text())
    r["rows"]["64"]["min_distance"]["gen_sets"][0] *= 1.01
    kept.write_text(json.dumps(r))
    res = subprocess.run(merge, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode != 0 and "rows at n = 64 are not reproduced" in res.stderr
    assert "sobol_owen n=256" not in res.stdout  # refused before any size was measured
    # --check-kept finds that row (as after a runtime change) and the report says so
    res = subprocess.run(merge[:4] + ["--check-kept", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    assert "sobol_owen: kept rows not reproduced at n = [64]" in res.stdout
    rows = json.loads(kept.read_text())["rows"]
    assert [rows[n]["reproduced"]["ok"] for n in ("64", "256")] == [False, True]
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "**Not reproduced by the current runtime** at n = 64 (checked on " in md
    res = subprocess.run([sys.executable, "benchmarks/violins.py", "--results",
                          str(tmp_path / "out")], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "out" / "violins.png").stat().st_size > 1000


def test_fidelity_pools_reference_files_of_further_seeds(tmp_path):
    env = {**__import__("os").environ, "DIFFSAMPLER_CACHE": str(tmp_path / "cache")}
    cmd = [sys.executable, "benchmarks/fidelity.py", "--models", "sobol_owen", "--sizes", "64",
           "--sets", "3", "--workers", "1", "--out", str(tmp_path / "out")]
    res = subprocess.run(cmd + ["--ref-pool", "sobol_owen:64:2:2-3"],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    # the seed-1 draw (2 x 3 sets) and two files of 2 sets: 10 sets, 5 a side
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "| 64 | 5 |" in md and "--ref-pool sobol_owen:64:2:2-3" in md
    ref = tmp_path / "cache" / "reference"
    assert (ref / "sobol_owen_n64_c2_s2.npz").exists() and (ref / "sobol_owen_n64_c2_s3.npz").exists()
    # --pool-only: the two files alone (4 sets, 2 a side), the option in the report; in a
    # fresh cache the seed-1 draw is not made just for its time per set
    fresh = {**env, "DIFFSAMPLER_CACHE": str(tmp_path / "fresh")}
    res = subprocess.run(cmd + ["--ref-pool", "sobol_owen:64:2:2-3", "--pool-only"],
                         capture_output=True, text=True, cwd=ROOT, env=fresh, timeout=600)
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "| 64 | 2 |" in md and "--ref-pool sobol_owen:64:2:2-3 --pool-only" in md
    drawn = sorted(p.name for p in (tmp_path / "fresh" / "reference").glob("sobol_owen_n64_c*.npz"))
    assert drawn == ["sobol_owen_n64_c2_s2.npz", "sobol_owen_n64_c2_s3.npz"]
    res = subprocess.run(cmd + ["--pool-only"], capture_output=True, text=True, cwd=ROOT,
                         env=env, timeout=600)
    assert res.returncode == 2 and "--pool-only: no --ref-pool" in res.stderr
    for bad in ("sobol_owen:64:2", "sobol_owen:64:2:1-3", "sobol_owen:x:2:2"):
        res = subprocess.run(cmd + ["--ref-pool", bad], capture_output=True, text=True,
                             cwd=ROOT, env=env, timeout=600)
        assert res.returncode == 2 and repr(bad) in res.stderr, res.stderr


def test_fidelity_against_stored_reference_figures(tmp_path):
    import shutil
    env = {**__import__("os").environ, "DIFFSAMPLER_CACHE": str(tmp_path / "cache")}
    run = [sys.executable, "benchmarks/fidelity.py", "--models", "sobol_owen", "--sets", "3",
           "--workers", "1", "--out", str(tmp_path / "out")]
    cmd = run + ["--sizes", "64"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    kept = tmp_path / "out" / "fidelity" / "sobol_owen.json"
    before = json.loads(kept.read_text())["rows"]["64"]
    shutil.rmtree(tmp_path / "cache")  # the reference sets are not at hand
    res = subprocess.run(cmd + ["--stored-reference"], capture_output=True, text=True, cwd=ROOT,
                         env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    assert not (tmp_path / "cache" / "reference").exists()  # nothing drawn for A and B
    after = json.loads(kept.read_text())["rows"]["64"]
    # the same model and seed against the kept reference side: the same figures
    for key in ("mae", "floor", "count", "empty"):
        assert after[key] == before[key], key
    for stat in ("gauss_mse", "min_distance"):
        assert after[stat] == before[stat]
    assert after["reference"]["settings"]["sets"] == 3
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "Reference side stored (`--stored-reference`): n = 64 from the run of" in md
    assert " --stored-reference` on " in md
    res = subprocess.run(run + ["--sizes", "64", "256", "--stored-reference"],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode != 0 and "sobol_owen has no kept row at n = 256" in res.stderr
    # a new model of the same sampler (a student) against another model's kept reference
    other = [a if a != "sobol_owen" else "sobol_owen_fast" for a in cmd]
    res = subprocess.run(other + ["--stored-reference", "sobol_owen"], capture_output=True,
                         text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    row = json.loads((tmp_path / "out" / "fidelity" / "sobol_owen_fast.json").read_text())
    row = row["rows"]["64"]
    assert row["reference"]["model"] == "sobol_owen"
    assert row["floor"] == before["floor"] and row["count"] == before["count"]
    assert row["gauss_mse"]["ref_sets"] == before["gauss_mse"]["ref_sets"]
    md = (tmp_path / "out" / "fidelity.md").read_text()
    assert "n = 64 from sobol_owen's run of" in md
    assert " --stored-reference sobol_owen` on " in md
    res = subprocess.run([a if a != "sobol_owen" else "ldbn" for a in cmd]
                         + ["--stored-reference", "sobol_owen"], capture_output=True,
                         text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode != 0
    assert "sobol_owen models 'sobol_owen', not ldbn's sampler 'ldbn'" in res.stderr


def test_post_processing_projections_reach_and_keep_the_structure():
    import numpy as np
    sys.path.insert(0, str(ROOT))
    from benchmarks.post_processing import project_to_net, stratify_1d
    from trainer.samplers import sample
    from trainer.stats import empty_elementary_fraction, stratified_projections

    rng = np.random.default_rng(0)
    white = rng.random((3, 256, 2))
    assert np.all(empty_elementary_fraction(white) > 0.2)
    assert np.all(empty_elementary_fraction(project_to_net(white)) == 0)  # any set -> a net
    assert np.all(stratified_projections(stratify_1d(white)))
    owen = sample("sobol_owen", 256, count=3, seed=1)
    np.testing.assert_array_equal(project_to_net(owen), owen)            # a net stays put
    ldbn = sample("ldbn", 256, count=3, seed=1)
    np.testing.assert_array_equal(stratify_1d(ldbn), ldbn)


def test_speed_results_merge_size_by_size():
    sys.path.insert(0, str(ROOT))
    from benchmarks.speed import merge_kept
    old = {"sot": {"sampler": "sot", "rows": {"256": {"alone_s": 1.0}, "4096": {"alone_s": 4.0}}},
           "gbn": {"sampler": "gbn", "rows": {"1024": {"alone_s": 2.0}}}}
    new = {"sot": {"sampler": "sot", "rows": {4096: {"alone_s": 5.0}}}}
    merged = merge_kept(old, new)
    assert merged["sot"]["rows"] == {256: {"alone_s": 1.0}, 4096: {"alone_s": 5.0}}
    assert merged["gbn"]["rows"] == {1024: {"alone_s": 2.0}}


def test_speed_peak_memory_is_the_childs_own():
    # Linux's ru_maxrss survives exec: a child of a big parent reported the parent's size
    big = np.ones(400 * 2 ** 20 // 8)  # this process: 400 MiB more, touched
    code = ("import sys; sys.path.insert(0, sys.argv[1]); "
            "from benchmarks.speed import _peak_mib; print(_peak_mib())")
    out = subprocess.run([sys.executable, "-c", code, str(ROOT)], capture_output=True,
                         text=True, check=True)
    assert 1 < float(out.stdout) < 200, out.stdout
    assert big.sum() == big.size
    from benchmarks.speed import card_of
    assert card_of("sot_fast")["sampler"] == "sot"  # without loading it here


def test_speed_report_dates_each_models_latest_run():
    """The report's header says which models' rows a run measured and which are older."""
    sys.path.insert(0, str(ROOT))
    from benchmarks.speed import _dates_text, kept_json, merge_kept
    old = {"sot": {"sampler": "sot", "rows": {}, "date": "2026-11-28"},
           "gbn": {"sampler": "gbn", "rows": {}, "date": "2026-11-28"},
           "ldbn": {"sampler": "ldbn", "rows": {}, "date": "2026-11-28"}}
    merged = merge_kept(old, {"sot": {"sampler": "sot", "rows": {}, "date": "2026-12-02"}})
    assert merged["gbn"]["date"] == "2026-11-28" and merged["sot"]["date"] == "2026-12-02"
    assert _dates_text(merged, "2026-12-02") == "2026-12-02 (sot), 2026-11-28 (the other 2 models)"
    # the dates survive speed.json, so the next run's header still has them
    again = merge_kept(json.loads(json.dumps(kept_json(merged))), {})
    assert {m: r["date"] for m, r in again.items()} == {m: r["date"] for m, r in merged.items()}
    assert _dates_text(old, "2026-12-02") == "2026-11-28"
    assert _dates_text({"a": {"rows": {}}}, "2026-12-02") == "2026-12-02"


def _speed_rows(monkeypatch, model: str, sizes: list[int], reference) -> tuple[dict, list[str]]:
    """speed.measure's rows for ``model`` with its children faked: every model timing 1 s,
    the reference's result ``reference(n)`` (None: stopped; an exception: failed); and the
    sizes at which the reference was started."""
    import argparse
    sys.path.insert(0, str(ROOT))
    from benchmarks import speed
    started = []

    def fake_child(args, timeout):
        if args[0] == "model":
            return {"alone_s": 1.0, "batch_s_per_set": 1.0, "peak_mib": 100.0}
        started.append(args[2])
        return reference(int(args[2]))

    monkeypatch.setattr(speed, "_run_child", fake_child)
    a = argparse.Namespace(models=[model], sizes=sizes, batch=32, repeats=1, threads=0,
                           ref_budget=120.0)
    return speed.measure(a)[model]["rows"], started


def test_speed_skips_the_reference_beyond_one_that_was_stopped(monkeypatch):
    # a slow reference stopped at the first size timed must not be started (and stopped
    # after 4x the budget) again at every larger size
    rows, started = _speed_rows(monkeypatch, "gbn_blob", [16384, 65536, 262144],
                                lambda n: None)  # the reference ran past its timeout
    assert started == ["16384"]
    assert "stopped" in rows[16384]["ref_note"]
    assert rows[65536]["ref_note"].startswith("not run") and rows[262144]["ref_s"] is None


def test_speed_names_the_size_whose_reference_failed(monkeypatch):
    # after a failing reference the larger sizes are skipped and say why, not "estimated"
    def reference(n):
        if n == 256:
            return {"ref_s": 0.5, "peak_mib": 50.0}
        raise RuntimeError("child ['reference'] failed:\nMemoryError: 37 GiB")

    rows, started = _speed_rows(monkeypatch, "poisson_disk", [256, 1024, 4096], reference)
    assert started == ["256", "1024"]
    assert rows[256]["ref_s"] == 0.5
    assert rows[1024]["ref_note"] == "failed: MemoryError: 37 GiB"
    assert rows[4096]["ref_note"] == "not run (failed at n = 1024)" and rows[4096]["ref_s"] is None


def test_speed_starts_its_reference_estimate_from_the_kept_rows(monkeypatch):
    # gbn_blob's reference took 40 s a set at 1024 in an earlier run: at 4096 it would take
    # ~320 s, over the 120 s budget, so a run that starts at 4096 must not start it at all
    import argparse
    sys.path.insert(0, str(ROOT))
    from benchmarks import speed
    calls = []

    def fake_child(args, timeout):
        calls.append(args[:3])
        return {"alone_s": 1.0, "batch_s_per_set": 1.0, "peak_mib": 100.0, "ref_s": 1.0}

    monkeypatch.setattr(speed, "_run_child", fake_child)
    kept = {"gbn_blob": {"sampler": "gbn_blob", "rows": {
        "256": {"ref_s": 9.0}, "1024": {"ref_s": 40.0},
        "16384": {"ref_s": None, "ref_note": "> 480 s (stopped)"}}}}
    assert speed.earlier_reference(kept, "gbn_blob", 4096, 120.0) == (1024, 40.0)
    assert speed.earlier_reference(kept, "gbn_blob", 65536, 120.0) == (16384, 480.0)
    assert speed.earlier_reference(kept, "gbn", 4096, 120.0) == (None, None)
    a = argparse.Namespace(models=["gbn_blob"], sizes=[4096], batch=32, repeats=1, threads=0,
                           ref_budget=120.0)
    row = speed.measure(a, kept)["gbn_blob"]["rows"][4096]
    assert [c for c in calls if c[0] == "reference"] == []
    assert row["ref_note"] == "not run (~320 s estimated)"
    calls.clear()
    speed.measure(a)  # nothing kept: the first size is always tried
    assert [c for c in calls if c[0] == "reference"] == [["reference", "gbn_blob", "4096"]]


def test_solver_sweep_settings_may_override_the_guidance():
    import argparse
    import pytest
    sys.path.insert(0, str(ROOT))
    from benchmarks.solver_sweep import load_with, parse_setting
    assert parse_setting("dpmpp_2m:10") == ("dpmpp_2m", 10)
    assert parse_setting("ddim:8:g3") == ("ddim", 8, 3)
    with pytest.raises(argparse.ArgumentTypeError, match="'ddim:8:3'"):
        parse_setting("ddim:8:3")
    plain = load_with("ldbn", None)
    guided = load_with("ldbn", 2)
    from diffsampler_rt.finish.pipeline import find
    assert find(guided.card["pipeline"], "structure_guidance") == {"steps": 2}
    assert guided is not plain  # the cached, bundled model is untouched:
    assert find(plain.card["pipeline"], "structure_guidance") == {"steps": 5}
    np = pytest.importorskip("numpy")
    a, b = plain.generate(256, 1, seed=0), guided.generate(256, 1, seed=0)
    assert a.shape == b.shape and not np.array_equal(a, b)


def test_quantized_report_runs_and_checks_the_float_file(tmp_path):
    out = tmp_path / "quantized.md"
    res = subprocess.run([sys.executable, "benchmarks/quantized.py", "--models", "ldbn_fast",
                          "--sizes", "256", "--sets", "3", "--workers", "1", "--out", str(out)],
                         capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert res.returncode == 0, res.stderr
    md = out.read_text()
    assert "## ldbn_fast" in md and "| 256 (3) | **8-bit, same noise** |" in md
    # another float file than the one the card names is refused
    wrong = tmp_path / "floats"
    wrong.mkdir()
    (wrong / "ldbn_fast.onnx").write_bytes((ROOT / "models/float/gbn_fast.onnx").read_bytes())
    res = subprocess.run([sys.executable, "benchmarks/quantized.py", "--models", "ldbn_fast",
                          "--float-dir", str(wrong), "--out", str(out)],
                         capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert res.returncode == 1 and "is not the network ldbn_fast was quantised from" in res.stderr


def test_integration_check_reads_the_cached_reference(tmp_path):
    import numpy as np
    from trainer.samplers import sample
    env = {**__import__("os").environ, "DIFFSAMPLER_CACHE": str(tmp_path)}
    cmd = [sys.executable, "benchmarks/integration_check.py", "sobol_owen", "64", "3", "8",
           "sobol_owen", "models/sobol_owen.onnx"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode != 0 and "no cached reference sets" in res.stderr
    (tmp_path / "reference").mkdir()
    np.savez(tmp_path / "reference" / "sobol_owen_n64_c8_s1.npz",
             pts=sample("sobol_owen", 64, count=8, seed=[1, 0]), per_set=0.0)
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0].startswith("sobol_owen n=64: 3 generated sets per model vs 8 reference")
    # the network by name and by path: the same sets, the same figures (timing aside)
    assert lines[1].split(": ", 1)[1].rsplit("[", 1)[0] == lines[2].split(": ", 1)[1].rsplit("[", 1)[0]
    assert "Gauss MSE" in lines[1] and "spectrum MAE" in lines[1]
    # a second seed's file is pooled with the first; a missing one is named
    res = subprocess.run(cmd[:7] + ["--ref-seeds", "1,2"], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=600)
    assert res.returncode != 0 and "sobol_owen_n64_c8_s2.npz" in res.stderr
    np.savez(tmp_path / "reference" / "sobol_owen_n64_c8_s2.npz",
             pts=sample("sobol_owen", 64, count=8, seed=[2, 0]), per_set=0.0)
    res = subprocess.run(cmd[:7] + ["--ref-seeds", "2,1"], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    assert "vs 16 reference sets (seeds 1, 2)" in res.stdout


def test_integration_check_unwarps_non_uniform_samplers(tmp_path):
    import numpy as np
    import diffsampler_rt
    from benchmarks.fidelity import integration_errors
    from trainer.samplers.densities import ramp_unwarp
    env = {**__import__("os").environ, "DIFFSAMPLER_CACHE": str(tmp_path)}
    (tmp_path / "reference").mkdir()
    u = np.random.default_rng(0).random((8, 64, 2))
    ref = np.stack([np.sqrt(u[..., 0]), u[..., 1]], -1)  # density 2x: unwarps to u
    np.savez(tmp_path / "reference" / "sot_ramp_n64_c8_s1.npz", pts=ref, per_set=0.0)
    cmd = [sys.executable, "benchmarks/integration_check.py", "sot_ramp", "64", "3", "8",
           "sot_ramp"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    gen = ramp_unwarp(diffsampler_rt.generate("sot_ramp", 64, 3, seed=77))
    want = integration_errors(gen)["gauss_mse"].mean() / integration_errors(u)["gauss_mse"].mean()
    assert f"Gauss MSE {100 * (want - 1):+.1f} %" in res.stdout.splitlines()[1]


def test_fidelity_marks_only_misses_beyond_their_noise():
    import numpy as np
    from benchmarks.fidelity import _fmt_rel, miss_mark, two_se
    rng = np.random.default_rng(0)
    ref = rng.gamma(4.0, 0.25, 200_000)  # per-set values, mean 1, relative sd 0.5

    def stat(gen: np.ndarray, ref: np.ndarray) -> dict:
        return {"rel": gen.mean() / ref.mean() - 1, "floor": 0.0,
                "gen_sets": gen.tolist(), "ref_sets": ref.tolist()}

    # two standard errors of the relative difference: 2 sqrt(0.25/64 + 0.25/64) at 64 a side
    few = stat(ref[:64], ref[64:128])
    assert abs(two_se(few) / (1 + few["rel"]) - 2 * np.sqrt(0.5 / 64)) < 0.05
    # a true 8 % excess: with 64 sets a side noise could explain it, with 20 000 it cannot
    assert miss_mark(stat(1.08 * ref[:64], ref[64:128]), 0.05) in ("", " ✗?")
    many = stat(1.08 * ref[:20_000], ref[20_000:40_000])
    assert miss_mark(many, 0.05) == " ✗" and two_se(many) < 0.02
    assert miss_mark(stat(ref[:20_000], ref[20_000:40_000]), 0.05) == ""
    # a kept result without per-set values (every current one has them): no interval
    assert two_se({"rel": 0.2, "floor": 0.0}) is None
    assert _fmt_rel({"rel": 0.2, "floor": 0.01}, 0.05) == "+20.0 % ✗ (+1.0)"
    assert _fmt_rel(many, 0.05).startswith("+8.")


def test_fidelity_holds_each_student_to_its_base_models_spectrum_target():
    from benchmarks.fidelity import TARGET_MAE, target_mae
    assert target_mae("sot_32") == TARGET_MAE["sot_32"] == 0.007
    assert target_mae("sot_32_fast") == 0.007 and target_mae("ldbn_fast") == 0.006
    assert target_mae("sot_fast") == TARGET_MAE["sot"]  # not sot_32's: the longest name
    # no target where the zoo sets none: the torus, blob and ramp variants and their students
    assert target_mae("gbn_torus_fast") is None and target_mae("sot_ramp") is None


def test_fidelity_tally_counts_every_figure_by_its_mark():
    from benchmarks.fidelity import STATS, _tally_lines, tally

    def row(rels: dict) -> dict:  # no per-set values: a miss is always beyond noise
        return {k: {"rel": rels.get(k, 0.0), "floor": 0.0} for k in STATS}

    noisy = {"rel": 0.08, "floor": 0.0, "gen_sets": [0.5, 1.5, 1.0], "ref_sets": [0.6, 1.4]}
    results = [{"name": "a", "rows": {64: row({"l2_star": 0.2}),
                                      256: {**row({}), "gauss_mse": noisy}}},
               {"name": "b", "rows": {64: row({"min_distance": -0.08, "ot_energy": 0.06})}}]
    assert tally(results) == {"a": {"within": 8, "noise": 1, "beyond": 1},
                              "b": {"within": 4, "noise": 0, "beyond": 1}}
    lines = _tally_lines(results)
    assert "| a | 10 | 8 | 1 | 1 |" in lines and lines[-1] == "| **all** | 15 | 12 | 1 | 2 |"


def test_any_n_report_runs(tmp_path):
    env = {**__import__("os").environ, "DIFFSAMPLER_CACHE": str(tmp_path / "cache")}
    cmd = [sys.executable, "benchmarks/any_n.py", "--models", "sobol_owen_fast", "rank1",
           "--sizes", "50", "--sets", "3", "--workers", "1", "--out", str(tmp_path / "out")]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "out" / "any_n.md").read_text()
    # sobol_owen_fast: the first 50 of a 64-point net in Sobol' order (card structure_prefix)
    assert "| 50 (8x8) | 3 | **first n, Sobol' order** |" in md
    assert "| 50 (8x8) | 3 | dropped at random |" in md
    assert "## rank1" in md and (tmp_path / "out" / "any_n.png").stat().st_size > 1000
    # a later run rewrites the models it measures and keeps the others' sections; its
    # pooled reference files join the seed-1 draw (6 + 4 sets: 5 a side)
    rest = ["--sets", "3", "--workers", "1", "--out", str(tmp_path / "out")]
    res = subprocess.run(cmd[:2] + ["--models", "rank1", "--sizes", "60",
                                    "--ref-pool", "rank1:60:2:2-3"] + rest,
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    (tmp_path / "out" / "any_n.md").unlink()
    res = subprocess.run(cmd[:2] + ["--report-only", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "out" / "any_n.md").read_text()
    owen, rank1 = md.split("## sobol_owen_fast")[1].split("## rank1")
    assert "| 50 (8x8) | 3 | **first n, Sobol' order** |" in owen
    assert "--sizes 50 --sets 3" in owen
    assert "| 60 (8x8) | 5 | **thinned** |" in rank1 and "| 50 (8x8)" not in rank1
    assert "--ref-pool rank1:60:2:2-3" in rank1 and "--ref-pool" not in owen
    # how the sets of n points were made: the first n in Sobol' order; a lattice model's
    # thinned sets are replaced, not restored
    assert "sets of n points: the first n, in Sobol' order" in owen
    assert "restored below" not in rank1 and "restored below" not in owen
    for bad, match in ((["--sizes", "64"], "64 is a perfect square"),
                       (["--models", "ldbn"], "not measured here"),
                       (["--pool-only"], "--pool-only: no --ref-pool")):
        res = subprocess.run(cmd[:2] + ["--models", "rank1", "--sizes", "50"] + bad,
                             capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
        assert res.returncode == 2 and match in res.stderr


def test_distilled_report_names_the_students_it_has_not_measured(tmp_path):
    sys.path.insert(0, str(ROOT))
    from benchmarks.distilled import students, write_report
    kept = tmp_path / "distilled"
    kept.mkdir()
    (kept / "gbn_fast.md").write_text("## gbn_fast\n\nkept section\n")
    out = tmp_path / "distilled.md"
    write_report(out)
    text = out.read_text()
    assert text.startswith("# Distilled students vs their teachers")
    assert text.endswith("## gbn_fast\n\nkept section\n")
    line = next(s for s in text.splitlines() if s.startswith("Not measured here yet: "))
    assert "`gbn_fast`" not in line
    assert all(f"`{m}`" in line for m in students() if m != "gbn_fast")


def test_speed_report_only_keeps_the_measuring_run_date(tmp_path):
    sys.path.insert(0, str(ROOT))
    from benchmarks.speed import last_run_date
    md = tmp_path / "speed.md"
    assert last_run_date(md) is None
    md.write_text("# Generation speed\n\n`python benchmarks/speed.py` on 2026-11-28: 2 cores\n")
    assert last_run_date(md) == "2026-11-28"


def test_fidelity_merge_draws_the_plot_examples_at_the_size_it_shows(tmp_path):
    # kept rows carry no example sets: a re-measure at 64 alone must not leave 64-point
    # examples under the kept 1024-point spectrum
    sys.path.insert(0, str(ROOT))
    from benchmarks.fidelity import merge_kept
    (tmp_path / "fidelity").mkdir()
    kept = {"date": "2026-01-01", "settings": {"seed": 1}, "model_sha256": "x",
            "rows": {"64": {"mae": 0.1}, "1024": {"mae": 0.2}}}
    (tmp_path / "fidelity" / "rank1.json").write_text(json.dumps(kept))
    now = {"name": "rank1", "sampler": "rank1",
           "rows": {64: {"mae": 0.3, "example_gen": np.zeros((64, 2))}}}
    merged = merge_kept(now, tmp_path, seed=1)
    assert merged["rows"][64]["mae"] == 0.3 and merged["rows"][1024]["mae"] == 0.2
    assert merged["rows"][1024]["example_gen"].shape == (1024, 2)
    assert merged["rows"][1024]["example_ref"].shape == (1024, 2)
    # measured at a size the plot shows: its own examples, nothing drawn for the kept rows
    now = {"name": "rank1", "sampler": "rank1",
           "rows": {1024: {"mae": 0.3, "example_gen": np.zeros((1024, 2))}}}
    assert "example_gen" not in merge_kept(now, tmp_path, seed=1)["rows"][64]


def test_fidelity_run_line_lists_only_the_runs_that_measured_rows():
    # a --merge run that measured no size (a reproduction check after a card change) keeps
    # every row from earlier runs; its own date and options are not a measurement
    sys.path.insert(0, str(ROOT))
    from benchmarks.fidelity import _row_runs
    early = {"date": "2026-11-25", "settings": {"sets": 256}}
    stored = {"date": "2026-11-20", "settings": {"sets": 64}}
    check = {"date": "2026-12-03", "settings": {"sets": 128},
             "rows": {64: {"measured": early}, 256: {"measured": early, "reference": stored}}}
    assert [r["date"] for r in _row_runs(check)] == ["2026-11-25", "2026-11-25", "2026-11-20"]
    measured = {**check, "rows": {**check["rows"], 1024: {"mae": 0.1}}}
    assert "2026-12-03" in [r["date"] for r in _row_runs(measured)]


def test_plot_example_reference_comes_from_the_cache_when_it_has_one(tmp_path, monkeypatch):
    # the slow samplers take minutes a set at 4096: a plot's example reuses a cached set
    sys.path.insert(0, str(ROOT))
    from benchmarks.common import example_reference, reference_path
    monkeypatch.setenv("DIFFSAMPLER_CACHE", str(tmp_path))
    fresh = example_reference("sobol_owen", 64, seed=3)
    assert fresh.shape == (64, 2) and np.all((fresh >= 0) & (fresh < 1))
    cached = np.random.default_rng(0).random((4, 64, 2))
    path = reference_path("sobol_owen", 64, 4, 9)
    path.parent.mkdir(parents=True)
    np.savez(path, pts=cached, per_set=0.1)
    # neither a stats file nor another size is taken for the sets
    np.savez(path.parent / "sobol_owen_n64_c4_s1_first2_stats_v1.npz", ot_energy=np.ones(4))
    np.savez(reference_path("sobol_owen", 256, 4, 1), pts=np.zeros((4, 256, 2)), per_set=0.1)
    np.testing.assert_array_equal(example_reference("sobol_owen", 64, seed=3), cached[0])
    assert example_reference("sobol_owen", 256, seed=3).shape == (256, 2)


def test_cpu_description_names_the_model_and_its_vnni(tmp_path):
    from benchmarks.common import cpu_description
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse avx avx2 fma\n")
    assert cpu_description(info) == "AMD EPYC (avx2; no VNNI)"
    info.write_text("model name\t: Xeon\nflags\t: avx2 avx512f avx512_vnni avx512_bf16\n")
    assert cpu_description(info) == "Xeon (avx2, avx512f, avx512_vnni, avx512_bf16)"
    assert cpu_description(tmp_path / "missing")  # the machine type, never an error


def test_speed_report_names_each_models_cpu():
    import json
    from benchmarks.speed import _cpus_text, kept_json, merge_kept
    old = {"gbn": {"sampler": "gbn", "rows": {}, "date": "2026-11-28"},
           "sot": {"sampler": "sot", "rows": {}, "date": "2026-11-28"}}
    assert _cpus_text(old) == "a CPU not recorded"  # a speed.json from before the CPU was kept
    merged = merge_kept(old, {"sot": {"sampler": "sot", "rows": {}, "date": "2026-12-04",
                                      "cpu": "AMD EPYC (avx2; no VNNI)"}})
    assert _cpus_text(merged) == "AMD EPYC (avx2; no VNNI) (sot); a CPU not recorded (gbn)"
    again = merge_kept(json.loads(json.dumps(kept_json(merged))), {})  # kept in speed.json
    assert again["sot"]["cpu"] == "AMD EPYC (avx2; no VNNI)" and "cpu" not in again["gbn"]


def test_calibration_report_records_a_card_taken_back(tmp_path, monkeypatch):
    """``--taken-back MODEL WHY`` marks an adopted row (the report says the shipped card is
    the earlier one, and why); a model without an adopted row is refused."""
    sys.path.insert(0, str(ROOT))
    from benchmarks import calibration
    shutil.copy(ROOT / "benchmarks" / "results" / "calibration.json", tmp_path)
    monkeypatch.setattr(calibration, "RESULTS", tmp_path)
    rows = json.loads((tmp_path / "calibration.json").read_text())
    adopted = next(r["model"] for r in rows if r.get("adopted"))
    monkeypatch.setattr(sys, "argv", ["calibration.py", "--report-only", "--taken-back",
                                      adopted, "two new misses"])
    calibration.main()
    row = next(r for r in json.loads((tmp_path / "calibration.json").read_text())
               if r["model"] == adopted)
    assert row["reverted"] == "two new misses"
    report = (tmp_path / "calibration.md").read_text()
    assert "then taken back: two new misses" in report
    assert f"| {adopted} | card (calibrated one taken back) |" in report
    kept = [r["model"] for r in rows if not r.get("adopted")]
    monkeypatch.setattr(sys, "argv", ["calibration.py", "--report-only", "--taken-back",
                                      kept[0], "x"])
    with pytest.raises(SystemExit):
        calibration.main()
