"""The network's input features of a frame in one Triton kernel (model.fused_features holds its tables and layout).

model.features computes them as PyTorch operations: ~150 kernels a frame for the garments' body-relative inputs
(velocity, body, Laplacian, gravity in local frames), each a few microseconds even replayed in a CUDA graph, ~1 ms
in all on an H100: more than the fused network they feed. Here one program handles BLOCK vertices of one frame:
its normal from the incident faces (a corner table, (V, F, 2): the two vertices after it in each face), its
Laplacian from its neighbours ((V, N) table), its local frame, and the nearest of the body's capsules in a loop
over them, and writes the stacked features (B, V, C) and, where the output is local, the frames (B, V, 9), rows
tangent, bitangent, normal. Same formulas and case splits as model.features and model.local_frames; the sums
run in another order (a vertex's faces in table order instead of atomic adds), so results agree to rounding.

The launcher is a custom operator (`torch.library.triton_op`, learned_cloth::features), like model.triton_conv's:
torch.export keeps it as one operator, defined in an export by a copy of this module. Set TRITON_INTERPRET=1 before importing
this module to run it on the CPU with Triton's interpreter (the tests do).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch.library import triton_op, wrap_triton

from model.local_frames import EDGE_TIE_BREAK as _TIE_BREAK
from model.triton_conv import NAMESPACE

BLOCK = 128
EPS = tl.constexpr(1e-12)                   # the floor of a norm divided by, as model.features' and local_frames'
EDGE_TIE_BREAK = tl.constexpr(_TIE_BREAK)   # (a kernel reads only constexpr globals)


@triton.jit
def _load3(ptr, index, mask):
    return (tl.load(ptr + index * 3, mask=mask, other=0.0), tl.load(ptr + index * 3 + 1, mask=mask, other=0.0),
            tl.load(ptr + index * 3 + 2, mask=mask, other=0.0))


@triton.jit
def _unit(x, y, z):
    inverse = 1.0 / tl.maximum(tl.sqrt(x * x + y * y + z * z), EPS)
    return x * inverse, y * inverse, z * inverse


@triton.jit
def _unit_tangent(x, y, z, nx, ny, nz):
    along = x * nx + y * ny + z * nz
    return _unit(x - along * nx, y - along * ny, z - along * nz)


@triton.jit
def _store3(out_ptr, row_base, offset: tl.constexpr, x, y, z, mask):
    tl.store(out_ptr + row_base + offset, x, mask=mask)
    tl.store(out_ptr + row_base + offset + 1, y, mask=mask)
    tl.store(out_ptr + row_base + offset + 2, z, mask=mask)


@triton.jit
def _store_vector(out_ptr, row_base, offset: tl.constexpr, x, y, z, mask, LOCAL: tl.constexpr,
                  tx, ty, tz, bx, by, bz, nx, ny, nz):
    """A vector feature at `offset`, in each vertex's frame where LOCAL (model.local_frames.to_local)."""
    if LOCAL:
        _store3(out_ptr, row_base, offset, tx * x + ty * y + tz * z, bx * x + by * y + bz * z,
                nx * x + ny * y + nz * z, mask)
    else:
        _store3(out_ptr, row_base, offset, x, y, z, mask)


@triton.jit
def _features_kernel(out_ptr, frames_ptr, x_ptr, prev_ptr, before_ptr, rest_ptr, a_ptr, b_ptr, ra_ptr, rb_ptr,
                     gravity_ptr, frame_time_ptr, corners_ptr, neighbours_ptr, valence_ptr, reference_ptr,
                     n_vertices, n_capsules, F: tl.constexpr, N: tl.constexpr, C: tl.constexpr,
                     POSITION: tl.constexpr, REST: tl.constexpr, NORMAL: tl.constexpr, LAPLACIAN: tl.constexpr,
                     VELOCITY: tl.constexpr, ACCELERATION: tl.constexpr, BODY: tl.constexpr,
                     GRAVITY: tl.constexpr, LOCAL: tl.constexpr, FRAMES: tl.constexpr, NEED_FRAMES: tl.constexpr,
                     GRAVITY_TANGENT: tl.constexpr, BLOCK_V: tl.constexpr):
    """POSITION ... GRAVITY: each feature's channel offset in the output, -1 where absent. LOCAL: vector inputs
    in the local frames; FRAMES: the frames written out; NEED_FRAMES: either."""
    frame = tl.program_id(1).to(tl.int64)
    rows = tl.program_id(0) * BLOCK_V + tl.arange(0, BLOCK_V)
    ok = rows < n_vertices
    rows = tl.where(ok, rows, 0).to(tl.int64)
    x_frame = x_ptr + frame * n_vertices * 3
    px, py, pz = _load3(x_frame, rows, ok)
    row_base = (frame * n_vertices + rows) * C

    nx = tl.zeros([BLOCK_V], tl.float32)
    ny = tl.zeros([BLOCK_V], tl.float32)
    nz = tl.zeros([BLOCK_V], tl.float32)
    if NEED_FRAMES or NORMAL >= 0:        # area-weighted normal: each incident face's cross product, summed
        for k in range(F):
            first = tl.load(corners_ptr + (rows * F + k) * 2, mask=ok, other=-1)
            second = tl.load(corners_ptr + (rows * F + k) * 2 + 1, mask=ok, other=-1)
            real = first >= 0
            fx, fy, fz = _load3(x_frame, tl.maximum(first, 0).to(tl.int64), real)
            gx, gy, gz = _load3(x_frame, tl.maximum(second, 0).to(tl.int64), real)
            fx, fy, fz, gx, gy, gz = fx - px, fy - py, fz - pz, gx - px, gy - py, gz - pz
            nx += tl.where(real, fy * gz - fz * gy, 0.0)
            ny += tl.where(real, fz * gx - fx * gz, 0.0)
            nz += tl.where(real, fx * gy - fy * gx, 0.0)
        nx, ny, nz = _unit(nx, ny, nz)

    tx, ty, tz = nx, ny, nz           # (placeholders where no frame is asked for: never stored)
    bx, by, bz = nx, ny, nz
    if NEED_FRAMES:
        reference = tl.load(reference_ptr + rows, mask=ok, other=0).to(tl.int64)
        rx, ry, rz = _load3(x_frame, reference, ok)
        tx, ty, tz = _unit_tangent(rx - px, ry - py, rz - pz, nx, ny, nz)
        if GRAVITY_TANGENT:
            gx, gy, gz = _unit(tl.load(gravity_ptr + frame * 3), tl.load(gravity_ptr + frame * 3 + 1),
                               tl.load(gravity_ptr + frame * 3 + 2))
            hx, hy, hz = _unit_tangent(gx + px * 0.0, gy + py * 0.0, gz + pz * 0.0, nx, ny, nz)
            tx, ty, tz = _unit(hx + EDGE_TIE_BREAK * tx, hy + EDGE_TIE_BREAK * ty, hz + EDGE_TIE_BREAK * tz)
        bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
        if FRAMES:
            frame_base = (frame * n_vertices + rows) * 9
            _store3(frames_ptr, frame_base, 0, tx, ty, tz, ok)
            _store3(frames_ptr, frame_base, 3, bx, by, bz, ok)
            _store3(frames_ptr, frame_base, 6, nx, ny, nz, ok)

    if POSITION >= 0:
        _store_vector(out_ptr, row_base, POSITION, px, py, pz, ok, LOCAL, tx, ty, tz, bx, by, bz, nx, ny, nz)
    if REST >= 0:                     # material coordinates: never turned into the local frame
        sx, sy, sz = _load3(rest_ptr, rows, ok)
        _store3(out_ptr, row_base, REST, sx, sy, sz, ok)
    if NORMAL >= 0:                   # (refused in local frames, where it would read (0, 0, 1))
        _store3(out_ptr, row_base, NORMAL, nx, ny, nz, ok)
    if LAPLACIAN >= 0:
        lx = tl.zeros([BLOCK_V], tl.float32)
        ly = tl.zeros([BLOCK_V], tl.float32)
        lz = tl.zeros([BLOCK_V], tl.float32)
        for k in range(N):
            other = tl.load(neighbours_ptr + rows * N + k, mask=ok, other=-1)
            ox, oy, oz = _load3(x_frame, tl.maximum(other, 0).to(tl.int64), other >= 0)
            lx += ox
            ly += oy
            lz += oz
        valence = tl.load(valence_ptr + rows, mask=ok, other=1.0)
        _store_vector(out_ptr, row_base, LAPLACIAN, lx / valence - px, ly / valence - py, lz / valence - pz, ok,
                      LOCAL, tx, ty, tz, bx, by, bz, nx, ny, nz)
    if VELOCITY >= 0 or ACCELERATION >= 0:
        frame_time = tl.load(frame_time_ptr)
        qx, qy, qz = _load3(prev_ptr + frame * n_vertices * 3, rows, ok)
        if VELOCITY >= 0:
            _store_vector(out_ptr, row_base, VELOCITY, (px - qx) / frame_time, (py - qy) / frame_time,
                          (pz - qz) / frame_time, ok, LOCAL, tx, ty, tz, bx, by, bz, nx, ny, nz)
        if ACCELERATION >= 0:
            ux, uy, uz = _load3(before_ptr + frame * n_vertices * 3, rows, ok)
            squared = frame_time * frame_time
            _store_vector(out_ptr, row_base, ACCELERATION, (px - 2.0 * qx + ux) / squared,
                          (py - 2.0 * qy + uy) / squared, (pz - 2.0 * qz + uz) / squared, ok, LOCAL,
                          tx, ty, tz, bx, by, bz, nx, ny, nz)
    if GRAVITY >= 0:
        gx = tl.load(gravity_ptr + frame * 3) + px * 0.0
        gy = tl.load(gravity_ptr + frame * 3 + 1) + py * 0.0
        gz = tl.load(gravity_ptr + frame * 3 + 2) + pz * 0.0
        _store_vector(out_ptr, row_base, GRAVITY, gx, gy, gz, ok, LOCAL, tx, ty, tz, bx, by, bz, nx, ny, nz)
    if BODY >= 0:                     # the nearest tapered capsule (model.features.capsule_distances' cases)
        best = tl.full([BLOCK_V], float("inf"), tl.float32)
        dx = tl.zeros([BLOCK_V], tl.float32)
        dy = tl.zeros([BLOCK_V], tl.float32)
        dz = tl.zeros([BLOCK_V], tl.float32)
        for capsule in range(n_capsules):     # (names of its own: a loop's variables keep one type)
            end = (frame * n_capsules + capsule) * 3
            ca_x, ca_y, ca_z = tl.load(a_ptr + end), tl.load(a_ptr + end + 1), tl.load(a_ptr + end + 2)
            axis_x = tl.load(b_ptr + end) - ca_x
            axis_y = tl.load(b_ptr + end + 1) - ca_y
            axis_z = tl.load(b_ptr + end + 2) - ca_z
            radius_a, radius_b = tl.load(ra_ptr + capsule), tl.load(rb_ptr + capsule)
            length = tl.sqrt(axis_x * axis_x + axis_y * axis_y + axis_z * axis_z)
            unit_x, unit_y, unit_z = axis_x / length, axis_y / length, axis_z / length
            sin_phi = (radius_a - radius_b) / length
            cos_phi = tl.sqrt(1.0 - sin_phi * sin_phi)
            rel_x, rel_y, rel_z = px - ca_x, py - ca_y, pz - ca_z
            s = rel_x * unit_x + rel_y * unit_y + rel_z * unit_z
            rad_x, rad_y, rad_z = rel_x - s * unit_x, rel_y - s * unit_y, rel_z - s * unit_z
            q = tl.sqrt(rad_x * rad_x + rad_y * rad_y + rad_z * rad_z)
            inverse_q = 1.0 / tl.maximum(q, EPS)
            along = s * cos_phi - q * sin_phi
            relb_x, relb_y, relb_z = rel_x - axis_x, rel_y - axis_y, rel_z - axis_z
            to_a = tl.sqrt(rel_x * rel_x + rel_y * rel_y + rel_z * rel_z)
            to_b = tl.sqrt(relb_x * relb_x + relb_y * relb_y + relb_z * relb_z)
            near_a = along <= 0.0
            near_b = along >= length * cos_phi
            distance = tl.where(near_a, to_a - radius_a,
                                tl.where(near_b, to_b - radius_b, s * sin_phi + q * cos_phi - radius_a))
            inverse_a, inverse_b = 1.0 / tl.maximum(to_a, EPS), 1.0 / tl.maximum(to_b, EPS)
            cx = tl.where(near_a, rel_x * inverse_a, tl.where(near_b, relb_x * inverse_b,
                                                               sin_phi * unit_x + cos_phi * rad_x * inverse_q))
            cy = tl.where(near_a, rel_y * inverse_a, tl.where(near_b, relb_y * inverse_b,
                                                               sin_phi * unit_y + cos_phi * rad_y * inverse_q))
            cz = tl.where(near_a, rel_z * inverse_a, tl.where(near_b, relb_z * inverse_b,
                                                               sin_phi * unit_z + cos_phi * rad_z * inverse_q))
            closer = distance < best          # the first of equal distances, as torch.min
            best = tl.where(closer, distance, best)
            dx, dy, dz = tl.where(closer, cx, dx), tl.where(closer, cy, dy), tl.where(closer, cz, dz)
        tl.store(out_ptr + row_base + BODY, best, mask=ok)
        _store_vector(out_ptr, row_base, BODY + 1, dx, dy, dz, ok, LOCAL, tx, ty, tz, bx, by, bz, nx, ny, nz)


@triton_op(f"{NAMESPACE}::features", mutates_args=())
def features(positions: torch.Tensor, previous: torch.Tensor | None, before_previous: torch.Tensor | None,
             rest: torch.Tensor, capsule_a: torch.Tensor | None, capsule_b: torch.Tensor | None,
             radius_a: torch.Tensor | None, radius_b: torch.Tensor | None, gravity: torch.Tensor | None,
             frame_time: torch.Tensor | None, corners: torch.Tensor, neighbours: torch.Tensor,
             valence: torch.Tensor, reference: torch.Tensor, layout: list[int], local_inputs: bool,
             frames_out: bool, gravity_tangent: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The stacked features (B, V, C) fp32 of `positions` (B, V, 3) and the frames (B, V, 9) where `frames_out`
    (else an empty tensor). `layout`: the channel offsets of position, rest_position, normal, laplacian,
    velocity, acceleration, body and gravity (-1: absent), then C. Inputs a feature does not read may be None."""
    batch, n_vertices = positions.shape[:2]
    out = positions.new_empty(batch, n_vertices, layout[-1])
    frames = positions.new_empty(batch, n_vertices, 9) if frames_out else positions.new_empty(0)
    # A pointer the kernel never follows (its feature absent, or no frames written) is given a real tensor's.
    pick = lambda tensor: positions if tensor is None else tensor      # noqa: E731
    grid = (triton.cdiv(n_vertices, BLOCK), batch)
    wrap_triton(_features_kernel)[grid](
        out, frames if frames_out else out, positions, pick(previous), pick(before_previous), rest,
        pick(capsule_a), pick(capsule_b), pick(radius_a), pick(radius_b), pick(gravity), pick(frame_time), corners,
        neighbours, valence, reference, n_vertices, 0 if capsule_a is None else capsule_a.shape[1],
        F=corners.shape[1], N=neighbours.shape[1], C=layout[-1], POSITION=layout[0], REST=layout[1],
        NORMAL=layout[2], LAPLACIAN=layout[3], VELOCITY=layout[4], ACCELERATION=layout[5], BODY=layout[6],
        GRAVITY=layout[7], LOCAL=local_inputs, FRAMES=frames_out, NEED_FRAMES=local_inputs or frames_out,
        GRAVITY_TANGENT=gravity_tangent, BLOCK_V=BLOCK, num_warps=4)
    return out, frames
