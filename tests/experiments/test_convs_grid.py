"""experiments.convs.grid: the parameter count it sizes architectures by (against the networks torch builds and
the paper's Table 3), the x it solves for a template, the tasks, runs and settings of a scene's grid (the workflow's
plan of them: test_workflow_convs.py)."""
import copy
import re

import pytest
import yaml

from experiments.convs import grid
from model.architecture import parse_architecture
from model.networks import NetworkSpec, build_network
from pipeline.core.config import resolve_scene, validate_config
from pipeline.core.errors import PipelineError
from workflow_runs import REPO

CONFIG = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
PAPER_ARCH = "D62 D124 D248 D D248 D_3 D248"


@pytest.mark.parametrize("arch, length, in_channels, width", [
    (PAPER_ARCH, 13, 3, 1.0), (PAPER_ARCH, 9, 3, 0.25), ("D8", 9, 13, 1.0), ("D D8 D_2 D16", 13, 4, 1.0),
    ("D D2 D4 D_5 D4", 9, 3, 1.0),                      # a pooling first; channel counts 2 and 4
    ("D57 D57 D114 D114 D228 D228 D_2 D228", 13, 13, 0.25), ("D30 D60 D_5 D60", 7, 16, 0.5)])
def test_the_parameter_count_is_the_built_networks(arch, length, in_channels, width):
    """The arithmetic the grid sizes templates by against model.networks' own count (torch), any pooling."""
    built = build_network(NetworkSpec(arch, f"RC{length}", "max", width, in_channels, 3)).parameter_count()
    assert grid.encoder_decoder_parameters(parse_architecture(arch, "D").scaled(width), length, in_channels) == built


def test_the_parameter_count_gives_the_papers_table_3():
    """docs/architecture.md: RC13 and RC9 of the paper's best network, and RC9 at x/2 and x/4."""
    count = lambda arch, length, width=1.0: grid.encoder_decoder_parameters(   # noqa: E731
        parse_architecture(arch, "D").scaled(width), length, 3)
    assert (count(PAPER_ARCH, 13), count(PAPER_ARCH, 9)) == (7_902_829, 5_471_897)
    assert (count(PAPER_ARCH, 9, 0.5), count(PAPER_ARCH, 9, 0.25)) == (1_371_757, 346_265)


def test_a_template_is_sized_to_the_nearest_count_and_gives_the_papers_x():
    """The paper's D^x D^2x D^4x D_5 D^4x sized to its best network at RC13 is x = 80 (its text: 7.8M weights);
    the chosen x's count is nearer the target than its neighbours', and the smallest on a tie."""
    target = 7_902_829
    arch, count = grid.resolve_template("Dx D2x D4x D_5 D4x", target, 13, 1.0, 3)
    assert arch == "D80 D160 D320 D_5 D320" and abs(count - 7.8e6) < 0.05e6
    for template, width, channels in (("Dx D2x D4x D_5 D4x", 0.25, 13), ("Dx Dx D2x D2x D4x D4x D_2 D4x", 1.0, 3),
                                      ("D2x_2 D D3x", 0.5, 7)):
        arch, count = grid.resolve_template(template, 500_000, 9, width, channels)
        x = next(x for x in range(1, 2000) if grid.instantiate(template, x) == arch)
        neighbours = [grid.encoder_decoder_parameters(parse_architecture(grid.instantiate(template, y), "D")
                                                      .scaled(width), 9, channels) for y in (x - 1, x + 1) if y]
        assert all(abs(count - 500_000) <= abs(other - 500_000) for other in neighbours)
        assert x == 1 or neighbours[0] != count        # a smaller x with the same count would have been chosen


def test_instantiate_keeps_poolings_repeats_and_fixed_tokens():
    assert grid.instantiate("Dx D2x_2 D D_3 D16 D4x", 10) == "D10 D20_2 D D_3 D16 D40"


def test_a_template_without_x_is_one_error():
    with pytest.raises(PipelineError, match="convs.archs: 'D8 D16' has no channel count in x"):
        grid.resolve_template("D8 D16", 1000, 9, 1.0, 3)


def settings(scene="pants", profile="cpu", **convs):
    config = copy.deepcopy(CONFIG)
    config["defaults"]["convs"].update(convs)
    return resolve_scene(config, scene, profile)


def test_the_tasks_are_the_upsampling_and_the_pose_decoder_where_the_scene_has_a_mannequin():
    assert grid.tasks(settings("pants")) == ["upsampling", "pose"]
    assert grid.tasks(settings("pants", pose=False)) == ["upsampling"]
    assert grid.tasks(settings("flag")) == ["upsampling"]


def test_every_run_has_its_own_folder_and_the_stage_gets_each_eval_and_train_log():
    s = settings("pants", profile="paper")
    runs = grid.runs("pants", s)
    assert len(runs) == 4 * 2 * 3 * 3 + 4 * 2 * 1 * 3                 # upsampling, then the pose decoder
    assert len({path for _, _, path, _ in runs}) == len(runs)
    assert runs[0] == ("upsampling", 0, "results/pants/convs/upsampling/a0/RC9/s0/eval.h5",
                       "results/pants/convs/upsampling/a0/RC9/s0/train.h5")
    assert runs[-1][:3] == ("pose", 2, "results/pants/convs/pose/a0/SPD13/s2/eval.h5")
    words = grid.stage_arguments("pants", s)
    assert words[:5] == ["--run", "upsampling", "0", runs[0][2], runs[0][3]] and words.count("--run") == len(runs)
    assert "--part" not in words and len(grid.stage_inputs("pants", s)) == 2 * len(runs)


def test_the_parts_of_a_grid_run_elsewhere_are_the_stages_inputs_and_flags():
    s = settings("pants", profile="paper")
    s["convs"] = {**s["convs"], "seeds": [2], "parts": ["elsewhere/seeds01.h5", "b c.h5"]}
    words, inputs = grid.stage_arguments("pants", s), grid.stage_inputs("pants", s)
    assert words[-4:] == ["--part", "elsewhere/seeds01.h5", "--part", "b c.h5"]
    assert inputs[-2:] == ["elsewhere/seeds01.h5", "b c.h5"] and len(inputs) == 2 * len(grid.runs("pants", s)) + 2


def test_the_architectures_are_the_scenes_and_templates_sized_to_it_at_each_length():
    s = settings("pants", profile="paper")
    assert grid.architecture(s, "upsampling", "a0", "SP9") == PAPER_ARCH
    assert grid.architecture(s, "upsampling", "a1", "EC13") == "D80 D160 D320 D_5 D320"
    assert grid.architecture(s, "pose", "a0", "RC9") == s["applications"]["pose"]["network"]["arch"]
    channels = grid.in_channels(s)
    assert channels == 13                                      # velocity 3, body 4, laplacian 3, gravity 3
    for length in (9, 13):
        scene = grid.encoder_decoder_parameters(parse_architecture(PAPER_ARCH, "D"), length, channels)
        for label in ("a1", "a2"):
            arch = parse_architecture(grid.architecture(s, "upsampling", label, f"RC{length}"), "D")
            assert abs(grid.encoder_decoder_parameters(arch, length, channels) / scene - 1) < 0.02


def test_every_task_reads_one_operators_file_of_every_operator_with_the_deepest_tasks_levels():
    s = settings("pants", epochs=3)
    operators = grid.operators_settings(s)["operators"]
    assert operators == {"conv": ["RC9", "EC9", "SP9", "SPD9", "RC13", "EC13", "SP13", "SPD13"], "levels": 11}
    upsampling, pose = grid.task_settings(s, "upsampling"), grid.task_settings(s, "pose")
    assert upsampling["operators"] == pose["operators"] == operators
    assert upsampling["training"]["epochs"] == pose["training"]["epochs"] == 3
    assert upsampling["network"]["arch"] == PAPER_ARCH and pose["network"]["arch"].startswith("U")
    assert pose["training"]["loss"] == s["applications"]["pose"]["training"]["loss"]
    assert "convs" not in upsampling and "applications" not in upsampling
    own = grid.task_settings(settings("pants"), "upsampling")["training"]["epochs"]
    assert own == settings("pants")["training"]["epochs"]          # epochs null: the task's own


@pytest.mark.parametrize("arch", ["D8' $(touch pwned) 'D8", "scene; rm", "Dx D2x\nD4x", "Dy"])
def test_the_schema_refuses_an_architecture_that_is_not_d_tokens_in_x(arch):
    config = copy.deepcopy(CONFIG)
    config["defaults"]["convs"]["archs"] = ["scene", arch]
    with pytest.raises(PipelineError, match="convs.archs"):
        validate_config(config, "config")


def test_two_architectures_that_are_one_network_are_refused_before_any_job():
    """At the cpu profile's width 0.25 the template's x = 61 and the scene's 62 channels both round to 16."""
    grid.check(settings("pants"))
    same = settings("pants", archs=["scene", "Dx D2x D4x D D4x D_3 D4x"])
    with pytest.raises(PipelineError, match=re.escape("convs.archs: 'scene' and 'Dx D2x D4x D D4x D_3 D4x' are the "
                                                      "same network (D^16 D^32 D^62 D D^62 D D D D^62) at RC9")):
        grid.check(same)
