"""Small dense linear algebra on covariance matrices, shared by the Kalman filters.

Symmetrising, testing and restoring positive definiteness at the precision floor, and
right division by an SPD matrix through its Cholesky factor (never an explicit inverse).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy.linalg.lapack import dpotrf

__all__ = [
    "HALF",
    "SYRK_IS_SYMMETRIC",
    "is_positive_definite",
    "repaired",
    "right_divide",
    "symmetrised",
]

HALF = np.array(0.5)  # a 0-d array multiplies faster than the Python float


def symmetrised(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2 as a new array."""
    P = P + P.T
    P *= HALF
    return P


def _syrk_is_symmetric() -> bool:
    """Whether numpy returns U^T U exactly symmetric (it calls BLAS syrk for a product with
    its own transpose); checked once, so the filter never relies on it blindly."""
    U = np.triu(np.arange(1.0, 37.0).reshape(6, 6) ** 0.5)
    product = U.T.dot(U)
    return bool(np.array_equal(product, product.T))


SYRK_IS_SYMMETRIC = _syrk_is_symmetric()


def is_positive_definite(P: np.ndarray) -> bool:
    """Whether a Cholesky factorisation of P succeeds (LAPACK dpotrf, ~0.4 us at n = 6)."""
    return dpotrf(P)[1] == 0


def repaired(P: np.ndarray) -> np.ndarray:
    """The nearest symmetric positive-definite matrix at the precision floor of P's scale.

    Rounding resolves a matrix only to about n eps ||P||; a covariance whose true
    eigenvalues span more than that (e.g. P0 = 1e12 I updated with R = 1e-12 I: 24 orders
    of magnitude) comes out of any covariance-form update with eigenvalues of either sign
    at the n eps ||P|| level. Raise the eigenvalues to that floor (x10 until a Cholesky
    factorisation succeeds): P grows by no more than the precision it could not resolve.
    """
    lam, V = np.linalg.eigh(P)
    if not np.all(np.isfinite(lam)):
        raise FloatingPointError("covariance is not finite")
    floor = P.shape[0] * np.finfo(float).eps * max(float(np.abs(lam).max()), 1e-300)
    for _ in range(16):
        candidate = symmetrised((V * np.maximum(lam, floor)) @ V.T)
        if is_positive_definite(candidate):
            return candidate
        floor *= 10.0
    raise np.linalg.LinAlgError("could not restore a positive-definite covariance")


def right_divide(B: np.ndarray, S: np.ndarray) -> np.ndarray:
    """B S^-1 for SPD S, by a Cholesky solve (raises LinAlgError if S is not PD)."""
    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(S), B.T).T
