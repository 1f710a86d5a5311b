"""Bring a sampled signal onto other time stamps without inventing data across gaps.

Every function returns NaN (the flight log's "not measured") before a stream's first sample, after
its last one, and wherever the nearest samples on either side are further apart than the allowed
gap: a 2 s dropout is not bridged by a straight line.
"""

from __future__ import annotations

import numpy as np

from multirotor_ros.io.flight_log import FloatArray


def median_period(ts: FloatArray) -> float:
    """Median interval between consecutive stamps [s] (inf for fewer than 2 stamps)."""
    return float(np.median(np.diff(ts))) if ts.size >= 2 else float("inf")


def sort_unique(ts: FloatArray, values: FloatArray) -> tuple[FloatArray, FloatArray, int]:
    """Stamps sorted, repeated stamps dropped (the first sample wins); returns the number dropped."""
    order = np.argsort(ts, kind="stable")
    ts, values = ts[order], values[order]
    keep = np.concatenate([[True], np.diff(ts) > 0]) if ts.size else np.zeros(0, bool)
    return ts[keep], values[keep], int(ts.size - np.count_nonzero(keep))


def _gap_mask(t: FloatArray, ts: FloatArray, max_gap: float) -> FloatArray:
    """True where t lies outside [ts0, ts-1] or between two samples further apart than max_gap."""
    after = np.searchsorted(ts, t, side="right") - 1
    outside = (after < 0) | (t > ts[-1])
    inside = ~outside & (after < ts.size - 1)
    gap = np.zeros(t.shape)
    gap[inside] = ts[after[inside] + 1] - ts[after[inside]]
    return outside | (gap > max_gap)


def interpolate(t: FloatArray, ts: FloatArray, values: FloatArray, max_gap: float) -> FloatArray:
    """Linear interpolation of samples (ts, values[n, k]) at t -> (len(t), k)."""
    if ts.size == 0:
        return np.full((t.size, values.shape[1]), np.nan)
    out = np.column_stack([np.interp(t, ts, values[:, i]) for i in range(values.shape[1])])
    out[_gap_mask(t, ts, max_gap)] = np.nan
    return out


def hold(t: FloatArray, ts: FloatArray, values: FloatArray, max_age: float) -> FloatArray:
    """Zero-order hold: the latest sample at or before t, if it is at most max_age old."""
    out = np.full((t.size, values.shape[1]), np.nan)
    if ts.size == 0:
        return out
    latest = np.searchsorted(ts, t, side="right") - 1
    valid = latest >= 0
    valid[valid] = (t[valid] - ts[latest[valid]]) <= max_age
    out[valid] = values[latest[valid]]
    return out


def interpolate_quaternion(t: FloatArray, ts: FloatArray, q: FloatArray, max_gap: float) -> FloatArray:
    """Unit quaternions (w, x, y, z) at t: normalised linear interpolation on a sign-continuous sequence.

    q and -q are the same attitude; flipping signs so that neighbours agree keeps the interpolation
    on the short arc. Between samples a few milliseconds apart this equals slerp to ~1e-6 rad.
    """
    q = np.array(q, dtype=float, copy=True)
    if q.shape[0] > 1:
        flips = np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2
        q[1:][flips == 1] *= -1.0
    out = interpolate(t, ts, q, max_gap)
    return out / np.linalg.norm(out, axis=1, keepdims=True)
