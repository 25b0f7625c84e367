"""The wall model: the channel walls of a phantom as evenly spaced points (mm) with normals
pointing out of the channel, memoised per phantom and spacing."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom, backbone_frame, entry_frame, entry_walls


@dataclass(frozen=True)
class WallModel:
    """The channel walls sampled evenly, with unit normals pointing out of the channel.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        Wall points (mm, phantom frame).
    normals : ndarray, shape (n, 2)
        Unit normals at the points, pointing away from the channel's interior.
    spacing_mm : float
        Arc-length spacing (mm) of the points.
    group : ndarray of int, shape (n,)
        Part of the channel: 0 the entry walls, 1 the spiral walls up to half a turn, 2 the
        second half-turn, 3 the rest with the closing cap. A rotation about the spiral
        centre hardly moves the log-spiral walls but does move groups 0 and 1.
    room_mm : ndarray, shape (n,)
        Distance (mm) along each point's normal to the next wall beyond it (across a septum
        between turns), ``inf`` where none lies within 1 mm.
    """

    points: np.ndarray
    normals: np.ndarray
    spacing_mm: float
    group: np.ndarray
    room_mm: np.ndarray

    @property
    def length_mm(self) -> float:
        """Total wall length (mm) represented."""
        return len(self.points) * self.spacing_mm

    def subsample(self, spacing_mm: float) -> "WallModel":
        """Every k-th point, so that the spacing is about ``spacing_mm`` (mm) or more."""
        k = max(1, int(round(spacing_mm / self.spacing_mm)))
        return WallModel(self.points[::k], self.normals[::k], self.spacing_mm * k, self.group[::k], self.room_mm[::k])


def _resample(line: np.ndarray, spacing_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``spacing_mm`` (mm) along a polyline, their unit left normals and arc lengths."""
    seg = np.diff(line, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    n = max(2, int(np.floor(s[-1] / spacing_mm)) + 1)
    si = (np.arange(n) + 0.5) * (s[-1] / n)
    pts = np.stack([np.interp(si, s, line[:, 0]), np.interp(si, s, line[:, 1])], axis=1)
    eps = 0.5 * spacing_mm
    ahead = np.stack([np.interp(si + eps, s, line[:, 0]), np.interp(si + eps, s, line[:, 1])], axis=1)
    behind = np.stack([np.interp(si - eps, s, line[:, 0]), np.interp(si - eps, s, line[:, 1])], axis=1)
    tangent = ahead - behind
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    return pts, np.stack([-tangent[:, 1], tangent[:, 0]], axis=1), si


# wall_model's last results, keyed by (phantom, spacing_mm): every registration and every
# check() of the same phantom reuses them (~2.5 ms each). Their arrays are read-only.
_WALL_MODEL_CACHE: dict[tuple[Phantom, float], WallModel] = {}


def wall_model(phantom: Phantom = DEFAULT_PHANTOM, spacing_mm: float = 0.02) -> WallModel:
    """All walls of the channel as evenly spaced points with normals pointing out of it.

    Parameters
    ----------
    phantom : Phantom
        Phantom configuration.
    spacing_mm : float
        Arc-length spacing (mm) of the points.

    Returns
    -------
    WallModel
        Outer and inner spiral walls, the two entry walls and the closing cap at theta_end.
        Every normal points away from the channel's interior, so an edge's polarity (dark to
        bright along the normal or against it) means the same on every wall. The model is
        memoised per phantom and spacing (the last few kept), so its arrays are read-only.
    """
    key = (phantom, float(spacing_mm))
    model = _WALL_MODEL_CACHE.get(key)
    if model is None:
        model = _build_wall_model(phantom, float(spacing_mm))
        for a in (model.points, model.normals, model.group, model.room_mm):
            a.flags.writeable = False
        if len(_WALL_MODEL_CACHE) >= 4:
            _WALL_MODEL_CACHE.clear()
        _WALL_MODEL_CACHE[key] = model
    return model


def _build_wall_model(phantom: Phantom, spacing_mm: float) -> WallModel:
    """:func:`wall_model` computed afresh (phantom lengths in mm)."""
    def outward(nrm: np.ndarray, ref: np.ndarray) -> np.ndarray:
        return np.where((np.sum(nrm * ref, axis=1) < 0)[:, None], -nrm, nrm)

    parts = []
    for wall, sign in ((phantom.outer_wall, 1.0), (phantom.inner_wall, -1.0)):
        pts, nrm, si = _resample(wall.points, spacing_mm)
        half_turns = (np.interp(si, wall.s, wall.theta) - phantom.theta_start) // np.pi
        # out of the channel: away from the spiral centre on the outer wall, towards it on the inner
        parts.append((pts, outward(nrm, sign * pts), 1 + np.minimum(half_turns, 2).astype(int)))
    _, _, n_w = entry_frame(phantom)
    for segment, out in zip(entry_walls(phantom), (n_w, -n_w)):
        pts, nrm, _ = _resample(segment, spacing_mm)
        parts.append((pts, outward(nrm, out[None, :]), np.zeros(len(pts), int)))
    cap = np.stack([phantom.inner_wall.points[-1], phantom.outer_wall.points[-1]])
    pts, nrm, _ = _resample(cap, spacing_mm)
    t_end = backbone_frame(phantom.theta_end, phantom)[1]
    parts.append((pts, outward(nrm, t_end), np.full(len(pts), 3)))
    points, normals = np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])
    return WallModel(points, normals, float(spacing_mm), np.concatenate([p[2] for p in parts]),
                     _room(points, normals, spacing_mm))


def _room(points: np.ndarray, normals: np.ndarray, spacing_mm: float, reach_mm: float = 1.0) -> np.ndarray:
    """Distance (mm) along each outward normal to the next wall beyond (``inf`` within
    ``reach_mm``): the first of the probes every ``spacing_mm`` out from the point that lies
    within a spacing of another wall point."""
    tree = cKDTree(points)
    room = np.full(len(points), np.inf)
    for s in np.arange(3.0 * spacing_mm, reach_mm + 1e-9, spacing_mm):
        todo = np.isinf(room)
        if not todo.any():
            break
        dist, _ = tree.query(points[todo] + s * normals[todo], distance_upper_bound=spacing_mm)
        hit = np.flatnonzero(todo)[np.isfinite(dist)]
        room[hit] = s
    return room
