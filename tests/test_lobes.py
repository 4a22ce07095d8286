"""Noise lobes joined to a low-contrast object (issue 25): each part of a component tested like a speck.

Truth: a synthetic specimen whose only object is a sphere; every part of the surface farther than the interface
from it is noise by construction.
"""

import numpy as np
import pytest

from apt_filters.core.mesh import split_components
from apt_filters.refine import remove_specks
from apt_filters.refine.specks import trim_lobes
from tests.speck_specimens import contoured_sphere

CENTRE, RADIUS = (0.0, 0.0, -10.0), 3.5


def _trimmed(contrast: float, seed: int):
    """A 3.5 nm-radius sphere ``contrast`` richer in Al than the matrix (efficiency 0.4), contoured midway; the
    surface after the speck test, after :func:`trim_lobes`, and what it did."""
    iso = 0.10 + contrast / 2
    c = contoured_sphere(centre=CENTRE, radius=RADIUS, contrast=contrast, width=0.3, box=20.0, efficiency=0.4,
                         iso=iso, seed=seed)
    ions, ranges = c.specimen.ions, c.specimen.ranges
    kept, specks = remove_specks(c.mesh, fields=c.fields, mask=c.mask, ions=ions, ranges=ranges, species="Al", iso=iso)
    out, lobes = trim_lobes(kept, specks, values=c.values, fields=c.fields, mask=c.mask, ions=ions, ranges=ranges,
                            species="Al", iso=iso)
    return kept, out, lobes


def _beyond(mesh) -> np.ndarray:
    """nm each vertex lies outside the true sphere."""
    return np.linalg.norm(mesh.vertices - CENTRE, axis=1) - RADIUS


@pytest.mark.parametrize("seed", [1, 6])
def test_a_noise_lobe_joined_to_a_5_point_sphere_is_trimmed(seed):
    before, after, lobes = _trimmed(0.05, seed)
    # the first contour after the speck test: one component, reaching well beyond the sphere (a lobe)
    assert len(split_components(before)) == 1 and _beyond(before).max() > 3.5
    assert lobes.removed >= 1 and lobes.tested > lobes.removed and lobes.volume > 0
    parts = split_components(after)
    assert len(parts) == 1
    assert _beyond(after).max() < 2.6  # the lobe gone: what remains is the object and the delocalization's reach
    assert before.signed_volume() > parts[0].signed_volume() > 0.95 * before.signed_volume()  # only the lobe went


def test_a_high_contrast_sphere_is_left_alone():
    before, after, lobes = _trimmed(0.15, 1)
    assert lobes.removed == 0 and after is before


def test_the_segregant_searchs_ions_give_the_same_trim():
    """The pipeline hands :func:`trim_lobes` the ions its segregant search selected near the same surface (exact
    distances within 3 nm, the side only beyond): the trim is the same to the bit as from a selection of its own."""
    from apt_filters.refine.segregants import segregant_ions

    iso = 0.125
    c = contoured_sphere(centre=CENTRE, radius=RADIUS, contrast=0.05, width=0.3, box=20.0, efficiency=0.4,
                         iso=iso, seed=1)
    ions, ranges = c.specimen.ions, c.specimen.ranges
    kept, specks = remove_specks(c.mesh, fields=c.fields, mask=c.mask, ions=ions, ranges=ranges, species="Al", iso=iso)
    common = dict(values=c.values, fields=c.fields, mask=c.mask, ions=ions, ranges=ranges, species="Al", iso=iso)
    own, own_lobes = trim_lobes(kept, specks, **common)
    given, given_lobes = trim_lobes(kept, specks, **common, near=segregant_ions(kept, ions))
    assert own_lobes.tested >= 2 and own_lobes == given_lobes
    assert np.array_equal(own.vertices, given.vertices) and np.array_equal(own.faces, given.faces)
