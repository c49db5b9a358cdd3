"""Array reads for the Jacobi sweeps' inner loops, cheaper than Warp's indexing on a GPU.

Warp's `a[i]` wraps a negative index (a compare and an add of the array's length) and multiplies the index by the
stride in 64 bits: ~8 instructions before each load. And a vector element is read a float at a time, as Warp's
vectors are 4-byte aligned. A sweep's gather is a chain of such reads: an entry, then its constraint, its other
end's position and mass. So those instructions lie on the sweep's critical path; they were ~40 of the ~115
instructions an entry of `kernels.distance_correction` (sm_90 SASS).

`fetch(a, i)` is a[i] for 0 <= i < len(a), one multiply-add into the address. On CUDA a vec4 or vec2i element is
one 16- or 8-byte load, and so is a vec3 in a 16-byte slot (the block frame's shared positions). That needs
elements aligned to their size, as arrays the solver allocates are. Same values as a[i]: on the CPU, and wherever a
result is compared bit for bit, nothing changes but the instructions.
"""
from __future__ import annotations

import warp as wp

# a[i]'s address: the index times the stride, in 32 bits unsigned before the 64-bit add (i >= 0, and i * stride
# < 4 GiB: a float array of a billion entries)
_ADDRESS = "(reinterpret_cast<char*>(arr.data) + (unsigned)i * (unsigned)arr.strides[0])"


@wp.func_native("return *reinterpret_cast<float*>" + _ADDRESS + ";")
def fetch(arr: wp.array(dtype=float), i: int) -> float: ...


@wp.func_native("return *reinterpret_cast<int*>" + _ADDRESS + ";")
def fetch(arr: wp.array(dtype=int), i: int) -> int: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    if (arr.strides[0] == 16) {
        const float4 v = *reinterpret_cast<const float4*>""" + _ADDRESS + """;
        return wp::vec3(v.x, v.y, v.z);
    }
#endif
    return *reinterpret_cast<wp::vec3*>""" + _ADDRESS + """;
""")
def fetch(arr: wp.array(dtype=wp.vec3), i: int) -> wp.vec3: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    const float4 v = *reinterpret_cast<const float4*>""" + _ADDRESS + """;
    return wp::vec4(v.x, v.y, v.z, v.w);
#else
    return *reinterpret_cast<wp::vec4*>""" + _ADDRESS + """;
#endif
""")
def fetch(arr: wp.array(dtype=wp.vec4), i: int) -> wp.vec4: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    const int2 v = *reinterpret_cast<const int2*>""" + _ADDRESS + """;
    return wp::vec2i(v.x, v.y);
#else
    return *reinterpret_cast<wp::vec2i*>""" + _ADDRESS + """;
#endif
""")
def fetch(arr: wp.array(dtype=wp.vec2i), i: int) -> wp.vec2i: ...


@wp.func_native("return *reinterpret_cast<wp::vec3i*>" + _ADDRESS + ";")
def fetch(arr: wp.array(dtype=wp.vec3i), i: int) -> wp.vec3i: ...
