"""One CUDA graph over static input buffers (`CapturedCall`): how the deployment path runs a frame in one launch
sequence (model.inference, the timing of the evaluate and trade-off stages, bench/). Torch only, so that an
export's `kernels` package carries it too: deploy/runner.py replays the fused program this way."""
from __future__ import annotations

import torch


class CapturedCall:
    """`fn(*inputs)` captured as one CUDA graph over static input buffers: calling it copies the new inputs in
    and replays the graph. The returned tensor is the graph's static output, overwritten by the next call
    (clone it to keep it). Inputs must keep the shapes, dtypes and device of the examples."""

    def __init__(self, fn, *example_inputs: torch.Tensor, warmup: int = 3):
        device = example_inputs[0].device
        # The graph reads the buffers of whatever `fn` closes over (a network's weights and index tables) by
        # address: keep `fn` alive as long as the graph, or a caller's temporary module is freed after capture and
        # the replay reads reused memory (out-of-bounds indices: a device-side assert).
        self.fn = fn
        self.inputs = tuple(x.clone() for x in example_inputs)
        stream = torch.cuda.Stream(device)
        stream.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(stream), torch.inference_mode():
            for _ in range(max(warmup, 1)):         # allocator and cuBLAS workspaces settle before capture
                fn(*self.inputs)
        torch.cuda.current_stream(device).wait_stream(stream)
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph), torch.inference_mode():
            self.output = fn(*self.inputs)

    def __call__(self, *inputs: torch.Tensor) -> torch.Tensor:
        for static, given in zip(self.inputs, inputs, strict=True):
            static.copy_(given)
        self.graph.replay()
        return self.output
