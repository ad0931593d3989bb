"""Read an ONNX file's metadata (``ModelProto.metadata_props``) without onnxruntime or onnx,
and digest the network without them.

The runtime needs the model card before it opens the onnxruntime session, whose options
depend on it (a model that polishes its sets with sliced OT runs without spinning workers);
opening a session only to read the card cost a second session (sot_fast: ~75 ms a load). The ONNX
file is a protobuf message; the metadata are top-level field 14, repeated
``StringStringEntryProto`` (key = field 1, value = field 2). Only the wire format is read:
every other top-level field (the graph, ~99 % of the bytes) is skipped by its length.
"""
from __future__ import annotations

import hashlib
import os

#: ModelProto.metadata_props and StringStringEntryProto's key / value field numbers
METADATA_FIELD, KEY_FIELD, VALUE_FIELD = 14, 1, 2


class WireFormatError(ValueError):
    """The bytes are not a protobuf message (so not an ONNX file)."""


def _varint(buf: memoryview, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(buf) or shift > 63:
            raise WireFormatError(f"truncated or overlong varint at byte {pos}")
        b = buf[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, pos
        shift += 7


def _fields(buf: memoryview):
    """(field number, payload) of each field of a message; payload is a memoryview for
    length-delimited fields, None for the others (numbers, which nothing here needs)."""
    for field, payload, _ in _spans(buf):
        yield field, payload


def _spans(buf: memoryview):
    """(field number, payload as in :func:`_fields`, the field's whole bytes) of each
    field of a message."""
    pos = 0
    while pos < len(buf):
        start = pos
        tag, pos = _varint(buf, pos)
        field, wire = tag >> 3, tag & 7
        if field == 0:
            raise WireFormatError(f"field number 0 at byte {pos}")
        if wire == 0:
            _, pos = _varint(buf, pos)
            yield field, None, buf[start:pos]
        elif wire == 1 or wire == 5:
            pos += 8 if wire == 1 else 4
            yield field, None, buf[start:pos]
        elif wire == 2:
            size, pos = _varint(buf, pos)
            if pos + size > len(buf):
                raise WireFormatError(f"field {field} runs past the end of the file")
            yield field, buf[pos:pos + size], buf[start:pos + size]
            pos += size
        else:  # 3, 4: groups (not used by ONNX); 6, 7: invalid
            raise WireFormatError(f"unsupported wire type {wire} at byte {pos}")
    if pos != len(buf):
        raise WireFormatError("the last field runs past the end")


def read_metadata(path: str | os.PathLike) -> dict[str, str]:
    """The ``metadata_props`` of the ONNX file at ``path`` as a dict (later keys win, as in
    onnxruntime's ``custom_metadata_map``).

    Raises
    ------
    WireFormatError
        If the file is not a protobuf message or an entry is not UTF-8.

    Examples
    --------
    >>> from diffsampler_rt.model import resolve
    >>> from diffsampler_rt.card import CARD_KEY
    >>> CARD_KEY in read_metadata(resolve("rank1"))
    True
    """
    with open(path, "rb") as f:
        buf = memoryview(f.read())
    out: dict[str, str] = {}
    for field, payload in _fields(buf):
        if field != METADATA_FIELD or payload is None:
            continue
        entry = {KEY_FIELD: "", VALUE_FIELD: ""}
        for sub, text in _fields(payload):
            if sub in entry and text is not None:
                try:
                    entry[sub] = bytes(text).decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise WireFormatError(f"metadata entry is not UTF-8 ({exc})") from None
        out[entry[KEY_FIELD]] = entry[VALUE_FIELD]
    return out


def network_digest(path: str | os.PathLike, algorithm: str = "sha256") -> str:
    """The ``hashlib`` digest (hex) of the ONNX file at ``path`` less its
    ``metadata_props``: of the network (graph, weights, opsets), not of the model card, so
    it is the same after a card edit (``python -m export set-defaults``) that leaves the
    network as it was. The bytes are those onnx serialises for the model without its
    metadata.

    Raises
    ------
    WireFormatError
        If the file is not a protobuf message.

    Examples
    --------
    >>> from diffsampler_rt.model import resolve
    >>> len(network_digest(resolve("rank1"))), len(network_digest(resolve("rank1"), "sha1"))
    (64, 40)
    """
    with open(path, "rb") as f:
        buf = memoryview(f.read())
    digest = hashlib.new(algorithm)
    for field, _, raw in _spans(buf):
        if field != METADATA_FIELD:
            digest.update(raw)
    return digest.hexdigest()


def network_sha256(path: str | os.PathLike) -> str:
    """:func:`network_digest` in sha256: how a card's ``"guide"`` pins its guide."""
    return network_digest(path, "sha256")
