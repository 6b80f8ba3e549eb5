#!/usr/bin/env python3
"""Our TEM CPU inference against ONNX Runtime on the same network, side by side.

Builds each level's graph (features, head, body, merge, pixel shuffle, tail, bicubic base) in
ONNX from the shipped weights (exported by `terrain tem-export`), checks that ONNX Runtime gives
our output on the fixed probe (max |dh| < 1 mm), then times one quad (input 100x100 incl.
margin -> 200x200) at batch 1 and 4 with 1 thread and all threads, in ONNX Runtime and in ours
(`terrain tem-bench`, the same thread counts), and prints ms per quad and ours/reference.
The two are timed in alternation, `--rounds` rounds of `--repeats` runs each, so that a busy
neighbour on a shared machine slows both alike: the medians are the medians of the rounds'
medians; the best are each side's fastest single run.

    pip install onnxruntime onnx numpy
    cargo build --release && python3 tools/tem_vs_onnx.py [--bin target/release/terrain]
"""
import argparse
import json
import os
import subprocess
import tempfile
import time

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper


def cubic_weights(t, a=-0.75):
    near = lambda x: ((a + 2) * x - (a + 3)) * x * x + 1
    far = lambda x: ((a * x - 5 * a) * x + 8 * a) * x - 4 * a
    return [far(t + 1), near(t), near(1 - t), far(2 - t)]


def build(level, side):
    """ONNX model of one TEM level for input [B, 1, side, side] (metres)."""
    inits, nodes = [], []

    def const(name, arr):
        inits.append(numpy_helper.from_array(np.asarray(arr, dtype=np.float32), name))
        return name

    def conv(x, name, w, b, pad):
        out = name + "_out"
        ins = [x, const(name + "_w", w)] + ([const(name + "_b", b)] if b is not None else [])
        nodes.append(helper.make_node("Conv", ins, [out], pads=[pad] * 4, name=name))
        return out

    def op(kind, ins, name, **attrs):
        nodes.append(helper.make_node(kind, ins, [name], name=name, **attrs))
        return name

    scale, gain = level["scale_m"], level["feature_gain"]
    const_i64(inits, "pads1", [0, 0, 1, 1, 0, 0, 1, 1])
    const_i64(inits, "pads2", [0, 0, 2, 2, 0, 0, 2, 2])
    xn = op("Div", ["x", const("scale", [scale])], "xn")
    xp = op("Pad", [xn, "pads1"], "xp", mode="edge")
    box = np.full((3, 3), -1 / 9.0)
    box[1, 1] += 1
    gx = np.zeros((3, 3)); gx[1, 0], gx[1, 2] = -0.5, 0.5
    gz = np.zeros((3, 3)); gz[0, 1], gz[2, 1] = -0.5, 0.5
    k = np.stack([box, gx, gz])[:, None] * gain
    f3 = conv(xp, "feat", k, None, 0)
    g = op("Slice", [f3, const_i64(inits, "s1", [1]), const_i64(inits, "e3", [3]), const_i64(inits, "ax1", [1])], "grad")
    mag = op("ReduceSum", [op("Abs", [g], "absg"), const_i64(inits, "ax1b", [1])], "mag", keepdims=1)
    feats = op("Concat", [f3, mag], "feats", axis=1)
    c = {k: {"w": np.array(v["w"]).reshape(v["shape"]), "b": v["b"]} for k, v in level["convs"].items()}
    head = conv(feats, "head", c["head"]["w"], c["head"]["b"], 1)
    b = head
    for i in range(4):
        b = op("Relu", [conv(b, f"body{i}", c[f"body.{i}"]["w"], c[f"body.{i}"]["b"], 1)], f"relu{i}")
    merged = op("Add", [conv(b, "merge", c["merge"]["w"], c["merge"]["b"], 1), head], "merged")
    shuffled = op("DepthToSpace", [merged], "shuffled", blocksize=2, mode="CRD")
    residual = conv(shuffled, "tail", c["tail"]["w"], c["tail"]["b"], 1)
    even, odd = cubic_weights(0.75), cubic_weights(0.25)
    taps = [even + [0.0], [0.0] + odd]
    bk = np.array([[np.outer(taps[dy], taps[dx]) for dy in range(2) for dx in range(2)]]).transpose(1, 0, 2, 3)
    xp2 = op("Pad", ["x", "pads2"], "xp2", mode="edge")
    base = op("DepthToSpace", [conv(xp2, "bicubic", bk, None, 0)], "base", blocksize=2, mode="CRD")
    op("Add", [base, op("Mul", [residual, const("scale2", [scale])], "res_m")], "y")
    graph = helper.make_graph(
        nodes, f"tem_{level['level']}",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["B", 1, side, side])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["B", 1, 2 * side, 2 * side])],
        inits,
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def const_i64(inits, name, v):
    inits.append(numpy_helper.from_array(np.array(v, dtype=np.int64), name))
    return name


def session(model, threads):
    o = ort.SessionOptions()
    o.intra_op_num_threads = threads
    o.inter_op_num_threads = 1
    o.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(model.SerializeToString(), o, providers=["CPUExecutionProvider"])


def time_ms(fn, repeats):
    """Median and least milliseconds of `repeats` calls of `fn` after one untimed call."""
    fn()
    best = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best.append((time.perf_counter() - t) * 1e3)
    return float(np.median(best)), float(min(best))


def alternate(a, ref, ours_cmd, per, key):
    """ONNX Runtime (`ref`, one call) and ours (`ours_cmd`, a bench command printing JSON with
    `key` and `min_` + `key`) timed in alternation, `a.rounds` rounds of `a.repeats` runs each,
    both divided by `per`: (ORT median, ours median, ORT best, ours best), the medians the
    medians of the rounds' medians."""
    refs, ours = [], []
    for _ in range(a.rounds):
        refs.append(time_ms(ref, a.repeats))
        out = json.loads(subprocess.run(ours_cmd + ["--repeats", str(a.repeats)], check=True, capture_output=True, text=True).stdout)
        ours.append((out[key], out["min_" + key]))
    med = lambda v: float(np.median([m for m, _ in v]))
    best = lambda v: min(b for _, b in v)
    return med(refs) / per, med(ours), best(refs) / per, best(ours)


def print_header(unit, *first):
    """The table's header: the `first` columns, then ORT and ours per `unit`, median and best."""
    cols = [f"{c:>7}" for c in first] + [f"{'ORT ms/' + unit:>14}", f"{'ours ms/' + unit:>15}", f"{'ours/ORT':>9}", f"{'best ORT':>9}", f"{'best ours':>10}", f"{'best ratio':>11}"]
    print(" ".join(cols))


def print_row(first, r):
    """One row of the table: the `first` values, then `alternate`'s four numbers and ratios."""
    ref, ours, ref_best, ours_best = r
    cols = [f"{c:>7}" for c in first] + [f"{ref:>14.2f}", f"{ours:>15.2f}", f"{ours / ref:>9.2f}", f"{ref_best:>9.2f}", f"{ours_best:>10.2f}", f"{ours_best / ref_best:>11.2f}"]
    print(" ".join(cols))


def parse_args(doc, *extra):
    """The command line of the *_vs_onnx tools: --bin, --weights, --repeats and `extra`
    (flag, type, default) tuples."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    here = os.path.dirname(os.path.abspath(__file__))
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(here, "..", "target"))
    ap.add_argument("--bin", default=os.path.join(target, "release", "terrain"))
    ap.add_argument("--weights", default=os.path.join(here, "..", "weights"))
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=5)
    for flag, kind, default in extra:
        ap.add_argument(flag, type=kind, default=default)
    return ap.parse_args()


def export(a, command):
    """The JSON that `terrain <command> --weights W --out FILE` writes (weights and probe)."""
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "export.json")
        subprocess.run([a.bin, command, "--weights", a.weights, "--out", path], check=True)
        return json.load(open(path))


def main():
    a = parse_args(__doc__, ("--level", int, 0))
    exported = export(a, "tem-export")
    lv = exported["levels"][a.level]
    side = exported["probe_side"]
    model = build(lv, side)
    onnx.checker.check_model(model)
    x = np.array(lv["probe_input"], dtype=np.float32).reshape(1, 1, side, side)
    want = np.array(lv["probe_output"], dtype=np.float32).reshape(1, 1, 2 * side, 2 * side)
    got = session(model, 1).run(["y"], {"x": x})[0]
    diff = float(np.abs(got - want).max())
    print(f"level {a.level}: ONNX Runtime {ort.__version__} vs ours on the probe: max |dh| {diff:.2e} m")
    assert diff < 1e-3, "the ONNX graph is not our network"
    cores = os.cpu_count()
    print_header("quad", "threads", "batch")
    for threads in sorted({1, cores}):
        for batch in (1, 4):
            s = session(model, threads)
            xb = np.repeat(x, batch, axis=0)
            cmd = [a.bin, "tem-bench", "--level", str(a.level), "--batch", str(batch), "--threads", str(threads), "--weights", a.weights]
            print_row((threads, batch), alternate(a, lambda: s.run(["y"], {"x": xb}), cmd, batch, "ms_per_quad"))


if __name__ == "__main__":
    main()
