"""model.regressors: a trained network rebuilt from what model.pt saves, whichever its kind, answers exactly as the
network that was saved; the fields each kind needs, and a decoder onto a level the operators lack, are told apart."""
import dataclasses

import pytest
import torch

from model.feature_regressor import FeatureRegressor
from model.feature_spec import FeatureSpec
from model.features import FrameStore
from model.networks import NetworkSpec, build_network
from model.regressors import check_levels, input_spec, rebuild_regressor, saved_fields
from model.tasks import VectorRegressor, VectorSpec, VectorStore
from model_meshes import identity_subdivider


def round_trip(model, spec: NetworkSpec):
    """The regressor rebuilt from the plain values model.pt would hold: the specs as dicts, the state dict."""
    saved = dataclasses.asdict(model.spec)
    return rebuild_regressor(spec, input_spec(spec, saved), {k: v.clone() for k, v in model.state_dict().items()})


def test_an_encoder_decoder_comes_back_as_the_same_feature_regressor(grid):
    vertices, faces, mesh = grid
    features = FeatureSpec(("position", "laplacian"), "local", "local", "edge")
    spec = NetworkSpec("D8 D D8", "RC7", "max", 1.0, features.channels)
    model = FeatureRegressor(build_network(spec), features, faces, vertices)
    for buffer in (model.input_offset, model.input_scale, model.output_scale):   # not the defaults: loading matters
        buffer.copy_(torch.rand_like(buffer) + 0.5)
    again = round_trip(model, spec)
    assert isinstance(again, FeatureRegressor) and again.spec == features
    frames = torch.as_tensor(vertices, dtype=torch.float32)[None].repeat(2, 1, 1)
    frames += 0.01 * torch.randn_like(frames)
    store = FrameStore(frames, identity_subdivider(frames.shape[1]), torch.tensor([0, 0]), torch.zeros(2, 0, 3),
                       torch.zeros(2, 0, 3), torch.zeros(0),
                       torch.zeros(0), torch.tensor([[0.0, -1.0, 0.0]] * 2), 1 / 60)
    batch = store.batch(torch.arange(2))
    with torch.no_grad():
        assert torch.equal(model.eval()(batch, mesh), again.eval()(batch, mesh))


def test_a_decoder_comes_back_as_the_same_vector_regressor(grid):
    _, _, mesh = grid
    spec = NetworkSpec("U8 U U4 U3", "RC7", in_channels=5, coarse_vertices=mesh.vertex_counts[4])
    model = VectorRegressor(build_network(spec), VectorSpec(("pose",)), torch.randn(5), torch.rand(5) + 0.5, 0.3)
    again = round_trip(model, spec)
    assert isinstance(again, VectorRegressor) and again.spec == VectorSpec(("pose",))
    batch = VectorStore(torch.zeros(3, 42, 3), torch.randn(3, 5)).batch(torch.arange(3))
    with torch.no_grad():
        assert torch.equal(model.eval()(batch, mesh), again.eval()(batch, mesh))


def test_each_kind_names_the_fields_it_needs_and_refuses_the_other_kinds_inputs():
    encoder_decoder, decoder = NetworkSpec("D8 D8", "RC7"), NetworkSpec("U8 U3", "RC7", coarse_vertices=4)
    assert set(saved_fields(encoder_decoder)["features"]) == {"inputs", "input_frame", "output_frame",
                                                               "frame_tangent"}
    assert saved_fields(decoder) == {"spec": {"coarse_vertices": int}}
    with pytest.raises(TypeError):       # an encoder-decoder's saved inputs are not a decoder's
        input_spec(decoder, dataclasses.asdict(FeatureSpec()))
    with pytest.raises(ValueError, match="inputs must be distinct names"):
        input_spec(encoder_decoder, {"inputs": ["pose"], "input_frame": "dataset", "output_frame": "dataset",
                                     "frame_tangent": "edge"})


def test_a_decoder_onto_a_level_the_operators_lack_is_refused_before_it_is_built():
    check_levels(NetworkSpec("U8 U3", "RC7", coarse_vertices=12), [42, 20, 12])
    check_levels(NetworkSpec("D8 D8", "RC7"), [42])          # an encoder-decoder's levels are checked on its mesh
    with pytest.raises(ValueError, match="a decoder onto 13 coarse vertices"):
        check_levels(NetworkSpec("U8 U3", "RC7", coarse_vertices=13), [42, 20, 12])
