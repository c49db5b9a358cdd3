"""Upsample low-res cloth frames with an exported upsampler, using torch and numpy only (no project code).

    python runner.py EXPORT_DIR INPUT [INPUT ...] --out OUT [--device cpu|cuda] [--fused] [--threads N]
        [--batch 16] [--gravity X,Y,Z | --gravity GRAVITY.npy] [--capsules CAPSULES.npz] [--frame-time SECONDS]

EXPORT_DIR is a folder written by `python -m pipeline.export_model` (this script is copied into it). INPUTs are the
low-res frames of one sequence in time order: .npy arrays of shape (V_low, 3) or (F, V_low, 3), or .obj files of
one frame each, with the training mesh's vertex order (their faces, if any, must be its faces). OUT is a .npy file
(F, V_high, 3) float32, or an .obj file (with several frames, one file per frame: OUT's stem + _0000, _0001, ...).

What else a model needs is in its upsampler.json (`inputs`): previous frames come from the input sequence itself
(a sequence's first frame is its own previous frame: zero velocity); `gravity` is --gravity, one direction or a
.npy (F, 3) in the frames' reference frame (default: 0,-1,0); the body is --capsules, an .npz with arrays `a`, `b`
((P, 3) or (F, P, 3) capsule end points) and `radius_a`, `radius_b` (P,); `frame_time` is --frame-time (default:
the training data's, from the manifest). Frames go through the program --batch at a time.

The program is loaded with torch.export.load only after checking that nothing in it would be unpickled (every
tensor stored raw, no example inputs, no compiled code): a .pt2 from elsewhere is refused, never executed.

--fused (with --device cuda) runs instead the export's program of the fused bf16 network, if it was exported on
CUDA (upsampler.json's `fused`): its Triton launchers are operators (learned_cloth::*) defined by the export's
`kernels` package, which this script imports first (Python code from the export folder, run as it is: use --fused
only with exports you made yourself); the program itself is checked like the other, and runs as one CUDA graph
replayed per batch shape. Triton, which PyTorch's CUDA wheels bring, compiles the kernels at the first call.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import zipfile
from pathlib import Path

import numpy as np
import torch
from torch.export.passes import move_to_device_pass

FORMAT = "trimesh-cnn/deployed-1"
PROGRAM, LOW_FACES, HIGH_FACES = "upsampler.pt2", "low_faces.npy", "high_faces.npy"
FUSED_PROGRAM = "upsampler_fused_cuda.pt2"      # the fused network's program, in an export made on CUDA
KERNELS = "kernels"                             # the package defining its operators, in the same export
OPERATOR_NAMESPACE = "learned_cloth"
OPERATORS = ("fused_conv", "gather_sum", "few_channel_conv", "normed_products", "prepare", "features", "stencil",
             "persistent")
INPUTS = ("low_positions", "low_previous", "low_before_previous", "capsule_a", "capsule_b", "radius_a", "radius_b",
          "gravity", "frame_time")


class RunnerError(Exception):
    """Bad input: printed as one `error:` line, exit status 2."""


def check_no_pickle(path: Path) -> None:
    """RunnerError unless every payload torch.export.load would read from the archive is raw tensor bytes or
    JSON: its loader unpickles tensors marked `use_pickle`, custom objects, and example inputs."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            root = names[0].split("/", 1)[0] + "/" if names else ""
            for name in names:
                part = name[len(root):] if name.startswith(root) else name
                if part.startswith("data/sample_inputs/") and archive.getinfo(name).file_size:
                    raise RunnerError(f"{path}: holds example inputs, which loading would unpickle")
                if part.endswith("_config.json") and part.startswith(("data/weights/", "data/constants/")):
                    for key, payload in json.loads(archive.read(name))["config"].items():
                        if payload.get("use_pickle") or not str(payload.get("path_name")).startswith(
                                ("weight_", "tensor_")):
                            raise RunnerError(f"{path}: '{key}' is not a raw tensor (it would be unpickled)")
                elif not part.startswith(("data/weights/weight_", "data/constants/tensor_", "models/", ".data/",
                                          "data/sample_inputs/", "archive_format", "archive_version", "byteorder")):
                    raise RunnerError(f"{path}: unexpected entry '{name}' (compiled code or pickled data?)")
    except (zipfile.BadZipFile, KeyError, ValueError, AttributeError) as err:
        raise RunnerError(f"{path}: not a torch.export program ({type(err).__name__})") from None


def load_export(folder: Path, device: str, fused: bool = False):
    """The program (as a callable module on `device`; with `fused`, the fused network's program), its
    manifest and the low- and high-res faces."""
    try:
        manifest = json.loads((folder / "upsampler.json").read_text())
    except (OSError, ValueError) as err:
        raise RunnerError(f"{folder}: no readable upsampler.json ({type(err).__name__})") from None
    try:
        names = [item["name"] for item in manifest["inputs"]]
        valid = manifest["format"] == FORMAT and set(names) <= set(INPUTS) and names[:1] == ["low_positions"] \
            and isinstance(manifest["n_low_vertices"], int)
    except (TypeError, KeyError):
        valid = False
    if not valid:
        raise RunnerError(f"{folder}: upsampler.json is not a {FORMAT} manifest")
    module = load_fused(folder, manifest, device) if fused else load_program(folder / PROGRAM, device)
    try:
        low_faces, high_faces = (np.load(folder / name, allow_pickle=False) for name in (LOW_FACES, HIGH_FACES))
    except (OSError, ValueError) as err:
        raise RunnerError(f"{folder}: unreadable faces ({err})") from None
    return module, manifest, low_faces, high_faces


def _unloadable(path: Path, device: str, err: Exception) -> RunnerError:
    return RunnerError(f"{path}: cannot be loaded by torch {torch.__version__} on {device} "
                       f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})")


def load_program(path: Path, device: str):
    """The torch.export program at `path`, checked for pickled payloads, as a callable module on `device`."""
    check_no_pickle(path)
    try:
        program = torch.export.load(path)
        if device != "cpu":
            program = move_to_device_pass(program, device)
    except Exception as err:  # torch raises many types for a damaged archive or one of another torch version
        raise _unloadable(path, device, err) from None
    return program.module()


def load_fused(folder: Path, manifest: dict, device: str):
    """The export's program of the fused network on `device`, its operators registered from the export's KERNELS
    package first, called as CUDA graphs (`Replayed`); RunnerError for an export without one or a device that is
    not CUDA."""
    if not isinstance(manifest.get("fused"), dict) or not device.startswith("cuda"):
        raise RunnerError(f"{folder}: --fused runs the fused program of an export made on CUDA, on --device cuda "
                          f"(this export has {'one' if manifest.get('fused') else 'none'})")
    register_operators(folder / KERNELS)
    program = load_program(folder / FUSED_PROGRAM, device)
    return Replayed(program, _import("learned_cloth_graph", folder / KERNELS / "cuda_graph.py").CapturedCall)


class Replayed:
    """The fused program as one replayed CUDA graph per input shapes (a sequence's last batch may be smaller).
    Called directly, each of its ~50 operators pays Python dispatch and Triton's launcher: 4.4 ms a frame on an
    H100 for RC9 x/4 at 15k vertices, against 0.4 replayed (bench/infer.py, exported-fused and
    exported-fused-graph)."""

    def __init__(self, program, captured_call):
        self.program, self.captured_call, self.graphs = program, captured_call, {}

    def __call__(self, **inputs: torch.Tensor) -> torch.Tensor:
        names = tuple(inputs)
        key = tuple((name, tuple(value.shape)) for name, value in inputs.items())
        if key not in self.graphs:
            self.graphs[key] = self.captured_call(lambda *values: self.program(**dict(zip(names, values))),
                                                  *inputs.values())
        return self.graphs[key](*inputs.values()).clone()     # the graph's output buffer is the next call's too


def register_operators(package: Path) -> None:
    """Import the package at `package`, whose modules register the learned_cloth operators, unless this process
    has them already (the project's own model.triton_conv, triton_features, triton_stencil and persistent_kernel
    define the same)."""
    namespace = getattr(torch.ops, OPERATOR_NAMESPACE)
    have = [hasattr(namespace, name) for name in OPERATORS]
    if all(have):
        return
    if any(have):
        raise RunnerError(f"{package}: this process defines some of the {OPERATOR_NAMESPACE} operators but not all "
                          f"(import model.triton_conv, triton_features, triton_stencil and persistent_kernel, or none)")
    _import(f"{OPERATOR_NAMESPACE}_kernels", package / "__init__.py", package)


def _import(name: str, path: Path, package: Path | None = None):
    """The module (or, with `package`, the package) at `path`, imported as `name`."""
    spec = importlib.util.spec_from_file_location(name, path, submodule_search_locations=None if package is None
                                                  else [str(package)])
    try:
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except Exception as err:  # no Triton (a CPU build of torch), or a damaged package
        sys.modules.pop(name, None)
        raise RunnerError(f"{path}: the fused operators cannot be imported ({type(err).__name__}: {err}); they "
                          f"need Triton, which PyTorch's CUDA wheels install") from None
    return module


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (T, 3), 0-based, of an OBJ file (texture/normal indices ignored)."""
    vertices, faces = [], []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        fields = line.split()
        try:
            if fields[:1] == ["v"]:
                vertices.append([float(x) for x in fields[1:4]])
            elif fields[:1] == ["f"]:
                corners = [int(field.split("/")[0]) for field in fields[1:]]
                if len(corners) != 3 or min(corners) < 1:
                    raise ValueError("not a triangle of positive indices")
                faces.append([c - 1 for c in corners])
        except ValueError as err:
            raise RunnerError(f"{path}:{number}: unreadable OBJ line ({err})") from None
    return np.asarray(vertices, dtype=np.float64).reshape(-1, 3), np.asarray(faces, dtype=np.int64).reshape(-1, 3)


def _canonical(faces: np.ndarray) -> np.ndarray:
    """Triangles rotated to start at their smallest index, sorted: equal for the same oriented triangles."""
    faces = np.asarray(faces, dtype=np.int64)
    shift = faces.argmin(axis=1)[:, None]
    rotated = np.take_along_axis(faces, (shift + np.arange(3)) % 3, axis=1)
    return rotated[np.lexsort(rotated.T[::-1])]


def read_frames(paths: list[Path], low_faces: np.ndarray, n_low: int) -> np.ndarray:
    """The low-res frames (F, V_low, 3) float32 of the input files, in order."""
    frames = []
    for path in paths:
        if path.suffix.lower() == ".obj":
            vertices, faces = read_obj(path)
            if len(faces) and not np.array_equal(_canonical(faces), _canonical(low_faces)):
                raise RunnerError(f"{path}: its faces are not those of the mesh the model was trained on")
            frames.append(vertices[None])
        else:
            try:
                array = np.load(path, allow_pickle=False)
            except (OSError, ValueError) as err:
                raise RunnerError(f"{path}: not a readable .npy array ({err})") from None
            frames.append(array[None] if array.ndim == 2 else array)
        if frames[-1].ndim != 3 or frames[-1].shape[1:] != (n_low, 3) or not np.isfinite(frames[-1]).all():
            raise RunnerError(f"{path}: expected finite positions of {n_low} vertices, (V, 3) or (F, V, 3); got "
                              f"shape {frames[-1].shape[1:] if frames[-1].ndim == 3 else frames[-1].shape}")
    return np.concatenate(frames).astype(np.float32)


def per_frame(array: np.ndarray, n_frames: int, shape: tuple[int, ...], what: str) -> np.ndarray:
    """An array given once (`shape`) or per frame ((n_frames, *shape)) as (n_frames, *shape)."""
    array = np.asarray(array, dtype=np.float32)
    if array.shape == shape:
        array = np.broadcast_to(array, (n_frames, *shape))
    if array.shape != (n_frames, *shape) or not np.isfinite(array).all():
        raise RunnerError(f"{what}: expected finite values of shape {shape} or {(n_frames, *shape)}, got "
                          f"{array.shape}")
    return array


def program_inputs(names: list[str], frames: np.ndarray, args, manifest: dict) -> dict[str, np.ndarray]:
    """Every input the program takes, per frame (leading axis F) or constant (radii, frame time)."""
    n_frames, index = len(frames), np.arange(len(frames))
    values = {"low_positions": frames, "low_previous": frames[np.maximum(index - 1, 0)],
              "low_before_previous": frames[np.maximum(index - 2, 0)]}
    if "gravity" in names:
        given = args.gravity or "0,-1,0"
        try:
            gravity = np.load(given, allow_pickle=False) if given.endswith(".npy") else \
                np.array(given.split(","), dtype=np.float64)
        except (OSError, ValueError) as err:
            raise RunnerError(f"--gravity {given}: not three numbers or a .npy array ({err})") from None
        gravity = per_frame(gravity, n_frames, (3,), f"--gravity {given}")
        values["gravity"] = gravity / np.maximum(np.linalg.norm(gravity, axis=1, keepdims=True), 1e-12)
    if "capsule_a" in names:
        if args.capsules is None:
            raise RunnerError("this model sees the body: give --capsules CAPSULES.npz (a, b, radius_a, radius_b)")
        try:
            with np.load(args.capsules, allow_pickle=False) as body:
                a, b, ra, rb = (body[key] for key in ("a", "b", "radius_a", "radius_b"))
        except (OSError, ValueError, KeyError) as err:
            raise RunnerError(f"{args.capsules}: not an .npz with a, b, radius_a, radius_b ({err})") from None
        count = np.shape(ra)[0] if np.ndim(ra) == 1 else 0
        if count == 0:
            raise RunnerError(f"{args.capsules}: needs at least one capsule (radius_a of shape (P,))")
        values.update(capsule_a=per_frame(a, n_frames, (count, 3), f"{args.capsules} a"),
                      capsule_b=per_frame(b, n_frames, (count, 3), f"{args.capsules} b"),
                      radius_a=per_frame(ra, 1, (count,), f"{args.capsules} radius_a")[0],
                      radius_b=per_frame(rb, 1, (count,), f"{args.capsules} radius_b")[0])
    if "frame_time" in names:
        frame_time = args.frame_time if args.frame_time is not None else manifest.get("frame_time")
        if not isinstance(frame_time, (int, float)) or not frame_time > 0:
            raise RunnerError("this model sees velocities: give --frame-time SECONDS (> 0)")
        values["frame_time"] = np.float32(frame_time)
    return {name: values[name] for name in names}


def upsample(module, inputs: dict[str, np.ndarray], n_frames: int, batch: int, device: str) -> np.ndarray:
    """The program over the frames, `batch` at a time: (F, V_high, 3) float32."""
    constant = {"radius_a", "radius_b", "frame_time"}
    outputs = []
    with torch.inference_mode():
        for start in range(0, n_frames, batch):
            chunk = {name: torch.as_tensor(np.array(value if name in constant else value[start:start + batch]),
                                           device=device) for name, value in inputs.items()}
            outputs.append(module(**chunk).cpu().numpy())
    return np.concatenate(outputs)


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in vertices]
    lines += [f"f {a} {b} {c}" for a, b, c in np.asarray(faces) + 1]
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("export", type=Path, help="folder written by pipeline.export_model")
    parser.add_argument("inputs", type=Path, nargs="+", help="low-res frames: .npy or .obj, in time order")
    parser.add_argument("--out", type=Path, required=True, help=".npy (F, V_high, 3) or .obj")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--fused", action="store_true",
                        help="run the fused bf16 program (an export made on CUDA; --device cuda) instead of the "
                             "fp32 one")
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--batch", type=int, default=16, help="frames per call")
    parser.add_argument("--gravity", help="X,Y,Z or a .npy (F, 3): gravity's direction (default 0,-1,0)")
    parser.add_argument("--capsules", help=".npz with a, b ((P, 3) or (F, P, 3)), radius_a, radius_b (P,)")
    parser.add_argument("--frame-time", type=float, help="seconds between frames (default: the training data's)")
    args = parser.parse_args(argv)
    if args.out.suffix.lower() not in (".npy", ".obj") or args.batch < 1:
        raise RunnerError("--out must end in .npy or .obj, and --batch be >= 1")
    if args.threads:
        torch.set_num_threads(args.threads)
    module, manifest, low_faces, high_faces = load_export(args.export, args.device, args.fused)
    frames = read_frames(args.inputs, low_faces, manifest["n_low_vertices"])
    names = [item["name"] for item in manifest["inputs"]]
    high = upsample(module, program_inputs(names, frames, args, manifest), len(frames), args.batch, args.device)
    if args.out.suffix.lower() == ".npy":
        np.save(args.out, high.astype(np.float32), allow_pickle=False)
    elif len(high) == 1:
        write_obj(args.out, high[0], high_faces)
    else:
        for i, vertices in enumerate(high):
            write_obj(args.out.with_name(f"{args.out.stem}_{i:04d}.obj"), vertices, high_faces)


if __name__ == "__main__":
    try:
        main()
    except RunnerError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
