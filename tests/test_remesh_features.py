"""Feature detection (remesh/features.py) against sheets folded by a known angle."""

import numpy as np
from scipy.spatial import cKDTree

from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import features as feat, quality, remesh
from tests import remesh_shapes as shapes

EDGE = 0.5  # target edge (nm); the sheets' grid step is 0.25


def folded_sheet(fold: float, fade: tuple[float, float] | None = None, step: float = 0.25) -> TriMesh:
    """An open square sheet, x and y in [-2, 2], folded along x = 0 by ``fold`` degrees (the part at
    x > 0 turned up); with ``fade`` = (y0, y1) the fold angle falls to 0 between y0 and y1 (half a
    cosine, so that the sheet has no kink across the fade) and the two sides join past the
    crease's end (one patch)."""
    n = int(round(4 / step)) + 1
    x, y = np.meshgrid(np.linspace(-2, 2, n), np.linspace(-2, 2, n), indexing="ij")
    angle = np.full_like(y, np.radians(fold))
    if fade is not None:
        angle *= 0.5 + 0.5 * np.cos(np.pi * np.clip((y - fade[0]) / (fade[1] - fade[0]), 0.0, 1.0))
    xp = np.maximum(x, 0.0)
    vertices = np.c_[np.minimum(x, 0.0).ravel() + (xp * np.cos(angle)).ravel(), y.ravel(), (xp * np.sin(angle)).ravel()]
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a, b, c, d = (i * n + j).ravel(), ((i + 1) * n + j).ravel(), ((i + 1) * n + j + 1).ravel(), (i * n + j + 1).ravel()
    return TriMesh(vertices, np.r_[np.c_[a, b, c], np.c_[a, c, d]])


def fold_edges(mesh: TriMesh, y_max: float) -> np.ndarray:
    """(e,) bool: edges on the fold line x = 0 with y below ``y_max``."""
    ends = mesh.vertices[mesh.topology.edge_vertices]
    on = (np.abs(ends[..., 0]) < 1e-9).all(axis=1) & (np.abs(ends[..., 2]) < 1e-9).all(axis=1)
    return on & (ends[..., 1].max(axis=1) <= y_max + 1e-9)


def test_crease_inside_one_patch_is_a_curve():
    """A 70° fold that fades out at the sheet's far rim: its two sides are one patch, yet every fold
    edge where the fold is sharp (over 60° up to y = 0.5) is on a feature curve, and no edge off
    the fold is."""
    mesh = folded_sheet(70.0, fade=(0.0, 2.0))
    found = feat.detect(mesh, 40.0, min_area=EDGE**2, miss=0.125 * EDGE)
    assert found.n_patches == 1
    sharp = fold_edges(mesh, 0.5)
    assert found.edge[sharp].all()
    boundary = mesh.topology.edge_faces == 1
    fold_line = fold_edges(mesh, 2.0)
    assert not found.edge[~boundary & ~fold_line].any()
    # without the chord-miss rule (the default) a crease inside a patch is no feature
    assert not feat.detect(mesh, 40.0, min_area=EDGE**2).edge[sharp].any()


def test_remesh_keeps_a_crease_inside_one_patch():
    """The remesh of the fading fold keeps it: its output edges over 40° cover the sharp part of the
    fold line within a tenth of the edge (the benchmark's feature F1 tolerance)."""
    mesh = folded_sheet(70.0, fade=(0.0, 2.0))
    result = remesh(mesh, edge_length=EDGE)
    assert result.kept_input == 0
    out = result.mesh
    reference = quality.sample_edges(mesh.vertices, mesh.topology.edge_vertices[fold_edges(mesh, 0.5)], 0.05)
    kept = quality.sample_edges(out.vertices, quality.feature_edges(out), 0.05)
    assert len(kept) and np.all(cKDTree(kept).query(reference)[0] <= 0.1 * EDGE)


def test_bends_of_a_coarse_curved_surface_are_no_creases():
    """A marching-cubes gyroid at 1 nm (no crease anywhere) has lone edges turned by just over 40°,
    its curvature across one coarse edge; over two faces a side the turn fades: no curve is made of
    them (only the open rim's curves)."""
    mesh = shapes.gyroid(half=8.0)
    assert len(quality.feature_edges(mesh)) > 0
    found = feat.detect(mesh, 40.0, min_area=EDGE**2, miss=0.125 * EDGE)
    pair = mesh.topology.edge_pairs()
    border = (pair[:, 1] >= 0) & (found.patch[pair[:, 0]] != found.patch[np.maximum(pair[:, 1], 0)])
    boundary = mesh.topology.edge_faces == 1
    assert not found.edge[~boundary & ~border].any()
