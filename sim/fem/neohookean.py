"""The stable Neo-Hookean energy density (Smith, de Goes, Kim 2018) and its Hessian's analytic eigensystem (Smith,
Kim, de Goes 2019; Kim and Eberle 2022, sec. 7.3), as Warp functions in float64.

    Psi(F) = mu/2 (I_C - 3) - mu (J - 1) + lambda/2 (J - 1)^2,   I_C = |F|^2,  J = det F

is zero with zero stress at rest and under any rotation, and finite for every F, inverted or flat included (no
log J), which is why a Newton step that inverts an element on its way does no harm. Its Hessian dP/dF (9 x 9) has
a closed-form eigensystem in the rotation-variant SVD F = U diag(sigma) V^T (U, V rotations, sigma_2 carrying the
sign of J): for each plane (i, j), with k the third axis, a twist U (e_i e_j^T - e_j e_i^T) V^T / sqrt 2 of
eigenvalue mu + s sigma_k and a flip U (e_i e_j^T + e_j e_i^T) V^T / sqrt 2 of eigenvalue mu - s sigma_k,
s = lambda (J - 1) - mu; and three scalings U diag(q) V^T, q an eigenvector of the 3 x 3 matrix
A = mu I + lambda c c^T + s [[0, s_z, s_y], [s_z, 0, s_x], [s_y, s_x, 0]], c = (s_y s_z, s_x s_z, s_x s_y). Clamping
the negative eigenvalues at zero gives the nearest positive semi-definite Hessian, the one projected Newton uses.
"""
from __future__ import annotations

import warp as wp

vec9d = wp.types.vector(length=9, dtype=wp.float64)
mat99d = wp.types.matrix(shape=(9, 9), dtype=wp.float64)

INV_SQRT2 = wp.constant(wp.float64(0.7071067811865476))


@wp.func
def cofactor(F: wp.mat33d):
    """dJ/dF: column j is the cross product of F's other two columns (no inverse: defined for singular F)."""
    f0 = wp.vec3d(F[0, 0], F[1, 0], F[2, 0])
    f1 = wp.vec3d(F[0, 1], F[1, 1], F[2, 1])
    f2 = wp.vec3d(F[0, 2], F[1, 2], F[2, 2])
    c0 = wp.cross(f1, f2)
    c1 = wp.cross(f2, f0)
    c2 = wp.cross(f0, f1)
    return wp.mat33d(c0[0], c1[0], c2[0], c0[1], c1[1], c2[1], c0[2], c1[2], c2[2])


@wp.func
def energy_density(F: wp.mat33d, mu: wp.float64, lam: wp.float64):
    J = wp.determinant(F)
    ic = wp.ddot(F, F)
    one = wp.float64(1.0)
    half = wp.float64(0.5)
    return half * mu * (ic - wp.float64(3.0)) - mu * (J - one) + half * lam * (J - one) * (J - one)


@wp.func
def stress(F: wp.mat33d, mu: wp.float64, lam: wp.float64):
    """First Piola-Kirchhoff stress dPsi/dF = mu F + (lambda (J - 1) - mu) cof(F)."""
    J = wp.determinant(F)
    return mu * F + (lam * (J - wp.float64(1.0)) - mu) * cofactor(F)


@wp.func
def flatten(M: wp.mat33d):
    """Row-major: entry 3 r + c is M[r, c]."""
    return vec9d(M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2], M[2, 0], M[2, 1], M[2, 2])


@wp.func
def unit_pair(i: int, j: int, sign: wp.float64):
    """(e_i e_j^T + sign e_j e_i^T) / sqrt 2."""
    M = wp.mat33d()
    M[i, j] = INV_SQRT2
    M[j, i] = sign * INV_SQRT2
    return M


@wp.func
def stress_derivative(F: wp.mat33d, mu: wp.float64, lam: wp.float64, project: bool):
    """dP/dF as a 9 x 9 matrix (row-major flattening of both), from its eigensystem; with `project`, negative
    eigenvalues are clamped at zero."""
    U = wp.mat33d()
    sigma = wp.vec3d()
    V = wp.mat33d()
    wp.svd3(F, U, sigma, V)
    # Rotation-variant SVD: reflections moved into the smallest singular value, so J = s_x s_y s_z.
    one = wp.float64(1.0)
    if wp.determinant(U) < wp.float64(0.0):
        U = U * wp.diag(wp.vec3d(one, one, -one))
        sigma = wp.vec3d(sigma[0], sigma[1], -sigma[2])
    if wp.determinant(V) < wp.float64(0.0):
        V = V * wp.diag(wp.vec3d(one, one, -one))
        sigma = wp.vec3d(sigma[0], sigma[1], -sigma[2])
    J = sigma[0] * sigma[1] * sigma[2]
    s = lam * (J - one) - mu
    Vt = wp.transpose(V)
    H = mat99d()
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        twist = mu + s * sigma[k]
        flip = mu - s * sigma[k]
        if project:
            twist = wp.max(twist, wp.float64(0.0))
            flip = wp.max(flip, wp.float64(0.0))
        t = flatten(U * unit_pair(i, j, -one) * Vt)
        f = flatten(U * unit_pair(i, j, one) * Vt)
        H += twist * wp.outer(t, t) + flip * wp.outer(f, f)
    c = wp.vec3d(sigma[1] * sigma[2], sigma[0] * sigma[2], sigma[0] * sigma[1])
    A = mu * wp.identity(n=3, dtype=wp.float64) + lam * wp.outer(c, c) + s * wp.mat33d(
        wp.float64(0.0), sigma[2], sigma[1], sigma[2], wp.float64(0.0), sigma[0], sigma[1], sigma[0],
        wp.float64(0.0))
    Q = wp.mat33d()
    a = wp.vec3d()
    wp.eig3(A, Q, a)
    for m in range(3):
        value = a[m]
        if project:
            value = wp.max(value, wp.float64(0.0))
        e = flatten(U * wp.diag(wp.vec3d(Q[0, m], Q[1, m], Q[2, m])) * Vt)
        H += value * wp.outer(e, e)
    return H
