"""Binary descriptor matching, vectorised: brute force with a ratio test, and guided search by
projection (candidates within a radius and a scale window of where a map point should appear)."""

from __future__ import annotations

import numpy as np

TH_HIGH = 100  # ORB-SLAM's Hamming thresholds
TH_LOW = 50
NO_MATCH = 256.0


def _signs(descriptors: np.ndarray) -> np.ndarray:
    return np.unpackbits(descriptors, axis=1).astype(np.float32) * 2.0 - 1.0


def hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) Hamming distances between rows of two uint8 descriptor arrays.

    As a matrix product of the bits mapped to +-1 (``d = (256 - a.b) / 2``): BLAS computes the
    whole table several times faster than pairwise popcounts in NumPy, exactly."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)), np.float32)
    return (256.0 - _signs(a) @ _signs(b).T) * 0.5


def best_unique(distances: np.ndarray, max_distance: float, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Row/column pairs: each row's best column if under ``max_distance`` and clearly better than
    its second best (``best < ratio * second``); a column claimed twice keeps its closest row."""
    if distances.size == 0 or distances.shape[1] == 0:
        return np.zeros(0, int), np.zeros(0, int)
    if distances.shape[1] > 1:
        two = np.partition(distances, 1, axis=1)[:, :2]
        best, second = two[:, 0], two[:, 1]
    else:
        best, second = distances[:, 0], np.full(len(distances), NO_MATCH)
    cols = np.argmin(distances, axis=1)
    good = (best <= max_distance) & (best < ratio * second)
    rows = np.flatnonzero(good)
    cols, best = cols[good], best[good]
    order = np.argsort(best, kind="stable")
    _, first = np.unique(cols[order], return_index=True)
    keep = np.sort(order[first])
    return rows[keep], cols[keep]


def rotation_consistent(angle_a: np.ndarray, angle_b: np.ndarray, bins: int = 30) -> np.ndarray:
    """Mask of matches whose orientation change falls in the three most popular histogram bins
    (ORB-SLAM's check: a rigid image motion rotates all keypoints alike)."""
    if len(angle_a) == 0:
        return np.zeros(0, bool)
    change = np.mod(angle_b - angle_a, 360.0)
    index = np.minimum((change * bins / 360.0).astype(int), bins - 1)
    counts = np.bincount(index, minlength=bins)
    top = np.argsort(counts)[::-1][:3]
    keep_bins = [b for b in top if counts[b] >= 0.1 * counts[top[0]]]
    return np.isin(index, keep_bins)


def match_descriptors(a: np.ndarray, b: np.ndarray, max_distance: float = TH_LOW, ratio: float = 0.75) -> tuple[np.ndarray, np.ndarray]:
    return best_unique(hamming_matrix(a, b), max_distance, ratio)


def hamming_pairs(a: np.ndarray, b: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Hamming distances between ``a[rows[k]]`` and ``b[cols[k]]`` for each k (popcount of the
    XOR). Gathered one 64-bit column at a time: a 1-D take is about ten times faster than
    indexing whole 32-byte rows, which dominated the cost."""
    a64, b64 = np.ascontiguousarray(a).view(np.uint64), np.ascontiguousarray(b).view(np.uint64)
    total = np.zeros(len(rows), np.uint16)
    for word in range(a64.shape[1]):
        total += np.bitwise_count(a64[:, word].take(rows) ^ b64[:, word].take(cols))
    return total.astype(np.float32)


def best_unique_pairs(rows: np.ndarray, cols: np.ndarray, distances: np.ndarray, max_distance: float, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`best_unique` over a sparse candidate list (absent pairs count as no match).

    Each row's best and second-best distances come from reductions over the row's run of
    candidates (one sort by row only if they are not grouped already: the callers' are), not
    from sorting every candidate. Ties go to the lowest column, as ``argmin`` over a dense table
    would."""
    if len(rows) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    rows, cols = rows.astype(np.int64), cols.astype(np.int64)
    if np.any(rows[1:] < rows[:-1]):
        order = np.argsort(rows, kind="stable")
        rows, cols, distances = rows[order], cols[order], distances[order]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    best = np.minimum.reduceat(distances, starts)
    is_best = distances == np.repeat(best, np.diff(np.r_[starts, len(rows)]))
    best_col = np.minimum.reduceat(np.where(is_best, cols, np.iinfo(np.int64).max), starts)
    second = np.minimum.reduceat(np.where(is_best, np.float32(NO_MATCH), distances), starts)
    tied = np.add.reduceat(is_best.astype(np.int32), starts) > 1
    second[tied] = best[tied]
    good = (best <= max_distance) & (best < ratio * second)
    rows, cols, best = rows[starts[good]], best_col[good], best[good]
    if len(rows) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    # a column claimed by several rows keeps the closest (the lowest row among equals)
    order = np.argsort((cols * 257 + best.astype(np.int64)) * (int(rows.max()) + 1) + rows)
    claimed = order[np.r_[True, cols[order][1:] != cols[order][:-1]]]
    keep = np.sort(claimed)
    return rows[keep], cols[keep]


def pairs_within(xy_a: np.ndarray, radius: np.ndarray, xy_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with ``|xy_a[i] - xy_b[j]| <= radius[i]``, i ascending (``xy_a`` finite).

    ``b`` is bucketed in a grid of square cells sorted row by row, so the cells within a point's
    own radius are, row by row, one contiguous run found by binary search: the candidates follow
    each point's radius (tracking's grow with the pyramid level, 15 to 54 px), where one k-d
    tree query radius for all would compare level-0 points with up to 13 times too many keypoints."""
    cell = max(float(np.min(radius)), float(np.max(radius)) / 8, 4.0)  # at most 17 grid rows per point
    reach = np.ceil(radius / cell).astype(np.int64)  # cells each side
    origin = np.minimum(xy_a.min(axis=0), xy_b.min(axis=0)) - cell * (reach.max() + 1)
    columns = int((max(xy_a[:, 0].max(), xy_b[:, 0].max()) - origin[0]) // cell) + reach.max() + 2
    cell_b = ((xy_b - origin) // cell).astype(np.int64)
    key_b = cell_b[:, 1] * columns + cell_b[:, 0]
    order_b = np.argsort(key_b, kind="stable")
    key_b = key_b[order_b]
    cell_a = ((xy_a - origin) // cell).astype(np.int64)
    offsets = np.arange(-reach.max(), reach.max() + 1)
    point, row_offset = np.divmod(np.flatnonzero(np.abs(offsets)[None, :] <= reach[:, None]), len(offsets))  # (point, grid row) runs
    row = cell_a[point, 1] + offsets[row_offset]
    start = np.searchsorted(key_b, row * columns + cell_a[point, 0] - reach[point], "left")
    stop = np.searchsorted(key_b, row * columns + cell_a[point, 0] + reach[point], "right")
    counts = stop - start
    rows = np.repeat(point, counts)
    cols = order_b[np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts - start, counts)]
    d = xy_a[rows] - xy_b[cols]
    near = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] <= radius[rows] * radius[rows]
    return rows[near], cols[near]


def match_in_window(
    desc_a: np.ndarray,
    xy_a: np.ndarray,
    desc_b: np.ndarray,
    xy_b: np.ndarray,
    radius: np.ndarray | float,
    max_distance: float,
    ratio: float,
    octave_a: np.ndarray | None = None,
    octave_b: np.ndarray | None = None,
    octave_window: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Match rows of ``a`` to rows of ``b`` lying within ``radius`` pixels of ``xy_a`` (and, when
    octaves are given, within ``octave_window`` pyramid levels).

    Only pairs inside the window have their descriptors compared (tracking projects thousands
    of map points against a thousand keypoints)."""
    radius = np.broadcast_to(np.asarray(radius, float), (len(xy_a),))
    finite = np.flatnonzero(np.isfinite(xy_a).all(axis=1) & np.isfinite(radius))
    if len(finite) == 0 or len(xy_b) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    rows, cols = pairs_within(xy_a[finite], radius[finite], xy_b)
    rows = finite[rows]
    if octave_a is not None and octave_b is not None:
        same_scale = np.abs(octave_a[rows] - octave_b[cols]) <= octave_window
        rows, cols = rows[same_scale], cols[same_scale]
    return best_unique_pairs(rows, cols, hamming_pairs(desc_a, desc_b, rows, cols), max_distance, ratio)
