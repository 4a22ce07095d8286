"""The analysis choices a sweep varies: iso-value, voxel size, delocalization and transfer function."""

from __future__ import annotations

import copy
import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass

from apt_filters.core.errors import AptFiltersError
from apt_filters.pipeline import config as cfg

CHOICE_COLUMNS = ("iso", "voxel", "delocalization", "kernel")
"""The columns that name a choice in sweep.csv, in this order."""


@dataclass(frozen=True)
class Choice:
    """One point of a sweep: the values it sets (None: the base configuration's).

    ``delocalization`` is 3 sigma per axis x, y, z in nm (gaussian kernel only).
    """

    iso: float | None = None
    voxel: float | None = None
    delocalization: tuple[float, float, float] | None = None
    kernel: str | None = None

    def apply(self, base: cfg.PipelineConfig) -> cfg.PipelineConfig:
        """A copy of ``base`` with this choice's values, checked like a configuration file."""
        config = copy.deepcopy(base)
        if self.iso is not None:
            if len(config.surface) != 1:
                raise AptFiltersError("sweeping the iso-value needs exactly one surface in the base configuration")
            config.surface[0].iso = float(self.iso)
        if self.voxel is not None:
            config.voxel.size = float(self.voxel)
        if self.delocalization is not None:
            config.voxel.delocalization = [float(v) for v in self.delocalization]
        if self.kernel is not None:
            config.voxel.kernel = self.kernel
        config = cfg.from_dict(dataclasses.asdict(config), source="sweep choice")
        cfg.check_config(config)
        return config

    def values(self, config: cfg.PipelineConfig) -> dict:
        """The choice columns as run (the base's values where the choice leaves them)."""
        return {"iso": config.surface[0].iso if len(config.surface) == 1 else None,
                "voxel": config.voxel.size,
                "delocalization": " ".join(f"{v:g}" for v in config.voxel.delocalization),
                "kernel": config.voxel.kernel}

    def tag(self, config: cfg.PipelineConfig) -> str:
        """A folder name for this choice's run, e.g. ``iso0.15_voxel1_deloc3-3-1.5_gaussian``."""
        v = self.values(config)
        iso = f"iso{v['iso']:g}_" if v["iso"] is not None else ""
        return f"{iso}voxel{v['voxel']:g}_deloc{v['delocalization'].replace(' ', '-')}_{v['kernel']}"


def choice_grid(*, isos: Sequence[float] = (), voxels: Sequence[float] = (),
                delocalizations: Sequence[Sequence[float]] = (), kernels: Sequence[str] = ()) -> list[Choice]:
    """Every combination of the values given (an empty list leaves that choice at the base's value).

    Raises
    ------
    AptFiltersError
        A value out of range (checked again per run by the configuration) or a repeated value.
    """
    for name, values in (("iso", isos), ("voxel", voxels), ("kernel", kernels),
                         ("delocalization", [tuple(d) for d in delocalizations])):
        if len(set(values)) != len(values):
            raise AptFiltersError(f"--{name} lists a value twice")
    for d in delocalizations:
        if len(d) != 3 or any(not 0 < float(v) < 100 for v in d):
            raise AptFiltersError(f"a delocalization is three 3-sigma widths x y z in nm (0-100), got {list(d)}")
    axes = [list(isos) or [None], list(voxels) or [None],
            [tuple(float(v) for v in d) for d in delocalizations] or [None], list(kernels) or [None]]
    return [Choice(*values) for values in itertools.product(*axes)]
