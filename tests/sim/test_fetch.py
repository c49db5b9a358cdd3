"""sim.xpbd.fetch: the sweeps' array reads give what Warp's indexing gives, for every element type they serve, on a
contiguous array and on a strided view (the block frame's positions are vec3 in 16-byte slots, one 16-byte load on
CUDA), on the CPU and, where there is one, on a GPU. The reference is numpy's indexing of the same data."""
import numpy as np
import pytest
import warp as wp

from sim.xpbd.fetch import fetch

DEVICES = ["cpu"] + (["cuda:0"] if wp.get_cuda_device_count() else [])


@wp.kernel
def read_all(ids: wp.array(dtype=int), f: wp.array(dtype=float), n: wp.array(dtype=int), v3: wp.array(dtype=wp.vec3),
             v4: wp.array(dtype=wp.vec4), v2i: wp.array(dtype=wp.vec2i), v3i: wp.array(dtype=wp.vec3i),
             out_f: wp.array(dtype=float), out_n: wp.array(dtype=int), out_v3: wp.array(dtype=wp.vec3),
             out_v4: wp.array(dtype=wp.vec4), out_v2i: wp.array(dtype=wp.vec2i), out_v3i: wp.array(dtype=wp.vec3i)):
    k = wp.tid()
    i = ids[k]
    out_f[k] = fetch(f, i)
    out_n[k] = fetch(n, i)
    out_v3[k] = fetch(v3, i)
    out_v4[k] = fetch(v4, i)
    out_v2i[k] = fetch(v2i, i)
    out_v3i[k] = fetch(v3i, i)


def slotted_vec3(values: np.ndarray, device: str) -> tuple[wp.array, wp.array]:
    """values (n, 3) as a vec3 view with a 16-byte stride over an (n, 4) array (its owner, kept alive)."""
    padded = np.concatenate([values, np.full((len(values), 1), np.nan, np.float32)], axis=1)
    owner = wp.array(padded, dtype=wp.vec4, device=device)
    view = wp.array(ptr=owner.ptr, shape=(len(values),), strides=(16,), dtype=wp.vec3, device=device)
    return owner, view


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("slotted", [False, True])
def test_fetch_reads_what_indexing_reads(device, slotted):
    rng = np.random.default_rng(7)
    n = 1000
    f = rng.standard_normal(n).astype(np.float32)
    ints = rng.integers(-2**31, 2**31 - 1, size=n, dtype=np.int64).astype(np.int32)
    v3 = rng.standard_normal((n, 3)).astype(np.float32)
    v4 = rng.standard_normal((n, 4)).astype(np.float32)
    v2i = rng.integers(-1000, 1000, size=(n, 2)).astype(np.int32)
    v3i = rng.integers(-1000, 1000, size=(n, 3)).astype(np.int32)
    ids = np.concatenate([[0, n - 1], rng.integers(0, n, size=300)]).astype(np.int32)
    owner, v3_arr = slotted_vec3(v3, device) if slotted else (None, wp.array(v3, dtype=wp.vec3, device=device))
    outs = [wp.zeros(len(ids), dtype=t, device=device) for t in (float, int, wp.vec3, wp.vec4, wp.vec2i, wp.vec3i)]
    wp.launch(read_all, dim=len(ids), device=device,
              inputs=[wp.array(ids, dtype=int, device=device), wp.array(f, dtype=float, device=device),
                      wp.array(ints, dtype=int, device=device), v3_arr, wp.array(v4, dtype=wp.vec4, device=device),
                      wp.array(v2i, dtype=wp.vec2i, device=device), wp.array(v3i, dtype=wp.vec3i, device=device),
                      *outs])
    for out, ref in zip(outs, (f, ints, v3, v4, v2i, v3i)):
        np.testing.assert_array_equal(out.numpy(), ref[ids])
