"""Compiled (numba) kernel of the traffic's hot path: the free distance along each vehicle's path.

Why numba: every frame each of up to 100 vehicles tests up to 550 obstacles (cars as three circles, pedestrians)
against 20 samples of its path; most pairs are rejected by a bounding-box test and the rest stop at their first
hit, which loops do cheaply and array code (all pairs, all samples) does not.
"""

from __future__ import annotations

import math

import numpy as np

from brlcli.jit import jit


@jit
def path_gaps(pose: np.ndarray, path_xy: np.ndarray, obs: np.ndarray, owner: np.ndarray, car_xy: np.ndarray,
              corridor: np.ndarray, obs_half: np.ndarray, samples_m: np.ndarray, reach_m: float,
              length_m: float) -> np.ndarray:
    """Per vehicle: the free distance (m, bumper to obstacle) to the first obstacle on its sampled path.

    pose (V, 3) x, y, yaw; path_xy (V, K, 2) the path at samples_m (K,) ahead; obs (O, 2) obstacle points with their
    corridor half-widths (O,), reach beyond the point along the path obs_half (O,), and owner (O,): the car index
    into car_xy (its centre decides whether it is ahead) or -1 for a pedestrian. A car's own points are skipped, and
    so is a car level with or behind the vehicle."""
    n_v, n_k = path_xy.shape[0], path_xy.shape[1]
    gap = np.full(n_v, np.inf)
    for v in range(n_v):
        px, py = pose[v, 0], pose[v, 1]
        c, s = math.cos(pose[v, 2]), math.sin(pose[v, 2])
        for o in range(obs.shape[0]):
            ox, oy = obs[o, 0], obs[o, 1]
            if abs(ox - px) >= reach_m or abs(oy - py) >= reach_m:
                continue
            w = owner[o]
            if w == v:
                continue
            if w >= 0 and (car_xy[w, 0] - px) * c + (car_xy[w, 1] - py) * s <= 0.0:
                continue
            r2 = corridor[o] * corridor[o]
            for k in range(n_k):
                qx, qy = path_xy[v, k, 0], path_xy[v, k, 1]
                if (qx - ox) ** 2 + (qy - oy) ** 2 < r2:
                    k1, k0 = min(k + 1, n_k - 1), max(k - 1, 0)
                    tx, ty = path_xy[v, k1, 0] - path_xy[v, k0, 0], path_xy[v, k1, 1] - path_xy[v, k0, 1]
                    norm = max(math.sqrt(tx * tx + ty * ty), 1e-9)
                    along = ((ox - qx) * tx + (oy - qy) * ty) / norm  # the obstacle's offset along the tangent
                    g = samples_m[k] + min(max(along, -2.0), 2.0) - length_m / 2 - obs_half[o]
                    if g < gap[v]:
                        gap[v] = g
                    break
    return gap


@jit
def sample_paths(points: np.ndarray, cum: np.ndarray, base: np.ndarray, first: np.ndarray, last: np.ndarray,
                 lengths: np.ndarray, chain: np.ndarray, s0: np.ndarray, samples_m: np.ndarray) -> np.ndarray:
    """Positions (V, K, 2) at arc lengths s0 + samples_m along each vehicle's chain of three polylines (V, 3) of a
    `_PathTable` (points, cumulative lengths, per-polyline base, first and last segment); past the chain's end, its
    last point."""
    n_v, n_k = chain.shape[0], samples_m.shape[0]
    out = np.empty((n_v, n_k, 2))
    for v in range(n_v):
        j = 0
        offset = 0.0  # arc length of the chain before polyline j
        p = chain[v, 0]
        k_seg = first[p]
        for k in range(n_k):
            s = s0[v] + samples_m[k] - offset
            while s > lengths[p] and j < 2:
                offset += lengths[p]
                s -= lengths[p]
                j += 1
                p = chain[v, j]
                k_seg = first[p]
            s = min(max(s, 0.0), lengths[p])
            g = base[p] + s
            while k_seg < last[p] and cum[k_seg + 1] <= g:
                k_seg += 1
            seg = max(cum[k_seg + 1] - cum[k_seg], 1e-9)
            f = (g - cum[k_seg]) / seg
            out[v, k, 0] = points[k_seg, 0] + f * (points[k_seg + 1, 0] - points[k_seg, 0])
            out[v, k, 1] = points[k_seg, 1] + f * (points[k_seg + 1, 1] - points[k_seg, 1])
    return out
