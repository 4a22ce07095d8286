"""Density artefacts of a reconstruction: where fewer or more ions are kept than the efficiency says.

An artefact is a function ``keep(points (N, 3)) -> (N,)`` in [0, 1] of an atom's true position: the
probability that a detected atom there is kept (:attr:`SpecimenSpec.artefacts`; the generator draws it
after the species, so the compositions, and with them the truth, are unchanged; only where the ions
are, and how many, changes). With several artefacts the probabilities multiply.

- :class:`EfficiencyPatches`: regions of the detector that see fewer ions (a worn or shadowed part of
  the micro-channel plate), each a Gaussian dip in x, y through the whole depth.
- :class:`LocalMagnification`: a phase evaporating at another field than the matrix is reconstructed
  at another density (ions spread out over, or crowded into, its image). Modelled as the density
  ratio ``ratio`` inside ``shape`` against outside, switching over the feature's tanh width; the
  trajectory aberrations that also shift ions across the interface are not modelled, so the
  true surfaces stay exact.
"""

from __future__ import annotations

import numpy as np

from apt_filters.core.errors import AptFiltersError


class EfficiencyPatches:
    """Gaussian dips of the kept fraction in x, y: ``prod_i (1 - depth_i exp(-|xy - c_i|^2 / (2 r_i^2)))``.

    Parameters
    ----------
    centers : (k, 2) float, nm
    radii : (k,) float, nm (Gaussian sigmas)
    depths : (k,) float in [0, 1)
    """

    kind = "efficiency_patches"

    def __init__(self, centers, radii, depths):
        self.centers = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
        self.radii = np.asarray(radii, dtype=np.float64).reshape(-1)
        self.depths = np.asarray(depths, dtype=np.float64).reshape(-1)
        if not (len(self.centers) == len(self.radii) == len(self.depths) and (self.radii > 0).all()
                and ((self.depths >= 0) & (self.depths < 1)).all()):
            raise AptFiltersError("efficiency patches: one radius > 0 nm and one depth in [0, 1) per centre")

    def keep(self, points: np.ndarray) -> np.ndarray:
        out = np.ones(len(points))
        for c, r, d in zip(self.centers, self.radii, self.depths):
            out *= 1 - d * np.exp(-0.5 * np.sum((points[:, :2] - c) ** 2, axis=1) / r ** 2)
        return out

    def params(self) -> dict:
        return {"kind": self.kind, "centers": self.centers.tolist(), "radii": self.radii.tolist(),
                "depths": self.depths.tolist()}


class LocalMagnification:
    """Density ``ratio`` inside ``shape`` against outside, blended as the feature's composition (tanh of
    width ``width`` nm); the larger of the two densities is kept whole."""

    kind = "local_magnification"

    def __init__(self, shape, ratio: float, width: float):
        self.shape, self.ratio, self.width = shape, float(ratio), float(width)
        if not (self.ratio > 0 and self.width > 0):
            raise AptFiltersError("local magnification: the density ratio and width must be > 0")

    def keep(self, points: np.ndarray) -> np.ndarray:
        inside = 0.5 * (1 - np.tanh(self.shape.sdf(points) / self.width))
        return (1 + (self.ratio - 1) * inside) / max(1.0, self.ratio)

    def params(self) -> dict:
        return {"kind": self.kind, "shape": self.shape.params(), "ratio": self.ratio, "width": self.width}
