"""Symbolic phase: the block sparsity pattern of the implicit system, built once per model."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["BlockPattern"]


class BlockPattern:
    """Sorted, de-duplicated 3x3 block pattern (block CSR) over ``n`` block rows.

    Always contains the diagonal. Built from the (row, col) block coordinates that
    force terms can touch, so storage is proportional to the number of pairs.

    Parameters
    ----------
    n : int
        Block rows (free particles).
    rows, cols : array_like of int, shape (k,)
        Block coordinates the force terms touch (duplicates allowed); the diagonal is added.

    Attributes
    ----------
    n : int
        Block rows (free particles).
    indptr, indices : ndarray of int32/int64
        Block CSR structure.
    nnzb : int
        Number of stored 3x3 blocks.
    diagonal_positions : ndarray of int64, shape (n,)
        Position of each diagonal block in the block data array.
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
        """Position in the block data array of each block ``(rows[k], cols[k])`` (must be in the pattern).

        Parameters
        ----------
        rows, cols : array_like of int, shape (k,)
            Block coordinates; a block outside the pattern gives a wrong position, it is not checked.

        Returns
        -------
        ndarray of int64, shape (k,)
        """
        return np.searchsorted(self._keys, np.asarray(rows, np.int64) * self.n + np.asarray(cols, np.int64))

    def empty_bsr(self) -> sp.bsr_matrix:
        """A BSR matrix of this pattern with zero blocks (its ``data`` is filled by the assembler).

        Returns
        -------
        scipy.sparse.bsr_matrix, shape (3n, 3n)
            Blocksize (3, 3), ``data`` of shape (nnzb, 3, 3).
        """
        data = np.zeros((self.nnzb, 3, 3))
        return sp.bsr_matrix((data, self.indices, self.indptr), shape=(3 * self.n, 3 * self.n))

    def scalar_permutation(self, fmt: str):
        """``(perm, indices, indptr)`` so that a CSR/CSC matrix with this pattern has
        ``data = bsr.data.ravel()[perm]`` (computed once, then a single gather per conversion).

        Parameters
        ----------
        fmt : {"csr", "csc"}
            The scalar format.

        Returns
        -------
        perm : ndarray of int64, shape (9 nnzb,)
            Gather from the flattened block data.
        indices, indptr : ndarray
            The scalar matrix's structure (sorted indices).
        """
        if fmt not in self._perm:
            probe = sp.bsr_matrix((np.arange(1, 9 * self.nnzb + 1, dtype=np.float64).reshape(-1, 3, 3),
                                   self.indices, self.indptr), shape=(3 * self.n, 3 * self.n))
            m = probe.tocsr() if fmt == "csr" else probe.tocsc()
            m.sort_indices()
            self._perm[fmt] = (m.data.astype(np.int64) - 1, m.indices.copy(), m.indptr.copy())
        return self._perm[fmt]
