"""experiments.multi.garments: the multi-garment target's checks, products and job arguments (the workflow's plan
of them: test_workflow_multi.py)."""
import pytest

from experiments.multi import garments
from pipeline.core.errors import PipelineError

GARMENTS = ["pants", "skirt"]


def scene_settings(**changes):
    return {"network": {"arch": "D16 D32", "width": 0.25}, "training": {"epochs": 4}, "device": "cpu",
            "frames": 100, "sequences": 4, **changes}


def test_the_garments_must_be_scenes_and_no_scene_may_be_named_multi():
    garments.check_garment_names(GARMENTS, {"pants": {}, "skirt": {}, "patch": {}})
    with pytest.raises(PipelineError, match="multi.scenes: 'dress' is not a scene \\(known: pants, patch, skirt\\)"):
        garments.check_garment_names(["pants", "dress", "cape"], ["skirt", "patch", "pants"])
    with pytest.raises(PipelineError, match="a scene may not be named 'multi'"):
        garments.check_garment_names(GARMENTS, ["pants", "skirt", "multi"])


def test_the_garments_share_network_training_and_device_and_nothing_else_is_asked():
    settings = {"pants": scene_settings(), "skirt": scene_settings(frames=50, sequences=2), "patch": {}}
    garments.check_shared_settings(GARMENTS, settings)
    for key, value in (("network", {"arch": "D16 D32", "width": 0.5}), ("training", {"epochs": 5}),
                       ("device", "cuda:0")):
        settings["skirt"] = scene_settings(**{key: value})
        with pytest.raises(PipelineError, match=f"scenes 'pants' and 'skirt' differ in {key}"):
            garments.check_shared_settings(GARMENTS, settings)


def test_the_target_is_the_shared_network_then_each_garments_view_and_evaluation():
    products = garments.multi_products(GARMENTS)
    assert products[:5] == ["results/multi/model.pt", "results/multi/train.h5", "results/multi/multi.h5",
                            "results/multi/training_curve.png", "results/multi/report.md"]
    assert products[5:] == [f"results/multi/{scene}/{name}" for scene in GARMENTS
                            for name in ("model.pt", "eval.h5", "report.md", "report.html", "renders", "videos",
                                         "export")]


def test_the_jobs_arguments_name_each_garments_files():
    assert garments.scene_files(GARMENTS, "dataset.h5") == ["results/pants/dataset.h5", "results/skirt/dataset.h5"]
    assert garments.train_arguments(GARMENTS) == [
        "--garment", "pants", "results/pants/settings.json", "results/pants/dataset.h5", "results/pants/operators.h5",
        "results/multi/pants/model.pt",
        "--garment", "skirt", "results/skirt/settings.json", "results/skirt/dataset.h5", "results/skirt/operators.h5",
        "results/multi/skirt/model.pt"]
    assert garments.report_arguments(GARMENTS) == [
        "--garment", "pants", "results/multi/pants/eval.h5", "results/pants/eval.h5",
        "--garment", "skirt", "results/multi/skirt/eval.h5", "results/skirt/eval.h5"]
