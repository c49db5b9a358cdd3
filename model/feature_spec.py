"""What the upsampling network sees, named: the per-vertex feature names and their channel counts, the axes they
are expressed in, and `FeatureSpec`, the choice a scene's `network.*` settings make and model.pt stores.

Plain Python (no torch), so that the settings can be checked where they are read (pipeline.core.config, which every
stage and the workflow import) by the same rules the network is built by; model.features computes the features.
"""
from __future__ import annotations

import dataclasses


# name -> channel count
FEATURE_CHANNELS = {
    "position": 3,           # S x_low, absolute, in the dataset frame (the paper's input)
    "centered_position": 3,  # S x_low minus its per-frame mean: the shape without where it is
    "rest_position": 3,      # the subdivided rest mesh: which material point a vertex is (constant per vertex)
    "normal": 3,             # area-weighted unit vertex normal of S x_low
    "laplacian": 3,          # umbrella Laplacian (mean of neighbours - vertex): local curvature / folds
    "velocity": 3,           # (S x_low(f) - S x_low(f-1)) / dt, zero at a sequence's first frame
    "acceleration": 3,       # (velocity(f) - velocity(f-1)) / dt with the same rule at f-1
    "strain": 2,             # principal stretches - 1 of S x_low against the rest mesh (compression < 0)
    "body": 4,               # signed distance to the nearest capsule, then the unit direction away from it
    "gravity": 3,            # unit gravity direction in the dataset frame (the same at every vertex)
    "previous_output": 3,    # the network's own displacement at the previous frame (zero at a sequence's first
                             # frame): autoregressive, for the detail that depends on the cloth's history
}
TANGENTS = ("edge", "gravity")   # how a local frame's tangent is chosen (model.local_frames)
FRAMES = ("dataset", "local")    # the axes vectors are expressed in: the dataset's, or each vertex's own


def check_features(names: tuple[str, ...], local_inputs: bool, frame_tangent: str) -> None:
    """ValueError unless `names` are distinct feature names (FEATURE_CHANNELS) that can be stacked as asked."""
    unknown = [n for n in names if n not in FEATURE_CHANNELS]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"inputs must be distinct names among {', '.join(FEATURE_CHANNELS)}; got "
                         f"{', '.join(map(str, names)) or 'none'}")
    if frame_tangent not in TANGENTS:
        raise ValueError(f"frame_tangent must be one of {', '.join(TANGENTS)}, got '{frame_tangent}'")
    if local_inputs and "normal" in names:
        raise ValueError("in local frames the normal is (0, 0, 1) at every vertex: drop 'normal' from the inputs")


@dataclasses.dataclass(frozen=True)
class FeatureSpec:
    """What the network sees and in which axes it answers (stored in model.pt; config `network.*`)."""

    inputs: tuple[str, ...] = ("position",)    # FEATURE_CHANNELS names, stacked in this order
    input_frame: str = "dataset"               # vector inputs in the dataset's axes or each vertex's local frame
    output_frame: str = "dataset"              # the predicted displacement's axes, likewise
    frame_tangent: str = "edge"                # local frames' tangent (model.local_frames)

    def __post_init__(self):
        object.__setattr__(self, "inputs", tuple(self.inputs))
        for name, value in (("input_frame", self.input_frame), ("output_frame", self.output_frame)):
            if value not in FRAMES:
                raise ValueError(f"{name} must be one of {', '.join(FRAMES)}, got '{value}'")
        check_features(self.inputs, self.input_frame == "local", self.frame_tangent)

    @property
    def channels(self) -> int:
        return sum(FEATURE_CHANNELS[n] for n in self.inputs)
