"""RandLA-Net's forward pass on the CPU: today's torch against ONNX Runtime and OpenVINO (float32,
and bfloat16 where the CPU has it), on every crop of a whole scan's plan, in one process.

    .venv/bin/pip install onnx onnxruntime openvino      # the engines (not installed by setup)
    .venv/bin/python bench/cpu_engines.py [--points 1000000] [--threads 2] [--crops 0]

Per engine: seconds per crop (after one warm-up), the speed-up over torch, the one-off cost
(export to ONNX, compilation), the largest logit difference and the share of crop points whose
label (argmax) is torch's. Engines that are not installed are listed as such.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from helpers.report import header

from jointseg.network.anchored import anchored_cloud
from jointseg.network.randlanet.engine import FlatInputs
from jointseg.network.randlanet.predict import RandLANetPredictor
from jointseg.network.registry import load
from jointseg.synth import make_room

Run = Callable[[list[np.ndarray]], np.ndarray]


def onnx_bytes(model: torch.nn.Module, example: list[torch.Tensor], layers: int) -> bytes:
    """The model exported for inputs of exactly the example's shapes (a dynamic-shape export
    labels wrongly: the pooling's sizes are traced as constants)."""
    buffer = io.BytesIO()
    # torch's stub names paths only; export writes to any binary file object (its docs say so)
    torch.onnx.export(FlatInputs(model, layers).eval(), tuple(example), buffer,  # type: ignore[arg-type]
                      dynamo=False, opset_version=17)  # fmt: skip
    return buffer.getvalue()


def ort_engine(blob: bytes, threads: int) -> Run:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    sess = ort.InferenceSession(blob, opts, providers=["CPUExecutionProvider"])
    names = [i.name for i in sess.get_inputs()]
    return lambda xs: sess.run(None, dict(zip(names, xs, strict=True)))[0]


def openvino_engine(blob: bytes, threads: int, precision: str) -> Run:
    import openvino as ov

    core = ov.Core()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "randlanet.onnx"
        path.write_bytes(blob)
        model = core.read_model(str(path))
    config = {"INFERENCE_NUM_THREADS": threads, "PERFORMANCE_HINT": "LATENCY",
              "INFERENCE_PRECISION_HINT": precision}  # fmt: skip
    compiled = core.compile_model(model, "CPU", config)
    request = compiled.create_infer_request()
    return lambda xs: request.infer(xs)[0].copy()


def crop_inputs(net: RandLANetPredictor, points: int, limit: int) -> list[list[torch.Tensor]]:
    """The inputs of every crop of a synthetic room's plan (the first ``limit`` when > 0)."""
    room = make_room(1501, points=points)
    lower = room.xyz.min(axis=0)
    cloud = anchored_cloud([(room.xyz, room.rgb)], net.grid_size, lower)
    plan = net.plan(cloud, seed=0)
    crops = np.arange(len(plan) if limit <= 0 else min(limit, len(plan)))
    out = []
    for batch, _ in net.batches(cloud, plan, crops, 0):
        out.append([batch.features, *batch.coords, *batch.neighbours, *batch.pools,
                    *batch.upsamples])  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--crops", type=int, default=0, help="crops timed (0: the whole plan)")
    args = ap.parse_args()
    header()
    torch.set_num_threads(args.threads)
    net = load()
    assert isinstance(net, RandLANetPredictor), "the bundled network is RandLA-Net"
    model = net.model.eval()
    inputs = crop_inputs(net, args.points, args.crops)
    layers = (len(inputs[0]) - 1) // 4
    with torch.inference_mode():
        model(inputs[0][0], *[list(inputs[0][1 + i * layers : 1 + (i + 1) * layers])
                              for i in range(4)])  # fmt: skip
        t = time.perf_counter()
        ref = [FlatInputs(model, layers)(*xs).numpy() for xs in inputs]
        torch_s = (time.perf_counter() - t) / len(inputs)
    print(f"{len(inputs)} crops of {inputs[0][0].shape[1]} points, {args.threads} threads\n")
    print("| engine | s per crop | speed-up | one-off (s) | max logit diff | labels as torch |")
    print("|---|---|---|---|---|---|")
    print(f"| torch {torch.__version__} | {torch_s:.4f} | 1.00 | 0 | 0 | 1.0000 |")
    t = time.perf_counter()
    try:
        blob = onnx_bytes(model, inputs[0], layers)
    except Exception as exc:  # the onnx package missing, or an operator the exporter lacks
        print(f"| (no ONNX export: {type(exc).__name__}: {str(exc)[:80]}) | | | | | |")
        return
    export_s = time.perf_counter() - t
    engines: dict[str, Callable[[], Run]] = {
        "ONNX Runtime": lambda: ort_engine(blob, args.threads),
        "OpenVINO f32": lambda: openvino_engine(blob, args.threads, "f32"),
        "OpenVINO bf16": lambda: openvino_engine(blob, args.threads, "bf16"),
    }
    for name, make in engines.items():
        try:
            t = time.perf_counter()
            run = make()
            np_inputs = [[x.numpy() for x in xs] for xs in inputs]
            run(np_inputs[0])
            once = export_s + time.perf_counter() - t
        except ImportError as exc:
            print(f"| {name} | not installed ({exc.name}) | | | | |")
            continue
        t = time.perf_counter()
        outs = [run(xs) for xs in np_inputs]
        per = (time.perf_counter() - t) / len(inputs)
        diff = max(float(np.abs(o - r).max()) for o, r in zip(outs, ref, strict=True))
        same = np.mean([float((o.argmax(-1) == r.argmax(-1)).mean())
                        for o, r in zip(outs, ref, strict=True)])  # fmt: skip
        print(f"| {name} | {per:.4f} | {torch_s / per:.2f} | {once:.2f} | {diff:.2g} "
              f"| {same:.4f} |")  # fmt: skip


if __name__ == "__main__":
    main()
