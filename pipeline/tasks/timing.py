"""How a trained network's inference is timed, the same way wherever a figure is reported (the evaluate stage's
report and eval.h5, the tradeoff stage's table): one frame per call after warm-up runs, synchronised on CUDA, on
the deployment path (model.inference's fast path, replayed as one CUDA graph on a GPU) beside eager PyTorch."""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch

from model.features import FrameStore
from model.inference import FastRegressor, captured_frames

WARMUP_RUNS = 3


def pick_frames(frames: np.ndarray, count: int) -> np.ndarray:
    """`count` of `frames` (sorted ids) spread evenly: the middle one of each of `count` equal parts (so one
    frame of a sequence is from its middle, not its first, still frame), or all of them."""
    n = min(max(count, 0), len(frames))
    return frames[((np.arange(n) + 0.5) * len(frames) / max(n, 1)).astype(np.int64)]


class InferenceTimes(np.ndarray):
    """ms of each timed frame on the deployment path (the array: eval.h5's inference_ms), carrying for the report
    the eager network's ms on the same frames (`eager`) and the deployment path in words (`path`)."""

    eager: np.ndarray
    path: str


def time_inference(model, mesh, store: FrameStore, ids: torch.Tensor) -> InferenceTimes:
    """Milliseconds per frame (batch of one: its input features and the network, S x_low given) for each frame
    of `ids` after warm-up runs, synchronised on CUDA: on the deployment path (model.inference.FastRegressor,
    fp32, replayed as one CUDA graph on CUDA, under inference_mode with the configured threads on the CPU) and,
    on the same frames, eager PyTorch."""
    sync = torch.cuda.synchronize if ids.is_cuda else (lambda: None)
    fast = FastRegressor(model, mesh).to(ids.device)
    path = "model.inference fast path, fp32, inference_mode"
    deployed = fast
    if ids.is_cuda:
        try:
            deployed = captured_frames(fast, store.batch(ids[:1]))
            path = "model.inference fast path, fp32, replayed as one CUDA graph"
        except RuntimeError as err:       # a feature's kernel that cannot be captured: time it launched
            path += f", launched kernel by kernel (no CUDA graph: {str(err).splitlines()[0]})"

    def per_frame(run: Callable, grad_mode) -> tuple[np.ndarray, torch.Tensor]:
        times, outputs = [], []
        with grad_mode():
            for i in range(-WARMUP_RUNS, len(ids)):
                frame = store.batch(ids[max(i, 0):max(i, 0) + 1])
                sync()
                start = time.perf_counter()
                output = run(frame)
                sync()
                if i >= 0:
                    times.append((time.perf_counter() - start) * 1e3)
                    outputs.append(output.clone())
        return np.asarray(times), torch.cat(outputs)

    eager_ms, expected = per_frame(lambda frame: model(frame, mesh), torch.no_grad)
    deployed_ms, got = per_frame(deployed, torch.inference_mode)
    difference = float((got - expected).abs().max() / expected.abs().max().clamp_min(1e-30))
    times = deployed_ms.view(InferenceTimes)
    times.eager, times.path = eager_ms, f"{path}; within {difference:.0e} of the eager output"
    return times


def time_decoder(model, mesh, store, ids: torch.Tensor) -> InferenceTimes:
    """time_inference for a decoder task (model.inference's fast path covers the encoder-decoder only): eager
    PyTorch under inference_mode, batch of one (the input vector given), after warm-up runs; synchronised on
    CUDA."""
    sync = torch.cuda.synchronize if ids.is_cuda else (lambda: None)
    times = []
    with torch.inference_mode():
        for i in range(-WARMUP_RUNS, len(ids)):
            frame = store.batch(ids[max(i, 0):max(i, 0) + 1])
            sync()
            start = time.perf_counter()
            model(frame, mesh)
            sync()
            if i >= 0:
                times.append((time.perf_counter() - start) * 1e3)
    measured = np.asarray(times).view(InferenceTimes)
    measured.eager, measured.path = measured, "eager PyTorch, fp32, inference_mode"
    return measured
