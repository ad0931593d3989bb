"""Circular padding in an 8-bit graph: padded after quantising, as slices and concatenations.

A net trained with circular padding (``"padding": "circular"``) exports each 3x3
convolution as ``Pad(mode="wrap")`` followed by an unpadded Conv; onnxruntime cannot fuse
that Pad into the convolution as it does zero padding. In the quantised gbn_torus_fast the
wrap Pads took 21 % of a batch's kernel time (32.8 ms of 154 for 32 sets at k = 32, two
threads). Two exact rewrites, used by :func:`export.quantize.quantize`:

- :func:`quantize_before_wrap_pads` pads the 8-bit values instead of the float ones
  (quantising is element-wise, wrap padding only copies elements): 32.8 -> 26.9 ms;
- :func:`unroll_wrap_pads` writes each wrap Pad as a Concat of the tensor with Slices of
  its far edges, along each padded axis: with both, 3.87 -> 3.55 ms an evaluation per set,
  35.8 -> 32.9 ms a 1024-point set of gbn_torus_fast batched (gbn_fast: 27.8);
- :func:`wrap_pads_channels_last` makes those copies channels-last where only 8-bit
  convolutions read the padded tensor. onnxruntime runs them channels-last on x86 and puts
  a Transpose before each; a slice along the last axis of an NCHW tensor copies one byte
  per row, of an NHWC one a whole pixel's channels (a (16, 32, 32, 32) uint8 wrap pad on
  one thread: 351 -> 65 us). The Transpose back to NCHW meets the one onnxruntime adds, and
  the two cancel. The Slices' axes are computed at run time: onnxruntime's transpose optimizer
  pushes a Transpose through Slices with constant axes, which brought the copies back to
  NCHW; an evaluation of a circular 8-bit network gets a few per cent faster.

On the float network the unrolled form was no faster than Pad (6.0 vs 5.8 ms an evaluation
per set), so float exports keep their Pads. The rewrites give the same tensors bit for bit.
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

_INT64_MAX = np.iinfo(np.int64).max


def _constant_ints(model: onnx.ModelProto) -> dict[str, list[int]]:
    """The values of the graph's initializers and Constant node outputs, as int lists."""
    values = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    for node in model.graph.node:
        if node.op_type == "Constant":
            values.update({node.output[0]: numpy_helper.to_array(a.t)
                           for a in node.attribute if a.name == "value"})
    return {k: v.astype(np.int64).ravel().tolist() for k, v in values.items()
            if np.issubdtype(v.dtype, np.integer)}


def unroll_wrap_pads(model: onnx.ModelProto) -> int:
    """Replace every ``Pad(mode="wrap")`` with constant pads of 0 or 1 by Slice and Concat.

    Edits ``model`` in place and returns how many Pad nodes it replaced. A wrap Pad whose
    pads are computed at run time, that has an ``axes`` input, or that pads by more than
    one entry is left as it is: a Slice of the last ``p`` entries equals the wrap only
    while ``p`` is at most the side, and the sides are known only at run time (a 3x3
    convolution pads by 1, which holds at every side).
    """
    constants = _constant_ints(model)
    graph = model.graph
    consts: dict[tuple[int, ...], str] = {}

    def const(values: list[int]) -> str:
        key = tuple(values)
        if key not in consts:
            name = f"wrap_pad_const_{len(consts)}"
            graph.initializer.append(numpy_helper.from_array(np.array(values, np.int64), name))
            consts[key] = name
        return consts[key]

    nodes = []
    replaced = 0
    pad_inputs: set[str] = set()
    for node in graph.node:
        pads = (constants.get(node.input[1])
                if node.op_type == "Pad" and _mode(node) == b"wrap" and len(node.input) < 4
                else None)
        if pads is None or not set(pads) <= {0, 1}:
            nodes.append(node)
            continue
        rank = len(pads) // 2
        current = node.input[0]
        padded_axes = [a for a in range(rank) if pads[a] or pads[a + rank]]
        for i, axis in enumerate(padded_axes):
            before, after = pads[axis], pads[axis + rank]
            out = node.output[0] if i == len(padded_axes) - 1 else f"{node.name}_wrap{axis}"
            parts = []
            if before:  # the last `before` entries go in front
                parts.append(f"{node.name}_head{axis}")
                nodes.append(helper.make_node(
                    "Slice", [current, const([-before]), const([_INT64_MAX]), const([axis])],
                    [parts[-1]], name=parts[-1]))
            parts.append(current)
            if after:  # the first `after` entries go behind
                parts.append(f"{node.name}_tail{axis}")
                nodes.append(helper.make_node(
                    "Slice", [current, const([0]), const([after]), const([axis])],
                    [parts[-1]], name=parts[-1]))
            nodes.append(helper.make_node("Concat", parts, [out], name=f"{node.name}_cat{axis}",
                                          axis=axis))
            current = out
        if not padded_axes:
            nodes.append(helper.make_node("Identity", [node.input[0]], [node.output[0]],
                                          name=node.name))
        replaced += 1
        pad_inputs.add(node.input[1])
    _set_nodes(graph, nodes, pad_inputs)  # the replaced Pads' pads constants
    return replaced


def quantize_before_wrap_pads(model: onnx.ModelProto) -> int:
    """Swap each ``Pad(mode="wrap") -> QuantizeLinear`` pair so the Pad copies 8-bit values.

    Quantising is element-wise and padding in wrap mode only copies elements, so the two
    commute exactly; padded after quantising, the copy moves a quarter of the bytes. Only a
    Pad whose output feeds that one QuantizeLinear alone is moved, and only where the
    QuantizeLinear's scale and zero point are initializers. Edits ``model`` in place and
    returns how many pairs it swapped.
    """
    graph = model.graph
    consumers = _readers(graph)
    outputs = {o.name for o in graph.output}
    initializers = {i.name for i in graph.initializer}
    quant_of: dict[int, onnx.NodeProto] = {}  # id of a moved Pad -> its QuantizeLinear
    for pad in graph.node:
        users = consumers.get(pad.output[0], [])
        if (pad.op_type != "Pad" or _mode(pad) != b"wrap" or len(users) != 1
                or users[0].op_type != "QuantizeLinear" or pad.output[0] in outputs
                or not set(users[0].input[1:]) <= initializers):
            continue
        quant_of[id(pad)] = users[0]
    moved = {id(q) for q in quant_of.values()}
    stale = set()
    nodes = []
    for node in graph.node:
        if id(node) in moved:
            continue  # emitted at its Pad's place, below
        quant = quant_of.get(id(node))
        if quant is not None:  # x -> QuantizeLinear -> unpadded -> Pad -> q
            stale.add(node.output[0])
            unpadded = f"{quant.output[0]}_unpadded"
            node.output[0], quant.output[0] = quant.output[0], unpadded
            quant.input[0], node.input[0] = node.input[0], unpadded
            nodes.append(quant)  # its other inputs are initializers: valid here
        nodes.append(node)
    del graph.node[:]
    graph.node.extend(nodes)
    kept = [v for v in graph.value_info if v.name not in stale]  # typed as float
    del graph.value_info[:]
    graph.value_info.extend(kept)
    return len(quant_of)


def wrap_pads_channels_last(model: onnx.ModelProto) -> int:
    """Make each unrolled wrap pad (:func:`unroll_wrap_pads`) whose result only QLinearConv
    nodes read copy channels-last, between a Transpose to NHWC and one back (the module's
    notes). Edits ``model`` in place and returns how many pads it rewrote.

    A pad is the pair ``Concat(axis=2)[Slice(u)[-1:], u, Slice(u)[:1]]`` then the same along
    axis 3, each Slice with constant starts, ends and axes, on a 4-d tensor; the first
    Concat's result read only by the second's Slices and Concat.
    """
    graph = model.graph
    constants = _constant_ints(model)
    made = {n.output[0]: n for n in graph.node}
    readers = _readers(graph)
    outputs = {o.name for o in graph.output}

    def wrap_along(cat: onnx.NodeProto | None, axis: int) -> str | None:
        """The tensor ``cat`` wrap-pads by one along ``axis``, or None if it does not."""
        if (cat is None or cat.op_type != "Concat" or len(cat.input) != 3
                or _axis(cat) != axis):
            return None
        head, tail = made.get(cat.input[0]), made.get(cat.input[2])
        source = cat.input[1]
        want = {0: ([-1], [_INT64_MAX]), 2: ([0], [1])}
        for i, node in ((0, head), (2, tail)):
            if (node is None or node.op_type != "Slice" or len(node.input) != 4
                    or node.input[0] != source
                    or [constants.get(n) for n in node.input[1:]] != [*want[i], [axis]]):
                return None
        return source

    replaced: dict[str, list[onnx.NodeProto]] = {}  # at the second Concat's place
    dropped: set[str] = set()
    old_axes: set[str] = set()
    for cat in graph.node:
        rows = made.get(cat.input[1]) if wrap_along(cat, 3) else None
        source = wrap_along(rows, 2) if rows else None
        users = readers.get(cat.output[0], [])
        if (source is None or cat.output[0] in outputs or not users
                or any(u.op_type != "QLinearConv" for u in users)
                or {id(u) for u in readers[rows.output[0]]}
                != {id(made[cat.input[0]]), id(made[cat.input[2]]), id(cat)}
                or any([id(u) for u in readers[name]] != [id(c)]  # each Slice: its Concat's
                       for c in (rows, cat) for name in (c.input[0], c.input[2]))):
            continue
        base = cat.name or cat.output[0]
        new = [helper.make_node("Transpose", [source], [f"{base}_nhwc"], perm=[0, 2, 3, 1],
                                name=f"{base}_nhwc")]
        current = new[0].output[0]
        for old_cat, axis in ((rows, 1), (cat, 2)):
            head, tail = made[old_cat.input[0]], made[old_cat.input[2]]
            parts = []
            for slice_ in (head, tail):
                parts.append(f"{slice_.output[0]}_nhwc")
                new.append(helper.make_node(
                    "Slice", [current, *slice_.input[1:3], f"wrap_pad_axis{axis}"],
                    [parts[-1]], name=parts[-1]))
                dropped.add(slice_.output[0])
                old_axes.add(slice_.input[3])
            dropped.add(old_cat.output[0])
            out = f"{old_cat.output[0]}_nhwc"
            new.append(helper.make_node("Concat", [parts[0], current, parts[1]], [out],
                                        axis=axis, name=out))
            current = out
        new.append(helper.make_node("Transpose", [current], [cat.output[0]], perm=[0, 3, 1, 2],
                                    name=f"{base}_nchw"))
        replaced[cat.output[0]] = new
    if not replaced:
        return 0
    names = {i.name for i in graph.input}
    side = "x" if "x" in names else graph.input[0].name
    # the axes 1 and 2 as k / k and 1 + 1 (k, the grid side, is >= 1): not constants
    nodes = [helper.make_node("Shape", [side], ["wrap_pad_side"], start=-1, name="wrap_pad_side"),
             helper.make_node("Div", ["wrap_pad_side", "wrap_pad_side"], ["wrap_pad_axis1"],
                              name="wrap_pad_axis1"),
             helper.make_node("Add", ["wrap_pad_axis1", "wrap_pad_axis1"], ["wrap_pad_axis2"],
                              name="wrap_pad_axis2")]
    for node in graph.node:
        if node.output[0] in replaced:
            nodes.extend(replaced[node.output[0]])
        elif node.output[0] not in dropped:
            nodes.append(node)
    _set_nodes(graph, nodes, old_axes)  # the old Slices' axes constants
    kept = [v for v in graph.value_info if v.name not in dropped]
    del graph.value_info[:]
    graph.value_info.extend(kept)
    return len(replaced)


def channels_last_note(count: int) -> str:
    """What a quantisation record's ``wrap_pads`` adds for ``count`` channels-last pads."""
    return f"; {count} of them copied channels-last" if count else ""


def _readers(graph: onnx.GraphProto) -> dict[str, list[onnx.NodeProto]]:
    """Each tensor name -> the nodes that read it."""
    readers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in node.input:
            readers.setdefault(name, []).append(node)
    return readers


def _set_nodes(graph: onnx.GraphProto, nodes: list[onnx.NodeProto], constants: set[str]) -> None:
    """Make ``nodes`` the graph's nodes, dropping those of the ``constants`` (initializers
    or Constant nodes) that nothing reads any more: onnxruntime warns about unused
    initializers at every session start."""
    unused = constants - {name for node in nodes for name in node.input}
    nodes = [n for n in nodes if not (n.op_type == "Constant" and n.output[0] in unused)]
    kept = [i for i in graph.initializer if i.name not in unused]
    del graph.initializer[:]
    graph.initializer.extend(kept)
    del graph.node[:]
    graph.node.extend(nodes)


def _axis(node: onnx.NodeProto) -> int | None:
    return next((helper.get_attribute_value(a) for a in node.attribute if a.name == "axis"),
                None)


def _mode(node: onnx.NodeProto) -> bytes:
    """A Pad node's mode attribute (ONNX's default: constant)."""
    return next((helper.get_attribute_value(a) for a in node.attribute if a.name == "mode"),
                b"constant")
