"""The runtime reads the model card from the ONNX file itself, before any session."""
import doctest

import numpy as np
import onnxruntime as ort
import pytest

from diffsampler_rt import metadata
from diffsampler_rt.metadata import WireFormatError, read_metadata
from trainer import zoo


@pytest.mark.parametrize("path", sorted(zoo.ZOO_DIR.glob("*.onnx")), ids=lambda p: p.stem)
def test_reads_what_onnxruntime_reads(path):
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert read_metadata(path) == dict(session.get_modelmeta().custom_metadata_map)


def test_entries_and_edge_cases(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper
    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    model = helper.make_model(graph)
    # non-ASCII text, an empty value, a repeated key (the last wins, as in onnxruntime)
    for key, value in (("a", "é ∑ 点"), ("empty", ""), ("a", "second")):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    path = tmp_path / "m.onnx"
    onnx.save(model, str(path))
    assert read_metadata(path) == {"a": "second", "empty": ""}
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert read_metadata(path) == dict(session.get_modelmeta().custom_metadata_map)
    data = path.read_bytes()
    (tmp_path / "cut.onnx").write_bytes(data[:-3])  # cut inside the last entry
    with pytest.raises(WireFormatError):
        read_metadata(tmp_path / "cut.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not an onnx file at all")
    with pytest.raises(WireFormatError, match="wire type"):
        read_metadata(tmp_path / "junk.onnx")
    (tmp_path / "empty.onnx").write_bytes(b"")
    assert read_metadata(tmp_path / "empty.onnx") == {}
    rng = np.random.default_rng(0)  # random bytes: an error or a dict, never anything else
    for _ in range(200):
        junk = rng.integers(0, 256, rng.integers(1, 64)).astype(np.uint8)
        (tmp_path / "r.onnx").write_bytes(junk.tobytes())
        try:
            assert isinstance(read_metadata(tmp_path / "r.onnx"), dict)
        except WireFormatError:
            pass


def test_network_digest_leaves_the_card_out(tmp_path):
    """network_sha256 is the sha256 of the file less its metadata_props (as onnx serialises
    the model without them): the same after a card edit, another for another network."""
    onnx = pytest.importorskip("onnx")
    import hashlib
    source = zoo.ZOO_DIR / "sot_32.onnx"
    model = onnx.load(str(source))
    del model.metadata_props[:]
    bare = model.SerializeToString()
    assert metadata.network_sha256(source) == hashlib.sha256(bare).hexdigest()
    (tmp_path / "bare.onnx").write_bytes(bare)
    assert metadata.network_sha256(tmp_path / "bare.onnx") == metadata.network_sha256(source)
    entry = model.metadata_props.add()
    entry.key, entry.value = "note", "a card edit"
    onnx.save(model, str(tmp_path / "edited.onnx"))
    assert metadata.network_sha256(tmp_path / "edited.onnx") == metadata.network_sha256(source)
    assert metadata.network_sha256(zoo.ZOO_DIR / "sot.onnx") != metadata.network_sha256(source)
    (tmp_path / "junk.onnx").write_bytes(b"not an onnx file at all")
    with pytest.raises(WireFormatError):
        metadata.network_sha256(tmp_path / "junk.onnx")


def test_docstring_examples():
    assert doctest.testmod(metadata).failed == 0
