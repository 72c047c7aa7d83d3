"""The robust parallel fit of the rows' points (step 4 of the algorithm in
docs/reference/equations.md): one offset per row, one shape for all, trimmed of outliers."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RowsFit:
    """Parallel row curves y = offsets[k] + shape[0] x (+ shape[1] x^2): one offset per row,
    one shape for all; `kept` counts each row's points that survived the trimming."""

    offsets: tuple[float, ...]
    shape: tuple[float, ...]
    kept: tuple[int, ...]

    def row(self, k: int) -> tuple[float, ...]:
        """Coefficients (c_0 up) of row k."""
        return (self.offsets[k], *self.shape)


def fit_parallel_rows(
    sides: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    trim: float,
    iterations: int,
    degree: int = 1,
    significance: float = 0.0,
) -> RowsFit | None:
    """Robust parallel curves through the points (x, y) of one or more rows: least squares, then
    `iterations` refits without the points further than `trim` robust spreads (1.4826 MAD).

    The rows of a field are parallel, so they share c_1 (and c_2) and differ in c_0 only: the
    heading of the corridor is fitted on the points of every row at once. A bend, though, must
    be seen in every row: with `degree` 2 each row first gets its own c_2, and the quadratic is
    kept only when all of them bend the same way by more than `significance` standard errors;
    otherwise the rows are fitted as lines. A gap in one row through which the next row shows
    bends that row's quadratic alone, and in straight rows the extra freedom only follows noise
    (a straight vineyard with 15 % missing plants was left through a gap with per-row quadratics).
    Returns None with too few points or no spread in x. Coordinates are centred first, so the
    normal equations stay well conditioned. One function: the trim loop and the bend test share
    the design matrix and the per-row bookkeeping, which smaller pieces would pass back and forth.
    """
    counts = [xs.shape[0] for xs, _ in sides]
    if min(counts, default=0) == 0:
        return None
    rows = len(sides)
    bounds = np.array([0, *itertools.accumulate(counts)])
    x = np.concatenate([xs for xs, _ in sides], dtype=np.float64)
    y = np.concatenate([ys for _, ys in sides], dtype=np.float64)
    x_mean = float(x.sum()) / x.shape[0]  # as x.mean(), without its generic machinery
    xc = x - x_mean
    # Design columns: one offset per row, the shared slope, and (degree 2) each row's own x^2,
    # stored one column per array row. The rows' points are consecutive blocks, so each row's
    # columns are filled by slices.
    columns = np.zeros((2 * rows + 1 if degree == 2 else rows + 1, x.shape[0]))
    columns[rows] = xc
    for k in range(rows):
        block = slice(bounds[k], bounds[k + 1])
        columns[k, block] = 1.0
        if degree == 2:
            columns[rows + 1 + k, block] = xc[block] * xc[block]
    start = None
    if degree == 2:
        bent = _trimmed_least_squares(columns, y, trim=trim, iterations=iterations)
        if bent is None:
            return None
        coefficients, keep, standard_errors = bent
        curvatures, errors = coefficients[rows + 1 :], standard_errors[rows + 1 :]
        if np.all(np.abs(curvatures) > significance * errors) and (np.all(curvatures > 0) or np.all(curvatures < 0)):
            joint = np.vstack([columns[: rows + 1], columns[rows + 1 :].sum(axis=0)])  # one shared c_2
            fit = _trimmed_least_squares(joint, y, trim=trim, iterations=0, keep=keep)
            if fit is not None:
                coefficients = fit[0]
                return _rows_fit(
                    coefficients[:rows],
                    float(coefficients[rows]),
                    float(coefficients[-1]),
                    x_mean,
                    keep,
                    bounds,
                    degree,
                )
        start = keep  # the line's trimming starts from the quadratics' inliers: one round fewer
    line = _trimmed_least_squares(columns[: rows + 1], y, trim=trim, iterations=iterations, keep=start)
    if line is None:
        return None
    coefficients, keep, _ = line
    return _rows_fit(coefficients[:rows], float(coefficients[-1]), 0.0, x_mean, keep, bounds, degree)


def _trimmed_least_squares(
    columns: np.ndarray, y: np.ndarray, *, trim: float, iterations: int, keep: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(coefficients, points kept, coefficient standard errors) of the trimmed least-squares fit
    of y on the design `columns` (one column per array row, p x n), or None when the kept points
    do not determine them. The standard errors are of the last refit only, computed once after
    the trimming rounds. `keep` (default: all points) is the set the first round fits.

    A step runs two of these fits, so each round is a handful of whole-array operations: the
    dropped points get weight 0 instead of being copied out, and the conditioning is judged by
    max|N| max|N^-1| of the small p x p normal matrix N (within a factor p^2 of its condition
    number) instead of an SVD."""
    keep = np.ones(y.shape[0], dtype=bool) if keep is None else keep
    weights = keep.astype(float)
    count = int(np.count_nonzero(keep))
    last = None
    for _ in range(iterations + 1):
        if count <= columns.shape[0]:
            break
        weighted = columns * weights
        normal = weighted @ columns.T
        try:
            inverse = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            break
        # N and N^-1 are positive semi-definite, so their largest entries lie on the diagonals.
        if normal.diagonal().max() * inverse.diagonal().max() > 1e10:
            break  # a row without spread in x, a column without points
        coefficients = inverse @ (weighted @ y)
        residual = np.abs(y - coefficients @ columns)
        last = (coefficients, keep, residual, inverse, count)
        spread = 1.4826 * _median(residual[keep])
        if spread <= 1e-6:  # the points lie on the curves to float32 precision (a micrometre at 8 m)
            break
        new_keep = residual <= trim * spread
        if not (new_keep ^ keep).any():
            break
        keep = new_keep
        weights = keep.astype(float)
        count = int(np.count_nonzero(keep))
    if last is None:
        return None
    coefficients, kept, residual, inverse, count = last
    variance = float(np.sum(residual[kept] ** 2)) / (count - columns.shape[0])
    return coefficients, kept, np.sqrt(np.maximum(variance * np.diag(inverse), 0.0))


def _median(values: np.ndarray) -> float:
    """np.median of a 1-D array without its generic machinery (a third of the fit's time)."""
    middle = values.shape[0] // 2
    if values.shape[0] % 2:
        return float(np.partition(values, middle)[middle])
    part = np.partition(values, (middle - 1, middle))
    return 0.5 * float(part[middle - 1] + part[middle])


def _rows_fit(
    offsets: np.ndarray, c1: float, c2: float, x_mean: float, keep: np.ndarray, bounds: np.ndarray, degree: int
) -> RowsFit:
    """The RowsFit of coefficients fitted in x - x_mean, given back in powers of x; row k's points
    are keep[bounds[k]:bounds[k + 1]]."""
    shape = (c1 - 2.0 * c2 * x_mean, c2) if degree == 2 else (c1,)
    kept = np.add.reduceat(keep.astype(np.int64), bounds[:-1])
    return RowsFit(
        offsets=tuple(float(o - c1 * x_mean + c2 * x_mean * x_mean) for o in offsets),
        shape=shape,
        kept=tuple(int(n) for n in kept),
    )


def polyval(x: np.ndarray | float, c: tuple[float, ...] | np.ndarray) -> np.ndarray | float:
    """c_0 + c_1 x + c_2 x^2 + ... by Horner's rule (numpy's polyval costs more than the fit here)."""
    result = c[-1]
    for coefficient in c[-2::-1]:
        result = result * x + coefficient
    return result
