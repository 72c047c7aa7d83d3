"""The row's geometry as the simulator measures it: projection onto the centreline, and the
trajectory record. Evaluation metrics build on these (`segmin.nav_eval.evaluation.metrics`); they
live here because the simulator ends a run by the same projection."""

from __future__ import annotations

import dataclasses
import math

import numpy as np


def project_onto_polyline(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project points (N, 2) onto a polyline (K, 2): `PolylineProjection(polyline).project(points)`."""
    return PolylineProjection(polyline).project(points)


class PolylineProjection:
    """A polyline's segments, computed once, onto which points are projected.

    The simulator projects the robot onto the row's centreline at every physics tick; the
    segments' lengths, directions and arc lengths are the same each time, and computing them
    was half the projection's cost."""

    def __init__(self, polyline: np.ndarray) -> None:
        line = np.asarray(polyline, dtype=float)
        if line.ndim != 2 or line.shape[0] < 2 or line.shape[1] != 2:
            raise ValueError(f"centreline must be (K>=2, 2), got {line.shape}")
        a, b = line[:-1], line[1:]
        seg = b - a
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        keep = seg_len > 1e-12
        self.a, self.seg, self.seg_len = a[keep], seg[keep], seg_len[keep]
        self.seg_len2 = self.seg_len**2
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])[:-1]
        self.lo = np.zeros(self.seg_len.shape)
        self.hi = np.ones(self.seg_len.shape)
        self.lo[0] = -np.inf  # extend before the entrance
        self.hi[-1] = np.inf  # and after the exit

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, lateral, tangent) of points (N, 2): arc length of the projection from the first
        vertex (the first and last segments are extended beyond the ends, so s < 0 before the
        entrance), signed lateral offset (left of the direction of travel positive) and the
        tangent angle."""
        a, seg, seg_len = self.a, self.seg, self.seg_len
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        rel = pts[:, None, :] - a[None, :, :]  # N x S x 2
        t = (rel * seg[None]).sum(-1) / self.seg_len2[None]  # N x S
        tc = np.clip(t, self.lo, self.hi)
        foot = a[None] + tc[..., None] * seg[None]
        dist2 = ((pts[:, None, :] - foot) ** 2).sum(-1)
        k = np.argmin(dist2, axis=1)
        rows = np.arange(pts.shape[0])
        s = self.cum[k] + tc[rows, k] * seg_len[k]
        d = seg[k] / seg_len[k, None]
        r = pts - a[k]
        lateral = d[:, 0] * r[:, 1] - d[:, 1] * r[:, 0]  # cross(d, r): left positive
        tangent = np.arctan2(d[:, 1], d[:, 0])
        return s, lateral, tangent


def polyline_length(polyline: np.ndarray) -> float:
    line = np.asarray(polyline, dtype=float)
    return float(np.hypot(*np.diff(line, axis=0).T).sum())


@dataclasses.dataclass
class Trajectory:
    """What the simulator records at every tick (arrays of equal length)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    plant_distance: np.ndarray  # footprint-to-nearest-trunk gap per tick (inf when no plants)

    @classmethod
    def from_rows(cls, rows: list[tuple[float, ...]]) -> Trajectory:
        arr = np.asarray(rows, dtype=float).reshape(-1, 7)
        return cls(*(arr[:, i].copy() for i in range(7)))

    def to_dict(self, digits: int = 5) -> dict[str, list[float]]:
        """JSON-ready lists, rounded (1e-5 m is far below anything measured; keeps files small)."""
        return {f.name: [round(float(v), digits) for v in getattr(self, f.name)] for f in dataclasses.fields(self)}


def point_on_polyline(polyline: np.ndarray, s: float) -> tuple[float, float, float]:
    """(x, y, tangent angle) at arc length s along the polyline (extrapolated past the ends)."""
    line = np.asarray(polyline, dtype=float)
    seg = np.diff(line, axis=0)
    lens = np.hypot(seg[:, 0], seg[:, 1])
    keep = lens > 1e-12
    a, seg, lens = line[:-1][keep], seg[keep], lens[keep]
    cum = np.concatenate([[0.0], np.cumsum(lens)])
    k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(lens) - 1))
    u = (s - cum[k]) / lens[k]
    p = a[k] + u * seg[k]
    return float(p[0]), float(p[1]), float(math.atan2(seg[k, 1], seg[k, 0]))
