"""Torch as the learning stages (train, evaluate) use it: deterministic and seeded on one device, with the
dataset's arrays moved onto it."""
from __future__ import annotations

import os

import numpy as np
import torch

from model.training import Frames
from pipeline.artifacts.dataset import LearningData
from pipeline.errors import PipelineError


def configure_torch(device: str, seed: int, threads: int | None = None) -> torch.device:
    """Deterministic, seeded torch on `device` using `threads` CPU threads (default: torch's choice); fails
    clearly if CUDA is asked for but absent."""
    if threads is not None:
        if threads < 1:
            raise PipelineError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise PipelineError(f"device '{device}' requested but torch finds no CUDA device (use --device cpu)")
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")   # deterministic cuBLAS
    torch.use_deterministic_algorithms(True)
    torch.set_flush_denormal(True)     # denormals in Adam's moments make CPU matmuls ~20x slower
    torch.manual_seed(seed)
    return torch.device(device)


def frames_on(data: LearningData, device: torch.device | str) -> Frames:
    """Every frame of the dataset as tensors on `device`."""
    return Frames(torch.as_tensor(data.inputs, device=device), torch.as_tensor(data.targets, device=device),
                  torch.as_tensor(data.faces.astype(np.int64), device=device))
