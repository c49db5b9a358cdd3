"""A trained network as the stages save and run it: wrapped in the regressor of its kind, rebuilt from what model.pt
saves (the network's spec, the regressor's input spec, the state dict).

The architecture's tokens say the kind: an encoder-decoder (D tokens) reads per-vertex features of the subdivided
low-res cloth (model.feature_regressor.FeatureRegressor, its mesh constants among its weights), a decoder (U
tokens) one vector per frame (model.tasks.VectorRegressor). Everything that depends on the kind is decided here,
so a reader of model.pt never tests an architecture's letter.
"""
from __future__ import annotations

from typing import Any, Mapping

import torch

from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.networks import NetworkSpec, build_network
from model.tasks import VectorRegressor, VectorSpec

Regressor = FeatureRegressor | VectorRegressor

# The plain values model.pt holds for each kind beyond those every model has, and their types (as
# pipeline.artifacts.model.check_plain reads them: a nested dict holds a group's fields).
_KIND_FIELDS = {
    "D": {"features": {"inputs": (list, tuple), "input_frame": str, "output_frame": str, "frame_tangent": str}},
    "U": {"spec": {"coarse_vertices": int}},
}


def saved_fields(spec: NetworkSpec) -> dict[str, Any]:
    """The fields model.pt must hold for a network of `spec`'s kind (and their types), beyond the shared ones."""
    return _KIND_FIELDS["U" if spec.letter == "U" else "D"]


def input_spec(spec: NetworkSpec, saved: Mapping[str, Any]) -> FeatureSpec | VectorSpec:
    """The regressor's inputs from model.pt's `features` (ValueError or TypeError if they are not of the kind)."""
    return VectorSpec(**saved) if spec.letter == "U" else FeatureSpec(**saved)


def check_levels(spec: NetworkSpec, vertex_counts: list[int]) -> None:
    """ValueError if `spec`'s network cannot run on operators with these levels' vertex counts, told before it is
    built: a decoder's fully connected layer maps onto its coarsest level, and one onto another size (possibly
    huge) would be allocated first."""
    if spec.letter == "U" and spec.coarse_vertices not in vertex_counts:
        raise ValueError(f"a decoder onto {spec.coarse_vertices} coarse vertices, but no level of the operators has "
                         f"that many")


def rebuild_regressor(spec: NetworkSpec, inputs: FeatureSpec | VectorSpec,
                      weights: Mapping[str, torch.Tensor]) -> Regressor:
    """The regressor of `spec`'s network reading `inputs`, with `weights` loaded (an encoder-decoder's mesh
    constants are among them). Raises KeyError, ValueError or RuntimeError for weights that do not fit."""
    net = build_network(spec)
    if isinstance(inputs, VectorSpec):
        model = VectorRegressor(net, inputs)
    else:
        model = FeatureRegressor(net, inputs, weights["features.faces"].numpy(), weights["features.rest"].numpy())
    model.load_state_dict(weights)
    return model
