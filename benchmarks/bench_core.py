"""The geometry layer's ion selection: the ions near a surface, in one streamed pass, against a KD-tree.

    python -m benchmarks.bench_core            # gamma-prime preset (~1.2 M ions), seed 1
    python -m benchmarks.bench_core --quick    # small preset (~250 k ions)

The surface: the specimen's Al iso-surface at 15 at.% (marching cubes, 1 nm voxels, specks removed,
subdivided once, as the refinement starts). Ours: :func:`apt_filters.core.nearby.select_near` within
4 nm (the refinement's selection radius), exact signed distances from the grid engine, streamed in
chunks; then the refinement's selection as a whole, :meth:`apt_filters.refine.band.NearIons.select`
(the walk to each ion's nearest vertex included). The peer: scipy's ``cKDTree`` over the vertices,
``query(..., distance_upper_bound=4)`` on every ion (nearest vertex within reach, what a selection
without a distance engine does). Both in the same process, one after the other, best of three.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from apt_filters.contour import marching_cubes
from apt_filters.core.nearby import select_near
from apt_filters.refine import remove_specks
from apt_filters.refine.subdivide import subdivide
from apt_filters.refine.band import NearIons
from apt_filters.synth import generate, preset
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize
from benchmarks.results import best_of, ratio, write_results

REACH = 4.0
NO_B = ConcentrationBasis(exclude=("B",))


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    name = "small" if args.quick else "gamma-prime"
    sp = generate(preset(name), seed=1)
    fields = voxelize(sp.ions, sp.ranges)
    c = fields.concentration("Al", NO_B).dense()
    mask = inside_mask(fields).dense()
    mesh = subdivide(remove_specks(marching_cubes(c, 0.15, spacing=fields.grid.voxel, origin=fields.grid.origin,
                                                  mask=mask), fields=fields, mask=mask, ions=sp.ions, ranges=sp.ranges,
                                   species="Al", iso=0.15, basis=NO_B)[0])
    positions = sp.ions.positions
    select_near(positions[:1000], mesh, REACH)  # compile
    NearIons.select(sp.ions.subset(slice(0, 1000)), sp.ranges, NO_B, mesh.vertices, mesh.faces, REACH)
    ours, near = best_of(lambda: select_near(positions, mesh, REACH))
    whole, _ = best_of(lambda: NearIons.select(sp.ions, sp.ranges, NO_B, mesh.vertices, mesh.faces, REACH))
    tree = cKDTree(mesh.vertices)
    peer, (d, _) = best_of(lambda: tree.query(positions, distance_upper_bound=REACH))
    n = len(positions)
    rows = [("core", f"ions within {REACH:g} nm of a {mesh.n_faces:,}-face surface, {n:,} ions", f"{ours:.2f} s",
             f"{peer:.2f} s (cKDTree, nearest vertex)", ratio(ours, peer)),
            ("core", "refinement's ion selection (NearIons.select, same ions)", f"{whole:.2f} s", "-", "-")]
    detail = "\n".join([
        "## Near-surface selection", "",
        f"Specimen: `{name}` seed 1, {n:,} ions; surface {mesh.n_vertices:,} vertices, {mesh.n_faces:,} faces. "
        f"Within {REACH:g} nm of the surface: {len(near.rows):,} ions (exact distance); within {REACH:g} nm of a "
        f"vertex: {int(np.isfinite(d).sum()):,}. Best of 3, wall time."])
    path = write_results("core", "Core: the ions near a surface", rows, [detail], intro=__doc__.split("\n\n", 2)[2])
    text = path.read_text()
    print(text)
    return text


if __name__ == "__main__":
    main()
