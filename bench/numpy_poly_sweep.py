#!/usr/bin/env python3
"""The reference for `vfp identify LOG --family poly --json`'s speed (README, "Speed and memory").

Reads a log with pandas, builds chamber 0's flow (the logged column), splits the cycles as
`sysid::dataset` does (flow smoothed over 0.2 s, deadband 5 % of the 95th percentile of |v'|,
phases confirmed after 0.2 s, cycle starts moved to where the volume turns by half its range),
holds out one cycle in five (rotating), and sweeps the 49 shapes 1 <= n, m <= 7 of
P = sum c_ij T_i(x) T_j(y) from one Gram matrix of the 64 Chebyshev columns of degree (7, 7)
(built from the moments sum T_r(x) T_s(y), r, s <= 14, as sysid does): each shape's fit is a
Cholesky solve of the Jacobi-scaled sub-block, its training and held-out errors follow from the
Gram matrices alone. The 10-fold cycle-blocked cross-validation the selection uses is done the
same way, from per-fold moments.

Prints the in-process time after the imports (reading included; wall and CPU) and the shape with the lowest
held-out RMSE. Usage: python3 bench/numpy_poly_sweep.py LOG.csv
"""
import sys
import time

import numpy as np
import pandas as pd

MAX_DEG = 7


def smooth(x, h):
    c = np.concatenate(([0.0], np.cumsum(x)))
    i = np.arange(len(x))
    lo = np.maximum(i - h, 0)
    hi = np.minimum(i + h + 1, len(x))
    return (c[hi] - c[lo]) / (hi - lo)


def flow_cycles(f, deadband, min_run):
    """Cycle label per sample: a new cycle at the first sample of each confirmed inflation run
    that follows a confirmed deflation (sysid::dataset::segment_cycles)."""
    sign = np.where(f > deadband, 1, np.where(f < -deadband, -1, 0))
    edges = np.flatnonzero(np.diff(sign)) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [len(sign)]))
    runs = [(s, sign[s]) for s, e in zip(starts, ends) if sign[s] != 0 and e - s >= min_run]
    bounds, phase, seen = [], 0, False
    for s, sg in runs:
        if sg > 0 and phase != 1:
            if seen:
                bounds.append(s)
            seen = True
        phase = 1 if sg > 0 else -1
    return np.asarray(bounds, dtype=int)


def troughs(v, h):
    """Indices of the volume's troughs, turns by at least h (sysid::cycles::turning_points)."""
    out, lo, hi, seeking = [], 0, 0, None
    for i, x in enumerate(v.tolist()):
        if seeking is None:
            if x <= v[lo]:
                lo = i
            if x >= v[hi]:
                hi = i
            if x - v[lo] >= h:
                out.append((lo, True))
                seeking, hi = True, i
            elif v[hi] - x >= h:
                out.append((hi, False))
                seeking, lo = False, i
        elif seeking:
            if x >= v[hi]:
                hi = i
            elif v[hi] - x >= h:
                out.append((hi, False))
                seeking, lo = False, i
        else:
            if x <= v[lo]:
                lo = i
            elif x - v[lo] >= h:
                out.append((lo, True))
                seeking, hi = True, i
    return out


def cycles(t, v, f):
    dt = np.median(np.diff(t))
    n_s = lambda s: max(int(round(s / dt)), 1)
    sm = smooth(f, n_s(0.2) // 2)
    deadband = 0.05 * np.sort(np.abs(sm))[int(round((len(sm) - 1) * 0.95))]
    bounds = flow_cycles(sm, deadband, n_s(0.2))
    q = np.sort(v)
    turns = troughs(v, 0.5 * (q[int(round((len(v) - 1) * 0.95))] - q[int(round((len(v) - 1) * 0.05))]))
    starts = []
    for k, (i, trough) in enumerate(turns):
        if not trough:
            continue
        lo = turns[k - 1][0] if k > 0 else 0
        hi = turns[k + 1][0] if k + 1 < len(turns) else len(v)
        near = bounds[(bounds > lo) & (bounds <= hi)]
        starts.append(int(near[np.argmin(np.abs(near - i))]) if len(near) else i)
    starts = sorted(set(starts))[1:]
    label = np.zeros(len(v), dtype=int)
    label[np.asarray(starts, dtype=int)] = 1
    return np.cumsum(label)


def chebyshev_columns(x, deg):
    t = np.empty((deg + 1, len(x)))
    t[0] = 1.0
    t[1] = x
    for k in range(2, deg + 1):
        t[k] = 2.0 * x * t[k - 1] - t[k - 2]
    return t


def gram_of(mu, idx):
    """Gram matrix of the columns T_i(x) T_j(y), (i, j) in idx, from the moments
    mu[r, s] = sum T_r(x) T_s(y), by T_i T_k = (T_(i+k) + T_|i-k|) / 2."""
    i, j = idx[:, 0], idx[:, 1]
    sx, dx = i[:, None] + i[None, :], np.abs(i[:, None] - i[None, :])
    sy, dy = j[:, None] + j[None, :], np.abs(j[:, None] - j[None, :])
    return 0.25 * (mu[sx, sy] + mu[sx, dy] + mu[dx, sy] + mu[dx, dy])


def moments(tx, ty, y, sel):
    """(mu, b, yy) of the samples sel."""
    tx, ty, y = tx[:, sel], ty[:, sel], y[sel]
    return tx @ ty.T, tx[: MAX_DEG + 1] @ (ty[: MAX_DEG + 1] * y).T, y @ y


def shape(n, m):
    return np.array([(i, j) for i in range(n + 1) for j in range(m + 1)])


def solve(mom, idx):
    g, b = gram_of(mom[0], idx), mom[1][idx[:, 0], idx[:, 1]]
    d = 1.0 / np.sqrt(np.diag(g))
    c = np.linalg.cholesky(g * d[:, None] * d[None, :])
    return np.linalg.solve(c.T, np.linalg.solve(c, b * d)) * d


def sse(mom, idx, c):
    g, b = gram_of(mom[0], idx), mom[1][idx[:, 0], idx[:, 1]]
    return max(mom[2] - 2.0 * c @ b + c @ g @ c, 0.0)


def sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def main(path):
    start, cpu = time.perf_counter(), time.process_time()
    df = pd.read_csv(path, comment="#")
    if "chamber" in df:
        df = df[df["chamber"] == 0]
    t = df["time_s"].to_numpy()
    v = df["volume_mm3"].to_numpy()
    f = df["flow_mm3_s"].to_numpy()
    p = df["pressure_kpa"].to_numpy()
    cyc = cycles(t, v, f)
    n_cyc = cyc[-1] + 1
    k = 5
    held = (cyc + cyc // k) % k == k - 1 if n_cyc >= k else np.arange(len(p)) >= len(p) - len(p) // 5
    sc = ((v.max() + v.min()) / 2, (v.max() - v.min()) / 2, (f.max() + f.min()) / 2, (f.max() - f.min()) / 2)
    tx = chebyshev_columns((v - sc[0]) / sc[1], 2 * MAX_DEG)
    ty = chebyshev_columns((f - sc[2]) / sc[3], 2 * MAX_DEG)
    train = ~held
    y = p - p[train].mean()
    # 10 folds of the training cycles (cycle b to fold b mod 10), each fold's moments; the
    # training moments are their sum
    _, blk = np.unique(cyc[train], return_inverse=True)
    fold = np.full(len(p), -1)
    fold[train] = blk % 10
    mf = [moments(tx, ty, y, fold == q) for q in range(10)]
    mt = tuple(sum(x) for x in zip(*mf))
    mh = moments(tx, ty, y, held)
    best = None
    for n in range(1, MAX_DEG + 1):
        for m in range(1, MAX_DEG + 1):
            idx = shape(n, m)
            c = solve(mt, idx)
            rmse_t = np.sqrt(sse(mt, idx, c) / train.sum())
            rmse_h = np.sqrt(sse(mh, idx, c) / max(held.sum(), 1))
            cv = sum(sse(mf[q], idx, solve(sub(mt, mf[q]), idx)) for q in range(10))
            if best is None or rmse_h < best[0]:
                best = (rmse_h, n, m, rmse_t, np.sqrt(cv / train.sum()))
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    print(f"samples {len(p)} (held out {held.sum()}), cycles {n_cyc}")
    print(f"best held-out: ({best[1]}, {best[2]}) RMSE {best[0]:.4f} kPa (train {best[3]:.4f}, cv {best[4]:.4f})")
    print(f"in-process time after imports: {elapsed * 1000:.0f} ms wall, {cpu * 1000:.0f} ms CPU")


if __name__ == "__main__":
    main(sys.argv[1])
