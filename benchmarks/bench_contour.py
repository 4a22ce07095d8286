"""Contouring benchmark: our marching cubes / dual contouring vs skimage (Lewiner) and VTK flying edges.

Run ``python -m benchmarks.bench_contour [--quick]``. Prints markdown tables:

1. time on the same 256³ field (128³ with --quick), ratios to skimage;
2. scaling with the number of active cells on a sparse 256³ field (few small spheres);
3. quality of every method on every analytic shape at 128³ (64³ with --quick).

All methods run in the same process one after another (the timing table round-robin over
the repeats), so their ratios share the machine's load; best of ``repeats`` wall-clock runs.
"""

from __future__ import annotations

import argparse

import numpy as np

from apt_filters.contour import dual_contouring, marching_cubes, surface_nets
from apt_filters.contour.cells import find_active_cells, prepare_field
from apt_filters.truth.metrics import evaluate
from apt_filters.truth.shapes import benchmark_shapes, field_gradient, grid
from apt_filters.core.mesh import TriMesh
from benchmarks.results import best_of, ratio, write_results


def skimage_mc(values, iso, spacing, origin) -> TriMesh:
    from skimage.measure import marching_cubes as sk

    verts, faces, _, _ = sk(values, iso, spacing=tuple(spacing), method="lewiner")
    return TriMesh(verts + origin, faces)


def vtk_flying_edges(values, iso, spacing, origin) -> TriMesh:
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    image = vtk.vtkImageData()
    image.SetDimensions(*values.shape)
    image.SetSpacing(*spacing)
    image.SetOrigin(*origin)
    image.GetPointData().SetScalars(numpy_to_vtk(values.ravel(order="F"), deep=False))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, iso)
    fe.ComputeNormalsOff()
    fe.ComputeGradientsOff()
    fe.ComputeScalarsOff()
    fe.Update()
    out = fe.GetOutput()
    verts = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    faces = vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    return TriMesh(verts, faces)


def outward(mesh: TriMesh) -> TriMesh:
    """Peers wind their triangles their own way: flip to outward normals for the metrics."""
    return mesh if mesh.signed_volume() >= 0 else TriMesh(mesh.vertices, mesh.faces[:, ::-1])


def timing_table(n: int, repeats: int) -> str:
    shape_name = "box_minus_sphere"  # flat, curved, convex and concave edges
    values, spacing, origin = grid(benchmark_shapes()[shape_name], n)
    methods = {
        "skimage lewiner": lambda: skimage_mc(values, 0.0, spacing, origin),
        "VTK flying edges": lambda: vtk_flying_edges(values, 0.0, spacing, origin),
        "ours MC": lambda: marching_cubes(values, 0.0, spacing, origin),
        "ours DC (field normals)": lambda: dual_contouring(values, 0.0, spacing, origin),
        "ours DC (no self-intersection repair)": lambda: dual_contouring(values, 0.0, spacing, origin,
                                                                         repair_intersections=False),
        "ours surface nets": lambda: surface_nets(values, 0.0, spacing, origin),
    }
    marching_cubes(values[:8, :8, :8], 0.0)  # build the case table outside the timings
    times = {name: (np.inf, None) for name in methods}
    for _ in range(repeats):  # round-robin, so that every method sees the same spells of load
        for name, fn in methods.items():
            t, mesh = best_of(fn, 1)
            times[name] = (min(t, times[name][0]), mesh)
    ref = times["skimage lewiner"][0]
    rows = [f"Field: {shape_name}, {n}³ float64.", "", "| method | time (s) | × skimage | faces |", "|---|---|---|---|"]
    for name, (t, mesh) in times.items():
        rows.append(f"| {name} | {t:.3f} | {t / ref:.2f} | {mesh.n_faces} |")
    return "\n".join(rows)


def scaling_table(n: int, repeats: int) -> str:
    rng = np.random.default_rng(1)
    axis = np.arange(n, dtype=np.float64)
    rows = [f"Sparse {n}³ fields of k spheres (radius 6 voxels).", "",
            "| spheres | active cells | ours MC (s) | ours DC (s) | skimage (s) | MC µs/active cell |",
            "|---|---|---|---|---|---|"]
    for k in (1, 8, 64):
        values = np.full((n, n, n), -10.0)
        for c in rng.uniform(10, n - 10, size=(k, 3)):
            lo, hi = np.maximum((c - 9).astype(int), 0), np.minimum((c + 10).astype(int), n)
            sub = np.meshgrid(*[axis[lo[a]:hi[a]] for a in range(3)], indexing="ij")
            d = 6.0 - np.sqrt(sum((sub[a] - c[a]) ** 2 for a in range(3)))
            values[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = np.maximum(values[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]], d)
        active = len(find_active_cells(prepare_field(values, 0.0, 1, 0, None, False)).cell)
        t_mc = best_of(lambda: marching_cubes(values, 0.0), repeats)[0]
        t_dc = best_of(lambda: dual_contouring(values, 0.0), repeats)[0]
        t_sk = best_of(lambda: skimage_mc(values, 0.0, np.ones(3), np.zeros(3)), repeats)[0]
        rows.append(f"| {k} | {active} | {t_mc:.3f} | {t_dc:.3f} | {t_sk:.3f} | {1e6 * t_mc / active:.1f} |")
    return "\n".join(rows)


COLUMNS = ["hausdorff", "chamfer", "normal_consistency", "edge_chamfer", "edge_f1", "min_angle", "q_mean",
           "boundary_edges", "non_manifold_edges", "non_manifold_vertices", "folded_pairs", "self_intersections"]


def quality_table(n: int, names: list[str] | None = None) -> str:
    rows = [f"Grid {n}³ on [-1, 1]³ (h = {2 / (n - 1):.4f} nm); distances in voxels; "
            "peers' faces flipped to outward where needed.", "",
            "| shape | method | " + " | ".join(COLUMNS) + " |", "|" + "---|" * (len(COLUMNS) + 2)]
    for shape_name, shape in benchmark_shapes().items():
        if names and shape_name not in names:
            continue
        values, spacing, origin = grid(shape, n)
        methods = {
            "skimage": lambda: outward(skimage_mc(values, 0.0, spacing, origin)),
            "VTK FE": lambda: outward(vtk_flying_edges(values, 0.0, spacing, origin)),
            "MC": lambda: marching_cubes(values, 0.0, spacing, origin),
            "DC exact normals": lambda: dual_contouring(values, 0.0, spacing, origin, gradient=field_gradient(shape)),
            "DC eno": lambda: dual_contouring(values, 0.0, spacing, origin),
            "DC central": lambda: dual_contouring(values, 0.0, spacing, origin, field_gradient="central"),
            "DC fit": lambda: dual_contouring(values, 0.0, spacing, origin, field_gradient="fit"),
            "surface nets": lambda: surface_nets(values, 0.0, spacing, origin),
        }
        for name, fn in methods.items():
            r = evaluate(fn(), shape, spacing[0]).as_dict()
            cells = [f"{r[c]:.3f}" if isinstance(r[c], float) else str(r[c]) for c in COLUMNS]
            rows.append(f"| {shape_name} | {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


TITLE = "Contouring (`apt_filters.contour`): marching cubes and dual contouring against skimage and VTK"
INTRO = ("All methods run in the same process one after another (the time table round-robin over the repeats, "
         "best of 3), so their ratios share the machine's load. Quality: distances in voxels; Hausdorff / Chamfer "
         "two-sided between uniform samples (20 per h²) of mesh and true surface; normal consistency: mean signed dot "
         "of face normal and true normal; edge metrics (NMC/NDC definition, thresholds scaled to the voxel): a sample "
         "(40 per h²) is an edge point if a sample within 0.3 h has a normal more than 78.5° away; edge F1 with match "
         "distance 0.3 h. DC rows: `dual_contouring` with exact normals (reference), ENO field normals (the default), "
         "central differences and least-squares fits.")


def _cell(table: str, first: str, second: str, column: int) -> float:
    """A figure of a markdown table: the row starting with cells ``first | second``, 0-based ``column``."""
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[:2] == [first, second] or (second == "" and cells[0] == first):
            return float(cells[column])
    raise KeyError((first, second))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller grids (128³ timing, 64³ quality)")
    parser.add_argument("--part", choices=["time", "scaling", "quality", "all"], default="all")
    parser.add_argument("--shapes", help="comma-separated shape names for the quality table (default: all)")
    args = parser.parse_args()
    big, small, repeats = (128, 64, 1) if args.quick else (256, 128, 3)
    sections, rows = [], []
    if args.part in ("time", "all"):
        table = timing_table(big, repeats)
        sections.append(f"## Time, {big}³ field\n\n{table}")
        sk = _cell(table, "skimage lewiner", "", 1)
        for name, label in (("ours MC", "marching cubes"), ("ours DC (field normals)", "dual contouring")):
            ours = _cell(table, name, "", 1)
            rows.append(("contour", f"{label}, {big}³ field (box minus sphere), time", f"{ours:.3f} s",
                         f"{sk:.3f} s (skimage Lewiner)", ratio(ours, sk)))
    if args.part in ("scaling", "all"):
        sections.append(f"## Scaling with active cells, {big}³\n\n" + scaling_table(big, repeats))
    if args.part in ("quality", "all"):
        table = quality_table(small, args.shapes.split(",") if args.shapes else None)
        sections.append(f"## Quality, all shapes × methods, {small}³\n\n{table}")
        if args.shapes is None:
            for measure, column in (("edge F1", 6), ("Hausdorff (voxels)", 2)):
                ours, peer = _cell(table, "rotated_box", "DC eno", column), _cell(table, "rotated_box", "skimage", column)
                rows.append(("contour", f"{measure}, rotated box, {small}³, dual contouring (ENO normals)",
                             f"{ours:.3f}", f"{peer:.3f} (skimage Lewiner)", ratio(ours, peer)))
    print("\n\n".join(sections))
    # the full run is made in parts (--part, --quick for 64³ quality): each part keeps the others' tables
    write_results("contour", TITLE, rows, sections, intro=INTRO, merge=True)

if __name__ == "__main__":
    main()
