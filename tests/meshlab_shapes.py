"""Meshes with exactly known geometry for the meshlab and objects tests (pymeshlab primitives)."""

from __future__ import annotations

import numpy as np
import pymeshlab

from apt_filters.core.mesh import TriMesh


def _primitive(make: str, **params) -> TriMesh:
    ms = pymeshlab.MeshSet()
    getattr(ms, make)(**params)
    m = ms.current_mesh()
    return TriMesh(m.vertex_matrix().copy(), m.face_matrix().astype(np.int64))


def sphere(radius: float = 1.0, center=(0.0, 0.0, 0.0), subdiv: int = 4) -> TriMesh:
    """Icosphere, outward normals; subdiv 4 = 5120 faces, volume 0.2% below the ball's."""
    t = _primitive("create_sphere", subdiv=subdiv)
    return TriMesh(t.vertices * radius + np.asarray(center), t.faces)


def box(size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0)) -> TriMesh:
    """Axis-aligned box, 12 faces, exact area and volume."""
    t = _primitive("create_cube", size=1.0)
    return TriMesh(t.vertices * np.asarray(size) + np.asarray(center), t.faces)


def torus(major: float = 3.0, minor: float = 1.0, center=(0.0, 0.0, 0.0)) -> TriMesh:
    """Torus around z, genus 1 (48 x 24 quads)."""
    t = _primitive("create_torus", hradius=major, vradius=minor, hsubdiv=48, vsubdiv=24)
    return TriMesh(t.vertices + np.asarray(center), t.faces)


def cut_below(mesh: TriMesh, z: float) -> TriMesh:
    """Drop the faces with any vertex below ``z`` (an object open at a flat specimen edge)."""
    keep = (mesh.vertices[mesh.faces, 2] >= z).all(axis=1)
    used = np.unique(mesh.faces[keep])
    remap = np.full(mesh.n_vertices, -1)
    remap[used] = np.arange(len(used))
    return TriMesh(mesh.vertices[used], remap[mesh.faces[keep]])


def merge(*meshes: TriMesh) -> TriMesh:
    """One mesh holding all the given ones as separate components."""
    offsets = np.cumsum([0] + [m.n_vertices for m in meshes[:-1]])
    return TriMesh(np.concatenate([m.vertices for m in meshes]),
                   np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]))
