"""How much delocalization a concentration iso-surface needs to be one sheet where the interface is, not noise.

The iso-surface of a noisy field ``c = s + e`` (signal ``s``, counting noise ``e``) is a single sheet
over an interface only where the signal's gradient across it, ``g = |grad s|``, exceeds the noise's
derivative along that normal, ``e_n``: where ``|e_n| > g`` the contour folds back on itself, and the
folds of neighbouring voxels join into handles, tunnels and extra boundary loops that no later step
removes (a wide low-contrast interface, 4.5 at.% points over a tanh width of 2.15 nm at efficiency 0.40:
Euler characteristic -12 where a disc has +1, half its vertices > 0.5 nm from the interface, the refined
area +33 %). The data set the kernel: the smallest growth ``k >= 1`` of the gaussian delocalization for which
fewer than one of the ``n`` voxels the interface crosses is expected to fold, ``R(k) >= z(n)``, with ``R =
g / std(e_n)`` and ``z(n)`` the two-sided normal quantile of ``1 / n``. Each step grows the kernel by the factor
``R`` asks for if it grew as ``k**1.5`` (:data:`GROWTH`) and measures ``R`` again at the grown kernel
(:func:`noise_limited_fields`), because the growth depends on the specimen: the noise's derivative would fall as
``k**-2.5`` (its counting noise as ``k**-1.5``, one more ``1/k``) if the kernel were not already below the voxel
across (0.5 nm in z) and the interface's gradient did not fall as the kernel nears its width. Measured on a
2.15 nm wide interface in the zoo's 24 x 24 x 40 nm box, ``R`` went 1.56 -> 2.42 -> 4.36 at ``k`` = 1, 1.35, 2
(``k**1.48``; one step lands within 2 %), its surface from Euler characteristic -12 through -1 to a disc (+1);
in a 16 x 16 x 18 nm box it grew as ``k**1.0`` and took three steps.

Both figures are measured, not modelled: the ions are split at random into two halves voxelized on the
same grid with the same kernel; their difference is pure noise (half of it is the full field's), and the
mean product of their gradients is the signal's squared gradient (the halves' noises are independent).
The voxels where the interface lies are those next to the iso-value crossing of the field smoothed to
twice the delocalization (a locator only, never contoured), in the connected layers that span half the
specimen's extent on two axes: interfaces across it, not closed objects. Sharp or high-contrast interfaces have
``R`` of 10 or more and keep the delocalization they were given (``k = 1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_dilation, find_objects, gaussian_filter, label
from scipy.stats import norm

from apt_filters.voxel.fields import voxelize
from apt_filters.voxel.mask import inside_mask

GROWTH = 1.5
"""Exponent of ``R``'s growth with the delocalization a step assumes (module docstring)."""

STEPS = 4
"""Growth steps at most, each measured again."""

MAX_FACTOR = 2.0
"""The largest growth of the delocalization: beyond twice AP Suite's default (6 x 6 x 3 nm), the kernel
reaches across small objects and the curvature of most interfaces, and a surface still noise-limited there
is reported as such instead (``NoiseScale.limited``)."""


@dataclass
class NoiseScale:
    """What :func:`noise_scale` measured.

    Attributes
    ----------
    factor : float
        Growth of the delocalization on every axis (1: unchanged), at most :data:`MAX_FACTOR`: one step's from the
        fields measured (:func:`noise_scale`), or all the steps' (:func:`noise_limited_fields`).
    ratio : float
        ``R``: the signal's gradient across the interface over the noise's derivative along it, at the last
        delocalization measured (inf where no interface voxel was found).
    needed : float
        ``z(n)``: the ratio at which fewer than one crossed voxel is expected to fold.
    voxels : int
        ``n``: voxels next to the interface.
    limited : bool
        The ratio is still short of ``needed`` at :data:`MAX_FACTOR` (or after :data:`STEPS` steps).
    """

    factor: float
    ratio: float
    needed: float
    voxels: int
    limited: bool = False


def noise_scale(fields, mask: np.ndarray, ions, ranges, species: str, iso: float, *, basis=None,
                seed: int = 0) -> NoiseScale:
    """The growth of ``fields``' gaussian delocalization its ``species`` iso-surface at ``iso`` needs (module
    docstring).

    Parameters
    ----------
    fields : Fields
        The voxelized ``ions`` (gaussian kernel).
    mask : (nx, ny, nz) bool
        Inside the specimen.
    ions, ranges : IonTable, RangeTable
        The ions voxelized, split at random into halves.
    species : str
    iso : float
        Iso-value, a fraction.
    basis : ConcentrationBasis, optional
        Of the concentration (default the voxelization's).
    seed : int
        Of the random split (the result is reproducible).
    """
    c = fields.concentration(species, basis).dense()
    valid = mask & np.isfinite(c)
    sigma = np.asarray(fields.delocalization) / 3.0 / fields.grid.voxel  # voxels
    locator = gaussian_filter(np.where(valid, c, iso), sigma * np.sqrt(3.0))  # variances add: twice the kernel
    above = locator > iso
    crossed = np.zeros_like(above)
    for axis in range(3):
        step = np.diff(above, axis=axis)
        crossed[tuple(slice(0, -1) if a == axis else slice(None) for a in range(3))] |= step
        crossed[tuple(slice(1, None) if a == axis else slice(None) for a in range(3))] |= step
    # only interfaces across the specimen (spanning half its extent on two axes, open at its edge): closed objects
    # keep the delocalization given (a low-contrast plate, 4 points over 0.6 nm at efficiency 0.49, lost its
    # inside level at 1.65x)
    layers, _ = label(valid & crossed, structure=np.ones((3, 3, 3)))
    inside = np.argwhere(mask)
    extent = inside.max(axis=0) - inside.min(axis=0) + 1
    open_at_edge = set(np.unique(layers[binary_dilation(~mask, iterations=2)]).tolist())
    across = [k + 1 for k, box in enumerate(find_objects(layers))
              if k + 1 in open_at_edge and sum(s.stop - s.start >= e / 2 for s, e in zip(box, extent)) >= 2]
    if not across:  # closed objects only: the halves are not voxelized (two passes over the ions saved)
        return NoiseScale(1.0, float("inf"), float("nan"), 0)
    halves = np.random.default_rng(seed).random(len(ions)) < 0.5
    parts = [voxelize(ions.subset(np.flatnonzero(h)), ranges, grid=fields.grid, kernel=fields.kernel,
                      delocalization=fields.delocalization, species=fields.kind, basis=fields.basis
                      ).concentration(species, basis).dense() for h in (halves, ~halves)]
    near = np.isin(layers, across) & np.isfinite(parts[0]) & np.isfinite(parts[1])
    n = int(near.sum())
    if n < 2:
        return NoiseScale(1.0, float("inf"), float("nan"), n)
    grad_a, grad_b = np.gradient(parts[0]), np.gradient(parts[1])
    signal = float(np.mean(sum(a[near] * b[near] for a, b in zip(grad_a, grad_b))))
    normal = [q[near] for q in np.gradient(locator)]
    length = np.sqrt(sum(q * q for q in normal)) + 1e-30
    noise_n = sum((a[near] - b[near]) / 2 * q / length for a, b, q in zip(grad_a, grad_b, normal))
    ratio = np.sqrt(max(signal, 0.0)) / max(float(np.std(noise_n)), 1e-30)
    needed = float(norm.isf(0.5 / n))
    factor = max(1.0, (needed / max(ratio, 1e-30)) ** (1.0 / GROWTH))
    return NoiseScale(float(min(factor, MAX_FACTOR)), float(ratio), needed, n, bool(factor > MAX_FACTOR))


def noise_limited_fields(fields, mask: np.ndarray, ions, ranges, species: str, iso: float, *, basis=None):
    """``(fields, mask, NoiseScale)``: ``ions`` voxelized again at the delocalization the ``species`` iso-surface at
    ``iso`` needs (module docstring), grown a step at a time and measured again, at most :data:`MAX_FACTOR` times
    that of ``fields`` in :data:`STEPS` steps; ``fields`` and ``mask`` themselves where no growth is needed.

    Parameters are those of :func:`noise_scale`; the returned mask is :func:`~apt_filters.voxel.inside_mask` of
    the returned fields (dense).
    """
    given, total = fields.delocalization, 1.0
    for step in range(STEPS + 1):
        scale = noise_scale(fields, mask, ions, ranges, species, iso, basis=basis)
        grow = min(scale.factor, MAX_FACTOR / total)
        if grow <= 1.0 or step == STEPS:
            break
        total *= grow
        fields = voxelize(ions, ranges, kernel=fields.kernel, voxel=fields.grid.voxel, species=fields.kind,
                          delocalization=tuple(total * d for d in given), basis=fields.basis,
                          efficiency=fields.efficiency)
        mask = inside_mask(fields).dense()
    return fields, mask, NoiseScale(float(total), scale.ratio, scale.needed, scale.voxels,
                                    bool(scale.factor > 1.0))
