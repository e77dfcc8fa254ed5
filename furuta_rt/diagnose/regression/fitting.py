"""Least squares scored on held-out time blocks.

Rows are split into B contiguous time blocks. A fit uses the per-block Gram sums, so the
leave-one-block-out fits (blocked K-fold cross-validation) cost no more than one fit: the CV error is
the held-out squared error summed over the blocks, and the spread of the B fold estimates gives a
jackknife standard error that respects the residuals' correlation in time.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Blocks:
    """Contiguous time blocks over the rows of one equation."""

    rows: np.ndarray  # indices of the rows used, in time order
    bounds: tuple[tuple[int, int], ...]  # [start, stop) into ``rows`` per block

    @classmethod
    def split(cls, mask: np.ndarray, n_blocks: int) -> Blocks:
        rows = np.flatnonzero(mask)
        edges = np.linspace(0, len(rows), n_blocks + 1).round().astype(int)
        return cls(rows, tuple((int(a), int(b)) for a, b in itertools.pairwise(edges)))

    @property
    def count(self) -> int:
        return len(self.bounds)


@dataclass(frozen=True)
class Stats:
    """Per-block sufficient statistics of y ≈ X c: G_b = XᵀX, h_b = Xᵀy, s_b = yᵀy, n_b."""

    G: np.ndarray  # (B, k, k)
    h: np.ndarray  # (B, k)
    s: np.ndarray  # (B,)
    n: np.ndarray  # (B,)
    scale: np.ndarray  # (k,) column scales used for conditioning

    @classmethod
    def of(cls, y: np.ndarray, X: np.ndarray, blocks: Blocks) -> Stats:
        return cls.of_rows(y[blocks.rows], X[blocks.rows], blocks)

    @classmethod
    def of_rows(cls, yr: np.ndarray, Xr: np.ndarray, blocks: Blocks) -> Stats:
        """``of`` from the rows already taken (``y[blocks.rows]``, ``X[blocks.rows]``: elementwise work on the rows
        alone gives the same numbers as on the whole recording, so a profile can take them once)."""
        return Design.of_rows(Xr, blocks).stats(yr, blocks)


@dataclass(frozen=True)
class Design:
    """The columns' side of Stats (scales, scaled rows, per-block G_b): one design serves every target fitted on it (a
    profile over a parameter of the target alone)."""

    Xs: np.ndarray  # (rows, k) the rows' columns over their scales
    G: np.ndarray  # (B, k, k)
    scale: np.ndarray  # (k,)

    @classmethod
    def of_rows(cls, Xr: np.ndarray, blocks: Blocks) -> Design:
        k = Xr.shape[1]
        scale = np.sqrt(_column_sums(Xr**2) / len(Xr)) if k else np.zeros(0)
        scale[scale == 0] = 1.0
        Xs = Xr / scale
        G = np.empty((blocks.count, k, k))
        for b, (a, e) in enumerate(blocks.bounds):
            xb = Xs[a:e]
            G[b] = xb.T @ xb
        return cls(Xs, G, scale)

    def stats(self, yr: np.ndarray, blocks: Blocks) -> Stats:
        """Stats of the target ``yr`` (the rows of ``blocks``) on these columns."""
        B, k = blocks.count, self.Xs.shape[1]
        h = np.empty((B, k))
        s = np.empty(B)
        n = np.empty(B)
        for b, (a, e) in enumerate(blocks.bounds):
            xb, yb = self.Xs[a:e], yr[a:e]
            h[b] = xb.T @ yb
            s[b] = yb @ yb
            n[b] = e - a
        return Stats(self.G, h, s, n, self.scale)


def _column_sums(a: np.ndarray) -> np.ndarray:
    """``np.sum(a, axis=0)`` of a C-ordered (n, k) array, the same numbers: with k ≥ 2 numpy adds the rows one after
    another, and a running sum down each column (cumsum) does the same additions with its inner loop along the column
    (several times faster than row by row for a few columns); a single column numpy sums pairwise, as it is."""
    if a.shape[1] < 2 or not len(a):
        return np.sum(a, axis=0)
    return np.cumsum(a.T, axis=1)[:, -1]


def _solve(G: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The ridge-conditioned solution of G c = h; G (..., k, k) and h (..., k) may hold a batch (one LAPACK solve per
    matrix either way, so a batch gives the same numbers as a loop)."""
    k = h.shape[-1]
    if k == 0:
        return h.copy()
    ridge = 1e-10 * (np.trace(G, axis1=-2, axis2=-1) / k + 1e-300)
    return np.linalg.solve(G + np.asarray(ridge)[..., None, None] * np.eye(k), h[..., None])[..., 0]


def _fold_solves(stats: Stats) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(G, h, per-fold coefficients (B, k)): the full-data sums and the leave-one-block-out solutions, in one batch."""
    G, h = stats.G.sum(0), stats.h.sum(0)
    return G, h, _solve(G[None] - stats.G, h[None] - stats.h)


@dataclass(frozen=True)
class Fit:
    coef: np.ndarray  # full-data estimate
    se: np.ndarray  # jackknife standard error over the leave-one-block-out fits
    fold_coef: np.ndarray  # (B, k)
    sse: float  # in-sample squared error
    cv_sse: float  # held-out squared error, summed over blocks
    cv_block: np.ndarray  # held-out squared error per block
    n: int

    @property
    def cv_rms(self) -> float:
        return float(np.sqrt(self.cv_sse / max(self.n, 1)))


def fit(stats: Stats) -> Fit:
    G, h, folds = _fold_solves(stats)
    s = stats.s.sum()
    coef = _solve(G, h)
    sse = float(s - 2 * coef @ h + coef @ G @ coef)
    B = len(stats.s)
    cvb = np.empty(B)
    for b in range(B):
        c = folds[b]
        cvb[b] = stats.s[b] - 2 * c @ stats.h[b] + c @ stats.G[b] @ c
    mean = folds.mean(0) if B else coef
    se = np.sqrt((B - 1) / B * np.sum((folds - mean) ** 2, axis=0)) if B > 1 else np.full(len(h), np.inf)
    return Fit(
        coef=coef / stats.scale, se=se / stats.scale, fold_coef=folds / stats.scale, sse=max(sse, 0.0),
        cv_sse=float(cvb.sum()), cv_block=cvb, n=int(stats.n.sum()),
    )


def paired_t(a: np.ndarray, b: np.ndarray) -> float:
    """Paired t statistic of a − b over blocks (±inf when the differences do not vary, 0 when they are all 0)."""
    d = a - b
    sd = float(np.std(d, ddof=1)) if len(d) > 1 else 0.0
    return float(np.sum(d) / (np.sqrt(len(d)) * sd)) if sd > 0 else float(np.sign(np.sum(d)) * np.inf if np.any(d) else 0.0)


def vertex(x: np.ndarray, y: np.ndarray, i: int) -> float:
    """Minimum of the parabola through the grid points i−1, i, i+1 (the grid point itself at an end)."""
    if i <= 0 or i >= len(x) - 1:
        return float(x[i])
    x0, x1, x2 = x[i - 1 : i + 2]
    y0, y1, y2 = y[i - 1 : i + 2]
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
    if a <= 0:
        return float(x1)
    return float(np.clip(-b / (2 * a), x0, x2))


def _sse(st: Stats) -> float:
    """The in-sample squared error of the full-data fit (``fit(st).sse`` without the fold solves)."""
    G, h, s = st.G.sum(0), st.h.sum(0), st.s.sum()
    coef = _solve(G, h)
    return max(float(s - 2 * coef @ h + coef @ G @ coef), 0.0)


def _train_sse(st: Stats) -> np.ndarray:
    _, h, folds = _fold_solves(st)
    s = st.s.sum()
    out = np.empty(len(st.s))
    for b in range(len(st.s)):
        out[b] = (s - st.s[b]) - folds[b] @ (h - st.h[b])
    return out


def fit_profiled(stats_of: Callable[[float], Stats], grid: np.ndarray) -> tuple[Fit, float, np.ndarray]:
    """The fit with a nonlinear parameter profiled out: on ``grid``, then refined between grid points by a
    parabola through the error curve.

    Returns the fit at the full-data optimum, that optimum, and the per-fold optima. The CV error is
    honest: each held-out block is predicted at the value that is best on the *other* blocks.
    """
    on_grid = [stats_of(float(v)) for v in grid]
    stats = dict(zip((float(v) for v in grid), on_grid, strict=True))
    full = np.array([_sse(st) for st in on_grid])
    train = np.array([_train_sse(st) for st in on_grid])  # (grid, B)
    B = train.shape[1]
    best = vertex(grid, full, int(np.argmin(full)))
    fold_best = np.array([vertex(grid, train[:, b], int(np.argmin(train[:, b]))) for b in range(B)])
    cache: dict[float, Fit] = {}

    def fit_at(v: float) -> Fit:  # a grid point's statistics are not built twice
        if v not in cache:
            cache[v] = fit(stats[v] if v in stats else stats_of(v))
        return cache[v]

    f = fit_at(best)
    cvb = np.array([fit_at(float(fold_best[b])).cv_block[b] for b in range(B)])
    honest = Fit(f.coef, f.se, f.fold_coef, f.sse, float(cvb.sum()), cvb, f.n)
    return honest, best, fold_best
