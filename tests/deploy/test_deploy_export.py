"""The exported upsampler end to end: a model.pt of the trained format (random weights, non-trivial
normalisation, body- and velocity-relative inputs in local frames) on operators built by the operators stage,
exported by the export_model stage, then upsampled by the export's own runner.py in an interpreter that cannot
import the project, against the eager network; plus the runner's file formats and its refusal of programs that
would unpickle."""
from __future__ import annotations

import ast
import importlib.util
import io
import json
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from deploy import export, runner
from deploy.export import EXPORT_TOLERANCE, FUSED_TOLERANCE, INPUTS, coarse_faces, eager_displacement
from geometry.loop_subdivision import loop_subdivide
from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.inference import UPSAMPLER_INPUTS
from model.networks import NetworkSpec, build_network
from pipeline import export_model, operators
from pipeline.core import cli
from pipeline.core.h5 import atomic_h5, write_csr
from pipeline.artifacts.model import load_model, save_model
from pipeline.artifacts.operators import load_hierarchy
from pipeline.artifacts.subdiv import read_subdivision
from stage_inputs import grid
from workflow_runs import SNAKEMAKE

SPEC = FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")
NETWORK = NetworkSpec("D8 D16 D D16", "RC7", "max", in_channels=SPEC.channels)
TRAINING = {"epochs": 1, "batch_size": 1, "lr": 1e-3, "seed": 0, "device": "cpu",
            "loss_weights": {"l1": 1.0, "l2": 0.0, "normal": 0.0}}
FRAME_TIME = 0.05
REPO = Path(__file__).resolve().parents[2]
PROJECT_PACKAGES = ("geometry", "scenes", "sim", "meshops", "model", "viz", "pipeline", "deploy")


def _write_model(folder: Path, spec: FeatureSpec, network: NetworkSpec, name: str) -> Path:
    torch.manual_seed(0)
    net = build_network(network)
    mesh = load_hierarchy(folder / "operators.h5", network.conv, net.n_levels)
    model = FeatureRegressor(net, spec, np.load(folder / "faces.npy"),
                             np.load(folder / "rest.npy"), torch.randn(spec.channels),
                             torch.rand(spec.channels) + 0.5, 0.02)
    save_model(folder / name, model, network, mesh, {"training": TRAINING})
    return folder / name


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("deploy")
    low, low_faces = grid(4)
    subdivision, faces = loop_subdivide(low, low_faces, 2)
    with atomic_h5(folder / "subdiv.h5", "subdivide") as out:
        write_csr(out, "S", subdivision)
        out["vertices"] = subdivision @ low
        out["faces"] = faces.astype(np.int32)
    np.save(folder / "low.npy", low)
    np.save(folder / "low_faces.npy", low_faces)
    np.save(folder / "faces.npy", faces)
    np.save(folder / "rest.npy", subdivision @ low)
    cli.run(operators.main, [str(folder / "subdiv.h5"), str(folder / "operators.h5"), "--conv", "RC7", "--levels",
                             "3", "--quiet"])
    _write_model(folder, SPEC, NETWORK, "model.pt")
    cli.run(export_model.main, [str(folder / name) for name in ("model.pt", "operators.h5", "subdiv.h5", "export")]
            + ["--frame-time", str(FRAME_TIME), "--quiet"])
    return folder


def _sequence(work: Path, n_frames: int = 3) -> np.ndarray:
    """Low-res frames of a sheet waving a little."""
    low = np.load(work / "low.npy")
    t = np.arange(n_frames)[:, None]
    frames = np.repeat(low[None], n_frames, axis=0)
    frames[:, :, 2] = 0.1 * np.sin(3 * low[:, 0] + 0.5 * t) * (1 - low[:, 1])
    return frames.astype(np.float32)


def _capsules(n_frames: int) -> dict[str, np.ndarray]:
    a = np.array([[0.0, 0.5, -0.3], [0.2, 0.2, -0.2]], dtype=np.float32)
    drift = 0.02 * np.arange(n_frames, dtype=np.float32)[:, None, None]
    return {"a": a + drift, "b": a + [0.0, -0.4, 0.0] + drift, "radius_a": np.array([0.2, 0.1], np.float32),
            "radius_b": np.array([0.15, 0.1], np.float32)}


def _expected(work: Path, frames: np.ndarray, body: dict, gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """S x_low and the eager model's displacement of each frame of a sequence."""
    model, mesh, _ = load_model(work / "model.pt", work / "operators.h5", "cpu")
    subdivision = read_subdivision(work / "subdiv.h5").S
    index = np.arange(len(frames))
    tensor = lambda x: torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float32)  # noqa: E731
    inputs = {"low_positions": tensor(frames), "low_previous": tensor(frames[np.maximum(index - 1, 0)]),
              "capsule_a": tensor(body["a"]), "capsule_b": tensor(body["b"]), "radius_a": tensor(body["radius_a"]),
              "radius_b": tensor(body["radius_b"]), "gravity": tensor(gravity), "frame_time": torch.tensor(FRAME_TIME)}
    smooth, displacement = eager_displacement(model, mesh, subdivision, inputs)
    return smooth.numpy(), displacement.numpy()


def test_manifest_names_the_inputs_the_model_needs(work):
    manifest = json.loads((work / "export" / "upsampler.json").read_text())
    assert [item["name"] for item in manifest["inputs"]] == ["low_positions", "low_previous", "capsule_a",
                                                             "capsule_b", "radius_a", "radius_b", "gravity",
                                                             "frame_time"]
    assert manifest["frame_time"] == FRAME_TIME and manifest["n_low_vertices"] == 16
    assert manifest["export_check"]["max_difference_vs_eager"] <= EXPORT_TOLERANCE
    assert np.array_equal(np.load(work / "export" / "low_faces.npy"), np.load(work / "low_faces.npy"))
    assert list(INPUTS) == list(UPSAMPLER_INPUTS) == list(runner.INPUTS)


def _run_without_the_project(export_dir: Path, folder: Path, *options: str) -> tuple[np.ndarray, np.ndarray]:
    """The export's runner.py on a waving sequence, run from `folder` (outside the repository) by a fresh
    interpreter that sees torch and numpy's site-packages but not the project (no .pth files: the editable install
    is one): the runner's high-res frames and the eager network's (S x_low + displacement, and the displacement)."""
    frames = _sequence(export_dir.parent)
    body = _capsules(len(frames))
    np.save(folder / "frames.npy", frames)
    np.savez(folder / "body.npz", **body)
    site = str(Path(torch.__file__).parents[1])
    script = f"""
import runpy, sys
sys.path.append({site!r})     # torch and numpy, without the .pth files that put the project on the path
for name in {PROJECT_PACKAGES!r}:
    try:
        __import__(name)
    except ModuleNotFoundError:
        continue
    sys.exit(f"project package {{name}} is importable")
sys.argv = ["runner.py", {str(export_dir)!r}, "frames.npy", "--out", "high.npy", "--capsules", "body.npz",
            "--gravity", "0,-2,0", "--threads", "1", *{list(options)!r}]
runpy.run_path({str(export_dir / "runner.py")!r}, run_name="__main__")
leaked = sorted({{m.split(".")[0] for m in sys.modules}} & set({PROJECT_PACKAGES!r}))
sys.exit(f"the runner imported {{leaked}}" if leaked else 0)
"""
    env = {**os.environ, "PYTHONPATH": ""}
    done = subprocess.run([sys.executable, "-S", "-c", script], cwd=folder, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr + done.stdout
    assert not folder.resolve().is_relative_to(REPO)
    smooth, displacement = _expected(export_dir.parent, frames, body, np.tile([0.0, -1.0, 0.0], (len(frames), 1)))
    high = np.load(folder / "high.npy")
    assert high.shape == smooth.shape
    return high - smooth, displacement


def test_runner_without_the_project_upsamples_like_the_eager_network(work, tmp_path):
    """The CPU program gives S x_low + the eager displacement of every frame."""
    got, displacement = _run_without_the_project(work / "export", tmp_path)
    assert np.abs(got - displacement).max() <= EXPORT_TOLERANCE * np.abs(displacement).max()
    assert np.abs(displacement).max() > 1e-3          # the network is not silent


def test_a_cpu_export_has_no_fused_program_and_the_runner_says_so(work, tmp_path, monkeypatch):
    assert json.loads((work / "export" / "upsampler.json").read_text())["fused"] is None
    assert not (work / "export" / runner.FUSED_PROGRAM).exists() and not (work / "export" / runner.KERNELS).exists()
    monkeypatch.chdir(tmp_path)
    np.save("frames.npy", _sequence(work, 1))
    np.savez("body.npz", **_capsules(1))
    with pytest.raises(runner.RunnerError, match="--fused runs the fused program of an export made on CUDA"):
        runner.main([str(work / "export"), "frames.npy", "--out", "x.npy", "--capsules", "body.npz", "--fused"])


def test_the_operators_package_is_the_projects_modules_with_relative_imports_and_refuses_a_project_import(
        monkeypatch):
    files = export.kernel_package()
    assert set(files) == {f"{runner.KERNELS}/{name}.py" for name in ("__init__", *export.KERNEL_MODULES)}
    for name in export.KERNEL_MODULES:
        source = files[f"{runner.KERNELS}/{name}.py"].decode()
        original = (REPO / "model" / f"{name}.py").read_text()
        assert "from model." not in source and source.count("\n") == original.count("\n")
        assert source.replace("from .", "from model.") == original
    # The operators the modules register are the runner's list.
    defined = re.findall(r'@triton_op\(f"\{NAMESPACE\}::(\w+)"', "".join(
        (REPO / "model" / f"{name}.py").read_text() for name in export.KERNEL_MODULES))
    assert sorted(defined) == sorted(runner.OPERATORS)
    monkeypatch.setattr(export, "KERNEL_MODULES", ("triton_conv", "layers", "fused_network"))  # needs mesh_hierarchy
    with pytest.raises(ValueError, match="model/fused_network.py imports model.mesh_hierarchy: the operators' "
                                         "package would need the project"):
        export.kernel_package()


def test_a_runner_without_the_operators_package_says_what_it_needs(tmp_path, monkeypatch):
    monkeypatch.setattr(runner, "OPERATORS", ("no_such_operator",))     # none registered in this process
    with pytest.raises(runner.RunnerError, match="the fused operators cannot be imported .* need Triton"):
        runner.register_operators(tmp_path / "kernels")


@pytest.mark.skipif(importlib.util.find_spec("triton") is None,
                    reason="the operators are Triton kernels (PyTorch's CUDA wheels bring Triton; the CPU build does not)")
def test_the_operators_package_registers_every_operator_of_the_project_without_it(tmp_path):
    """Written into a folder and imported by the runner in an interpreter that cannot import the project, the
    package registers every operator of runner.OPERATORS."""
    for name, contents in export.kernel_package().items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(contents)
    sites = [str(Path(torch.__file__).parents[1]), str(Path(importlib.util.find_spec("triton").origin).parents[1])]
    script = f"""
import runpy, sys
sys.path += {sites!r}
runner = runpy.run_path({str(REPO / "deploy" / "runner.py")!r})
runner["register_operators"](runner["Path"]({str(tmp_path / runner.KERNELS)!r}))
import torch
leaked = sorted({{m.split(".")[0] for m in sys.modules}} & set({PROJECT_PACKAGES!r}))
missing = [n for n in runner["OPERATORS"] if not hasattr(torch.ops.learned_cloth, n)]
sys.exit(f"leaked {{leaked}}, missing {{missing}}" if leaked or missing else 0)
"""
    done = subprocess.run([sys.executable, "-S", "-c", script], cwd=tmp_path, env={**os.environ, "PYTHONPATH": ""},
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr + done.stdout


@pytest.mark.skipif(not torch.cuda.is_available() or importlib.util.find_spec("triton") is None,
                    reason="the fused program's operators are Triton kernels for a CUDA GPU")
@pytest.mark.parametrize("form", [None, *export.FUSED_FORMS])
def test_the_fused_program_runs_without_the_project_within_one_percent_of_the_fp32_network(work, tmp_path,
                                                                                           monkeypatch, form):
    """Exported on CUDA, the folder also holds the program of the fused bf16 path and the package of its
    operators; the runner, in a fresh interpreter without the project, registers them from the package and runs
    the program with --fused within 1 % of the eager fp32 network's largest displacement, as the export checked.
    The export keeps the faster of the network's forms on its GPU (None: as it chooses), each form timed in the
    manifest; either form, forced, exports and runs so (the persistent kernel made from its spec in that
    interpreter)."""
    if form is not None:
        monkeypatch.setattr(export, "FUSED_FORMS", {form: export.FUSED_FORMS[form]})
    export_dir = work / f"export_cuda_{form}"
    if not export_dir.exists():
        cli.run(export_model.main, [str(work / name) for name in ("model.pt", "operators.h5", "subdiv.h5")]
                + [str(export_dir), "--frame-time", str(FRAME_TIME), "--device", "cuda", "--quiet"])
    fused = json.loads((export_dir / "upsampler.json").read_text())["fused"]
    assert fused["program"] == runner.FUSED_PROGRAM and (export_dir / runner.FUSED_PROGRAM).stat().st_size > 0
    assert fused["kernels"] == runner.KERNELS and (export_dir / runner.KERNELS / "triton_conv.py").is_file()
    assert fused["operators"] and fused["max_difference_vs_eager"] <= FUSED_TOLERANCE
    timings = fused["ms_per_call"]
    assert set(timings) == ({form} if form else set(export.FUSED_FORMS)) and min(timings.values()) > 0
    assert fused["network_kernels"] == min(timings, key=timings.get)
    assert (f"{runner.OPERATOR_NAMESPACE}.persistent.default" in fused["operators"]) == \
        (fused["network_kernels"] == "persistent")
    runner.check_no_pickle(export_dir / runner.FUSED_PROGRAM)
    got, displacement = _run_without_the_project(export_dir, tmp_path, "--fused", "--device", "cuda")
    difference = np.abs(got - displacement).max() / np.abs(displacement).max()
    print(f"fused program ({fused['network_kernels']}, {timings}) vs eager fp32: {difference:.1e} of the largest "
          f"displacement")
    assert difference <= FUSED_TOLERANCE


def test_obj_frames_in_and_out_match_the_npy_path(work, tmp_path):
    frames = _sequence(work, 2)
    body = _capsules(2)
    np.savez(tmp_path / "body.npz", **body)
    low_faces = np.load(work / "low_faces.npy")
    for i, frame in enumerate(frames):
        runner.write_obj(tmp_path / f"low_{i}.obj", frame, low_faces[:, [1, 2, 0]])   # corners rotated: same faces
    np.save(tmp_path / "frames.npy", frames)
    common = [str(work / "export"), "--capsules", str(tmp_path / "body.npz")]
    runner.main([*common[:1], str(tmp_path / "low_0.obj"), str(tmp_path / "low_1.obj"), "--out",
                 str(tmp_path / "high.obj"), *common[1:]])
    runner.main([*common[:1], str(tmp_path / "frames.npy"), "--out", str(tmp_path / "high.npy"), "--batch", "1",
                 *common[1:]])
    expected = np.load(tmp_path / "high.npy")
    for i in range(2):
        vertices, faces = runner.read_obj(tmp_path / f"high_{i:04d}.obj")
        np.testing.assert_allclose(vertices, expected[i], atol=1e-6)
        assert np.array_equal(faces, np.load(work / "faces.npy"))


@pytest.mark.parametrize("args, message", [
    (["--out", "x.npy"], "give --capsules"),
    (["--out", "x.txt"], "must end in .npy or .obj"),
    (["--out", "x.npy", "--capsules", "body.npz", "--gravity", "1,2"], "expected finite values of shape"),
])
def test_runner_errors_are_one_line(work, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    np.save("frames.npy", _sequence(work, 1))
    np.savez("body.npz", **_capsules(1))
    with pytest.raises(runner.RunnerError, match=message):
        runner.main([str(work / "export"), "frames.npy", *args])


def test_runner_refuses_a_wrong_obj_mesh(work, tmp_path):
    low_faces = np.load(work / "low_faces.npy")
    runner.write_obj(tmp_path / "low.obj", _sequence(work, 1)[0], low_faces[:, [0, 2, 1]])    # flipped
    with pytest.raises(runner.RunnerError, match="not those of the mesh"):
        runner.read_frames([tmp_path / "low.obj"], low_faces, 16)


def _rewritten(source: Path, target: Path, change) -> Path:
    """A copy of a .pt2 archive with `change(name, bytes) -> bytes` applied to every entry."""
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w") as new:
        for name in old.namelist():
            new.writestr(name, change(name, old.read(name)))
    return target


def test_runner_refuses_programs_that_would_unpickle(work, tmp_path):
    program = work / "export" / "upsampler.pt2"
    runner.check_no_pickle(program)                                       # the export itself passes

    def pickled_weight(name: str, data: bytes) -> bytes:
        if not name.endswith("model_weights_config.json"):
            return data
        config = json.loads(data)
        next(iter(config["config"].values()))["use_pickle"] = True
        return json.dumps(config).encode()

    with pytest.raises(runner.RunnerError, match="would be unpickled"):
        runner.check_no_pickle(_rewritten(program, tmp_path / "a.pt2", pickled_weight))
    buffer = io.BytesIO()
    torch.save({"anything": 1}, buffer)
    samples = _rewritten(program, tmp_path / "b.pt2",
                         lambda name, data: buffer.getvalue() if "sample_inputs" in name else data)
    with pytest.raises(runner.RunnerError, match="example inputs"):
        runner.check_no_pickle(samples)
    with zipfile.ZipFile(_rewritten(program, tmp_path / "c.pt2", lambda name, data: data), "a") as archive:
        archive.writestr("upsampler/data/aotinductor/model/model.so", b"\x7fELF")
    with pytest.raises(runner.RunnerError, match="unexpected entry"):
        runner.check_no_pickle(tmp_path / "c.pt2")
    (tmp_path / "d.pt2").write_bytes(b"not a zip")
    with pytest.raises(runner.RunnerError, match="not a torch.export program"):
        runner.check_no_pickle(tmp_path / "d.pt2")


def test_runner_imports_only_torch_numpy_and_the_standard_library():
    tree = ast.parse((REPO / "deploy" / "runner.py").read_text())
    roots = {alias.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import)
             for alias in node.names}
    roots |= {node.module.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert roots - set(sys.stdlib_module_names) == {"numpy", "torch"}


def test_positions_only_model_takes_positions_only_and_a_failed_check_writes_nothing(work, tmp_path, monkeypatch,
                                                                                     capsys):
    spec = FeatureSpec()
    _write_model(work, spec, NetworkSpec("D8 D D8", "RC7", "avg"), "positions.pt")
    arguments = [str(work / "positions.pt"), str(work / "operators.h5"), str(work / "subdiv.h5")]
    cli.run(export_model.main, [*arguments, str(tmp_path / "export"), "--quiet"])
    manifest = json.loads((tmp_path / "export" / "upsampler.json").read_text())
    assert [item["name"] for item in manifest["inputs"]] == ["low_positions"] and manifest["frame_time"] is None
    monkeypatch.setattr(export, "EXPORT_TOLERANCE", -1.0)             # any difference is now too large
    with pytest.raises(SystemExit):
        cli.run(export_model.main, [*arguments, str(tmp_path / "refused"), "--quiet"])
    assert "differs from the eager network" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()


def test_export_stage_errors(work, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.run(export_model.main, [str(work / "model.pt"), str(work / "operators.h5"), str(work / "subdiv.h5"),
                                    str(tmp_path / "out"), "--quiet"])
    assert exit_info.value.code == 2
    assert "need the frame time" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_coarse_faces_undo_the_subdivision():
    low, low_faces = grid(3)
    subdivision, faces = loop_subdivide(low, low_faces, 2)
    assert np.array_equal(coarse_faces(subdivision, faces, subdivision @ low), low_faces)
    other = subdivision.copy()
    other.data[0] += 0.1                                                # another matrix of the same pattern
    with pytest.raises(ValueError, match="not the Loop subdivision"):
        coarse_faces(other, faces, subdivision @ low)
    with pytest.raises(ValueError, match="not a Loop subdivision"):
        coarse_faces(subdivision, faces[::-1], subdivision @ low)


def test_workflow_exports_on_request_only(tmp_path):
    """`results/<scene>/deploy` plans the export_model rule with paths and flags only; `results/<scene>/` (what
    `make run` builds) does not."""
    def dry_run(target: str) -> str:
        done = subprocess.run([*SNAKEMAKE, "--cores", "1", "--snakefile", str(REPO / "Snakefile"), "--directory",
                               str(tmp_path), "-n", "-p", target], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        return done.stdout
    planned = dry_run("results/patch/deploy")
    shell = next(line for line in planned.splitlines() if "-m pipeline.export_model" in line)
    words = shell.split(" -m pipeline.export_model ", 1)[1].split()
    assert words == ["results/patch/model.pt", "results/patch/operators.h5", "results/patch/subdiv.h5",
                     "results/patch/deploy", "--settings", "results/patch/settings.json", "--quiet", "2>&1", "|",
                     "tee", "results/patch/logs/export_model.log"]
    assert "rule export_model" not in dry_run("results/patch/")
