#!/usr/bin/env python3
"""Our sketch generator's CPU inference against ONNX Runtime on the same network, side by side.

Builds the generator's UNet (3x3 convolutions + ReLU, 2x2 mean pooling, nearest x2 upsampling,
skip concatenation, output = baseline channel + correction) in ONNX from the shipped weights
(exported by `terrain sketch-export`), checks that ONNX Runtime gives our output on the probe
(an example sketch; max difference < 1e-4 of the 0-1 height scale), then times one view (a 256x256
sketch with its 8 px mirrored margin: 272x272) with 1 thread and all threads in ONNX Runtime and in ours
(`terrain sketch-bench`, the same thread counts), and prints ms per sketch and ours/reference,
timed in alternation as in tools/tem_vs_onnx.py (`--rounds` rounds of `--repeats` runs each).

    pip install onnxruntime onnx numpy
    cargo build --release && python3 tools/sketch_vs_onnx.py [--bin target/release/terrain]
"""
import os

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from tem_vs_onnx import alternate, const_i64, export, parse_args, print_header, print_row, session


def build(exported):
    """ONNX model of the generator for input [1, in_channels, side, side] (heights / 255 out)."""
    inits, nodes = [], []
    convs = exported["convs"]

    def conv(x, name, relu):
        c = convs[name]
        w = np.array(c["w"], dtype=np.float32).reshape(c["shape"])
        wn, bn = name + "_w", name + "_b"
        inits.append(numpy_helper.from_array(w, wn))
        inits.append(numpy_helper.from_array(np.array(c["b"], dtype=np.float32), bn))
        out = name + "_out"
        nodes.append(helper.make_node("Conv", [x, wn, bn], [out], pads=[1, 1, 1, 1], name=name))
        if not relu:
            return out
        nodes.append(helper.make_node("Relu", [out], [name + "_relu"], name=name + "_relu"))
        return name + "_relu"

    scales = len(exported["widths"])
    inits.append(numpy_helper.from_array(np.array([1, 1, 2, 2], dtype=np.float32), "up_scales"))
    h, skips = "x", []
    for k in range(scales):
        if k > 0:
            nodes.append(helper.make_node("AveragePool", [h], [f"pool{k}"], kernel_shape=[2, 2], strides=[2, 2]))
            h = f"pool{k}"
        h = conv(conv(h, f"enc.{k}.a", True), f"enc.{k}.b", True)
        skips.append(h)
    for k in reversed(range(scales - 1)):
        nodes.append(helper.make_node("Resize", [h, "", "up_scales"], [f"up{k}"], mode="nearest", coordinate_transformation_mode="asymmetric", nearest_mode="floor"))
        nodes.append(helper.make_node("Concat", [f"up{k}", skips[k]], [f"cat{k}"], axis=1))
        h = conv(conv(f"cat{k}", f"dec.{k}.a", True), f"dec.{k}.b", True)
    correction = conv(h, "out", False)
    last = exported["in_channels"] - 1
    starts, ends, axes = (const_i64(inits, n, [v]) for n, v in (("b0", last), ("b1", last + 1), ("ax", 1)))
    nodes.append(helper.make_node("Slice", ["x", starts, ends, axes], ["base"]))
    nodes.append(helper.make_node("Add", ["base", correction], ["y"]))
    side, cin = exported["side"], exported["in_channels"]
    graph = helper.make_graph(
        nodes, "sketch_generator",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, cin, side, side])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 1, side, side])],
        inits,
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def main():
    a = parse_args(__doc__)
    exported = export(a, "sketch-export")
    model = build(exported)
    onnx.checker.check_model(model)
    side, cin = exported["side"], exported["in_channels"]
    x = np.array(exported["probe_input"], dtype=np.float32).reshape(1, cin, side, side)
    want = np.array(exported["probe_output"], dtype=np.float32).reshape(1, 1, side, side)
    got = session(model, 1).run(["y"], {"x": x})[0]
    diff = float(np.abs(got - want).max())
    print(f"sketch generator: ONNX Runtime {ort.__version__} vs ours on the probe: max |difference| {diff:.2e} (heights / 255)")
    assert diff < 1e-4, "the ONNX graph is not our network"
    print_header("sketch", "threads")
    for threads in sorted({1, os.cpu_count()}):
        s = session(model, threads)
        cmd = [a.bin, "sketch-bench", "--threads", str(threads), "--weights", a.weights]
        print_row((threads,), alternate(a, lambda: s.run(["y"], {"x": x}), cmd, 1, "ms_per_sketch"))


if __name__ == "__main__":
    main()
