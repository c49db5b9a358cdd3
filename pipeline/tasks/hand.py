"""Joint angles to hand skin (paper Table 4, "hand"): the input is the hand's 18 joint angles a frame; the
predictor is linear blend skinning of the rest skin by its bones; the decoder regresses the displacement to the
skin that the volumetric FEM moved there (hand_simulate). No physics at inference: the skin comes from the angles.

Its dataset is made by `pipeline.hand_dataset` from the hand's own runs (fem.h5, one per sequence), not by
`pipeline.dataset`, which gathers cloth runs (a low- and a high-res run per sequence); `train` and `evaluate` treat
it as any decoder task's. The report adds what a frame of the FEM cost beside the network's (Table 4's speedup).
"""
from __future__ import annotations

from pipeline.artifacts.dataset import read_task_attrs
from pipeline.core.errors import PipelineError
from pipeline.tasks.decoder import DecoderTask
from pipeline.tasks.task import DatasetRequest

# Root attrs of the hand's dataset.h5: the FEM's median ms a hand-frame, the device it ran on, the worlds it
# stepped together.
FEM_MS, FEM_DEVICE, FEM_WORLDS = "fem_ms_per_frame", "fem_device", "fem_worlds"


class HandTask(DecoderTask):
    name = "hand"
    predictor_label = "linear blend skinning"
    input_label = "linear blend skinning"
    truth_label = "FEM ground truth"
    input_description = ("the hand's 18 joint angles (radians: wrist flexion and deviation, per finger MCP flexion "
                         "and abduction and PIP flexion, the thumb's CMC flexion and abduction, MCP and IP flexion)")
    timing_reference = ("Paper Table 4 (hand: 18 joint angles -> 33,641 vertices, RC13 decoder, 5,746,175 "
                        "parameters): the decoder 25-134x faster than the CPU FEM simulation.")

    def prepare(self, request: DatasetRequest):
        raise PipelineError("task hand: its dataset is made from the hand's FEM runs by pipeline.hand_dataset "
                            "(results/<hand scene>/dataset.h5), not from cloth runs")

    def timing_note(self, dataset: str, network_ms: float) -> str:
        fem = read_task_attrs(dataset, (FEM_MS, FEM_DEVICE, FEM_WORLDS))
        if fem is None:
            return ""
        return (f"The FEM it replaces took a median **{fem[FEM_MS]:.1f} ms a frame** on {fem[FEM_DEVICE]} "
                f"(a batch of up to {fem[FEM_WORLDS]} sequence(s) stepped together, its time shared among them; each "
                f"frame minimised to its residual tolerance or its Newton limit): the "
                f"network is **{fem[FEM_MS] / network_ms:.0f}x faster** (Table 4's speedup column). ")
