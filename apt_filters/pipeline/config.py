"""The pipeline's configuration: defaults, TOML files, and command-line overrides.

Every run writes its fully resolved configuration as ``config.toml``, input paths absolute;
running again with ``--config config.toml`` from any folder reproduces the same numbers and
meshes. Relative input paths in a configuration file are relative to the file's folder.

Every number is checked against :data:`LIMITS` when the configuration is built, before any
file is read: NaN, infinities and values no specimen can need (a 10^300 nm voxel) are refused
in one line.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import tomli_w

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.numbers import within

if sys.version_info >= (3, 11):
    import tomllib
else:  # the same parser, from PyPI
    import tomli as tomllib


@dataclass
class InputConfig:
    ions: str = ""
    """Ion file (POS, EPOS, APT, CSV)."""
    ranges: str = ""
    """Range file (RRNG, RNG, ENV)."""
    relabel: list[str] = field(default_factory=list)
    """Species relabelled after reading, ``OLD=NEW`` (e.g. ``Cr2O=Ni``), in order."""
    unknown_species: str = "species"
    """Range-file names that are not chemical formulas: their own species, or unranged."""
    memory_budget: float = 0.0
    """Memory budget of the run in GB (0: half of this machine's memory). An ion table that does not
    fit beside the fields is memory-mapped from a native scratch copy instead of read into memory;
    a run whose fields cannot fit even so is refused before any work."""


@dataclass
class VoxelConfig:
    size: float = 1.0
    """Voxel edge in nm (AP Suite default)."""
    kernel: str = "gaussian"
    """Contribution transfer function: gaussian (AP Suite two-pass), sawtooth or square."""
    delocalization: list[float] = field(default_factory=lambda: [3.0, 3.0, 1.5])
    """Delocalization as 3 sigma per axis x, y, z in nm (AP Suite default)."""
    exclude: list[str] = field(default_factory=list)
    """Elements left out of the concentration's denominator besides the segregants found (see ``include``)."""
    include: list[str] = field(default_factory=list)
    """Elements kept in the denominator even where they peak at the surface. Otherwise every element whose
    fraction peaks at a concentration surface above both of its plateaus (5 standard errors; a segregant,
    which would dilute the species drawn and shrink its objects) is found from a first contour and left out
    (docs/refine.md, "Segregants")."""
    include_unranged: bool = False
    """Count unranged (background) ions in the denominator."""


@dataclass
class SurfaceConfig:
    species: str = ""
    """Element (or ion) whose concentration is contoured; empty for an iso-density surface."""
    iso: float = 0.0
    """Iso-concentration as a fraction (0..1), or iso-density in atoms/nm³ when species is empty."""


@dataclass
class ContourConfig:
    method: str = "mc"
    """mc (marching cubes) or dc (dual contouring, sharp features on smooth fields). mc by default: the
    delocalization has already rounded the edges of counted data, and dc can leave objects open on
    noisy fields (non-manifold sheets); the refinement then moves the surface (docs/pipeline.md)."""
    close_at_edge: bool = False
    """Close objects that meet the specimen edge (proxies) instead of leaving them open."""


@dataclass
class RefineConfig:
    enabled: bool = True
    """Move the iso-surface to where the ions' composition crosses midway between each object's
    plateaus (undoes the delocalization bias; concentration surfaces only)."""
    iterations: int = 12
    """Refinement iterations (each moves vertices at most 0.5 nm)."""
    speck_alpha: float = 0.001
    """Family-wise error rate of the speck test: a component is kept when its ions differ across it in the
    iso species' fraction beyond what noise draws at this iso-value, over all components at once
    (:mod:`apt_filters.refine.specks`); the others are specks, removed before refinement."""
    facets: bool = True
    """Rebuild sharp edges and corners where planar facets of an object meet (cuboids; spheres are
    untouched), on planes fitted to the ions where the facets close the object: the delocalization
    rounds edges and corners away, the ions still hold the planes (docs/refine.md)."""
    blur: list[float] = field(default_factory=list)
    """[lateral, depth] reconstruction blur sigmas in nm whose curvature bias is undone (a 3 nm sphere
    comes out ~2 % small under 0.3 / 0.1 nm). Empty: the lateral sigma is estimated from the ions (the
    profile width's dependence on the surface orientation, of the peak of the species ``voxel.exclude``
    leaves out where they peak at the surface, else of the score's step; depth taken as 0; no correction
    where one flat interface gives no estimate). [0, 0]: no correction."""
    cross_fit: bool = True
    """Plateaus from each half of the ions against the other half's surface (no self-selection: the
    ions that placed a surface read its plateaus biased); also gives the halves that choose each
    object's smoothness. It multiplies the refinement's time (docs/refine.md)."""
    select_modes: bool = True
    """Low-pass each closed object to the number of manifold harmonics that best predicts held-out ions
    (two-fold cross-validation on the cross-fit's halves), so each object keeps as much shape as its
    ions support and no more (needs cross_fit; docs/refine.md)."""
    marker: bool = True
    """Where the species ``voxel.exclude`` leaves out (segregants) peak at an object's surface, read its
    mean offset off that peak too and move it by the combination with the step's (the layer's common
    offset from the midpoint fitted over the objects; needs two objects): two independent placements of
    one surface combine into a better one (docs/refine.md)."""


@dataclass
class RemeshConfig:
    method: str = "cvt"
    """cvt (feature-preserving centroidal Voronoi) or none."""
    edge_length: float = 0.0
    """Target edge length in nm; 0 means half the voxel size."""
    feature_angle: float = 40.0
    """Dihedral angle in degrees above which an edge is a sharp feature that is kept."""


@dataclass
class ProxigramConfig:
    bin: float = 0.1
    """Bin width in nm (AP Suite default)."""
    extent: float = 0.0
    """Signed distances from -extent to +extent nm are binned; also the outer edge of the plateau windows.
    0: three times ``inner`` (analysis.width)."""
    inner: float = 0.0
    """Plateau windows start this far (nm) from the surface on each side, where the excess integration
    ends. 0: from the interface width fitted on the proxigram (beyond the step and the solutes' peaks)."""
    exclude_edge: bool = True
    """Leave out ions whose closest surface point is on the specimen edge (AP Suite default)."""
    solutes: list[str] = field(default_factory=list)
    """Elements whose interfacial excess is reported; empty means all minority elements."""


@dataclass
class AnalysisConfig:
    efficiency: float = 0.5
    """Detection efficiency, to turn ion counts into atoms."""
    audit: bool = True
    """Audit the range file against the mass spectrum and report its warnings."""
    maps: bool = True
    """Excess and plateau maps of the solutes on each surface (PLY vertex properties, report pictures,
    a chi-square test of uniform segregation per object)."""
    map_error: float = 0.25
    """Error level of the maps' patches, relative to each object's |excess| (floored at the error of
    an eighth of the object): patches grow until their predicted error reaches it."""


@dataclass
class PipelineConfig:
    input: InputConfig = field(default_factory=InputConfig)
    voxel: VoxelConfig = field(default_factory=VoxelConfig)
    surface: list[SurfaceConfig] = field(default_factory=list)
    contour: ContourConfig = field(default_factory=ContourConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    remesh: RemeshConfig = field(default_factory=RemeshConfig)
    proxigram: ProxigramConfig = field(default_factory=ProxigramConfig)
    analysis: AnalysisConfig = field(default_factory=AnalysisConfig)

    def to_toml(self) -> str:
        return tomli_w.dumps(_without_none(dataclasses.asdict(self)))


LIMITS: dict[tuple[str, str], tuple[str, str]] = {
    ("voxel", "size"): ("[0.01, 1000]", "nm"),
    ("voxel", "delocalization"): ("(0, 1000]", "nm"),
    ("surface", "iso"): ("(0, 1000]", ""),
    ("refine", "iterations"): ("[0, 1000]", ""),
    ("refine", "speck_alpha"): ("(0, 1)", ""),
    ("refine", "blur"): ("[0, 100]", "nm"),
    ("remesh", "edge_length"): ("[0, 1000]", "nm"),
    ("remesh", "feature_angle"): ("(0, 180]", "degrees"),
    ("proxigram", "bin"): ("(0, 100]", "nm"),
    ("proxigram", "extent"): ("[0, 1000]", "nm"),
    ("proxigram", "inner"): ("[0, 1000]", "nm"),
    ("analysis", "efficiency"): ("(0, 1]", ""),
}
"""Interval of every number (each element of a list), as ``"[lo, hi]"`` with ``(``/``)`` for open ends.
The bounds are what no APT specimen can need (a voxel of 1 µm covers a whole specimen; no solid
holds more than ~180 atoms/nm³), so that absurd values fail at once instead of as overflows."""

MAX_PROXIGRAM_BINS = 1_000_000
"""2 × extent / bin at most."""

MAX_FITTED_RANGE = 50.0
"""The widest proxigram range (nm) the interface-width fit may ask for (``analysis.width.MAX_RANGE``, spelled
here so that reading a configuration imports no analysis code; a test checks they agree)."""

ELEMENTS = {("input", "relabel"): str, ("voxel", "delocalization"): float, ("voxel", "exclude"): str,
            ("refine", "blur"): float,
            ("proxigram", "solutes"): str}
"""Type of the elements of list-valued keys."""

CHOICES = {
    ("input", "unknown_species"): ("species", "unranged"),
    ("voxel", "kernel"): ("gaussian", "sawtooth", "square"),
    ("contour", "method"): ("dc", "mc"),
    ("remesh", "method"): ("cvt", "none"),
}


def _without_none(value):
    """``value`` with the None entries of its tables left out (TOML has no null: a missing key means the default)."""
    if isinstance(value, dict):
        return {k: _without_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_without_none(v) for v in value]
    return value


def _coerce(section: str, cls, values: dict, source: str | None):
    if not isinstance(values, dict):
        raise AptFiltersError(f"[{section}] must be a table", source)
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise AptFiltersError(f"unknown key(s) in [{section}]: {', '.join(unknown)}", source)
    obj = cls()
    for key, value in values.items():
        expected = type(getattr(obj, key))
        # TOML writes 3.0 as 3 if a user types it so: ints are fine where floats are expected.
        accepted = (int, float) if expected is float else expected
        if not isinstance(value, accepted) or (isinstance(value, bool) and expected is not bool):
            raise AptFiltersError(f"[{section}] {key} = {value!r} should be {expected.__name__}", source)
        choices = CHOICES.get((section, key))
        if choices and value not in choices:
            raise AptFiltersError(f"[{section}] {key} must be one of {', '.join(choices)}, not {value!r}", source)
        element = ELEMENTS.get((section, key))
        if element is not None:
            ok = (int, float) if element is float else element
            if not all(isinstance(v, ok) and not isinstance(v, bool) for v in value):
                raise AptFiltersError(f"[{section}] {key} = {value!r} should be a list of {element.__name__}", source)
            value = [float(v) for v in value] if element is float else value
        _check_limit(section, key, value, source)
        setattr(obj, key, float(value) if expected is float else value)
    return obj


def _check_limit(section: str, key: str, value, source: str | None) -> None:
    """Refuse a number (or a list element) outside :data:`LIMITS`."""
    if (section, key) not in LIMITS:
        return
    interval, unit = LIMITS[section, key]
    for v in value if isinstance(value, list) else [value]:
        if not within(float(v), interval):
            raise AptFiltersError(f"[{section}] {key} = {v!r} is outside {interval} {unit}".rstrip(), source)


def check(config: PipelineConfig, source: str | None = None) -> None:
    """Checks that involve several keys (each key alone passed :data:`LIMITS` in :func:`from_dict`).

    Imports nothing heavy: a mistake is reported before numba or scipy load.
    """
    v = config.voxel
    if len(v.delocalization) != 3:
        raise AptFiltersError(f"[voxel] delocalization must be three numbers (x, y, z nm), got {v.delocalization}",
                              source)
    # the gaussian's second pass needs (deloc / 3)² > (voxel / 6)² (voxel.transfer.second_pass_sigma)
    if v.kernel == "gaussian" and any(d <= v.size / 2 for d in v.delocalization):
        raise AptFiltersError(f"gaussian delocalization {v.delocalization} nm must exceed half the voxel "
                              f"({v.size / 2:g} nm) on every axis", source)
    if len(config.refine.blur) not in (0, 2):
        raise AptFiltersError("[refine] blur must be [lateral, depth] sigmas >= 0 nm, or empty (estimated)", source)
    if config.refine.select_modes and not config.refine.cross_fit:
        raise AptFiltersError("[refine] select_modes needs cross_fit (its held-out ions are the cross-fit's halves): "
                              "set select_modes = false as well", source)
    for s in config.surface:
        if s.species and not 0 < s.iso < 1:
            raise AptFiltersError(f"iso-concentration of {s.species} must be a fraction in (0, 1), got {s.iso:g}",
                                  source)
    p = config.proxigram
    extent = p.extent or MAX_FITTED_RANGE
    if 2 * extent / p.bin > MAX_PROXIGRAM_BINS:
        raise AptFiltersError(f"[proxigram] {2 * extent / p.bin:.3g} bins (2 × extent / bin"
                              + ("" if p.extent else f", extent 0: up to {MAX_FITTED_RANGE:g} nm fitted")
                              + f"): more than {MAX_PROXIGRAM_BINS:,}", source)
    if p.inner and p.extent and p.inner >= p.extent:
        raise AptFiltersError(f"[proxigram] inner ({p.inner:g} nm) must be below extent ({p.extent:g} nm): the "
                              "plateau windows run from inner to extent", source)


def from_dict(data: dict, source: str | None = None) -> PipelineConfig:
    """Build a configuration from parsed TOML, refusing unknown sections and keys."""
    config = PipelineConfig()
    sections = {f.name: f for f in dataclasses.fields(PipelineConfig)}
    unknown = sorted(set(data) - set(sections))
    if unknown:
        raise AptFiltersError(f"unknown section(s): {', '.join(unknown)}", source)
    for name, value in data.items():
        if name == "surface":
            if not isinstance(value, list):
                raise AptFiltersError("surfaces are given as [[surface]] tables", source)
            config.surface = [_coerce(name, SurfaceConfig, v, source) for v in value]
        else:
            setattr(config, name, _coerce(name, type(getattr(config, name)), value, source))
    check(config, source)
    return config


OPTIONS = {
    "voxel": ("voxel", "size"), "kernel": ("voxel", "kernel"), "delocalization": ("voxel", "delocalization"),
    "exclude": ("voxel", "exclude"), "include": ("voxel", "include"), "method": ("contour", "method"),
    "remesh": ("remesh", "method"),
    "efficiency": ("analysis", "efficiency"), "blur": ("refine", "blur"), "speck_alpha": ("refine", "speck_alpha"), "relabel": ("input", "relabel"),
    "unknown_species": ("input", "unknown_species"), "memory_budget": ("input", "memory_budget"),
    "plateau_inner": ("proxigram", "inner"), "proxigram_range": ("proxigram", "extent"),
}
"""Run options (as ``apt-filters run`` and batch manifests name them) -> (section, key)."""


def with_options(config: PipelineConfig, options: dict, source: str) -> PipelineConfig:
    """``config`` with run options applied (None: left as is) and checked like a configuration file.

    ``options`` may hold ``input``, ``range``, ``species`` with ``iso`` (one concentration surface),
    ``density`` (one iso-density surface) and any key of :data:`OPTIONS`; other keys are refused.
    """
    unknown = sorted(set(options) - set(OPTIONS) - {"input", "range", "species", "iso", "density"})
    if unknown:
        raise AptFiltersError(f"unknown option(s): {', '.join(unknown)}", source)
    data = dataclasses.asdict(config)
    dash = "--" if source == "command line" else ""  # options are named as the user typed them
    if options.get("input") is not None:
        data["input"]["ions"] = str(options["input"])
    if options.get("range") is not None:
        data["input"]["ranges"] = str(options["range"])
    species, iso, density = options.get("species"), options.get("iso"), options.get("density")
    if species is not None or iso is not None or density is not None:
        if density is not None and (species is not None or iso is not None):
            raise AptFiltersError(f"give {dash}species with {dash}iso, or {dash}density, not both", source)
        if density is None and not (species and iso is not None):
            raise AptFiltersError(f"{dash}species and {dash}iso go together", source)
        data["surface"] = [{"species": species, "iso": iso} if density is None else {"species": "", "iso": density}]
    for name, (section, key) in OPTIONS.items():
        if options.get(name) is not None:
            data[section][key] = options[name]
    return from_dict(data, source=source)


def check_config(config: PipelineConfig) -> None:
    """Refuse a configuration that cannot run: no inputs or surfaces, values out of range."""
    if not config.input.ions or not config.input.ranges:
        raise AptFiltersError("an ion file and a range file are needed ([input] ions and ranges)")
    if not config.surface:
        raise AptFiltersError("no iso-surface asked for: give --species and --iso, --density, or [[surface]]")
    both = set(config.voxel.exclude) & set(config.voxel.include)
    if both:
        raise AptFiltersError(f"{', '.join(sorted(both))} cannot be both excluded from and included in the basis")
    check(config)


def read_toml(path: str | os.PathLike, what: str = "configuration file") -> dict:
    """Parse a TOML file; a missing or malformed one is one line naming it."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AptFiltersError(f"no such {what}", path) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise AptFiltersError(f"not valid TOML: {exc}", path) from None


def load(path: str | os.PathLike) -> PipelineConfig:
    """Read a pipeline configuration TOML file; relative input paths are relative to its folder."""
    path = Path(path)
    config = from_dict(read_toml(path), str(path))
    for key in ("ions", "ranges"):  # relative to the configuration file, not to where it is run from
        given = getattr(config.input, key)
        if given:
            setattr(config.input, key, str(path.parent / Path(given).expanduser()))
    return config
