"""Owned block rows of distributed sparse matrices, for products computed rank by rank.

A rank's part of a distributed matrix is its owned block rows. Here they are a scipy BSR matrix over *local*
block columns: the rank's own columns first (global block ``offset + i`` is local ``i``), then the other ranks'
columns its rows reference (its ghost columns), with :class:`Rows` keeping the global id of every local column.
With its ghosts' rows fetched from their owners (:func:`fetch_rows`), a product ``X Y`` of two such matrices is a
local product (``springsim.linsolve._kernels.bsr_matmat``: the serial path's compiled block kernels); rows a rank
computes for another rank's rows go to that rank (:func:`send_rows`) and are summed there (:class:`RowMerge`).
:class:`ScalarCSR` gives PETSc the scalar CSR of the owned rows (global columns, sorted in each row).

Every structure that depends on a pattern only (which blocks exist) is computed once and reused while the pattern
stays the same (the caller keeps it; ``matches``); a matrix of a mass-spring system keeps its pattern for the run.
Communication is by mpi4py's ``Alltoall``/``Alltoallv`` on numpy buffers, collective over the communicator.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["BlockCSR", "FromScalarCSR", "Halo", "RowMerge", "Rows", "ScalarCSR", "fetch_rows", "head", "local_columns",
           "offsets_of", "send_rows", "stack_rows", "take_rows"]


def offsets_of(mpi, n_own: int) -> np.ndarray:
    """Ownership offsets of a block dimension over the ranks, shape (size + 1,): rank ``r`` owns
    ``[offsets[r], offsets[r + 1])``. Collective."""
    return np.concatenate([[0], np.cumsum(mpi.allgather(int(n_own)))]).astype(np.int64)


class Rows:
    """A rank's owned block rows over local columns (module docstring).

    Parameters
    ----------
    bsr : scipy.sparse.bsr_matrix
        Shape ``(n_rows R, len(gids) N)``.
    gids : ndarray of int64
        Global block column of every local column: ``offset + arange(n_own)`` then the ghost columns, sorted.
    n_own : int
        Own block columns (``gids[:n_own]``).
    """

    __slots__ = ("bsr", "gids", "n_own")

    def __init__(self, bsr: sp.bsr_matrix, gids: np.ndarray, n_own: int):
        self.bsr, self.gids, self.n_own = bsr, gids, int(n_own)

    @property
    def ghosts(self) -> np.ndarray:
        """Global ids of the ghost columns (sorted)."""
        return self.gids[self.n_own:]

    def square(self) -> sp.bsr_matrix:
        """The blocks in own columns (the rank's diagonal block), square, indices sorted: the rows themselves (no
        copy) when they have no ghost column."""
        b = self.bsr
        if self.gids.size == self.n_own and b.has_sorted_indices:
            return b
        keep = b.indices < self.n_own
        rows = np.repeat(np.arange(b.indptr.size - 1), np.diff(b.indptr))[keep]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=b.indptr.size - 1))])
        R, N = b.blocksize
        out = sp.bsr_matrix((b.data[keep], b.indices[keep], indptr), shape=(b.shape[0], self.n_own * N))
        out.sort_indices()
        return out


def local_columns(gid: np.ndarray, lo: int, hi: int):
    """Local numbering of global block columns ``gid`` with own range ``[lo, hi)``: ``(local, gids)``."""
    ghosts = np.unique(gid[(gid < lo) | (gid >= hi)])
    own = (gid >= lo) & (gid < hi)
    local = np.where(own, gid - lo, (hi - lo) + np.searchsorted(ghosts, gid))
    return local, np.concatenate([np.arange(lo, hi, dtype=np.int64), ghosts])


def take_rows(indptr: np.ndarray, rows: np.ndarray):
    """``(indptr, positions)`` of the block rows ``rows`` of a CSR/BSR pattern: the sub-pattern's row pointer and the
    positions of its blocks in the original arrays."""
    lens = indptr[rows + 1] - indptr[rows]
    sub = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    pos = np.repeat(indptr[rows] - sub[:-1], lens) + np.arange(sub[-1], dtype=np.int64)
    return sub, pos


def _alltoallv(mpi, send: np.ndarray, scounts: np.ndarray, rcounts: np.ndarray, width: int = 1) -> np.ndarray:
    """``Alltoallv`` of the rows of ``send`` (``width`` values each) grouped by destination; the received rows in
    source order."""
    from mpi4py import MPI

    recv = np.empty((int(rcounts.sum()), width) if width > 1 else int(rcounts.sum()), dtype=send.dtype)
    sc, rc = (np.asarray(c, dtype=np.int64) * width for c in (scounts, rcounts))
    sd, rd = (np.concatenate([[0], np.cumsum(c)[:-1]]) for c in (sc, rc))
    mtype = MPI.DOUBLE if send.dtype == np.float64 else MPI.INT64_T
    mpi.Alltoallv([np.ascontiguousarray(send), (sc, sd), mtype], [recv, (rc, rd), mtype])
    return recv


def send_rows(mpi, dest: np.ndarray, indptr: np.ndarray, colgid: np.ndarray, data: np.ndarray, tag=None):
    """Send block rows to ranks (collective): row ``i`` (``indptr``, global columns ``colgid``, blocks ``data``) goes
    to rank ``dest[i]``; ``dest`` must be non-decreasing (rows grouped by destination). ``tag`` (int64 per row) is
    sent along (a row's global id, say).

    Returns
    -------
    indptr, colgid, data, tag, source : ndarray
        The rows this rank received, grouped by source rank in rank order, each source's in its order, and the
        rank each came from.
    """
    size = mpi.Get_size()
    lens = np.diff(indptr).astype(np.int64)
    counts = np.stack([np.bincount(dest, minlength=size),
                       np.bincount(dest, weights=lens, minlength=size)], axis=1).astype(np.int64)
    got = np.empty_like(counts)
    mpi.Alltoall(counts, got)
    width = int(np.prod(data.shape[1:]))
    rlens = _alltoallv(mpi, lens, counts[:, 0], got[:, 0])
    rtag = _alltoallv(mpi, np.asarray(tag if tag is not None else np.zeros(dest.size), dtype=np.int64),
                      counts[:, 0], got[:, 0])
    rcols = _alltoallv(mpi, np.asarray(colgid, dtype=np.int64), counts[:, 1], got[:, 1])
    rdata = _alltoallv(mpi, data.reshape(-1, width), counts[:, 1], got[:, 1], width)
    return (np.concatenate([[0], np.cumsum(rlens)]).astype(np.int64), rcols,
            rdata.reshape((-1,) + data.shape[1:]), rtag, np.repeat(np.arange(size), got[:, 0]))


class Halo:
    """Who owns a rank's ghost rows and which owned rows each rank wants (set up once per ghost set; collective).

    Parameters
    ----------
    mpi : mpi4py communicator
    offsets : ndarray
        Ownership offsets of the rows (:func:`offsets_of`).
    ghosts : ndarray of int64
        Global ids of the rows this rank needs from others (sorted).
    """

    def __init__(self, mpi, offsets: np.ndarray, ghosts: np.ndarray):
        self.mpi, self.ghosts = mpi, np.asarray(ghosts, dtype=np.int64)
        owner = np.searchsorted(offsets, self.ghosts, side="right") - 1
        # the owners learn which of their rows to send to whom (requests grouped by owner: the ghosts are sorted)
        _, _, _, wanted, self.send_dest = send_rows(mpi, owner, np.zeros(owner.size + 1, dtype=np.int64),
                                                    np.zeros(0, np.int64), np.zeros(0), tag=self.ghosts)
        self.send_local = wanted - int(offsets[mpi.Get_rank()])  # local ids of the requested owned rows

    def matches(self, ghosts: np.ndarray) -> bool:
        return np.array_equal(self.ghosts, ghosts)


def fetch_rows(halo: Halo, rows: Rows):
    """The ghost rows ``halo.ghosts`` of the distributed matrix whose owned rows are ``rows`` on every rank
    (collective): ``(indptr, colgid, data)`` in the order of ``halo.ghosts``, global columns."""
    b = rows.bsr
    sub, pos = take_rows(b.indptr, halo.send_local)
    indptr, colgid, data, _, _ = send_rows(halo.mpi, halo.send_dest, sub, rows.gids[b.indices[pos]], b.data[pos])
    return indptr, colgid, data  # grouped by owner in rank order: the ghosts' order (sorted ids)


def stack_rows(own: Rows, indptr: np.ndarray, colgid: np.ndarray, data: np.ndarray, lo: int, hi: int) -> Rows:
    """The owned rows ``own`` followed by the rows ``(indptr, colgid, data)``, over one local numbering of all their
    columns (own range ``[lo, hi)`` of global ids first, then the others sorted)."""
    b = own.bsr
    gid = np.concatenate([own.gids[b.indices], colgid])
    local, gids = local_columns(gid, lo, hi)
    R, N = b.blocksize
    ip = np.concatenate([b.indptr, b.indptr[-1] + indptr[1:]]).astype(np.int64)
    blocks = np.concatenate([b.data, data.reshape(-1, R, N)])
    out = sp.bsr_matrix((blocks, local, ip), shape=((ip.size - 1) * R, gids.size * N))
    return Rows(out, gids, hi - lo)


def head(b: sp.bsr_matrix, n: int) -> sp.bsr_matrix:
    """The first ``n`` block rows of ``b`` (views of its arrays)."""
    R, N = b.blocksize
    end = int(b.indptr[n])
    return sp.bsr_matrix((b.data[:end], b.indices[:end], b.indptr[:n + 1]), shape=(n * R, b.shape[1]), copy=False)


class RowMerge:
    """The sum of block rows given as (row, global column, block) triplets, onto a sorted pattern kept for triplets
    of the same keys.

    Parameters
    ----------
    rows, colgid : ndarray of int64
        Local row and global column of every block.
    n_rows, n_cols : int
        Local rows, global columns (for the keys).
    """

    def __init__(self, rows: np.ndarray, colgid: np.ndarray, n_rows: int, n_cols: int):
        self.keys = rows.astype(np.int64) * int(n_cols) + colgid
        self.order = np.argsort(self.keys, kind="stable")
        k = self.keys[self.order]
        first = np.concatenate([[True], k[1:] != k[:-1]]) if k.size else np.zeros(0, dtype=bool)
        starts = np.flatnonzero(first)
        ukeys = k[starts]
        # the first block of every key, then the m-th ones (m = 2, 3, ...: as many as ranks add to a row) in turn
        self.first = self.order[starts]
        group = np.cumsum(first) - 1
        place = np.arange(k.size) - starts[group]
        self.repeats = [(self.order[place == m], group[place == m]) for m in range(1, int(place.max(initial=0)) + 1)]
        self.identity = not self.repeats and np.array_equal(self.first, np.arange(k.size))
        self.rows, self.colgid = ukeys // n_cols, ukeys % n_cols
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(self.rows, minlength=n_rows))]).astype(np.int64)

    def matches(self, rows: np.ndarray, colgid: np.ndarray, n_cols: int) -> bool:
        return self.keys.size == rows.size and np.array_equal(self.keys, rows.astype(np.int64) * int(n_cols) + colgid)

    def __call__(self, blocks: np.ndarray) -> np.ndarray:
        """The summed blocks, in the pattern's order (rows, then global columns, ascending)."""
        if self.identity:
            return blocks
        out = blocks[self.first]
        for positions, targets in self.repeats:  # the second, third, ... block of each key that has them
            out[targets] += blocks[positions]
        return out


#: Block rows (or blocks) per chunk while the kept indices are built: the temporaries stay at a few MB.
_CHUNK = 1 << 12


def _index_type(largest: int):
    """int32 when ``largest`` fits, else int64 (the kept gather and scatter indices)."""
    return np.int32 if largest < 2**31 else np.int64


class _SortedPattern:
    """A :class:`Rows`' pattern with its blocks sorted by row, then global column (``order``: the blocks' positions in
    that order; ``brow``, ``gid``: each stored block's row and global column), and whether other rows have the same
    pattern (:meth:`matches`). ``petsc`` and ``writer`` are the caller's: the pattern in PETSc's index type, and how
    values are written (None: through PETSc's calls)."""

    def __init__(self, rows: Rows):
        b = rows.bsr
        lens = np.diff(b.indptr)
        self.brow = np.repeat(np.arange(lens.size, dtype=np.int64), lens)
        self.gid = rows.gids[b.indices]
        self.order = np.lexsort((self.gid, self.brow))  # (the rows stay in order)
        self._pattern = (b.indptr.copy(), b.indices.copy(), rows.gids.copy(), b.blocksize)
        self.petsc = self.writer = None

    def matches(self, rows: Rows) -> bool:
        ip, ix, gids, bs = self._pattern
        b = rows.bsr
        return (b.blocksize == bs and np.array_equal(b.indptr, ip) and np.array_equal(b.indices, ix)
                and np.array_equal(rows.gids, gids))


class ScalarCSR(_SortedPattern):
    """The scalar CSR of a :class:`Rows`' blocks with global columns sorted in every row, for PETSc's ``AIJ``
    matrices: the pattern (``indptr``, ``indices``) once, then the values of a matrix of the same pattern by one
    gather (``values``; ``perm`` is where each entry is in the blocks' flat array). A caller with a writer may drop
    ``indptr``, ``indices``, ``perm`` and ``petsc`` (:meth:`values` needs ``perm``).

    Parameters
    ----------
    rows : Rows
    """

    def __init__(self, rows: Rows):
        super().__init__(rows)
        b = rows.bsr
        R, N = b.blocksize
        order, brow, g = self.order, self.brow, self.gid
        rank = np.arange(order.size, dtype=np.int64) - b.indptr[brow]  # each sorted block's place in its row
        # scalar row I R + a holds its row's blocks' N columns in turn
        self.indptr = np.concatenate([[0], np.cumsum(np.repeat(np.diff(b.indptr) * N, R))]).astype(np.int64)
        nnz = int(self.indptr[-1])
        self.perm = np.empty(nnz, dtype=_index_type(nnz))
        self.indices = np.empty(nnz, dtype=_index_type(int(rows.gids.max(initial=0) + 1) * N))
        a, c = np.arange(R)[None, :, None], np.arange(N)[None, None, :]
        for k0 in range(0, order.size, _CHUNK):
            k = slice(k0, k0 + _CHUNK)
            ob, orow, orank = order[k, None, None], brow[k, None, None], rank[k, None, None]
            dest = (self.indptr[orow * R + a] + orank * N + c).ravel()
            self.perm[dest] = ((ob * R + a) * N + c).ravel()
            self.indices[dest] = (g[order[k], None, None] * N + c + 0 * a).ravel()
        self.brow = self.gid = self.order = None

    def values(self, rows: Rows) -> np.ndarray:
        return np.ascontiguousarray(rows.bsr.data).reshape(-1)[self.perm]


class BlockCSR(_SortedPattern):
    """The block CSR of a :class:`Rows`' square blocks with global block columns sorted in every row, for PETSc's
    ``BAIJ`` matrices: the pattern (``indptr``, ``indices``) once; the values row-major per block in that order
    (``values``, what ``MatSetValuesBlocked`` takes), and ``perm``: where each entry of PETSc's storage (blocks in the
    pattern's order, each stored column by column) is in the blocks' flat array, with ``entry_cols``, a global
    scalar column of each entry's block (which tells PETSc's diagonal part from the off-diagonal one).

    Parameters
    ----------
    rows : Rows
        Square blocks.
    """

    def __init__(self, rows: Rows):
        R, N = rows.bsr.blocksize
        if R != N:
            raise ValueError(f"BAIJ needs square blocks, got {R} x {N}")
        super().__init__(rows)
        self.indptr, self.indices = rows.bsr.indptr.astype(np.int64), self.gid[self.order]
        self.brow = self.gid = None
        nnz = self.order.size * R * N
        self.perm = np.empty(nnz, dtype=_index_type(nnz))
        r, c = np.arange(R)[None, None, :], np.arange(N)[None, :, None]
        for k0 in range(0, self.order.size, _CHUNK):  # entry (j, c, r) of the storage <- entry (r, c) of its block
            ob = self.order[k0:k0 + _CHUNK, None, None]
            self.perm[k0 * R * N:(k0 + ob.shape[0]) * R * N] = ((ob * R + r) * N + c).ravel()
        self.entry_cols = np.repeat(self.indices * N, R * N).astype(_index_type(int(rows.gids.max(initial=0) + 1) * N))

    def values(self, rows: Rows) -> np.ndarray:
        return np.ascontiguousarray(rows.bsr.data[self.order]).reshape(-1)


class FromScalarCSR:
    """Owned scalar CSR rows with global columns (a PETSc matrix's) as :class:`Rows` of ``bs x bs`` blocks: the
    pattern once (from ``getValuesCSR``), then the values read straight from the matrix's arrays (``__call__``,
    :class:`springsim.distributed._aij.AIJValues`). Every entry a block holds that the CSR lacks is zero.

    Parameters
    ----------
    indptr, indices : ndarray
        The owned rows' scalar pattern, global columns (sorted in every row).
    bs : int
    lo, hi : int
        Owned block range.
    n_cols : int
        Global block columns.

    Attributes
    ----------
    dest : ndarray
        Where each entry of the CSR goes in the blocks' flat array.
    """

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, bs: int, lo: int, hi: int, n_cols: int):
        n = (indptr.size - 1) // bs
        self.dest = np.empty(indices.size, dtype=_index_type(indices.size * bs * bs))
        counts, cols, done = [], [], 0
        for i0 in range(0, n, _CHUNK):  # block rows in chunks: np.unique's temporaries stay small
            i1 = min(n, i0 + _CHUNK)
            e0, e1 = int(indptr[i0 * bs]), int(indptr[i1 * bs])
            row = np.repeat(np.arange(i0 * bs, i1 * bs, dtype=np.int64), np.diff(indptr[i0 * bs:i1 * bs + 1]))
            col = indices[e0:e1].astype(np.int64)
            ukey, inv = np.unique((row // bs - i0) * n_cols + col // bs, return_inverse=True)
            self.dest[e0:e1] = ((inv + done) * bs + row % bs) * bs + col % bs
            counts.append(np.bincount(ukey // n_cols, minlength=i1 - i0))
            cols.append(ukey % n_cols)
            done += ukey.size
        ucol = np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64)
        self.indices, self.gids = local_columns(ucol, lo, hi)
        self.indptr = np.concatenate([[0], np.cumsum(np.concatenate(counts) if counts else [])]).astype(np.int64)
        self.n_own, self.bs, self.nblocks = hi - lo, bs, done
        #: the caller's: the matrix the pattern came from (its handle), and what reads its values from its arrays
        #: (:class:`springsim.distributed._aij.AIJValues`; None: ``getValuesCSR``)
        self.matrix = self.reader = None

    def __call__(self, A) -> Rows:
        """The owned rows of the PETSc matrix ``A`` (the one this pattern came from) with its current values (through
        :attr:`reader`, else ``getValuesCSR``)."""
        bs = self.bs
        blocks = np.zeros(self.nblocks * bs * bs)
        if self.reader is not None:
            self.reader.read(A, blocks)
        else:
            blocks[self.dest] = A.getValuesCSR()[2]
        bsr = sp.bsr_matrix((blocks.reshape(-1, bs, bs), self.indices, self.indptr),
                            shape=((self.indptr.size - 1) * bs, self.gids.size * bs))
        return Rows(bsr, self.gids, self.n_own)
