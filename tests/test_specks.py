"""The speck rule (issue 25): components are kept by a test on their ions against noise, not by volume.

Truth: synthetic specimens whose only object is known; every other component is noise by construction.
"""

import numpy as np
import pytest

from apt_filters.core.mesh import split_components
from apt_filters.refine import remove_specks
from apt_filters.refine.specks import holm
from tests.speck_specimens import contoured_sphere

CENTRE = (2.0, -1.0, -9.5)


def _specks(contrast: float, iso: float, seed: int, radius: float = 2.0):
    """A 2 nm-radius sphere (34 nm³) ``contrast`` richer in Al than the matrix, contoured at ``iso`` where noise
    draws blobs too; the components before the test and what the test did."""
    c = contoured_sphere(centre=CENTRE, radius=radius, contrast=contrast, width=0.2, box=22.0, efficiency=0.5,
                         iso=iso, seed=seed)
    kept, specks = remove_specks(c.mesh, fields=c.fields, mask=c.mask, ions=c.specimen.ions,
                                 ranges=c.specimen.ranges, species="Al", iso=iso)
    return split_components(c.mesh), kept, specks


def _is_sphere(part) -> bool:
    return bool(np.linalg.norm(part.vertices[part.faces].mean(axis=(0, 1)) - CENTRE) < 1.0)


@pytest.mark.parametrize("seed", [1, 2])
def test_noise_blobs_go_and_a_2_nm_sphere_at_a_10_point_contrast_stays(seed):
    parts, kept, specks = _specks(0.10, 0.125, seed)
    noise = [p for p in parts if not _is_sphere(p)]
    assert len(noise) >= 5  # the iso-value is low enough for noise to draw components: the test has work
    assert max(abs(p.signed_volume()) for p in noise if not len(p.boundary_edges())) > 1.0
    kept_parts = split_components(kept)
    assert len(kept_parts) == 1 and _is_sphere(kept_parts[0])
    assert specks.count == len(parts) - 1 and specks.tested == len(parts)
    assert specks.null[2] >= 20 and specks.null[0] > 0.5  # noise's own components score above 0: the bias
    sphere = next(i for i, p in enumerate(parts) if _is_sphere(p))
    assert specks.p_values[sphere] < 1e-6 and specks.z[sphere] > 5
    assert np.all(np.delete(specks.p_values, sphere) > specks.alpha)


def test_a_larger_alpha_keeps_more():
    """The family-wise level is the user's: at alpha = 0.5 the noise component nearest to significance is kept."""
    parts, _, specks = _specks(0.10, 0.125, 1)
    sphere = next(i for i, p in enumerate(parts) if _is_sphere(p))
    others = np.delete(specks.p_values, sphere)
    assert np.sum(specks.p_values <= 0.5) == 1 + np.sum(others <= 0.5)
    with pytest.raises(ValueError):
        remove_specks(parts[0], fields=None, mask=None, ions=None, ranges=None, species="Al", iso=0.1, alpha=0.0)


def test_holm_adjusts_step_down():
    p = np.array([0.01, 0.04, 0.03, 0.005])
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 -> 0.02, 0.03, 0.06, 0.04 -> monotone 0.02, 0.03, 0.06, 0.06
    assert holm(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])


def test_the_level_is_a_config_key_and_a_run_option_refused_outside_0_1():
    from apt_filters.cli.main import build_parser
    from apt_filters.cli.run import build_config
    from apt_filters.core.errors import AptFiltersError
    from apt_filters.pipeline import config as cfg

    assert cfg.PipelineConfig().refine.speck_alpha == 0.001
    args = build_parser().parse_args(["run", "x.pos", "-r", "x.rrng", "-o", "out", "--species", "Al", "--iso", "0.15",
                                      "--speck-alpha", "0.05"])
    assert build_config(args).refine.speck_alpha == 0.05
    for bad in (0.0, 1.0, float("nan")):
        with pytest.raises(AptFiltersError, match="speck_alpha"):
            cfg.with_options(cfg.PipelineConfig(), {"speck_alpha": bad}, "command line")


@pytest.mark.parametrize("close", [False, True])
def test_the_segregant_searchs_selection_gives_the_same_z_to_the_bit(close):
    """The pipeline selects the ions near the first contour once, for the segregant search and the speck test:
    the wider selection (4 nm, exact within 3, beyond by side on closed meshes) gives the very z of the test's own."""
    from apt_filters.refine.segregants import segregant_ions
    from apt_filters.refine.specks import kernel_sigma, side_z

    c = contoured_sphere(centre=CENTRE, radius=2.0, contrast=0.10, width=0.2, box=22.0, efficiency=0.5, iso=0.125,
                         seed=3, close=close)
    sp, fields, mesh = c.specimen, c.fields, c.mesh
    assert len(split_components(mesh)) >= 3 and (len(mesh.boundary_edges()) == 0) == close
    gap = kernel_sigma(fields)
    own = side_z(mesh, ions=sp.ions, ranges=sp.ranges, species="Al", basis=fields.basis, gap=gap)
    near = segregant_ions(mesh, sp.ions)
    assert np.isinf(near.distance).any() == close  # on a closed mesh: ions known by their side alone
    reused = side_z(mesh, ions=sp.ions, ranges=sp.ranges, species="Al", basis=fields.basis, gap=gap, near=near)
    assert np.array_equal(own, reused) and np.any(own != 0)
    with pytest.raises(ValueError):  # a selection too narrow for the test's reach is refused
        side_z(mesh, ions=sp.ions, ranges=sp.ranges, species="Al", basis=fields.basis, gap=gap + 2.0, near=near)
