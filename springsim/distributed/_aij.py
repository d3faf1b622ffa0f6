"""Direct access to a PETSc AIJ (or BAIJ) matrix's value arrays: the local block matrix's insertion
(:class:`DirectInsertion`) and the owned rows of a known pattern (:class:`AIJValues`).

``MatSetValuesBlockedLocalCSR`` finds every scalar entry's place in its row by a search, one 3x3 block at a
time, and sends the ghost rows through PETSc's stash; on the benchmark cloth (n = 256, one rank) that insertion
cost more than the assembly of the local matrix itself. The local pattern never changes, so the place of every
entry of the owned rows can be computed once: :class:`DirectInsertion` gathers the owned rows' values straight
into the arrays of the diagonal and off-diagonal ``SeqAIJ`` blocks (``MatSeqAIJGetArray``, through ctypes: not
in petsc4py 3.18) and leaves only the ghost rows to ``MatSetValuesBlockedLocal`` and the assembly.

The places come from the block pattern the matrix was preallocated with (every entry present, columns sorted),
split between the two blocks the way ``MATMPIAIJ`` stores them: the columns the rank owns in the diagonal block,
the others in the off-diagonal one in increasing global column (its compressed columns follow the sorted ghost
columns); each scalar row holds its blocks' three columns in that order. Only block-level arrays and one gather
index per owned entry are built. The caller checks the first insertion against PETSc's own
(:meth:`DirectInsertion.matches`) and keeps PETSc's path where they differ. Before writing, ``MatZeroEntries``
zeroes the arrays and, as for any change of values, invalidates the blocks' cached inverse diagonals that SOR
keeps.
"""

from __future__ import annotations

import ctypes

import numpy as np

__all__ = ["AIJValues", "DirectInsertion", "petsc_library", "reproduces"]

#: Blocks per chunk while the gather indices are built (the temporaries stay at a few MB).
_CHUNK = 1 << 16
#: Entries per chunk of :class:`AIJValues`' gathers and scatters (numpy converts int32 indices to a temporary intp
#: array: a chunk's, a few MB, rather than the whole pattern's).
_GATHER = 1 << 20


def petsc_library():
    """The PETSc shared library petsc4py is linked to (found among the process's mappings)."""
    with open("/proc/self/maps") as fh:
        paths = {line.split()[-1] for line in fh if "libpetsc" in line and ".so" in line}
    if not paths:
        raise OSError("PETSc's shared library is not mapped")
    return ctypes.CDLL(sorted(paths)[0])


def _seq_blocks(PETSc, lib, A) -> list:
    """The raw ``Mat`` handles of the diagonal and off-diagonal ``SeqAIJ`` blocks of ``A`` (``A`` itself alone on
    one rank)."""
    if A.getType() in ("seqaij", "seqbaij"):
        return [ctypes.c_void_p(A.handle)]
    Ad, Ao, colmap = ctypes.c_void_p(), ctypes.c_void_p(), ctypes.c_void_p()
    get = lib.MatMPIAIJGetSeqAIJ if A.getType() == "mpiaij" else lib.MatMPIBAIJGetSeqBAIJ
    get.restype = ctypes.c_int
    err = get(ctypes.c_void_p(A.handle), ctypes.byref(Ad), ctypes.byref(Ao), ctypes.byref(colmap))
    if err:
        raise PETSc.Error(err)
    return [Ad, Ao]


def _value_arrays(PETSc, lib, handles, nnz, blocked=False, read=False):
    """Yield ``(block index, writable view of its values)`` for the ``SeqAIJ`` (``blocked``: ``SeqBAIJ``) blocks
    ``handles`` of ``nnz`` entries each; every array is restored after (``read``: ``MatSeqAIJGetArrayRead``, which
    leaves the matrix's state as it was; the view must then not be written)."""
    get, restore = ((lib.MatSeqBAIJGetArray, lib.MatSeqBAIJRestoreArray) if blocked
                    else (lib.MatSeqAIJGetArrayRead, lib.MatSeqAIJRestoreArrayRead) if read
                    else (lib.MatSeqAIJGetArray, lib.MatSeqAIJRestoreArray))
    get.restype = restore.restype = ctypes.c_int
    for b, h in enumerate(handles):
        ptr = ctypes.c_void_p()
        err = get(h, ctypes.byref(ptr))
        if err:
            raise PETSc.Error(err)
        try:
            n = nnz[b]
            yield b, (np.ctypeslib.as_array((ctypes.c_double * n).from_address(ptr.value)) if n else np.zeros(0))
        finally:
            err = restore(h, ctypes.byref(ptr))
            if err:
                raise PETSc.Error(err)


def _checked_arrays(PETSc, lib, A, nnz, blocked=False, read=False):
    """:func:`_value_arrays` of ``A``'s blocks, asked for each time (PETSc may replace a parallel matrix's blocks, as
    ``MATMPIBAIJ`` does in a redundant coarse solve's set-up); ValueError when their sizes are not ``nnz``."""
    if _split_sizes(PETSc, A) != nnz:
        raise ValueError("the matrix no longer has the pattern its direct access was made for")
    return _value_arrays(PETSc, lib, _seq_blocks(PETSc, lib, A), nnz, blocked, read=read and not blocked)


def reproduces(PETSc, A, write, mpi) -> bool:
    """Whether ``write()`` leaves in ``A`` the matrix it holds now, judged by their products with a random vector
    (to 1e-12 of ``|A|_inf |x|_inf``: the order in which other ranks' rows are added is not fixed, while an entry in
    a wrong place changes the product by its own size), on every rank; ``A`` holds ``write``'s result after.
    Collective."""
    from mpi4py import MPI

    x, y = A.createVecs()
    x.array[:] = np.random.default_rng(1 + mpi.Get_rank()).uniform(0.5, 1.5, x.getLocalSize())
    A.mult(x, y)
    ref = y.array.copy()
    scale = A.norm(PETSc.NormType.INFINITY) * 1.5
    write()
    A.mult(x, y)
    ok = bool(np.all(np.abs(y.array - ref) <= 1e-12 * scale))
    x.destroy()
    y.destroy()
    return bool(mpi.allreduce(int(ok), op=MPI.MIN) == 1)


def _split_sizes(PETSc, A) -> tuple:
    """Entries of ``A``'s owned rows in its diagonal and off-diagonal blocks."""
    local = A.getInfo(PETSc.Mat.InfoType.LOCAL)["nz_used"]
    in_d = (A.getDiagonalBlock() if A.getType().startswith("mpi") else A).getInfo(PETSc.Mat.InfoType.LOCAL)["nz_used"]
    return int(in_d), int(local - in_d)


class AIJValues:
    """Write (or read) the owned rows of an AIJ or BAIJ matrix straight into (from) its value arrays.

    The matrix was preallocated from a pattern of global columns sorted in every row. ``MATMPIAIJ`` stores a row's
    entries in owned columns in its diagonal block and the others in the off-diagonal one, each part in the
    pattern's order; ``MATMPIBAIJ`` the same with blocks, each block column by column. The caller lists the entries
    in that storage order (``indices``: a global column of each, which tells the parts apart; ``source``: where
    each is in the arrays :meth:`insert` is given and :meth:`read` fills).

    Parameters
    ----------
    PETSc : module
    A : petsc4py Mat
        ``seqaij``, ``mpiaij``, ``seqbaij`` or ``mpibaij``, assembled, every entry of the pattern present.
    indices : ndarray
        A global column of every entry, in storage order.
    lib : ctypes.CDLL
        The PETSc library petsc4py uses.
    source : ndarray of int, optional
        Where each entry is in the flat arrays of :meth:`insert` and :meth:`read` (default: in storage order).

    Raises
    ------
    ValueError
        When ``A`` is not a real AIJ or BAIJ matrix or its blocks do not hold the pattern's entries.
    """

    def __init__(self, PETSc, A, indices, lib, source=None):
        indices = np.asarray(indices)
        if np.dtype(PETSc.ScalarType) != np.float64 or A.getType() not in ("seqaij", "mpiaij", "seqbaij", "mpibaij"):
            raise ValueError(f"direct insertion needs a real AIJ or BAIJ matrix, got {A.getType()} of "
                             f"{PETSc.ScalarType}")
        self.PETSc, self.lib = PETSc, lib
        self.blocked = A.getType().endswith("baij")
        cstart, cend = A.getOwnershipRangeColumn()
        in_d = (indices >= cstart) & (indices < cend)
        if source is None:
            source = np.arange(indices.size, dtype=np.int32 if indices.size < 2**31 else np.int64)
        self.parts = (source[in_d], source[~in_d])  # (boolean masks: no index array of the whole pattern)
        self.nnz = tuple(int(p.size) for p in self.parts)
        if _split_sizes(PETSc, A) != self.nnz:
            raise ValueError(f"the pattern's split {self.nnz} is not the matrix's {_split_sizes(PETSc, A)}")
        _seq_blocks(PETSc, lib, A)  # (raises where the blocks cannot be had)

    def insert(self, A, values: np.ndarray) -> None:
        """``A``'s owned rows = ``values`` (in the pattern's order, or ``source``'s). Collective (the assembly)."""
        A.zeroEntries()  # also invalidates the blocks' cached inverse diagonals (SOR's)
        for b, view in _checked_arrays(self.PETSc, self.lib, A, self.nnz, self.blocked):
            idx = self.parts[b]
            for lo in range(0, idx.size, _GATHER):  # numpy converts each chunk's indices to intp, not all of them
                hi = lo + _GATHER
                np.take(values, idx[lo:hi], out=view[lo:hi], mode="clip")  # "raise" would buffer the output
        A.assemble()

    def read(self, A, out: np.ndarray) -> None:
        """``out`` (in the pattern's order, or ``source``'s) = ``A``'s owned rows (``A``'s state unchanged, on AIJ).
        Not collective."""
        for b, view in _checked_arrays(self.PETSc, self.lib, A, self.nnz, self.blocked, read=True):
            idx = self.parts[b]
            for lo in range(0, idx.size, _GATHER):
                out[idx[lo:lo + _GATHER]] = view[lo:lo + _GATHER]


class DirectInsertion:
    """Write the owned block rows of a local BSR matrix into an assembled AIJ matrix of the same pattern.

    Parameters
    ----------
    PETSc : module
        ``petsc4py.PETSc`` (real double-precision scalars).
    A : petsc4py Mat
        ``seqaij`` or ``mpiaij``, assembled, preallocated with ``pattern`` (every entry present).
    pattern : tuple of ndarray
        ``(indptr, cols)``: the owned block rows' pattern in global block columns, sorted in each row; it contains
        every block of ``indptr`` and ``indices`` (and of the ghost rows other ranks send).
    indptr, indices : ndarray
        The local BSR pattern: block rows in local numbering, the first ``n_own`` of them owned.
    local_to_global : ndarray
        Global block index of every local block column.
    n_own : int
        Owned block rows.
    lib : ctypes.CDLL
        The PETSc library petsc4py uses.
    bs : int
        Block size.

    Raises
    ------
    ValueError
        When ``A`` is not AIJ with double scalars, or a local entry is not in its pattern.
    """

    def __init__(self, PETSc, A, pattern, indptr, indices, local_to_global, n_own: int, lib, bs: int = 3):
        if np.dtype(PETSc.ScalarType) != np.float64 or A.getType() not in ("seqaij", "mpiaij"):
            raise ValueError(f"direct insertion needs a real AIJ matrix, got {A.getType()} of {PETSc.ScalarType}")
        self.PETSc, self.lib = PETSc, lib
        pptr, pcols = (np.asarray(a, dtype=np.int64) for a in pattern)
        indptr, indices = np.asarray(indptr, dtype=np.int64), np.asarray(indices, dtype=np.int64)
        l2g = np.asarray(local_to_global, dtype=np.int64)
        rstart = A.getOwnershipRange()[0]
        cstart, cend = A.getOwnershipRangeColumn()
        if rstart % bs or cstart % bs or cend % bs:
            raise ValueError("the ownership ranges are not whole blocks")
        NB = A.getSize()[1] // bs
        # the matrix's blocks by row: in the diagonal part (owned block columns) or the off-diagonal one, each part
        # in increasing global column; scalar row 3r + i holds, per part, its blocks' 3 columns in that order
        prow = np.repeat(np.arange(pptr.size - 1, dtype=np.int64), np.diff(pptr))
        in_diag = (pcols >= cstart // bs) & (pcols < cend // bs)
        parts = (in_diag, ~in_diag)
        base, nnz, per_rows = np.empty(pcols.size, dtype=np.int64), [], []
        for part in parts:
            per_row = np.bincount(prow[part], minlength=pptr.size - 1)  # the part's blocks per block row
            before = np.concatenate([[0], np.cumsum(per_row)])  # ... in the rows above
            rank = np.cumsum(part) - 1 - before[prow]  # the block's place among its row's blocks of the part
            base[part] = (bs * bs * before[prow] + bs * rank)[part]
            nnz.append(bs * bs * int(before[-1]))
            per_rows.append(per_row)
        self.nnz = tuple(nnz)
        # the owned block rows' local blocks in that pattern
        nb = int(indptr[n_own])
        lrow = np.repeat(np.arange(n_own, dtype=np.int64), np.diff(indptr[:n_own + 1]))
        keys = prow * NB + pcols
        ekeys = lrow * NB + l2g[indices[:nb]]
        at = np.searchsorted(keys, ekeys)
        if nb and (at.max() >= keys.size or np.any(keys[np.minimum(at, keys.size - 1)] != ekeys)):
            raise ValueError("a local matrix entry is outside the PETSc matrix's pattern")
        del keys, ekeys
        r = np.arange(bs, dtype=np.int64)
        itype = np.int32 if bs * bs * max(nb, 1) < 2**31 else np.int64
        self.gather, self.unfed = [], []
        for b, (part, per_row) in enumerate(zip(parts, per_rows)):
            mine = np.flatnonzero(part[at])  # local blocks in this part, in BSR data order
            perm = np.full(self.nnz[b], -1, dtype=itype)
            for lo in range(0, mine.size, _CHUNK):  # bounded temporaries: a few MB per chunk of blocks
                k = mine[lo:lo + _CHUNK]
                width = bs * per_row[lrow[k]]  # scalar entries per row of the part in the block's row
                dest = base[at[k]][:, None, None] + width[:, None, None] * r[None, :, None] + r[None, None, :]
                perm[dest.ravel()] = ((bs * bs * k)[:, None, None] + bs * r[None, :, None]
                                      + r[None, None, :]).ravel()
            unfed = np.flatnonzero(perm < 0).astype(itype)  # entries only other ranks' ghost rows add to
            perm[unfed] = 0
            self.gather.append(perm)
            self.unfed.append(unfed)
        # the value arrays are written through raw pointers: their lengths must be PETSc's
        if _split_sizes(PETSc, A) != self.nnz:
            raise ValueError(f"the pattern's split {self.nnz} is not the matrix's {_split_sizes(PETSc, A)}")
        self.ghost = (indptr[n_own:] - indptr[n_own]).astype(PETSc.IntType), \
            indices[nb:].astype(PETSc.IntType), np.arange(n_own, indptr.size - 1, dtype=PETSc.IntType)
        self.ghost_offset = bs * bs * nb
        _seq_blocks(PETSc, lib, A)  # (raises where the blocks cannot be had)

    def insert(self, A, data: np.ndarray) -> None:
        """``A`` = the local matrix whose BSR values are ``data`` (summed over the ranks' ghost rows). Collective
        (the assembly sends the ghost rows to their owners).

        Parameters
        ----------
        A : petsc4py Mat
            The matrix this object was built for.
        data : ndarray, shape (blocks, bs, bs)
            The local BSR matrix's values (owned block rows first).
        """
        flat = data.reshape(-1)
        A.zeroEntries()  # also invalidates the blocks' cached inverse diagonals (SOR's)
        for b, view in _checked_arrays(self.PETSc, self.lib, A, self.nnz):
            np.take(flat, self.gather[b], out=view, mode="clip")  # "raise" would buffer the output
            view[self.unfed[b]] = 0.0
        ip, jj, rows = self.ghost
        if rows.size:
            A.setValuesBlockedLocalIJV(ip, jj, flat[self.ghost_offset:], addv=self.PETSc.InsertMode.ADD_VALUES,
                                       rowmap=rows)
        A.assemble()

    def matches(self, A, data: np.ndarray, mpi) -> bool:
        """Whether :meth:`insert` gives the matrix PETSc's insertion left in ``A`` for the same ``data``
        (:func:`reproduces`); ``A`` holds :meth:`insert`'s result after. Collective.

        Parameters
        ----------
        A : petsc4py Mat
            Assembled by PETSc's ``MatSetValuesBlockedLocal`` path from ``data``.
        data : ndarray
            The values it was assembled from.
        mpi : mpi4py communicator
        """
        return reproduces(self.PETSc, A, lambda: self.insert(A, data), mpi)
