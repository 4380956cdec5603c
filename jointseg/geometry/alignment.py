"""Yaw alignment: rotate the scan about z so its dominant wall directions are the x and y axes.

The paper's bounding-box step assumes an axis-aligned square room; estimating the dominant
horizontal normal direction first lifts that limit for any yaw.
"""

from __future__ import annotations

import numpy as np

from jointseg.lazy import import_open3d
from jointseg.voxels import cell_centroids, voxel_count

o3d = import_open3d()  # open3d without its Plotly viewer (jointseg.lazy)


def estimate_normals(xyz: np.ndarray, *, k: int = 16) -> np.ndarray:
    """Unit normals from the covariance of each point's ``k`` nearest neighbours (open3d)."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=k))
    return np.asarray(cloud.normals)


def point_normals(xyz: np.ndarray, spacing: float, *, max_voxels: int = 150_000) -> np.ndarray:
    """Normals for every point, computed once per voxel and shared by the voxel's points.

    Normals of a voxel-downsampled copy are as good for plane orientation and an order of
    magnitude cheaper than per-point normals on a dense scan.
    """
    voxel = max(2.0 * spacing, 1e-3)
    # count the cells of each size first: only the size kept is renumbered and averaged
    count, keys = voxel_count(xyz, voxel)
    while count > max_voxels:
        voxel *= 1.5
        count, keys = voxel_count(xyz, voxel)
    inverse, centroids = cell_centroids(xyz, keys)
    if len(centroids) < 4:
        return np.tile([0.0, 0.0, 1.0], (len(xyz), 1))
    normals = estimate_normals(centroids, k=min(16, len(centroids) - 1))
    return np.take(normals, inverse, axis=0)


def dominant_yaw(normals: np.ndarray, *, max_vertical_component: float = 0.3) -> float:
    """Yaw (degrees, in [-45, 45)) of the dominant pair of perpendicular wall directions.

    Normals of vertical surfaces vote with their horizontal angle folded modulo 90 degrees;
    the peak of a smoothed histogram, refined by a circular mean around it, is the answer.
    """
    horizontal = np.abs(normals[:, 2]) < max_vertical_component
    if horizontal.sum() < 10:
        return 0.0
    n = normals[horizontal]
    weight = np.hypot(n[:, 0], n[:, 1])
    theta = np.degrees(np.arctan2(n[:, 1], n[:, 0])) % 90.0
    hist, _ = np.histogram(theta, bins=180, range=(0.0, 90.0), weights=weight)
    kernel = np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2)
    padded = np.concatenate([hist[-6:], hist, hist[:6]])
    smooth = np.convolve(padded, kernel, mode="same")[6:-6]
    peak = (np.argmax(smooth) + 0.5) * 0.5
    # circular mean of the votes within 5 degrees of the peak, on the 90-degree circle
    delta = (theta - peak + 45.0) % 90.0 - 45.0
    near = np.abs(delta) < 5.0
    refined = peak + float(np.average(delta[near], weights=weight[near])) if near.any() else peak
    return float((refined + 45.0) % 90.0 - 45.0)


def rotation_z(yaw_deg: float) -> np.ndarray:
    """3x3 rotation matrix about z by ``yaw_deg`` degrees (counter-clockwise)."""
    a = np.radians(yaw_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
