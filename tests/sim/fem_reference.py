"""A second implementation of the stable Neo-Hookean energy and forces in numpy (float64, no eigensystem): what
the FEM tests hold the Warp kernels to."""
import numpy as np


def deformation_gradients(nodes: np.ndarray, rest: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T, 3, 3) F = Ds Dm^-1, columns of D the edges from corner 0."""
    Ds = np.transpose(nodes[tets[:, 1:]] - nodes[tets[:, :1]], (0, 2, 1))
    Dm = np.transpose(rest[tets[:, 1:]] - rest[tets[:, :1]], (0, 2, 1))
    return Ds @ np.linalg.inv(Dm)


def energy(nodes, rest, tets, mu, lam) -> float:
    F = deformation_gradients(nodes, rest, tets)
    J = np.linalg.det(F)
    Dm = np.transpose(rest[tets[:, 1:]] - rest[tets[:, :1]], (0, 2, 1))
    psi = 0.5 * mu * (np.einsum("tij,tij->t", F, F) - 3) - mu * (J - 1) + 0.5 * lam * (J - 1) ** 2
    return float((np.abs(np.linalg.det(Dm)) / 6 * psi).sum())


def gradient(nodes, rest, tets, mu, lam) -> np.ndarray:
    """dE/dx (N, 3): P = mu F + (lam (J - 1) - mu) J F^-T, node forces -V P Dm^-T."""
    F = deformation_gradients(nodes, rest, tets)
    J = np.linalg.det(F)
    P = mu * F + (lam * (J - 1) - mu)[:, None, None] * J[:, None, None] * np.transpose(np.linalg.inv(F), (0, 2, 1))
    Dm = np.transpose(rest[tets[:, 1:]] - rest[tets[:, :1]], (0, 2, 1))
    H = (np.abs(np.linalg.det(Dm)) / 6)[:, None, None] * P @ np.transpose(np.linalg.inv(Dm), (0, 2, 1))
    g = np.zeros_like(nodes)
    for a in range(3):
        np.add.at(g, tets[:, a + 1], H[:, :, a])
        np.add.at(g, tets[:, 0], -H[:, :, a])
    return g
