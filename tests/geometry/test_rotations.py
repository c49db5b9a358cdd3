"""Quaternion helpers against scipy."""
import numpy as np
from scipy.spatial.transform import Rotation

from geometry.rotations import quat_canonical, quat_multiply, quat_rotate, quat_to_matrix


def test_quaternion_helpers_match_scipy():
    rng = np.random.default_rng(0)
    q, r = Rotation.random(50, random_state=1), Rotation.random(50, random_state=2)
    v = rng.normal(size=(50, 3))
    np.testing.assert_allclose(quat_rotate(q.as_quat(), v), q.apply(v), atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q.as_quat()), q.as_matrix(), atol=1e-12)
    product = quat_canonical(quat_multiply(q.as_quat(), r.as_quat()))
    np.testing.assert_allclose(product, quat_canonical((q * r).as_quat()), atol=1e-12)
    assert (quat_canonical(-q.as_quat())[:, 3] >= 0).all()
