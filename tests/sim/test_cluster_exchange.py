"""sim.xpbd.cluster_exchange: a cluster's block gets only the positions its vertices' sweeps read, so the marks must
cover every read. Checked without a GPU: after frames of stacked sheets over a moving capsule (constraints,
self-contact lists of both kinds and body contact all in use), the vertices are dealt to pretend blocks in runs, each
vertex's reads marked for its block, and one sweep (contact_sweep.solve_with_collisions) run per block with every
position its block does not read made NaN: the block's vertices must come out bit for bit as from the whole
positions. And each block's incoming count is the number of vertices marked for it, its senders the blocks whose
runs hold them, its receivers the blocks that read its run (the done tokens' partners)."""
import numpy as np
import warp as wp

from sim.xpbd import contact_sweep, kernels
from sim.xpbd.cluster_exchange import ClusterExchange, mark_sweep_reads, owner_block, vertices_a_block
from sim.xpbd.kernels import DistanceConstraints
from sim.xpbd.self_contact import SelfContacts
from tests.sim.cloth_checks import contact_scene

BLOCKS = 16   # a cluster's most


@wp.kernel
def mark_all(blocks: int, lanes: int, world_vertices: int, constraints: DistanceConstraints, sc: SelfContacts,
             exchange: ClusterExchange):
    """Vertex i's reads marked for its block (runs of consecutive vertices, as a cluster deals them), by each of its
    `lanes` lanes."""
    i, lane = kernels.lane_of(wp.tid(), lanes)
    mark_sweep_reads(i, 0, world_vertices, owner_block(i, 0, exchange), blocks, lane, lanes, constraints, sc,
                     exchange)


def one_sweep(solver, x_in: np.ndarray) -> np.ndarray:
    sweep = kernels.JacobiSweep()
    template = solver._sweeps[1]
    sweep.x_in = wp.array(x_in, dtype=wp.vec3, device="cpu")
    sweep.x_out = wp.zeros(len(x_in), dtype=wp.vec3, device="cpu")
    sweep.lambda_in, sweep.lambda_out = template.lambda_in, wp.zeros_like(template.lambda_out)
    sweep.lambda_carry, sweep.lambda_per_entry = template.lambda_carry, template.lambda_per_entry
    wp.launch(contact_sweep.solve_with_collisions, dim=len(x_in), device="cpu",
              inputs=[solver._substeps[-1], solver.constraints, sweep, solver.contacts, solver.capsules, 1])
    return sweep.x_out.numpy()


def test_a_blocks_marks_cover_every_position_its_sweeps_read():
    _, solver = contact_scene("cpu")
    n = solver.world_vertices
    sc = solver.contacts
    assert sc.vertex_count.numpy().sum() > 0 and sc.face_count.numpy().sum() > 0   # both kinds of list in use
    assert solver.capsules.near.numpy().any()                                       # and the body
    for lanes in (1, 4):
        exchange = ClusterExchange()
        exchange.readers = wp.zeros(n, dtype=int, device="cpu")
        exchange.incoming, exchange.senders, exchange.receivers = (wp.zeros(BLOCKS, dtype=int, device="cpu")
                                                                   for _ in range(3))
        exchange.per_block = vertices_a_block(n, BLOCKS)
        wp.launch(mark_all, dim=n * lanes, device="cpu", inputs=[BLOCKS, lanes, n, solver.constraints, sc, exchange])
        readers = exchange.readers.numpy()
        owner = np.arange(n) // -(-n // BLOCKS)
        assert owner[-1] == BLOCKS - 1                             # every block has a run
        x = solver.state.read_positions()
        whole = one_sweep(solver, x)
        for block in range(BLOCKS):
            read = (readers >> block) & 1 == 1
            assert exchange.incoming.numpy()[block] == read.sum()
            assert read.sum() < n                                  # something to save: not every vertex
            assert exchange.senders.numpy()[block] == np.bitwise_or.reduce(1 << np.unique(owner[read]))
            readers_of_run = np.bitwise_or.reduce(readers[owner == block])
            assert exchange.receivers.numpy()[block] == readers_of_run
            assert readers_of_run != (1 << BLOCKS) - 1             # a block waits for some blocks only
            poisoned = np.where(read[:, None], x, np.nan)
            mine = owner == block
            np.testing.assert_array_equal(one_sweep(solver, poisoned)[mine], whole[mine])
