"""Row keys of the remesher (``remesh._arrays.row_keys``): one int64 per face row that never overflows (issue #29,
meshes of over 2**21 vertices), checked against ``np.unique(axis=0)`` and ``np.lexsort`` as the naive oracles."""

import numpy as np
import pytest

from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import mend, repair
from apt_filters.remesh._arrays import row_keys, unique_rows

BIG = 2**31 - 1  # the largest int32 vertex index


def _product_key(rows: np.ndarray, n: int) -> np.ndarray:
    """The key the remesher used before: ``(r0 * n + r1) * n + r2`` in int64, wrapping where it overflows."""
    rows = np.asarray(rows, np.int64)
    key = rows[:, 0].copy()
    with np.errstate(over="ignore"):
        for col in range(1, rows.shape[1]):
            key = key * np.int64(n) + rows[:, col]
    return key


def _oracle(rows: np.ndarray) -> tuple:
    return np.unique(rows, axis=0, return_index=True, return_inverse=True, return_counts=True)


def _assert_as_oracle(rows: np.ndarray) -> None:
    got, want = unique_rows(rows), _oracle(rows)
    for g, w in zip(got, want):
        assert np.array_equal(g, np.asarray(w).reshape(g.shape))
    key = row_keys(rows)
    assert np.array_equal(np.argsort(key, kind="stable"), np.lexsort(rows.T[::-1]))  # lexicographic order


def test_faces_that_the_product_key_merges_stay_apart():
    """Sorted faces (0, 5, 6) and (4, 5, 6) over 2**31 vertices: the product key is 4 * 2**62 = 2**64 apart, so
    equal in int64; the row keys keep them apart and the distinct rows are np.unique's."""
    rows = np.array([[0, 5, 6], [4, 5, 6], [7, 8, BIG], [0, 5, 6]])
    old = _product_key(rows, BIG + 1)
    assert old[0] == old[1]  # the collision the old key made
    key = row_keys(rows)
    assert len(np.unique(key)) == 3 and key[0] == key[3]
    _assert_as_oracle(rows)
    assert np.array_equal(repair.drop_duplicates(rows), rows[:3])  # the duplicate face removal kept both


@pytest.mark.parametrize("d", [1, 2, 3])
def test_rows_up_to_int32_indices_are_np_uniques(d):
    """Random rows with entries up to 2**31 - 1, a third of them repeated, d = 1, 2, 3: the distinct rows, first
    occurrences, inverse and counts are np.unique(axis=0)'s and the keys sort as the rows do."""
    rng = np.random.default_rng(7)
    rows = rng.integers(0, BIG + 1, (3000, d))
    rows[:, 0] %= 64  # many rows share their first column: the later columns decide
    rows = np.vstack([rows, rows[rng.integers(0, len(rows), 1500)]])
    rows[0, -1] = BIG
    _assert_as_oracle(rows)


def test_small_indices_keep_the_product_key():
    """Under 2**21 vertices the key is the product key itself (the remesh of every surface so far unchanged)."""
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 2**21, (5000, 3))
    assert np.array_equal(row_keys(rows), _product_key(rows, int(rows.max()) + 1))
    _assert_as_oracle(rows)


def test_rows_no_int64_can_key_are_refused():
    """Three distinct rows of entries up to 2**62: 3 * 2**62 keys do not fit in int64."""
    with pytest.raises(OverflowError):
        row_keys(np.array([[0, 0], [1, 2**62], [2, 1]]))


def test_mend_sees_a_new_face_the_product_key_took_for_an_old_one():
    """mend's changed faces over 2**22 vertices (a mesh a 10^9-ion run makes): after the mend, face (0, 5, 6) is
    new and (1, 2, 3) kept; before, (2**20, 5, 6) was there instead, whose product key is that of (0, 5, 6)
    (2**20 * 2**44 = 2**64). The new face is measured again, the kept one is not, and the input face beside the
    gone one is (with the product key: none of them)."""
    n = 2**22
    vertices = np.zeros((n, 3))  # never written: the pages stay unmapped
    after = TriMesh(vertices, np.array([[0, 5, 6], [1, 2, 3]]))
    before = TriMesh(vertices, np.array([[2**20, 5, 6], [1, 2, 3]]))
    assert len(set(_product_key(after.faces, n)) | set(_product_key(before.faces, n))) == 2
    source = TriMesh(np.eye(3) * 0.01, np.array([[0, 1, 2]]))
    inside, out = mend._changed(source, before, after, (np.zeros(1, bool), np.zeros(2, bool)), 0.1)
    assert out.tolist() == [True, False]
    assert inside.tolist() == [True]
