"""What a task says about its network, and the one reading of `network.*` into per-vertex inputs
(pipeline.core.config.feature_spec) that the config, train and the multi-garment training share."""
import pytest

from model.feature_spec import FeatureSpec
from pipeline.core.config import feature_spec
from pipeline.core.errors import PipelineError
from pipeline.tasks import TASKS

BODY_RELATIVE = {"inputs": ["velocity", "body", "laplacian", "gravity"], "input_frame": "local",
                 "output_frame": "local", "frame_tangent": "gravity"}


def test_the_settings_list_and_the_flags_comma_separated_text_are_one_spec():
    as_flag = {**BODY_RELATIVE, "inputs": "velocity,body,laplacian,gravity"}
    expected = FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")
    assert feature_spec(BODY_RELATIVE, True, "here") == feature_spec(as_flag, True, "here") == expected
    assert expected.channels == 3 + 4 + 3 + 3


@pytest.mark.parametrize("network, problem", [
    (BODY_RELATIVE, "input 'body' measures the cloth against the mannequin's capsules"),
    ({**BODY_RELATIVE, "inputs": ["normal"]}, "in local frames the normal is (0, 0, 1)"),
    ({**BODY_RELATIVE, "inputs": "velocity,velocity"}, "inputs must be distinct names"),
    ({**BODY_RELATIVE, "inputs": ["wind"]}, "inputs must be distinct names"),
    ({**BODY_RELATIVE, "input_frame": "torso"}, "input_frame must be one of dataset, local"),
])
def test_inputs_that_cannot_be_fed_are_one_error_naming_where_they_came_from(network, problem):
    with pytest.raises(PipelineError) as refused:
        feature_spec(network, False, "scenes.flag: network")
    assert str(refused.value).startswith("scenes.flag: network: ") and problem in str(refused.value)


def test_a_scene_with_a_mannequin_may_measure_against_its_body_and_any_scene_may_use_positions():
    assert feature_spec(BODY_RELATIVE, True, "x").inputs[1] == "body"
    plain = {"inputs": ["position"], "input_frame": "dataset", "output_frame": "dataset", "frame_tangent": "edge"}
    assert feature_spec(plain, False, "x") == FeatureSpec()


@pytest.mark.parametrize("task, own, other, kind", [
    ("upsampling", "D62 D124 D248 D D248 D_3 D248", "U8 U3", "an encoder-decoder, written with D tokens"),
    ("pose", "U208 U U208 U104 U52 U3", "D8 D8", "a decoder, written with U tokens"),
    ("pca", " U8 U3", "D8", "a decoder, written with U tokens"),
])
def test_each_task_accepts_its_own_kind_of_network_and_names_it_when_refusing_another(task, own, other, kind):
    TASKS[task].check_arch(own)
    TASKS[task].check_model({"spec": {"arch": own}}, "model.pt", "dataset.h5")
    with pytest.raises(PipelineError, match=f"--arch '{other}': the network of task '{task}' is {kind}"):
        TASKS[task].check_arch(other)
    with pytest.raises(PipelineError, match=f"model.pt: not a network of task '{task}'"):
        TASKS[task].check_model({"spec": {"arch": other}}, "model.pt", "dataset.h5")
