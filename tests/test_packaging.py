"""The runtime wheel ships diffsampler_rt and its models, and nothing with a generic name."""
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


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
    assert "diffsampler_rt/models/rank1.onnx" in names
    assert "diffsampler_rt/models/sobol_owen.onnx" in names
    assert "diffsampler_rt/models/guides/sot_32_guide.onnx" in names  # sot_32's guide


def test_wheel_requires_only_numpy_and_onnxruntime(wheel):
    z = zipfile.ZipFile(wheel)
    meta = z.read(next(n for n in z.namelist() if n.endswith("METADATA"))).decode()
    required = [l.split(":", 1)[1].strip() for l in meta.splitlines()
                if l.startswith("Requires-Dist:") and "extra ==" not in l]
    assert sorted(r.split(">")[0].split("=")[0].strip() for r in required) == ["numpy",
                                                                              "onnxruntime"]


def test_bundled_models_are_small():
    for path in (ROOT / "diffsampler_rt" / "models").rglob("*.onnx"):  # guides/ included
        assert path.stat().st_size <= 4_000_000, path.name


def test_wheel_states_its_licence(wheel):
    z = zipfile.ZipFile(wheel)
    meta = z.read(next(n for n in z.namelist() if n.endswith("METADATA"))).decode()
    assert "License-Expression: MIT" in meta.splitlines()
