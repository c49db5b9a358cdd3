"""A frame stepped in one launch, a thread block (or a cluster of blocks) per world (sim.xpbd.block_frame), against
the sweep kernels: the same per-vertex functions in the same order, so on the CPU (a block is one thread) every
position agrees bit for bit, contacts, pins, friction, several worlds, the overflow's second stepping and a
cluster's per-entry multipliers included. On CUDA a block's threads share its vertices (one a thread, or many with
few threads; in a cluster, several lanes a vertex) and the sums round as the sweep kernels' do, but FMA
contraction may differ between the two kernels, and contact decisions amplify the last bit: the CUDA tests hold
the block to the CPU as test_collision.test_cuda_graph_agrees_with_cpu holds the sweeps (1e-5 of the cloth's size
over the first 5 frames, 3 for the dancing pants, the mean within 2 % throughout) and to itself exactly. Without
a GPU, the layouts' choice and checks run on a described GPU, and the cluster kernel is compiled for sm_90."""
import warnings

import numpy as np
import pytest
import warp as wp

from geometry.harmonics import harmonic_basis
from scenes.grid import first_row_pins, grid_cloth
from sim.xpbd import (ClothModel, ClothSolver, FrameInputs, SolverSettings, UnstableSimulation,
                      harmonic_constraint)
from sim.xpbd import block_frame, world_search
from sim.xpbd import solver as solver_module
from sim.xpbd.solver import frame_kernel_of
from sim.xpbd.block_frame import BlockLayout
from tests.sim.cloth_checks import FakeGpu, coarse_pants_drives, contact_scene, run_worlds

CUDA = pytest.mark.skipif(not wp.get_cuda_device_count(), reason="no CUDA device")
FRAMES = 8
MOTIONS = ("karate", "walk", "rest")


@pytest.fixture(scope="module")
def pants_drives():
    return coarse_pants_drives(FRAMES, MOTIONS)


def pants_run(pants_drives, frame_kernel, device="cpu", worlds=slice(None), **solver):
    """The coarse pants, body and self-collision, pinned at the waist, one world a motion (or those `worlds`)."""
    garment, ids, radii, drives = pants_drives
    settings = SolverSettings(substeps=2, iterations=10, body_collision=True, self_collision=True,
                              frame_kernel=frame_kernel)
    return run_worlds(garment, ids, radii, drives[worlds], settings, FRAMES, device, **solver)


def folding_run(frame_kernel, device="cpu", frames=40, **solver):
    """A grid pinned along its middle whose halves swing down and meet face to face (self-contact, no body): the
    positions of every frame, the solver and the most contacts a vertex listed at a frame's end."""
    rest, faces = grid_cloth(0.3, 0.4, 0.04, plane="xz", origin=(-0.15, 1.0, -0.2))
    hinge = np.flatnonzero(np.isclose(rest[:, 2], 0.0))
    settings = SolverSettings(substeps=4, iterations=20, self_collision=True, damping=0.5, frame_kernel=frame_kernel)
    solver = ClothSolver(ClothModel(rest, faces, settings, hinge), device, **solver)
    positions, contacts = [], 0
    for _ in range(frames):
        solver.step(solver.state, FrameInputs(pin_targets=rest[hinge]))
        positions.append(solver.state.read_positions())
        contacts = max(contacts, int(solver.contacts.vertex_count.numpy().max()))
    return np.array(positions), solver, contacts


def close_to(reference, x, early=5):
    """The CUDA tolerance of the module docstring (`early` frames held to 1e-5)."""
    size = np.ptp(reference[0].reshape(-1, 3), axis=0).max()
    error = np.abs(reference - x).reshape(len(x), -1).max(axis=1) / size
    assert error[:early].max() < 1e-5, error[:early]
    np.testing.assert_allclose(x.reshape(len(x), -1, 3).mean(axis=1), reference.reshape(len(x), -1, 3).mean(axis=1),
                               atol=0.02 * size)


# ---------------------------------------------------------------------------------------------------------------
# CPU: bit for bit


def test_contacts_step_as_the_sweeps_bit_for_bit():
    block, solver = contact_scene("cpu", frame_kernel="block")
    assert solver.frame_kernel == "block" and solver.block_layout == BlockLayout(1) and not solver.block_shared
    assert solver.contacts.vertex_count.numpy().max() > 0 and (solver.capsules.push.numpy() > 0).any()
    sweeps, solver = contact_scene("cpu", frame_kernel="sweeps")
    assert solver.frame_kernel == "sweeps"
    np.testing.assert_array_equal(block, sweeps)


def test_worlds_of_pants_step_as_the_sweeps_and_as_alone(pants_drives):
    """Three worlds, each its own motion (pins and body), in one launch; a world stepped alone is block 0 of a
    launch of one, and moves as it does as block 1 of three."""
    block, solver = pants_run(pants_drives, "block")
    assert solver.frame_kernel == "block" and solver.contacts.vertex_count.numpy().max() > 0
    sweeps, _ = pants_run(pants_drives, "sweeps")
    np.testing.assert_array_equal(block, sweeps)
    alone, _ = pants_run(pants_drives, "block", worlds=slice(1, 2))
    np.testing.assert_array_equal(block[1], alone[0])
    assert np.abs(block[0] - block[1]).max() > 0.01   # the worlds do differ


def test_a_grid_folding_onto_itself_steps_as_the_sweeps():
    block, _, contacts = folding_run("block")
    assert contacts > 0
    sweeps, _, _ = folding_run("sweeps")
    np.testing.assert_array_equal(block, sweeps)


def hanging_run(hanging_cloth, frame_kernel, bending=True, **solver):
    """Two worlds of the hanging cloth (no contacts), their pins swung differently: the positions after 10 frames
    (`solver`: more of ClothSolver's arguments; the sweeps take no block_layout)."""
    rest, faces, pins = hanging_cloth
    settings = SolverSettings(substeps=3, iterations=15, bending=bending, frame_kernel=frame_kernel)
    solver = ClothSolver(ClothModel(rest, faces, settings, pins), "cpu", worlds=2,
                         **(solver if frame_kernel == "block" else {}))
    for f in range(10):
        swing = np.array([0.05 * np.sin(f / 3), 0.0, 0.02 * f])
        solver.step(solver.state, FrameInputs(pin_targets=np.stack([rest[pins], rest[pins] + swing])))
    return solver.state.read_positions()


@pytest.mark.parametrize("bending", [True, False])
def test_a_hanging_cloth_without_contacts_steps_as_the_sweeps(hanging_cloth, bending):
    np.testing.assert_array_equal(hanging_run(hanging_cloth, "block", bending),
                                  hanging_run(hanging_cloth, "sweeps", bending))


def test_multipliers_kept_per_entry_step_as_one_per_constraint(monkeypatch, pants_drives):
    """A cluster's sweeps keep a multiplier per entry of the vertices' lists (both endpoints their own copy, as
    no thread may read another block's write in the same sweep): on the CPU, forced for the block frame, the pants
    (body, self-contact, compliant bending) step as the sweeps with one multiplier per constraint, bit for bit."""
    monkeypatch.setattr(solver_module, "per_entry_multipliers", lambda frame_kernel, layout: frame_kernel == "block")
    block, solver = pants_run(pants_drives, "block")
    assert solver._sweeps[0].lambda_per_entry == 1 and solver.model.settings.bending_compliance > 0
    assert solver._sweeps[0].lambda_in.shape[0] == len(MOTIONS) * solver.constraints.entries.shape[0]
    np.testing.assert_array_equal(block, pants_run(pants_drives, "sweeps")[0])


def test_full_lists_grow_and_the_frame_is_stepped_again():
    """The overflow flag of the block's search: lists with room for 2 grow and the frame is stepped again, ending
    where the sweeps with room to spare end."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        small, solver = contact_scene("cpu", frame_kernel="block", contact_capacity=2)
    assert solver.frames_stepped_again >= 1 and solver.contacts.vertex_contacts.shape[1] > 2
    roomy, _ = contact_scene("cpu", frame_kernel="sweeps", contact_capacity=64)
    np.testing.assert_array_equal(small, roomy)


@pytest.mark.parametrize("threads", [7, 64, 1024])
def test_threads_of_a_block_meet_at_the_barriers(threads, monkeypatch, pants_drives, hanging_cloth):
    """Warp's CPU blocks (fibers that take turns at the barriers): a block of 7 threads (several vertices each, the
    last ones fewer), 64, or more threads than vertices (idle ones still meet every barrier) steps as the sweeps,
    with contacts and without. A missing barrier lets a thread run into the next step before the others wrote what
    it reads (the sweeps' and the sorted lists' barriers and, without self-contact, the prediction's are caught so;
    the search's boxes, padded, hide a stale box for a while)."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    block, solver = contact_scene("cpu", frame_kernel="block", block_layout=BlockLayout(threads))
    assert solver.block_layout.threads == threads
    np.testing.assert_array_equal(block, contact_scene("cpu", frame_kernel="sweeps")[0])
    block, _ = pants_run(pants_drives, "block", block_layout=BlockLayout(threads))
    np.testing.assert_array_equal(block, pants_run(pants_drives, "sweeps")[0])
    np.testing.assert_array_equal(*(hanging_run(hanging_cloth, frame_kernel, block_layout=BlockLayout(threads))
                                    for frame_kernel in ("block", "sweeps")))


@pytest.mark.parametrize("room", [0, 1, 4])
def test_pairs_whose_hits_miss_the_queue_test_them_themselves(room, monkeypatch, pants_drives):
    """The search's queue of candidates with room for `room` a vertex (the pants' vertices meet ~10 triangles'
    boxes each): none, so every pair tests its own hits; or full partway through a substep, so the pair that
    reaches its end leaves its slots below it empty and tests its hits itself, and the pairs after it do. In blocks
    of 64 threads on the CPU, three worlds with their own queues, the pants step as the sweeps bit for bit."""
    monkeypatch.setattr(world_search, "QUEUE_PER_VERTEX", room)
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    block, solver = pants_run(pants_drives, "block", block_layout=BlockLayout(64))
    assert solver._world_search.queue_room == room * solver.world_vertices
    np.testing.assert_array_equal(block, pants_run(pants_drives, "sweeps")[0])


def test_a_blow_up_names_its_world():
    rest, faces = grid_cloth(0.2, 0.2, 0.1, plane="xz")
    settings = SolverSettings(max_speed=1.0, frame_kernel="block")
    solver = ClothSolver(ClothModel(rest, faces, settings, np.zeros(0, int)), "cpu", worlds=3)
    velocities = np.zeros((3 * len(rest), 3))
    velocities[2 * len(rest):] = [0.0, 5.0, 0.0]
    solver.state.write_velocities(velocities)
    with pytest.raises(UnstableSimulation, match="world 2, substep 0"):
        solver.step(solver.state)


def test_the_setting_and_the_cloth_choose_the_kernels(monkeypatch):
    rest, faces = grid_cloth(0.4, 0.4, 0.1, plane="xy", origin=(0, 1, 0))
    pins = first_row_pins(rest, "xy", "corners")

    def kernel(frame_kernel, harmonic=None, **solver):
        model = ClothModel(rest, faces, SolverSettings(frame_kernel=frame_kernel), pins, harmonic=harmonic)
        return ClothSolver(model, "cpu", **solver).frame_kernel

    assert SolverSettings().frame_kernel == "sweeps"
    assert kernel("auto") == "sweeps"            # the CPU's default
    assert kernel("block") == "block" and kernel("sweeps") == "sweeps"
    basis, _, mass = harmonic_basis(rest, faces, 3)
    harmonic = harmonic_constraint(basis, mass, pins)
    assert kernel("block", harmonic) == "sweeps"  # the harmonic projection needs the sweep kernels
    monkeypatch.setattr(block_frame, "MAX_BLOCK_VERTICES", len(rest) - 1)
    assert kernel("block") == "sweeps"            # too large for a block
    monkeypatch.undo()
    auto = ClothModel(rest, faces, SolverSettings(frame_kernel="auto"), pins)
    assert frame_kernel_of(auto, FakeGpu(90)) == "block"       # a world in a cluster's shared memory
    assert frame_kernel_of(auto, FakeGpu(90), worlds=8) == "block"     # 8 clusters of 16 blocks on 132 SMs
    assert frame_kernel_of(auto, FakeGpu(90), worlds=9) == "sweeps"    # clusters of 8: slower
    assert frame_kernel_of(auto, FakeGpu(90, sm_count=16), worlds=2) == "sweeps"
    assert frame_kernel_of(auto, FakeGpu(120)) == "sweeps"     # clusters of 8 at most there: not measured faster
    assert frame_kernel_of(auto, FakeGpu(80)) == "sweeps"      # no clusters: one block was slower
    monkeypatch.setattr(block_frame, "SHARED_VERTICES", len(rest) - 1)
    assert frame_kernel_of(auto, FakeGpu(90)) == "sweeps"      # in global memory: slower
    monkeypatch.undo()
    with pytest.raises(ValueError, match="threads must be 1 to 1024"):
        kernel("block", block_layout=BlockLayout(0))
    with pytest.raises(ValueError, match="must be integers"):
        kernel("block", block_layout=BlockLayout(32.0))
    with pytest.raises(ValueError, match=r"lanes must be one of \(1,\) on cpu"):
        kernel("block", block_layout=BlockLayout(32, lanes=4))
    with pytest.raises(ValueError, match="cluster_blocks must be 1 here"):   # no clusters on the CPU
        kernel("block", block_layout=BlockLayout(32, cluster_blocks=2))
    with pytest.raises(ValueError, match="block_layout applies"):
        kernel("sweeps", block_layout=BlockLayout(1))
    with pytest.raises(ValueError, match="frame_kernel"):
        SolverSettings(frame_kernel="graph")


def test_the_default_layout_fills_the_gpu_once():
    hopper = FakeGpu(90)
    # a block's threads: its run of vertices (48 of 757) times the lanes, in whole warps
    assert block_frame.default_layout(757, 1, hopper) == BlockLayout(384, 16, 8)   # a vertex a group
    assert block_frame.default_layout(1024, 1, hopper) == BlockLayout(512, 16, 8)
    assert block_frame.default_layout(1025, 1, hopper) == BlockLayout(288, 16, 4)  # 8 lanes would need 520
    assert block_frame.default_layout(block_frame.SHARED_VERTICES, 1, hopper) == BlockLayout(352, 16, 4)
    assert block_frame.default_layout(757, 3, hopper) == BlockLayout(384, 16, 8)   # 48 of 132 SMs
    assert block_frame.default_layout(757, 9, hopper) == BlockLayout(384, 8, 4)    # 95 x 4 = 380
    assert block_frame.default_layout(20, 1, hopper) == BlockLayout(32, 16, 8)
    assert block_frame.default_layout(757, 64, hopper) == BlockLayout(1024, 2, 4)
    assert block_frame.default_layout(757, 512, hopper) == BlockLayout(1024, 1, 4)
    assert block_frame.default_layout(757, 1, FakeGpu(120, 84)).cluster_blocks == 8   # portable size
    assert block_frame.default_layout(757, 1, FakeGpu(80)) == BlockLayout(768)         # no clusters
    assert block_frame.default_layout(3661, 1, hopper) == BlockLayout(1024)           # not in shared memory
    for layout in (BlockLayout(256, 16, 4), BlockLayout(1024, 1, 16)):
        assert block_frame.checked_layout(layout, hopper, 757) == layout
    with pytest.raises(ValueError, match="cluster_blocks must be 1 here"):
        block_frame.checked_layout(BlockLayout(256, 2, 4), FakeGpu(80), 757)
    with pytest.raises(ValueError, match="cluster_blocks must be 1 here"):
        block_frame.checked_layout(BlockLayout(256, 2, 4), hopper, 3661)
    with pytest.raises(ValueError, match="cluster_blocks must be 1 here"):
        block_frame.checked_layout(BlockLayout(256, 32, 4), hopper, 757)
    with pytest.raises(ValueError, match="divide the threads"):
        block_frame.checked_layout(BlockLayout(6, 1, 4), hopper, 757)
    assert BlockLayout.from_text("128x8x4") == BlockLayout(128, 8, 4) and str(BlockLayout(128, 8, 4)) == "128x8x4"
    assert BlockLayout.from_text("768") == BlockLayout(768)
    for bad in ("", "x", "128x-1", "1e3", "128x8x4x2", "128 x 8"):
        with pytest.raises(ValueError, match="THREADS"):
            BlockLayout.from_text(bad)


def nvrtc_compiles_for_hopper() -> bool:
    wp.init()
    from warp._src.context import runtime   # the archs Warp's bundled NVRTC targets (no public accessor)
    return 90 in (runtime.nvrtc_supported_archs or ())


@pytest.mark.skipif(not nvrtc_compiles_for_hopper(), reason="this Warp build has no NVRTC for sm_90")
@pytest.mark.parametrize("threads", [256, 1024])
def test_the_cluster_kernel_compiles_for_a_hopper_gpu_without_one(tmp_path, threads):
    """Warp's NVRTC compiles CUDA without a GPU: the cluster's inline PTX (remote stores counted on transaction
    barriers, cluster barriers) assembles for sm_90 (a cubin: ptxas ran), and the PTX asks for the layout's
    cluster and block size (what the launch relies on). At 1,024 threads a block Warp's own shared memory is
    largest: the positions' two buffers must still fit the 48 KB beside it (ptxas refuses the kernel otherwise)."""
    kernel = block_frame.frame_kernel(BlockLayout(threads, 16, 4), FakeGpu(90))
    cubin = wp.compile_aot_module(kernel.module, arch=90, module_dir=tmp_path / "cubin", use_ptx=False)
    assert len(cubin) == 1 and cubin[0].suffix == ".cubin" and cubin[0].stat().st_size > 0
    (ptx,) = wp.compile_aot_module(kernel.module, arch=90, module_dir=tmp_path / "ptx", use_ptx=True)
    text = ptx.read_text()
    assert ".reqnctapercluster 16, 1, 1" in text and f".maxntid {threads}, 1, 1" in text
    # a vertex's slot, to the blocks that read it, and a block's done token, to the blocks that send it positions
    assert text.count("st.async.shared::cluster.mbarrier::complete_tx::bytes.v4.b32") == 2
    assert "mbarrier.try_wait.parity" in text and "barrier.cluster.arrive.release" in text


# ---------------------------------------------------------------------------------------------------------------
# CUDA: one vertex a thread, several, one thread a block; clusters of blocks; one world and three


def cuda_clusters():
    return wp.get_cuda_device_count() and wp.get_device("cuda:0").arch >= 90


CLUSTERS = pytest.mark.skipif(not cuda_clusters(), reason="no CUDA device with thread block clusters")
# One block of a thread a vertex (the default without clusters), a warp, one thread; clusters of 2 to 16 blocks with
# 1 to 8 lanes a vertex (a block of 32 threads of 8 lanes: 4 vertices a block at a time).
LAYOUTS = [None, BlockLayout(32), BlockLayout(1)]
CLUSTER_LAYOUTS = [BlockLayout(256, 4, 4), BlockLayout(64, 2, 1), BlockLayout(32, 16, 8), BlockLayout(128, 8, 2)]


@CUDA
@pytest.mark.parametrize("layout", LAYOUTS + [pytest.param(c, marks=CLUSTERS) for c in CLUSTER_LAYOUTS])
@pytest.mark.parametrize("shared", [True, False])
def test_cuda_block_agrees_with_the_cpu(layout, shared, monkeypatch):
    if layout is not None and layout.cluster_blocks > 1 and not shared:
        pytest.skip("a cluster keeps its world in shared memory")
    if not shared:   # the sweeps' positions in global memory, as a world too large for shared memory has them
        monkeypatch.setattr(block_frame, "SHARED_VERTICES", 0)
    cpu, _ = contact_scene("cpu", frame_kernel="block")
    cuda, solver = contact_scene("cuda:0", frame_kernel="block", block_layout=layout)
    assert solver.frame_kernel == "block" and solver.block_shared == shared
    assert solver.block_layout == (layout or block_frame.default_layout(solver.world_vertices, 1, solver.device))
    close_to(cpu, cuda)
    again, _ = contact_scene("cuda:0", frame_kernel="block", block_layout=layout)
    np.testing.assert_array_equal(again, cuda)   # deterministic: integer atomics only, lists sorted
    sweeps, _ = contact_scene("cuda:0", 1, frame_kernel="sweeps")
    close_to(sweeps, cuda)


@CUDA
@pytest.mark.parametrize("layout", [None, BlockLayout(32), pytest.param(BlockLayout(128, 8, 4), marks=CLUSTERS)])
def test_cuda_worlds_of_pants_agree_with_the_cpu(pants_drives, layout):
    cpu, _ = pants_run(pants_drives, "block")
    cuda, solver = pants_run(pants_drives, "block", "cuda:0", block_layout=layout)
    assert solver.frame_kernel == "block"
    for w in range(len(MOTIONS)):
        close_to(cpu[w], cuda[w], early=3)   # karate amplifies a last bit sooner than the sheets do
    alone, _ = pants_run(pants_drives, "block", "cuda:0", worlds=slice(2, 3), block_layout=layout)
    np.testing.assert_array_equal(cuda[2], alone[0])


@CUDA
def test_cuda_folding_grid_agrees_with_the_cpu():
    cpu, _, _ = folding_run("block")
    cuda, solver, contacts = folding_run("block", "cuda:0")
    assert solver.frame_kernel == "block" and contacts > 0
    close_to(cpu, cuda)


@CUDA
def test_cuda_full_lists_grow_and_the_frame_is_stepped_again():
    small, solver = contact_scene("cuda:0", frame_kernel="block", contact_capacity=2)
    assert solver.frames_stepped_again >= 1
    roomy, _ = contact_scene("cuda:0", frame_kernel="block", contact_capacity=64)
    np.testing.assert_array_equal(small, roomy)


@CUDA
def test_auto_chooses_the_block_frame_where_clusters_serve():
    _, solver = contact_scene("cuda:0")
    assert solver.frame_kernel == ("block" if cuda_clusters() else "sweeps")
