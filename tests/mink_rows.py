"""Comparing collision rows with mink's, which sum through the machine's BLAS.

mink's collision row is ``normal @ jac`` (``compute_contact_normal_jacobian``): numpy's matmul, so
OpenBLAS's dgemv, whose kernel OpenBLAS picks for the CPU. On an AMD EPYC with AVX-512 it takes the
SkylakeX kernel, which sums the three terms in another order than the Haswell and Zen kernels and
than our kernels (``ik_kernels.collision_rows``): at the first state of
``test_assembled_rows_are_the_limits_rows``, 5 of 390 entries were up to 7e-18 off (0.023040663744057138
against ...145); with ``OPENBLAS_CORETYPE=Haswell`` or ``Zen`` the same run is equal to the bit. So the
rows are compared to a few ulps of their largest possible entry (a unit normal times a lever arm under
2 m), everything else about them still to the bit.
"""

from __future__ import annotations

import numpy as np

COLLISION_ROW_ATOL = 4 * np.finfo(float).eps * 2.0


def assert_collision_rows_equal(actual: np.ndarray, desired: np.ndarray) -> None:
    """``actual`` is mink's collision rows ``desired`` up to the order the machine's BLAS sums them in:
    the same shape, the same non-finite entries, every value within COLLISION_ROW_ATOL."""
    actual, desired = np.asarray(actual), np.asarray(desired)
    assert actual.shape == desired.shape, (actual.shape, desired.shape)
    np.testing.assert_array_equal(np.isfinite(actual), np.isfinite(desired))
    np.testing.assert_allclose(actual, desired, rtol=0, atol=COLLISION_ROW_ATOL)
