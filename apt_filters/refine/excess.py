"""Interfacial excess of a solute per object, divided by that object's own surface area.

The excess count does not depend much on where the surface lies (a segregant with equal plateaus
on both sides has none), but the area does: the excess per area of a shrunken marching-cubes
surface is too high by the ratio of the areas. :func:`object_excess` gives both figures for
any surface, so the raw and refined results can be reported side by side.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from apt_filters.contour.components import component_table
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh, topology, vertex_normals
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.band import NearIons
from apt_filters.refine.levels import plateaus, within_rim
from apt_filters.voxel import ConcentrationBasis

EXCESS_WINDOW = (1.0, 3.0)
"""nm from the surface between which :func:`object_excess` measures the solute's plateaus, each side.

The segregation shell, blurred by the reconstruction and by the surface's own noise (~0.2 nm rms), still
holds solute 0.75 nm from the interface (synthetic B shell of sigma 0.25 nm with 0.3/0.1 nm blur: ~3 % of
the excess on each side beyond 0.75 nm): a plateau window from 0.75 nm counts that tail as plateau, so the
expected counts come out high and the excess low. Gamma-prime seeds 1-5, 20 precipitates against their
TRUE surfaces: excess count -4.6 % (mean signed) from 0.75 nm, -1.8 % from 1.0 nm; refined surfaces,
seeds 1-3: -5.4 -> -1.4 %, seeds 4-5: -7.4 -> -3.5 %. From 1.25 or 1.5 nm the bias is no smaller than
the noise of the thinner windows (benchmarks/results_refine.md). The same as the proxigram's excess
(analysis, plateaus 1-3 nm)."""


@dataclass
class ObjectExcess:
    """Excess of one solute at one object's interface.

    Attributes
    ----------
    component : int
    excess_ions : float
        Solute ions in the band ``|d| <= half_width`` minus the plateau fractions times the
        atoms on each side of the surface in that band (Krakauer-Seidman with flat plateaus).
    area : float
        The object's surface area, nm².
    ions_per_nm2 : float
        ``excess_ions / area`` (divide by the detection efficiency for atoms/nm²).
    """

    component: int
    excess_ions: float
    area: float
    ions_per_nm2: float

    def as_dict(self) -> dict:
        return asdict(self)


def object_excess(mesh: TriMesh, ions: IonTable, ranges: RangeTable, solute: str, half_width: float = 1.5,
                  window=EXCESS_WINDOW) -> list[ObjectExcess]:
    """Excess of ``solute`` at each connected surface of ``mesh`` per its own area.

    The solute's plateaus are measured ``window`` nm from the surface each side (:data:`EXCESS_WINDOW`:
    beyond the blurred segregation shell).

    Fractions count every ranged element (the solute must be in the denominator here).
    ``half_width`` (nm) must cover the segregation shell and the blur on both sides. Ions beyond the rim of
    an open surface count nowhere (:func:`~apt_filters.refine.levels.within_rim`).
    """
    components = topology(mesh.faces, mesh.n_vertices).vertex_components
    n_comp = int(components.max()) + 1 if mesh.n_vertices else 0
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    reach = max(window[1], half_width) + 1.0
    ions_near = NearIons.select(ions, ranges, ConcentrationBasis(), vertices, mesh.faces, reach)
    atoms = ions_near.atoms
    if solute not in atoms.elements:
        raise AptFiltersError(f"solute {solute!r} is not a ranged element ({', '.join(atoms.elements)})")
    k = atoms.elements.index(solute)
    band = within_rim(ions_near.band(vertices, vertex_normals(vertices, mesh.faces), reach), ions_near, mesh, reach)
    levels = plateaus(band, atoms, components, n_comp, solute, window)
    near = np.abs(band.distance) <= half_width
    comp = components[band.vertex]
    a = atoms.atoms[band.index]
    total, solute_atoms = a.sum(axis=1).astype(np.float64), a[:, k].astype(np.float64)
    areas = {c.id: c.area for c in component_table(TriMesh(mesh.vertices, mesh.faces,
                                                           face_scalars={"component": mesh.face_components()}))}
    out = []
    for c, lv in enumerate(levels):
        mine = near & (comp == c)
        inside = mine & (band.distance < 0)
        expected = lv.inside[k] * total[inside].sum() + lv.outside[k] * total[mine & ~inside].sum()
        excess = float(solute_atoms[mine].sum() - expected)
        out.append(ObjectExcess(c, excess, areas[c], excess / areas[c]))
    return out
