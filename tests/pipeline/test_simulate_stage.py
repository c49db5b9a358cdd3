"""Scene and simulate stages: contents, the harmonic residual on the shipped scenes, and bad input."""
import subprocess
import sys

import h5py
import numpy as np
import pytest
import yaml

from geometry.rigid import apply_rigid
from pipeline.core.config import resolve_scene, write_settings

CONFIG = yaml.safe_load(open("workflow_config.yaml"))


def stage(*args):
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True)


@pytest.fixture(scope="module", params=["patch", "flag"])
def scene_run(request, tmp_path_factory):
    """The scene's low- and high-res runs on the CPU profile, through the stage CLIs."""
    d = tmp_path_factory.mktemp(request.param)
    write_settings(resolve_scene(CONFIG, request.param, "cpu"), d / "settings.json")
    steps = [("pipeline.scene", d / "settings.json", d / "scene.h5", "--sequence", "train_000"),
             ("pipeline.subdivide", d / "scene.h5", d / "subdiv.h5", "--quiet"),
             ("pipeline.simulate", "low", d / "settings.json", d / "scene.h5", d / "sim_low.h5", "--quiet"),
             ("pipeline.simulate", "high", d / "settings.json", d / "scene.h5", d / "subdiv.h5", d / "sim_low.h5",
              d / "sim_high.h5", "--quiet")]
    for step in steps:
        run = stage(*map(str, step))
        assert run.returncode == 0, run.stderr
    return d


def test_high_res_holds_the_low_frequencies_of_the_low_res_on_every_frame(scene_run):
    with h5py.File(scene_run / "sim_high.h5") as f:
        residual = f["harmonic_residual"][()]
        positions = f["positions"][()]
        assert f.attrs["n_harmonics"] == int(np.ceil(positions.shape[1] / 40))
    assert np.isfinite(positions).all()
    assert residual.max() < 1e-5


def test_artifacts_are_self_describing(scene_run):
    for name in ("scene.h5", "sim_low.h5", "sim_high.h5"):
        with h5py.File(scene_run / name) as f:
            for attr in ("stage", "config", "versions", "length_unit"):
                assert attr in f.attrs, (name, attr)
    with h5py.File(scene_run / "sim_low.h5") as f:
        assert f["positions"].dtype == np.float32
        assert f["solve_ms"].shape == (f["positions"].shape[0],)
        assert "warp-lang" in f.attrs["versions"]
    for name in ("sim_low.h5", "sim_high.h5"):
        with h5py.File(scene_run / name) as f:
            assert 0.0 <= f.attrs["setup_seconds"] < 60.0 and f.attrs["batch"] == 1


def rod_positions(rotation: np.ndarray, translation: np.ndarray, pivot: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The rod's motion as the driver defines it, independently of the 4x4 transforms: R (p - pivot) + pivot + t."""
    return np.einsum("fij,pj->fpi", rotation, points - pivot) + pivot + translation[:, None, :]


def test_pins_follow_the_driver_in_both_runs(scene_run):
    with h5py.File(scene_run / "scene.h5") as s, h5py.File(scene_run / "sim_low.h5") as low:
        targets, pins = s["pins/targets"][()], s["pins/ids"][()]
        np.testing.assert_allclose(low["positions"][:, pins], targets, atol=1e-5)
        driver = [s[f"driver/{k}"][()] for k in ("rotation", "translation", "pivot")]
        np.testing.assert_allclose(apply_rigid(s["pins/transforms"][()][:, s["pins/part"][()]],
                                               s["rest/vertices"][()][pins]), targets, atol=1e-5)
    with h5py.File(scene_run / "sim_high.h5") as high:
        # Loop subdivision keeps the old vertices first: the low-res pins are pinned in the high-res run too,
        # moved by the same rigid driver from their (subdivided) rest positions.
        high_pins = high["pins/ids"][()]
        assert set(pins) <= set(high_pins)
        expected = rod_positions(*driver, high["rest_vertices"][()][high_pins])
        np.testing.assert_allclose(high["positions"][:, high_pins], expected, atol=1e-5)


def test_cloth_moves_and_keeps_its_edges(scene_run):
    with h5py.File(scene_run / "sim_low.h5") as f:
        x, faces, rest = f["positions"][()], f["faces"][()], f["rest_vertices"][()]
    assert np.abs(x[-1] - x[0]).max() > 0.01  # something happened
    e = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    ratio = np.linalg.norm(x[:, e[:, 0]] - x[:, e[:, 1]], axis=2) / np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    assert ratio.max() < 1.05 and ratio.min() > 0.74


def _corrupt_scene(src, dst, edit):
    with h5py.File(src) as f, h5py.File(dst, "w") as g:
        for key in f.attrs:
            g.attrs[key] = f.attrs[key]
        names = []
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        for name in names:
            g.create_dataset(name, data=f[name][()])
        edit(g)


def _nan_vertex(g):
    v = g["rest/vertices"][()]
    v[3, 1] = np.nan
    g["rest/vertices"][...] = v


def _non_manifold(g):
    v, f = g["rest/vertices"][()], g["rest/faces"][()]
    del g["rest/faces"]
    g["rest/faces"] = np.concatenate([f, [[f[0, 0], f[0, 1], len(v) - 1]]]).astype(np.int32)


@pytest.mark.parametrize("edit, message", [(_nan_vertex, "contains NaN"), (_non_manifold, "")])
def test_bad_scene_gives_one_clear_error_and_no_output(tmp_path, edit, message):
    settings = tmp_path / "settings.json"
    write_settings(resolve_scene(CONFIG, "patch", "cpu"), settings)
    assert stage("pipeline.scene", str(settings), str(tmp_path / "scene.h5"), "--sequence", "train_000").returncode == 0
    _corrupt_scene(tmp_path / "scene.h5", tmp_path / "bad.h5", edit)
    out = tmp_path / "sim_low.h5"
    run = stage("pipeline.simulate", "low", str(settings), str(tmp_path / "bad.h5"), str(out), "--quiet")
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {tmp_path / 'bad.h5'}") and message in lines[0]
    assert "Traceback" not in run.stderr
    assert not out.exists() and not list(tmp_path.glob(".*.tmp.h5"))


def test_missing_input_file(tmp_path):
    settings = tmp_path / "settings.json"
    write_settings(resolve_scene(CONFIG, "patch", "cpu"), settings)
    run = stage("pipeline.simulate", "low", str(settings), str(tmp_path / "nope.h5"), str(tmp_path / "o.h5"))
    assert run.returncode == 2 and "nope.h5: input file does not exist" in run.stderr
    assert not (tmp_path / "o.h5").exists()


def tiny_garment(scene: str, frames: int) -> dict:
    """A garment scene's CPU-profile settings shrunk to a coarse mesh, a short settle and a cheap solver."""
    settings = resolve_scene(CONFIG, scene, "cpu")
    mannequin = dict(settings["drivers"]["mannequin"], settle_frames=1, blend_frames=2)
    settings.update(frames=frames, mesh=dict(settings["mesh"], max_edge=0.25),
                    solver=dict(settings["solver"], substeps=2, iterations=5),
                    drivers=dict(settings["drivers"], mannequin=mannequin),
                    high_res=dict(settings["high_res"], subdivision_levels=1))
    return settings


def test_a_batch_of_sequences_writes_what_each_run_alone_writes(tmp_path):
    """Two training sequences of a coarse garment (different motion programs, body and self collision) and the
    held-out walk, stepped as one batch by the stage (its per-sequence targets and residuals on two threads),
    against each stepped alone: the same positions and harmonic residuals, bit for bit (the solver's worlds are
    independent and sum in the same order)."""
    write_settings(tiny_garment("pants", 6), tmp_path / "settings.json")
    names = ("train_000", "train_001", "held_out_000")
    for name in names:
        run = stage("pipeline.scene", str(tmp_path / "settings.json"), str(tmp_path / f"{name}.h5"), "--sequence", name)
        assert run.returncode == 0, run.stderr
    run = stage("pipeline.subdivide", str(tmp_path / "train_000.h5"), str(tmp_path / "subdiv.h5"), "--quiet")
    assert run.returncode == 0, run.stderr
    both = {}
    for mode, groups in (("batch", [names]), ("alone", [(n,) for n in names])):
        for group in groups:
            low = [str(tmp_path / p) for n in group for p in (f"{n}.h5", f"{mode}_{n}_low.h5")]
            high = [str(tmp_path / p) for n in group
                    for p in (f"{n}.h5", "subdiv.h5", f"{mode}_{n}_low.h5", f"{mode}_{n}_high.h5")]
            for level, files in (("low", low), ("high", high)):
                threads = ("--threads", "2") if (mode, level) == ("batch", "high") else ()
                run = stage("pipeline.simulate", level, str(tmp_path / "settings.json"), *files, *threads, "--quiet")
                assert run.returncode == 0, run.stderr
        for n in names:
            for level in ("low", "high"):
                with h5py.File(tmp_path / f"{mode}_{n}_{level}.h5") as f:
                    both[mode, n, level] = f["positions"][()], f.attrs["batch"]
                    if level == "high":
                        both[mode, n, "residual"] = f["harmonic_residual"][()]
    for n in names:
        for level in ("low", "high"):
            np.testing.assert_array_equal(both["batch", n, level][0], both["alone", n, level][0])
            assert (both["batch", n, level][1], both["alone", n, level][1]) == (3, 1)
        np.testing.assert_array_equal(both["batch", n, "residual"], both["alone", n, "residual"])
    assert np.abs(both["batch", "train_000", "high"][0] - both["batch", "train_001", "high"][0]).max() > 1e-3


def test_a_batch_refuses_sequences_of_another_garment(tmp_path):
    for scene, name in (("pants", "train_000"), ("skirt", "train_000")):
        write_settings(tiny_garment(scene, 3), tmp_path / f"{scene}.json")
        run = stage("pipeline.scene", str(tmp_path / f"{scene}.json"), str(tmp_path / f"{scene}.h5"), "--sequence",
                    name)
        assert run.returncode == 0, run.stderr
    run = stage("pipeline.simulate", "low", str(tmp_path / "pants.json"), str(tmp_path / "pants.h5"),
                str(tmp_path / "a.h5"), str(tmp_path / "skirt.h5"), str(tmp_path / "b.h5"), "--quiet")
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [f"error: {tmp_path / 'skirt.h5'}: not the same mesh as "
                                               f"{tmp_path / 'pants.h5'}: a batch steps sequences of one garment"]
    assert not (tmp_path / "a.h5").exists() and not (tmp_path / "b.h5").exists()
    run = stage("pipeline.simulate", "low", str(tmp_path / "pants.json"), str(tmp_path / "pants.h5"), "--quiet")
    assert run.returncode == 2 and "groups of SCENE OUT" in run.stderr


def test_threads_below_one_are_refused_with_one_line(tmp_path):
    run = stage("pipeline.simulate", "high", str(tmp_path / "settings.json"), "s.h5", "d.h5", "l.h5", "o.h5",
                "--threads", "0", "--quiet")
    assert run.returncode == 2 and run.stderr.strip().splitlines() == ["error: --threads 0: give at least 1"]
    assert not (tmp_path / "o.h5").exists()


def test_per_frame_product_is_a_matrix_product_per_frame():
    """The harmonic targets' B^T M (S x_low) over all frames at once, dense and sparse, against a loop of products."""
    import scipy.sparse as sp
    from pipeline.solvers.harmonic_targets import per_frame_product
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5, 7, 3)).astype(np.float32)
    for A in (rng.normal(size=(4, 7)), sp.random(9, 7, density=0.4, random_state=1, format="csr")):
        expected = np.stack([A @ frame for frame in x])
        np.testing.assert_allclose(per_frame_product(A, x), expected, rtol=1e-6, atol=1e-6)


def test_factored_harmonic_targets_equal_the_product_over_every_high_res_vertex():
    """(B^T M S) x_low plus the moved vertices' offsets equals B^T M over the whole cleared S x_low, with and
    without a body; a body that moves no vertex leaves the targets those of S x_low."""
    import scipy.sparse as sp
    from pipeline.solvers.harmonic_targets import BasisProducts, harmonic_targets_of
    rng = np.random.default_rng(3)
    S = sp.random(40, 12, density=0.3, random_state=2, format="csr")
    x_low = rng.normal(size=(6, 12, 3)).astype(np.float32)
    mass_basis_t = rng.normal(size=(5, 40))
    products = BasisProducts(mass_basis_t, S)
    smooth = np.stack([S @ x for x in x_low.astype(np.float64)])

    def floor():                  # a "body" below z = 0: moves the vertices under it up onto it
        cleared = smooth.copy()
        cleared[..., 2] = np.maximum(cleared[..., 2], 0.0)
        moved = np.flatnonzero((cleared != smooth).any(axis=(0, 2)))
        assert 0 < len(moved) < len(smooth[0])
        return moved, (cleared - smooth)[:, moved]

    for moved in (floor(), None):
        cleared = smooth if moved is None else np.maximum(smooth, [-np.inf, -np.inf, 0.0])
        expected = np.stack([mass_basis_t @ x for x in cleared])
        got = harmonic_targets_of(x_low, products, moved)
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    np.testing.assert_allclose(products.high(cleared.astype(np.float32)),
                               np.stack([mass_basis_t @ x for x in cleared.astype(np.float32)]), rtol=1e-12, atol=1e-12)
    nothing_moved = (np.zeros(0, dtype=np.int64), np.zeros((len(x_low), 0, 3), dtype=np.float32))
    untouched = harmonic_targets_of(x_low, products, nothing_moved)
    np.testing.assert_allclose(untouched, np.stack([mass_basis_t @ x for x in smooth]), rtol=1e-12, atol=1e-12)


def test_a_run_written_while_stepping_appears_only_once_finished(tmp_path):
    """simulation_writer (the high-res stage writes each chunk of frames as it is stepped): frames in any order
    read back as written once finished; a block that raises after some frames, or ends with the writer
    unfinished, leaves no file at all (not even a temporary one)."""
    from pipeline.artifacts.simulation import SimulationRun, read_trajectory, simulation_writer
    rng = np.random.default_rng(0)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    x = rng.normal(size=(5, 4, 3)).astype(np.float32)
    run = SimulationRun(x, faces, x[0].astype(np.float64), np.array([0]), np.zeros(5), 5)
    with simulation_writer(tmp_path / "sim.h5", "high", {}, (5, 4), "cpu", "mesh") as writer:
        writer.frames(3, x[3:])
        writer.frames(0, x[:3])
        writer.finish(run)
    np.testing.assert_array_equal(read_trajectory(tmp_path / "sim.h5").positions, x)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.h5"]

    with pytest.raises(RuntimeError, match="blew up"):
        with simulation_writer(tmp_path / "failed.h5", "high", {}, (5, 4), "cpu", "mesh") as writer:
            writer.frames(0, x[:3])
            raise RuntimeError("blew up")
    with pytest.raises(ValueError, match="unfinished"):
        with simulation_writer(tmp_path / "unfinished.h5", "high", {}, (5, 4), "cpu", "mesh") as writer:
            writer.frames(0, x)
    with pytest.raises(ValueError, match=r"frames \[3 4\] not written"):
        with simulation_writer(tmp_path / "short.h5", "high", {}, (5, 4), "cpu", "mesh") as writer:
            writer.frames(0, x[:3])
            writer.finish(run)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.h5"]


def test_the_solver_kind_is_optional_and_names_a_registered_solver(tmp_path):
    """`solver.kind` absent (every settings file written before it existed) or `xpbd` is the cloth's adapter, with
    the same solver settings; an unknown kind is refused by the schema and, were it to get past it, by the
    registry; `x-optional` spares `kind` only: a missing `solver.substeps` is still an error."""
    from pipeline.core.config import read_settings
    from pipeline.core.errors import PipelineError
    from pipeline.solvers import registry, xpbd
    settings = resolve_scene(CONFIG, "patch", "cpu")
    assert "kind" not in settings["solver"] and registry.level_names() == ["low", "high", "free"]
    named = dict(settings, solver=dict(settings["solver"], kind="xpbd"))
    for path, written in (("absent.json", settings), ("named.json", named)):
        write_settings(written, tmp_path / path)
        read = read_settings(tmp_path / path)
        assert registry.solver_level(read, "high", path) is xpbd.LEVELS["high"]
        assert xpbd.solver_settings(read) == xpbd.solver_settings(settings)
    write_settings(dict(settings, solver=dict(settings["solver"], kind="mpm")), tmp_path / "mpm.json")
    with pytest.raises(PipelineError, match=r"solver\.kind: 'mpm' is not one of \['xpbd', 'fem'\]"):
        read_settings(tmp_path / "mpm.json")
    for kind in ("mpm", "fem"):     # fem is a kind, but the hand's own stage runs it
        with pytest.raises(PipelineError, match=rf"^x\.json: solver\.kind '{kind}' is not a kind the simulate stage "
                                                rf"steps \(it steps: xpbd; "):
            registry.solver_level(dict(settings, solver={"kind": kind}), "low", "x.json")
    with pytest.raises(PipelineError, match=r"the xpbd solver makes no 'middle' run \(its runs: low, high, free\)"):
        registry.solver_level(settings, "middle", "patch.json")
    write_settings(dict(settings, solver={k: v for k, v in settings["solver"].items() if k != "substeps"}),
                   tmp_path / "no_substeps.json")
    with pytest.raises(PipelineError, match="missing key 'substeps' in solver"):
        read_settings(tmp_path / "no_substeps.json")


def drifting_level(offsets: np.ndarray, unstable_at: int | None = None):
    """A solver kind's level that is no cloth: every vertex of world w moves by offsets[w] a frame (and, at frame
    `unstable_at`, world 1 blows up); its run measures each frame's index, as its `measure` sees the frames."""
    from pipeline.artifacts.scene import read_rest_mesh, read_scene_drive
    from pipeline.artifacts.simulation import SimulationRun, harmonic_residual
    from pipeline.solvers.level import Level, PreparedBatch
    from sim.solver import UnstableSimulation

    class DriftState:
        def __init__(self, positions):
            self.positions = positions

        def read_world_positions(self):
            return self.positions.astype(np.float32)

    class DriftSolver:
        def __init__(self, rest, worlds):
            self.model, self.worlds = rest, worlds
            self.state = DriftState(np.repeat(rest[None], worlds, axis=0))
            self.frame = 0

        def step(self, state, inputs):
            self.frame += 1
            if self.frame == unstable_at:
                raise UnstableSimulation(1, 2, "drifted off")
            state.positions = state.positions + inputs

    def prepare(settings, groups, device, quiet, threads, settled):
        scene_paths = [group[0] for group in groups]
        rest, faces = read_rest_mesh(scene_paths[0])
        n_frames = [read_scene_drive(path, False).n_frames for path in scene_paths]
        solver = DriftSolver(rest, len(groups))
        seen = [np.zeros(n) for n in n_frames]

        def measure(w, first, end, positions):
            seen[w][first:end] += np.arange(first, end)

        def run(w, positions, solve_ms, setup_seconds):
            return SimulationRun(positions, faces, rest, np.array([0]), solve_ms, 7,
                                 (harmonic_residual(seen[w], 1),), batch_worlds=solver.worlds,
                                 setup_seconds=setup_seconds)

        return PreparedBatch("drift", solver, scene_paths, n_frames, "one translation",
                             lambda f: offsets[:len(groups), None], run, measure)

    return {"low": Level(("SCENE",), "a drift", prepare)}


@pytest.mark.parametrize("unstable_at", [None, 5])
def test_the_stage_steps_whatever_solver_the_registry_holds(tmp_path, monkeypatch, capsys, unstable_at):
    """The xpbd kind replaced in the registry by a solver that only translates the mesh: the stage steps it over
    40 frames (three chunks of stepped frames) as a batch of two worlds and writes each world's file with its
    positions, mesh and measure (each frame measured once); a blow-up in world 1 is one error naming its scene
    and frame, and leaves no file."""
    from pipeline import scene, simulate
    from pipeline.artifacts.scene import read_rest_mesh
    from pipeline.core import cli
    from pipeline.solvers import registry
    write_settings(dict(resolve_scene(CONFIG, "patch", "cpu"), frames=40), tmp_path / "settings.json")
    scene.main([str(tmp_path / "settings.json"), str(tmp_path / "scene.h5"), "--sequence", "train_000"])
    offsets = np.array([[0.0, 0.01, 0.0], [0.02, 0.0, 0.0]])
    monkeypatch.setitem(registry.KINDS, "xpbd", drifting_level(offsets, unstable_at))
    outputs = [tmp_path / "a.h5", tmp_path / "b.h5"]
    argv = ["low", str(tmp_path / "settings.json"), str(tmp_path / "scene.h5"), str(outputs[0]),
            str(tmp_path / "scene.h5"), str(outputs[1]), "--quiet"]
    if unstable_at:
        with pytest.raises(SystemExit):
            cli.run(simulate.main, argv)
        assert capsys.readouterr().err.splitlines() == [
            f"error: {tmp_path / 'scene.h5'}: drift: simulation blew up (drifted off) at frame 5, substep 2"]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.h5", "settings.json"]
        return
    cli.run(simulate.main, argv)
    rest, faces = read_rest_mesh(tmp_path / "scene.h5")
    for w, path in enumerate(outputs):
        with h5py.File(path) as f:
            expected = rest[None] + np.arange(40)[:, None, None] * offsets[w]
            np.testing.assert_allclose(f["positions"][()], expected, atol=1e-6)
            np.testing.assert_array_equal(f["faces"][()], faces)
            np.testing.assert_array_equal(f["harmonic_residual"][()], np.arange(40))
            assert (f.attrs["batch"], f.attrs["n_constraints"], f.attrs["n_harmonics"]) == (2, 7, 1)
            assert f.attrs["stage"] == "simulate_low" and f["solve_ms"].shape == (40,)
