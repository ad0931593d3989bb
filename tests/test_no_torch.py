"""The runtime must work where torch (and scipy) cannot even be imported."""
import ast
import subprocess
import sys
from pathlib import Path

RUNTIME = Path(__file__).resolve().parents[1] / "diffsampler_rt"

BLOCKER = """
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('torch', 'scipy', 'ot', 'trainer', 'export'):
            raise ImportError(f'{name} is blocked in this test')
sys.meta_path.insert(0, Block())
try:
    import torch
    raise SystemExit('torch imported')
except ImportError:
    pass
import diffsampler_rt
pts = diffsampler_rt.generate('rank1', 576, seed=0, steps=5)
assert pts.shape == (576, 2), pts.shape
pts = diffsampler_rt.generate('poisson_disk_fast', 256, seed=0)  # with its minimum spacing
assert pts.shape == (256, 2), pts.shape
pts = diffsampler_rt.generate('sobol_owen', 625, count=2, seed=0, steps=5)
assert pts.shape == (2, 625, 2)
print(pts.shape, 'torch' in sys.modules, 'scipy' in sys.modules)
"""


def test_runtime_runs_with_torch_blocked():
    res = subprocess.run([sys.executable, "-c", BLOCKER], capture_output=True, text=True,
                         cwd=RUNTIME.parent)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "(2, 625, 2) False False"


def test_runtime_imports_only_numpy_onnxruntime_and_stdlib():
    allowed = {"numpy", "onnxruntime"} | set(sys.stdlib_module_names)
    optional = {"plot.py": {"matplotlib"}}  # optional extras, imported lazily
    for path in RUNTIME.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            else:
                continue
            for name in names:
                ok = allowed | optional.get(path.name, set())
                assert name.split(".")[0] in ok, f"{path.name} imports {name}"
