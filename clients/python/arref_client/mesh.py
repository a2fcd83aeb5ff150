"""Mesh files (PLY, OBJ, STL through Open3D) and their split into HoloLens-like surfaces.

No frame conversion happens here: vertices stay in the file's convention and the surfaces are
sent with that FrameConvention; the server converts (and flips the winding for Unity).
"""

from dataclasses import dataclass

import numpy as np


@dataclass
class Mesh:
    vertices: np.ndarray   # (N, 3) float64, metres
    triangles: np.ndarray  # (M, 3) int64 vertex indices


def load_mesh(path):
    """Reads a PLY, OBJ or STL file through Open3D (Debian's python3-open3d), imported only here.
    Raises ValueError naming the file when it cannot be read or holds no triangles."""
    import os

    import open3d as o3d

    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such file")
    mesh = o3d.io.read_triangle_mesh(path)  # reports a bad file only as a warning and an empty mesh
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    if len(triangles) == 0:
        raise ValueError(f"{path}: cannot read a triangle mesh from it (PLY, OBJ or STL)")
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise ValueError(f"{path}: a face names a vertex outside 0..{len(vertices) - 1}")
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"{path}: non-finite vertex coordinates")
    return Mesh(vertices, triangles)


@dataclass
class SurfacePart:
    corner: np.ndarray     # (3,) the surface's origin in world, in the mesh's convention
    vertices: np.ndarray   # (n, 3) relative to corner
    triangles: np.ndarray  # (m, 3) local indices


def split_into_surfaces(mesh, chunk_m=1.0):
    """One surface per chunk_m cube of a world grid (the cube of each triangle's centroid), in grid
    order, like the spatial mapper's (and the C++ SplitIntoSurfaces)."""
    v = mesh.vertices
    t = mesh.triangles
    centroids = v[t].mean(axis=1)
    keys = np.floor(centroids / chunk_m).astype(np.int64)
    order = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))
    keys, t = keys[order], t[order]
    starts = np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1
    parts = []
    for lo, hi in zip(np.r_[0, starts], np.r_[starts, len(t)]):
        tris = t[lo:hi]
        used, local = np.unique(tris, return_inverse=True)
        corner = keys[lo].astype(np.float64) * chunk_m
        parts.append(SurfacePart(corner, v[used] - corner, local.reshape(-1, 3)))
    return parts
