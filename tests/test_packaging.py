"""The runtime wheel ships diffsampler_rt and its models, and nothing with a generic name."""
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the samplers the wheel ships one model each for
SAMPLERS = ["gbn", "poisson_disk", "sot", "ldbn", "sobol_owen", "rank1", "lattice", "sot_ramp",
            "gbn_blob", "sot_32"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheel")
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                          "--no-build-isolation", "-q", "-w", str(out), str(ROOT)],
                         capture_output=True, text=True)
    if res.returncode != 0:
        pytest.fail(res.stderr[-2000:])
    (path,) = out.glob("diffsampler_rt-*.whl")
    return path


@pytest.mark.slow
def test_wheel_contents(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"diffsampler_rt"}
    sources = {p.relative_to(ROOT).as_posix() for p in (ROOT / "diffsampler_rt").rglob("*.py")}
    assert sources <= set(names), sorted(sources - set(names))  # subpackages included
    shipped = {n.rsplit("/", 1)[1][:-5] for n in names if n.endswith(".onnx")}
    assert shipped == set(SAMPLERS)  # one network per sampler, under the sampler's name
    assert all(n.startswith("diffsampler_rt/models/") for n in names if n.endswith(".onnx"))
    assert wheel.stat().st_size <= 30 * 2**20


def test_wheel_requires_only_numpy_and_onnxruntime(wheel):
    z = zipfile.ZipFile(wheel)
    meta = z.read(next(n for n in z.namelist() if n.endswith("METADATA"))).decode()
    required = [l.split(":", 1)[1].strip() for l in meta.splitlines()
                if l.startswith("Requires-Dist:") and "extra ==" not in l]
    assert sorted(r.split(">")[0].split("=")[0].strip() for r in required) == ["numpy",
                                                                              "onnxruntime"]


def test_bundled_models_are_small():
    for path in (ROOT / "diffsampler_rt" / "models").rglob("*.onnx"):
        assert path.stat().st_size <= 4_000_000, path.name


def test_each_shipped_model_is_a_network_of_the_repository():
    """The wheel's models are byte copies of networks kept in models/ (trained, reported and
    distilled under their own names); the card names the network and its sampler."""
    import diffsampler_rt
    networks = {p.read_bytes(): p.stem for p in (ROOT / "models").glob("*.onnx")}
    for name in SAMPLERS:
        path = ROOT / "diffsampler_rt" / "models" / f"{name}.onnx"
        assert path.read_bytes() in networks, name
        card = diffsampler_rt.load(path).card
        assert card["name"] == networks[path.read_bytes()]
        assert card["sampler"] == ("sot" if name == "sot_32" else name)


def test_wheel_states_its_licence(wheel):
    z = zipfile.ZipFile(wheel)
    meta = z.read(next(n for n in z.namelist() if n.endswith("METADATA"))).decode()
    assert "License-Expression: MIT" in meta.splitlines()
