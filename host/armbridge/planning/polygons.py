"""Planar polylines against polygons, in numba: the geometry both robots' checkers share.

An arm in the plane is a polyline of n links (base, joints, tip). Obstacles
are polygons (k >= 2 vertices; a 2-vertex polygon is a wall segment, as in
OMPL's kinematic-chain environments) packed into three arrays:

* verts (V, 2): every polygon's vertices, one after the other;
* starts (P+1,): polygon p is verts[starts[p]:starts[p+1]];
* bbox (P, 4): each polygon's box (xmin, ymin, xmax, ymax) grown by the margin.

`points_hit` answers "does any link come within sqrt(r2) of a polygon" (the
exact Minkowski sum of the polygon with a disc, not a buffered copy);
`points_clearance` gives each link's distance to the nearest polygon (0 when
it crosses an edge or lies inside): the dist_l of the WJRRT paper's eq. (8),
which the paper computes with GJK; for a segment against a polygon in the
plane the exact distance is the least of the edge-edge distances, so no
iterative solver is needed. `self_hit` checks non-adjacent links against
each other (the self-collision of OMPL's KinematicChainValidityChecker).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def pt_seg_d2(px, py, ax, ay, bx, by):
    """Squared distance from point p to segment ab."""
    vx, vy = bx - ax, by - ay
    wx, wy = px - ax, py - ay
    vv = vx * vx + vy * vy
    t = 0.0
    if vv > 0.0:
        t = (wx * vx + wy * vy) / vv
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    dx, dy = wx - t * vx, wy - t * vy
    return dx * dx + dy * dy


@njit(cache=True)
def seg_seg_d2(ax, ay, bx, by, cx, cy, dx, dy):
    """Squared distance between segments ab and cd; 0 when they cross."""
    o1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    o2 = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
    o3 = (dx - cx) * (ay - cy) - (dy - cy) * (ax - cx)
    o4 = (dx - cx) * (by - cy) - (dy - cy) * (bx - cx)
    if ((o1 > 0.0 and o2 < 0.0) or (o1 < 0.0 and o2 > 0.0)) and ((o3 > 0.0 and o4 < 0.0) or (o3 < 0.0 and o4 > 0.0)):
        return 0.0
    m = pt_seg_d2(ax, ay, cx, cy, dx, dy)
    v = pt_seg_d2(bx, by, cx, cy, dx, dy)
    if v < m:
        m = v
    v = pt_seg_d2(cx, cy, ax, ay, bx, by)
    if v < m:
        m = v
    v = pt_seg_d2(dx, dy, ax, ay, bx, by)
    if v < m:
        m = v
    return m


@njit(cache=True)
def inside(px, py, verts, s, e):
    """Even-odd point-in-polygon for the vertices verts[s:e] (never inside a 2-vertex wall)."""
    res = False
    j = e - 1
    for i in range(s, e):
        xi, yi = verts[i, 0], verts[i, 1]
        xj, yj = verts[j, 0], verts[j, 1]
        if (yi > py) != (yj > py):
            xc = xi + (py - yi) * (xj - xi) / (yj - yi)
            if px < xc:
                res = not res
        j = i
    return res


@njit(cache=True)
def chain_points(q, lengths, bx, by, bth, pts):
    """Fill pts (n+1, 2) with the polyline of relative joint angles q[:n], base (bx, by), heading bth."""
    n = lengths.size
    th = bth
    x = bx
    y = by
    pts[0, 0] = x
    pts[0, 1] = y
    for j in range(n):
        th += q[j]
        x += lengths[j] * math.cos(th)
        y += lengths[j] * math.sin(th)
        pts[j + 1, 0] = x
        pts[j + 1, 1] = y


@njit(cache=True)
def points_hit(pts, verts, starts, bbox, r2):
    """First (polygon, link) the polyline pts touches, encoded poly * n_links + link; -1 if free."""
    nl = pts.shape[0] - 1
    axmin = pts[0, 0]
    axmax = pts[0, 0]
    aymin = pts[0, 1]
    aymax = pts[0, 1]
    for k in range(1, nl + 1):
        axmin = min(axmin, pts[k, 0])
        axmax = max(axmax, pts[k, 0])
        aymin = min(aymin, pts[k, 1])
        aymax = max(aymax, pts[k, 1])
    for p in range(starts.size - 1):
        if axmax < bbox[p, 0] or axmin > bbox[p, 2] or aymax < bbox[p, 1] or aymin > bbox[p, 3]:
            continue
        s, e = starts[p], starts[p + 1]
        for k in range(nl):
            ax, ay, bx, by = pts[k, 0], pts[k, 1], pts[k + 1, 0], pts[k + 1, 1]
            if (max(ax, bx) < bbox[p, 0] or min(ax, bx) > bbox[p, 2]
                    or max(ay, by) < bbox[p, 1] or min(ay, by) > bbox[p, 3]):
                continue
            if inside(ax, ay, verts, s, e):
                return p * nl + k
            j = e - 1
            for i in range(s, e):
                if seg_seg_d2(ax, ay, bx, by, verts[j, 0], verts[j, 1], verts[i, 0], verts[i, 1]) <= r2:
                    return p * nl + k
                j = i
    return -1


@njit(cache=True)
def points_clearance(pts, verts, starts, out):
    """out[k] = distance of link k to the nearest polygon (0 inside or crossing); returns the least.

    With no polygons every entry is inf.
    """
    nl = pts.shape[0] - 1
    least = np.inf
    for k in range(nl):
        ax, ay, bx, by = pts[k, 0], pts[k, 1], pts[k + 1, 0], pts[k + 1, 1]
        best = np.inf
        for p in range(starts.size - 1):
            s, e = starts[p], starts[p + 1]
            if inside(ax, ay, verts, s, e):
                best = 0.0
                break
            j = e - 1
            for i in range(s, e):
                d2 = seg_seg_d2(ax, ay, bx, by, verts[j, 0], verts[j, 1], verts[i, 0], verts[i, 1])
                if d2 < best:
                    best = d2
                j = i
            if best == 0.0:
                break
        out[k] = math.sqrt(best) if best < np.inf else np.inf
        if out[k] < least:
            least = out[k]
    return least


@njit(cache=True)
def obstacle_clearance(pts, verts, starts, bbox, out):
    """out[k] = distance of link k's centre line to the nearest polygon (0 inside or crossing), as
    points_clearance (the same loop; this one is the certified edge check's, in its inner loop),
    skipping polygons whose box is already farther than the best (boxes are a lower
    bound); returns the least."""
    nl = pts.shape[0] - 1
    least = np.inf
    for k in range(nl):
        ax, ay, bx, by = pts[k, 0], pts[k, 1], pts[k + 1, 0], pts[k + 1, 1]
        x0, x1, y0, y1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
        best = np.inf
        for p in range(starts.size - 1):
            gx = max(bbox[p, 0] - x1, x0 - bbox[p, 2], 0.0)
            gy = max(bbox[p, 1] - y1, y0 - bbox[p, 3], 0.0)
            if gx * gx + gy * gy >= best:
                continue
            s, e = starts[p], starts[p + 1]
            if inside(ax, ay, verts, s, e):
                best = 0.0
                break
            j = e - 1
            for i in range(s, e):
                d2 = seg_seg_d2(ax, ay, bx, by, verts[j, 0], verts[j, 1], verts[i, 0], verts[i, 1])
                if d2 < best:
                    best = d2
                j = i
            if best == 0.0:
                break
        out[k] = math.sqrt(best) if best < np.inf else np.inf
        if out[k] < least:
            least = out[k]
    return least


@njit(cache=True)
def self_hit(pts, r2):
    """True when two non-adjacent links of the polyline pts come within sqrt(r2) of each other."""
    nl = pts.shape[0] - 1
    for a in range(nl - 2):
        for b in range(a + 2, nl):
            if seg_seg_d2(pts[a, 0], pts[a, 1], pts[a + 1, 0], pts[a + 1, 1],
                          pts[b, 0], pts[b, 1], pts[b + 1, 0], pts[b + 1, 1]) <= r2:
                return True
    return False


def polygon_arrays(polygons: Sequence[Any], r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(verts, starts, bbox) of the module doc for polygons given as (k, 2) vertex lists; bbox grown by r."""
    polys = [np.asarray(p, dtype=float).reshape(-1, 2) for p in polygons]
    verts = np.ascontiguousarray(np.concatenate(polys, axis=0)) if polys else np.zeros((0, 2))
    starts = np.zeros(len(polys) + 1, dtype=np.int64)
    starts[1:] = np.cumsum([len(p) for p in polys])
    bbox = np.zeros((len(polys), 4))
    for i, p in enumerate(polys):
        bbox[i] = [p[:, 0].min() - r, p[:, 1].min() - r, p[:, 0].max() + r, p[:, 1].max() + r]
    return verts, starts, bbox
