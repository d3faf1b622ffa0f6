"""Symbolic phase: the block sparsity pattern of the implicit system, built once per model."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["BlockPattern"]


class BlockPattern:
    """Sorted, de-duplicated 3x3 block pattern (block CSR) over ``n`` block rows.

    Always contains the diagonal. Built from the (row, col) block coordinates that
    force terms can touch, so storage is proportional to the number of pairs.

    Attributes
    ----------
    n : int
        Block rows (free particles).
    indptr, indices : ndarray of int32/int64
        Block CSR structure.
    nnzb : int
        Number of stored 3x3 blocks.
    """

    def __init__(self, n: int, rows: np.ndarray, cols: np.ndarray):
        self.n = int(n)
        diag = np.arange(self.n, dtype=np.int64)
        keys = np.unique(np.concatenate([diag * self.n + diag,
                                         np.asarray(rows, np.int64) * self.n + np.asarray(cols, np.int64)]))
        self._keys = keys
        r = keys // max(self.n, 1)
        idx_dtype = np.int32 if keys.size < 2**31 and 3 * self.n < 2**31 else np.int64
        self.indices = (keys - r * self.n).astype(idx_dtype)
        self.indptr = np.zeros(self.n + 1, dtype=idx_dtype)
        np.cumsum(np.bincount(r, minlength=self.n), out=self.indptr[1:])
        self.nnzb = int(keys.size)
        self.diagonal_positions = self.locate(diag, diag)
        self._perm: dict[str, tuple] = {}

    def locate(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Position in the block data array of each block ``(rows[k], cols[k])`` (must be in the pattern)."""
        return np.searchsorted(self._keys, np.asarray(rows, np.int64) * self.n + np.asarray(cols, np.int64))

    def empty_bsr(self) -> sp.bsr_matrix:
        data = np.zeros((self.nnzb, 3, 3))
        return sp.bsr_matrix((data, self.indices, self.indptr), shape=(3 * self.n, 3 * self.n))

    def scalar_permutation(self, fmt: str):
        """``(perm, indices, indptr)`` so that a CSR/CSC matrix with this pattern has
        ``data = bsr.data.ravel()[perm]`` (computed once, then a single gather per conversion)."""
        if fmt not in self._perm:
            probe = sp.bsr_matrix((np.arange(1, 9 * self.nnzb + 1, dtype=np.float64).reshape(-1, 3, 3),
                                   self.indices, self.indptr), shape=(3 * self.n, 3 * self.n))
            m = probe.tocsr() if fmt == "csr" else probe.tocsc()
            m.sort_indices()
            self._perm[fmt] = (m.data.astype(np.int64) - 1, m.indices.copy(), m.indptr.copy())
        return self._perm[fmt]
