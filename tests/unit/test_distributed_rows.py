"""The communication-free parts of springsim.distributed._rows (the owned block rows of the distributed smoothed
aggregation's products) against dense references; the collective parts run under MPI in tests/distributed."""

import numpy as np
import pytest
import scipy.sparse as sp

from springsim.distributed import _rows


def _random_rows(rng, n_rows, lo, hi, n_ghost_pool, R, N, density=0.3):
    """Owned block rows with own columns [lo, hi) and a few ghost columns, as Rows, and the dense matrix over the
    global columns 0 .. max."""
    n_global = hi + n_ghost_pool
    pool = np.concatenate([np.arange(0, lo), np.arange(hi, n_global)])
    cols_used = np.unique(np.concatenate([np.arange(lo, hi), rng.choice(pool, size=min(5, pool.size), replace=False)]))
    pattern = rng.random((n_rows, cols_used.size)) < density
    pattern[np.arange(n_rows), np.arange(n_rows) % cols_used.size] = True  # no empty row
    rr, cc = np.nonzero(pattern)
    gid = cols_used[cc]
    local, gids = _rows.local_columns(gid, lo, hi)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rr, minlength=n_rows))])
    data = rng.standard_normal((rr.size, R, N))
    rows = _rows.Rows(sp.bsr_matrix((data, local, indptr), shape=(n_rows * R, gids.size * N)), gids, hi - lo)
    dense = np.zeros((n_rows * R, n_global * N))
    for k in range(rr.size):
        dense[rr[k] * R:(rr[k] + 1) * R, gid[k] * N:(gid[k] + 1) * N] = data[k]
    return rows, dense


def _global_dense(rows: _rows.Rows, n_global: int) -> np.ndarray:
    """The Rows' blocks placed at their global columns, dense."""
    b = rows.bsr
    R, N = b.blocksize
    out = np.zeros((b.shape[0], n_global * N))
    full = b.toarray()
    for j, g in enumerate(rows.gids):
        out[:, g * N:(g + 1) * N] = full[:, j * N:(j + 1) * N]
    return out


@pytest.mark.parametrize("R, N", [(3, 3), (3, 6), (6, 6)])
def test_local_numbering_keeps_own_columns_first_then_sorted_ghosts(R, N):
    rng = np.random.default_rng(R * 10 + N)
    rows, dense = _random_rows(rng, 12, 4, 9, 6, R, N)
    assert np.array_equal(rows.gids[:rows.n_own], np.arange(4, 9))
    assert np.all(np.diff(rows.ghosts) > 0) and not np.any((rows.ghosts >= 4) & (rows.ghosts < 9))
    np.testing.assert_array_equal(_global_dense(rows, dense.shape[1] // N), dense)
    sq = rows.square().toarray()  # the own columns only
    np.testing.assert_array_equal(sq, dense[:, 4 * N:9 * N])


@pytest.mark.parametrize("R, N", [(3, 3), (3, 6), (6, 6)])
def test_scalar_csr_is_the_owned_rows_with_sorted_global_columns(R, N):
    rng = np.random.default_rng(7 + R + N)
    rows, dense = _random_rows(rng, 20, 10, 20, 15, R, N)
    csr = _rows.ScalarCSR(rows)
    ref = sp.csr_matrix((csr.values(rows), csr.indices, csr.indptr), shape=dense.shape)
    np.testing.assert_array_equal(ref.toarray(), dense)
    for i in range(dense.shape[0]):  # PETSc's preallocation wants every row's columns sorted
        assert np.all(np.diff(csr.indices[csr.indptr[i]:csr.indptr[i + 1]]) > 0)
    assert csr.matches(rows)
    other = _rows.Rows(sp.bsr_matrix((rows.bsr.data, rows.bsr.indices[::-1].copy(), rows.bsr.indptr),
                                     shape=rows.bsr.shape), rows.gids, rows.n_own)
    assert not csr.matches(other)


class _FakeMatrix:
    """What FromScalarCSR asks of a PETSc matrix when it cannot read its arrays: getValuesCSR."""

    def __init__(self, csr):
        self.csr = csr

    def getValuesCSR(self):
        return self.csr.indptr, self.csr.indices, self.csr.data


def test_scalar_rows_become_blocks_over_the_local_numbering():
    rng = np.random.default_rng(3)
    bs, lo, hi, n_global = 3, 5, 11, 20
    dense = np.zeros(((hi - lo) * bs, n_global * bs))
    for i in range(hi - lo):  # some blocks, some entries of them missing (zero in the blocks)
        for g in rng.choice(n_global, size=4, replace=False):
            block = rng.standard_normal((bs, bs)) * (rng.random((bs, bs)) < 0.7)
            dense[i * bs:(i + 1) * bs, g * bs:(g + 1) * bs] = block
    csr = sp.csr_matrix(dense)
    csr.sort_indices()
    conv = _rows.FromScalarCSR(csr.indptr, csr.indices, bs, lo, hi, n_global)
    rows = conv(_FakeMatrix(csr))
    np.testing.assert_array_equal(_global_dense(rows, n_global), dense)
    assert np.array_equal(rows.gids[:rows.n_own], np.arange(lo, hi))
    csr.data *= 2.0  # new values, same pattern
    np.testing.assert_array_equal(_global_dense(conv(_FakeMatrix(csr)), n_global), 2.0 * dense)


def test_row_merge_sums_repeated_blocks_onto_a_sorted_pattern():
    rng = np.random.default_rng(11)
    n_rows, n_cols = 6, 9
    rows = rng.integers(0, n_rows, 40)
    cols = rng.integers(0, n_cols, 40)
    blocks = rng.standard_normal((40, 2, 2))
    merge = _rows.RowMerge(rows, cols, n_rows, n_cols)
    summed = merge(blocks)
    dense = np.zeros((n_rows, n_cols, 2, 2))
    np.add.at(dense, (rows, cols), blocks)
    got = np.zeros_like(dense)
    got[merge.rows, merge.colgid] = summed
    np.testing.assert_allclose(got, dense, rtol=0, atol=1e-14)
    keys = merge.rows * n_cols + merge.colgid
    assert np.all(np.diff(keys) > 0) and merge.indptr[-1] == keys.size
    assert merge.matches(rows, cols, n_cols) and not merge.matches(rows[::-1], cols, n_cols)
    # keys already sorted and unique: the blocks are returned as they are
    order = np.unique(rows * n_cols + cols, return_index=True)[1]
    same = _rows.RowMerge(rows[order], cols[order], n_rows, n_cols)
    assert same.identity and np.array_equal(same(blocks[order]), blocks[order])


def test_take_rows_and_head_select_block_rows():
    b = sp.bsr_matrix(np.arange(1.0, 1.0 + 8 * 6).reshape(8, 6) * (np.arange(8)[:, None] % 3 != 1), blocksize=(2, 2))
    sub, pos = _rows.take_rows(b.indptr, np.array([3, 0]))
    for k, r in enumerate([3, 0]):
        np.testing.assert_array_equal(b.indices[pos[sub[k]:sub[k + 1]]], b.indices[b.indptr[r]:b.indptr[r + 1]])
    np.testing.assert_array_equal(_rows.head(b, 2).toarray(), b.toarray()[:4])


def test_block_csr_orders_blocks_and_petsc_storage():
    """BlockCSR: the blocks by row and global column, row-major per block for MatSetValuesBlocked; ``perm`` lists
    the entries in PETSc's BAIJ storage (each block column by column) and ``entry_cols`` a column of each entry's
    block."""
    rng = np.random.default_rng(5)
    rows, dense = _random_rows(rng, 10, 3, 13, 8, 3, 3)
    blk = _rows.BlockCSR(rows)
    vals = blk.values(rows).reshape(-1, 3, 3)
    flat = rows.bsr.data.reshape(-1)
    for i in range(10):
        for p in range(blk.indptr[i], blk.indptr[i + 1]):
            g = blk.indices[p]
            np.testing.assert_array_equal(vals[p], dense[3 * i:3 * i + 3, 3 * g:3 * g + 3])
            # PETSc's storage of block p: column c, then row r
            np.testing.assert_array_equal(flat[blk.perm[9 * p:9 * p + 9]].reshape(3, 3).T, vals[p])
            assert np.all(blk.entry_cols[9 * p:9 * p + 9] // 3 == g)
        assert np.all(np.diff(blk.indices[blk.indptr[i]:blk.indptr[i + 1]]) > 0)
    assert blk.matches(rows)
    with pytest.raises(ValueError, match="square blocks"):
        _rows.BlockCSR(_random_rows(rng, 4, 0, 4, 3, 3, 6)[0])
