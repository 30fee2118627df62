#!/usr/bin/env python3
"""Anchors for `cargo xtask bench runtime --anchors`: the same exported sartor weights timed in
the tools a user would otherwise pick.

Given an exported sartor model folder (`model.json` + `model.safetensors`, the runtime format of
`crates/sartor-runtime/src/format.rs`) and a file of inputs with sartor's own outputs for them,
this script builds the per-frame wrinkle step

    x̂ = (x − wrinkle_in_mean) / wrinkle_in_std
    h' = GRUCell(x̂, h)                          (PyTorch's GRU: gates r, z, n stacked)
    y = wrinkle.out(h')                          (dense: 3V values; PCA: k coefficients, then
                                                  y = pca.mean + pca.basis · y)
    displacement = y · wrinkle_out_std + wrinkle_out_mean

and runs it at batch 1, one frame per call, the state carried from frame to frame as a game
would, in

- PyTorch eager (`torch.inference_mode`),
- PyTorch compiled (`torch.compile`, where it works; the error text is recorded where it does
  not),
- ONNX Runtime on the CPU (the step exported with `torch.onnx.export`; inputs `x` and `h`,
  outputs `displacement` and `h_next`), with `intra_op_num_threads` = threads and
  `inter_op_num_threads` = 1, called both with `InferenceSession.run` and with an I/O binding
  (preallocated buffers, the state output bound as the next input); both are timed, and the
  caller takes the faster as the best anchor.

for each thread count (`torch.set_num_threads` / `intra_op_num_threads`). First every engine
runs the stored input frames from a zero state and its displacements are compared with sartor's
(max abs difference, metres).

The inputs file (safetensors, f32): `inputs` [T, I] raw wrinkle inputs in the model's layout,
`outputs` [T, 3V] sartor's f32 displacements for them (zero initial state).

Output: one JSON line on stdout with the set-up (versions, the ONNX export, each engine's
agreement or error); then the script answers timing requests on stdin, one JSON line each
(`{"threads": t, "frames": f}` → the median and mean ms per frame of every working engine at
`t` threads over `f` frames after the warm-up frames), until stdin closes. The caller times
sartor's own step between the requests, so that every round of the comparison is taken within
seconds (on a VM whose speed drifts over minutes, timings a minute apart disagreed by a third).
`--check` only checks that the Python packages are importable (exit status 3 and an install hint
on stderr when they are not).

Install (a plain `pip install torch` pulls about 5 GB of CUDA packages; fine for a benchmark
venv):

    python3 -m venv .venv-anchors
    .venv-anchors/bin/pip install torch onnx onnxruntime numpy safetensors
"""

import argparse
import importlib
import json
import os
import platform
import sys
import tempfile
import time
import traceback

FORMAT = "sartor-anchors"
VERSION = 2
PACKAGES = ["numpy", "safetensors", "torch", "onnx", "onnxruntime"]
INSTALL_HINT = (
    "python3 -m venv .venv-anchors && "
    ".venv-anchors/bin/pip install torch onnx onnxruntime numpy safetensors "
    "(then run with SARTOR_PYTHON=.venv-anchors/bin/python or --anchors-python)"
)
# The longest error text kept in the report.
MAX_ERROR_CHARS = 2000


def check_packages():
    """Import every needed package; exit 3 with an install hint when any is missing."""
    missing, versions = [], {}
    for name in PACKAGES:
        try:
            module = importlib.import_module(name)
            versions[name] = getattr(module, "__version__", "unknown")
        except Exception as e:  # noqa: BLE001 - a broken install reads like a missing one
            missing.append(f"{name} ({type(e).__name__}: {e})")
    if missing:
        print(
            f"bench/anchors.py: missing Python packages for {sys.executable}: "
            + ", ".join(missing)
            + f". Install them with: {INSTALL_HINT}",
            file=sys.stderr,
        )
        sys.exit(3)
    versions["python"] = platform.python_version()
    return versions


def error_text(e):
    """`Type: message`, cut to MAX_ERROR_CHARS."""
    text = f"{type(e).__name__}: {e}"
    if len(text) > MAX_ERROR_CHARS:
        text = text[: MAX_ERROR_CHARS - 3] + "..."
    return text


def median(values):
    s = sorted(values)
    n = len(s)
    if n == 0:
        return float("nan")
    return s[n // 2] if n % 2 == 1 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def load_model(model_dir):
    """The header (dict) and the tensors (name -> f32 numpy array) of a sartor model folder."""
    import numpy as np
    from safetensors.numpy import load_file

    with open(os.path.join(model_dir, "model.json"), encoding="utf-8") as f:
        header = json.load(f)
    tensors = load_file(os.path.join(model_dir, "model.safetensors"))
    return header, {k: np.asarray(v, dtype=np.float32) for k, v in tensors.items()}


def build_step(header, t):
    """The per-frame wrinkle step as a torch module: (x [1, I], h [1, H]) -> (d [1, 3V], h')."""
    import torch

    sizes = header["sizes"]
    n_in = sizes["n_betas"] + sizes["n_pose_features"]
    hidden = sizes["gru_hidden"]
    output = sizes["output"]
    pca = output != "dense"

    def param(name):
        return torch.nn.Parameter(torch.from_numpy(t[name].copy()), requires_grad=False)

    class Step(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.gru = torch.nn.GRUCell(n_in, hidden)
            self.gru.weight_ih = param("wrinkle.gru.weight_ih")
            self.gru.weight_hh = param("wrinkle.gru.weight_hh")
            self.gru.bias_ih = param("wrinkle.gru.bias_ih")
            self.gru.bias_hh = param("wrinkle.gru.bias_hh")
            rows = t["wrinkle.out.weight"].shape[0]
            self.out = torch.nn.Linear(hidden, rows)
            self.out.weight = param("wrinkle.out.weight")
            self.out.bias = param("wrinkle.out.bias")
            if pca:
                k = output["pca"]
                self.pca = torch.nn.Linear(k, t["wrinkle.pca.basis"].shape[0])
                self.pca.weight = param("wrinkle.pca.basis")
                self.pca.bias = param("wrinkle.pca.mean")
            else:
                self.pca = None
            for name in ["wrinkle_in_mean", "wrinkle_in_std", "wrinkle_out_mean", "wrinkle_out_std"]:
                self.register_buffer(name.replace("wrinkle_", ""), torch.from_numpy(t["norm." + name].copy()))

        def forward(self, x, h):
            h_next = self.gru((x - self.in_mean) / self.in_std, h)
            y = self.out(h_next)
            if self.pca is not None:
                y = self.pca(y)
            return y * self.out_std + self.out_mean, h_next

    step = Step().eval()
    for p in step.parameters():
        p.requires_grad_(False)
    return step, n_in, hidden


class TorchEngine:
    """Eager or compiled torch step with the state carried as a tensor."""

    def __init__(self, fn, hidden):
        import torch

        self.torch = torch
        self.fn = fn
        self.hidden = hidden

    def reset(self):
        self.h = self.torch.zeros(1, self.hidden)

    def frame(self, x):
        d, self.h = self.fn(x, self.h)
        return d

    def to_numpy(self, d):
        return d.numpy().reshape(-1)

    def prepare(self, inputs):
        return [self.torch.from_numpy(inputs[i : i + 1].copy()) for i in range(inputs.shape[0])]


class OrtRunEngine:
    """ONNX Runtime, `InferenceSession.run` with numpy in and out."""

    def __init__(self, session, hidden):
        import numpy as np

        self.np = np
        self.session = session
        self.hidden = hidden

    def reset(self):
        self.h = self.np.zeros((1, self.hidden), dtype=self.np.float32)

    def frame(self, x):
        d, self.h = self.session.run(None, {"x": x, "h": self.h})
        return d

    def to_numpy(self, d):
        return d.reshape(-1)

    def prepare(self, inputs):
        return [inputs[i : i + 1].copy() for i in range(inputs.shape[0])]


class OrtBindingEngine:
    """ONNX Runtime with an I/O binding: preallocated CPU buffers, the state output of one frame
    bound as the next frame's state input (no copies between frames)."""

    def __init__(self, session, hidden, n_out):
        import numpy as np
        import onnxruntime as ort

        self.np = np
        self.ort = ort
        self.session = session
        self.hidden = hidden
        self.binding = session.io_binding()
        self.d = np.zeros((1, n_out), dtype=np.float32)
        self.h_a = np.zeros((1, hidden), dtype=np.float32)
        self.h_b = np.zeros((1, hidden), dtype=np.float32)
        self.v_d = ort.OrtValue.ortvalue_from_numpy(self.d)
        self.v_a = ort.OrtValue.ortvalue_from_numpy(self.h_a)
        self.v_b = ort.OrtValue.ortvalue_from_numpy(self.h_b)
        self.binding.bind_ortvalue_output("displacement", self.v_d)

    def reset(self):
        self.h_a[:] = 0.0
        self.h_b[:] = 0.0

    def frame(self, x):
        b = self.binding
        b.bind_ortvalue_input("x", x)
        b.bind_ortvalue_input("h", self.v_a)
        b.bind_ortvalue_output("h_next", self.v_b)
        self.session.run_with_iobinding(b)
        self.v_a, self.v_b = self.v_b, self.v_a
        return self.d

    def to_numpy(self, d):
        return d.reshape(-1).copy()

    def prepare(self, inputs):
        return [self.ort.OrtValue.ortvalue_from_numpy(inputs[i : i + 1].copy()) for i in range(inputs.shape[0])]


def agreement(engine, inputs, want):
    """Run the stored frames from a zero state; max abs difference with sartor's outputs."""
    import numpy as np

    engine.reset()
    xs = engine.prepare(inputs)
    worst = 0.0
    for x, w in zip(xs, want):
        got = engine.to_numpy(engine.frame(x))
        worst = max(worst, float(np.max(np.abs(got.astype(np.float64) - w))))
    return worst


def timing(engine, inputs, warmup, frames):
    """Median and mean wall ms per frame over `frames` frames after `warmup`, state carried."""
    engine.reset()
    xs = engine.prepare(inputs)
    ms = []
    clock = time.perf_counter_ns
    for i in range(warmup + frames):
        x = xs[i % len(xs)]
        start = clock()
        engine.frame(x)
        end = clock()
        if i >= warmup:
            ms.append((end - start) / 1e6)
    return median(ms), sum(ms) / len(ms)


def export_onnx(step, n_in, hidden, path):
    """Export the step; returns (exporter name, None) or (None, error text)."""
    import torch

    x = torch.zeros(1, n_in)
    h = torch.zeros(1, hidden)
    kwargs = dict(input_names=["x", "h"], output_names=["displacement", "h_next"], opset_version=17)
    errors = []
    for exporter, extra in [("torchscript", {"dynamo": False}), ("dynamo", {"dynamo": True}), ("default", {})]:
        try:
            with torch.inference_mode(False), torch.no_grad():
                torch.onnx.export(step, (x, h), path, **kwargs, **extra)
            return exporter, None
        except TypeError as e:  # an older torch without the `dynamo` argument
            errors.append(f"{exporter}: {error_text(e)}")
        except Exception as e:  # noqa: BLE001
            errors.append(f"{exporter}: {error_text(e)}")
    return None, " | ".join(errors)


def build_engines(args, threads, step, n_in, hidden, n_out, inputs, want, onnx_path, export_error):
    """Every engine at every thread count, each checked against sartor's outputs: a list of
    entries (`engine`, `threads`, `call` for ONNX Runtime, `max_abs_diff`, `setup_s`, `error`)
    and, for those that work, the engine object under `obj`."""
    import copy

    import onnxruntime as ort
    import torch

    entries = []

    def add(name, t, make, extra=None):
        entry = {"engine": name, "threads": t}
        entry.update(extra or {})
        try:
            start = time.perf_counter()
            torch.set_num_threads(t)
            with torch.inference_mode():
                engine = make()
                entry["max_abs_diff"] = agreement(engine, inputs, want)
            entry["setup_s"] = time.perf_counter() - start
            entry["error"] = None
            entry["obj"] = engine
        except Exception as e:  # noqa: BLE001 - recorded in the report, as the brief asks
            entry["error"] = error_text(e)
            entry["traceback_tail"] = traceback.format_exc()[-MAX_ERROR_CHARS:]
        print(
            f"  anchors {name} {t} thread(s): "
            + (f"ready, max abs diff {entry['max_abs_diff']:.2e}"
               if entry["error"] is None else f"failed: {entry['error'][:200]}"),
            file=sys.stderr,
            flush=True,
        )
        entries.append(entry)

    for t in threads:
        add("pytorch_eager", t, lambda: TorchEngine(step, hidden))
        if args.no_compile:
            entries.append({"engine": "pytorch_compiled", "threads": t, "error": "skipped (--no-compile)"})
        else:
            # A copy of the module per thread count: Inductor builds the thread count into the
            # code it generates, and Dynamo keeps one compiled entry per module object.
            add("pytorch_compiled", t,
                lambda: TorchEngine(torch.compile(copy.deepcopy(step), fullgraph=True, dynamic=False), hidden))
        if export_error is not None:
            entries.append({"engine": "onnxruntime", "threads": t, "error": "ONNX export failed: " + export_error})
            continue

        def session(t=t):
            options = ort.SessionOptions()
            options.intra_op_num_threads = t
            options.inter_op_num_threads = 1
            options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
            options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
            return ort.InferenceSession(onnx_path, options, providers=["CPUExecutionProvider"])

        add("onnxruntime", t, lambda: OrtRunEngine(session(), hidden), {"call": "run"})
        add("onnxruntime", t, lambda: OrtBindingEngine(session(), hidden, n_out), {"call": "io_binding"})
    return entries


def serve(entries, inputs, warmup):
    """Answer timing requests on stdin until it closes: each line a JSON object `{"threads": t,
    "frames": f}`; each answer one JSON line `{"threads": t, "times": [...]}` with the median
    and mean ms per frame of every working engine at `t` threads over `f` frames after `warmup`
    (the state reset first)."""
    import torch

    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        t, frames = int(request["threads"]), int(request["frames"])
        torch.set_num_threads(t)
        times = []
        with torch.inference_mode():
            for e in entries:
                if e["threads"] != t or e.get("obj") is None:
                    continue
                median_ms, mean_ms = timing(e["obj"], inputs, warmup, frames)
                times.append({"engine": e["engine"], "call": e.get("call"),
                              "ms_per_frame": median_ms, "ms_per_frame_mean": mean_ms})
        print(json.dumps({"threads": t, "times": times}), flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", help="exported sartor model folder")
    parser.add_argument("--io", help="safetensors with `inputs` [T, I] and sartor's `outputs` [T, 3V]")
    parser.add_argument("--threads", default="1,2", help="comma-separated thread counts")
    parser.add_argument("--warmup", type=int, default=50, help="untimed frames before each timing")
    parser.add_argument("--no-compile", action="store_true", help="skip torch.compile")
    parser.add_argument("--check", action="store_true", help="only check the Python packages")
    args = parser.parse_args()

    versions = check_packages()
    if args.check:
        print(json.dumps({"format": FORMAT, "version": VERSION, "versions": versions}))
        return
    if not args.model or not args.io:
        parser.error("--model and --io are required (unless --check)")

    import numpy as np
    import torch
    from safetensors.numpy import load_file

    threads = [int(s) for s in args.threads.split(",") if s]
    header, tensors = load_model(args.model)
    io = load_file(args.io)
    inputs = np.ascontiguousarray(io["inputs"], dtype=np.float32)
    want = np.asarray(io["outputs"], dtype=np.float64)
    step, n_in, hidden = build_step(header, tensors)
    n_out = want.shape[1]
    if inputs.shape[1] != n_in:
        raise SystemExit(f"inputs have {inputs.shape[1]} columns, the model takes {n_in}")

    report = {
        "format": FORMAT,
        "version": VERSION,
        "model": args.model,
        "sizes": header["sizes"],
        "versions": versions,
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "processor": platform.processor() or platform.machine(),
        "frames_checked": int(inputs.shape[0]),
        "warmup_frames": args.warmup,
        "max_abs_output": float(np.max(np.abs(want))),
    }
    with tempfile.TemporaryDirectory(prefix="sartor-anchors-") as tmp:
        onnx_path = os.path.join(tmp, "step.onnx")
        start = time.perf_counter()
        exporter, export_error = export_onnx(step, n_in, hidden, onnx_path)
        report["onnx_export"] = {
            "exporter": exporter,
            "error": export_error,
            "seconds": time.perf_counter() - start,
        }
        entries = build_engines(args, threads, step, n_in, hidden, n_out, inputs, want, onnx_path, export_error)
        report["engines"] = [{k: v for k, v in e.items() if k != "obj"} for e in entries]
        # The set-up, then timings on request (see `serve`).
        print(json.dumps(report), flush=True)
        serve(entries, inputs, args.warmup)


if __name__ == "__main__":
    main()
