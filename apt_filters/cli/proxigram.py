"""``apt-filters proxigram IONS --range R --mesh MESH -o OUTDIR``: proxigram and interfacial excess.

Writes into OUTDIR: ``proxigram.csv`` (pooled, one row per bin), ``proxigram_objects.csv``
(one row per object and bin), ``proxigram.png`` and, with ``--solute``, ``excess.json``. The
ion file is streamed in chunks, so memory stays bounded for 10^8-10^9 ions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from apt_filters.cli.options import add_output
from apt_filters.cli.numbers import number
from apt_filters.core.atomic import refuse_inputs
from apt_filters.core.errors import AptFiltersError

ORDER = 80
INSTRUMENTS = ("EIKOS", "Invizio", "LEAP 5000R", "LEAP 5000S", "LEAP 6000")
"""Names of ``analysis.excess.INSTRUMENT_EFFICIENCY`` (spelled here so ``--help`` imports no analysis code;
a test checks they agree)."""
MAX_BINS = 1_000_000
"""2 × --range-nm / --bin at most."""
MAX_RANGE = 50.0
"""The widest range the width fit may ask for, nm (``analysis.width.MAX_RANGE``, spelled here so that
``--help`` imports no analysis code; a test checks they agree)."""


def run(args: argparse.Namespace) -> int:
    from apt_filters.io import read_ranges
    from apt_filters.io.readers import ion_format
    from apt_filters.pipeline.inputs import match_species

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise AptFiltersError("exists and is not a folder", out)
    for path, missing in ((args.ions, "no such file"), (args.mesh, "mesh file not found")):
        if not Path(path).is_file():  # before the heavy imports: a mistake is reported at once
            raise AptFiltersError(missing, path)
    ion_format(args.ions)
    if 2 * (args.range_nm or MAX_RANGE) / args.bin > MAX_BINS:
        raise AptFiltersError(f"--range-nm {args.range_nm or MAX_RANGE:g} / --bin {args.bin:g} make more than "
                              f"{MAX_BINS:,} bins" + ("" if args.range_nm else " (the largest fitted range)"))
    ranges = read_ranges(args.range_file)
    names = ranges.elements + [i for i in ranges.ions if i not in ranges.elements]
    if args.solute:
        args.solute = match_species(args.solute, names, what="solute")
    if args.species:
        args.species = match_species(args.species, names, what="species")

    from apt_filters.analysis.excess import INSTRUMENT_EFFICIENCY, interfacial_excess, write_excess_json
    from apt_filters.analysis.width import fitted_proxigram
    from apt_filters.io import iter_ion_chunks
    from apt_filters.meshlab.bridge import read_mesh

    mesh = read_mesh(args.mesh)
    if args.instrument:
        efficiency = INSTRUMENT_EFFICIENCY[args.instrument]
    else:
        efficiency = args.efficiency
    targets = ["proxigram.csv", "proxigram_objects.csv", "proxigram.png"] + (["excess.json"] if args.solute else [])
    refuse_inputs([out / t for t in targets], [args.ions, args.range_file, args.mesh])
    if not args.force:
        existing = [t for t in targets if (out / t).exists()]
        if existing:
            raise AptFiltersError(f"{', '.join(existing)} exist already; pass --force to replace them", out)
    out.mkdir(parents=True, exist_ok=True)
    class Chunks:  # read again for each proxigram the width fit asks for
        def __iter__(self):
            return iter_ion_chunks(args.ions)

    outer = args.outer if args.outer is not None else args.range_nm
    prox, windows = fitted_proxigram(ions=Chunks(), ranges=ranges, mesh=mesh, species=args.species or "",
                                     solutes=[args.solute] if args.solute else [], bin_width=args.bin,
                                     inner=args.inner, outer=outer, keep_edge=args.keep_edge, iso_value=args.iso)
    print(windows.describe())
    results = (interfacial_excess(prox, args.solute, efficiency, windows.inner, windows.outer,
                                  fit=windows.fit_of(args.solute)) if args.solute else [])
    pooled = prox.pooled()
    pooled.write_csv(out / "proxigram.csv", overwrite=args.force)
    prox.write_csv(out / "proxigram_objects.csv", overwrite=args.force)
    prox.plot(out / "proxigram.png", overwrite=args.force,
              title=f"{Path(args.ions).name} across {Path(args.mesh).name}", windows=(windows.inner, windows.outer))
    if results:
        write_excess_json(out / "excess.json", results, overwrite=args.force)
    in_range = int(pooled.counts.sum() + pooled.unranged.sum())
    print(f"{args.ions}: {prox.n_ions:,} ions, {prox.n_candidates:,} in the narrow band, {in_range:,} within "
          f"±{windows.outer:g} nm of {len(prox.object_ids)} object(s) ({pooled.areas[0]:.4g} nm²); "
          f"{prox.n_rim:,} at the open rim {'kept' if args.keep_edge else 'left out'}")
    for r in results:
        name = "pooled" if r.object_id < 0 else f"object {r.object_id}"
        print(f"  excess {r.solute} {name}: {r.integration.gamma_detected:.4g} ± "
              f"{r.integration.gamma_detected_error:.2g} detected/nm² (integration), "
              f"{r.cumulative.gamma_detected:.4g} ± {r.cumulative.gamma_detected_error:.2g} (cumulative); "
              f"{r.integration.gamma_atoms:.4g} atoms/nm² at efficiency {efficiency:g}")
    print(f"wrote {', '.join(str(out / t) for t in targets)}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "proxigram", help="proximity histogram and interfacial excess across an iso-surface",
        description="Composition against the exact signed distance of each ion to an iso-surface "
                    "(positive inside the region above the iso-value; mesh normals point out of it), per "
                    "object and pooled, with binomial errors; and, with --solute, the Gibbsian interfacial "
                    "excess (proxigram integration and Krakauer-Seidman cumulative method). Ions whose "
                    "closest point is on the rim of an open surface are left out unless --keep-edge.")
    p.add_argument("ions", metavar="IONS", help="ion file: .pos, .epos, .apt, .csv or .txt")
    p.add_argument("--range", "-r", dest="range_file", metavar="R", required=True,
                   help="range file (.rrng, .rng or .env)")
    p.add_argument("--mesh", "-m", metavar="MESH", required=True,
                   help="iso-surface (.ply, .obj, .stl, .off), normals out of the region above the iso-value")
    add_output(p, "folder for the outputs", metavar="OUTDIR")
    p.add_argument("--bin", type=number("(0, 100]", "nm"), default=0.1, help="bin width in nm (default 0.1)")
    p.add_argument("--range-nm", type=number("(0, 1000]", "nm"), default=None,
                   help="half range of distances in nm, the plateau windows' outer edge (default: 3 x the inner "
                        "edge)")
    p.add_argument("--species", metavar="EL", help="the surface's iso species, whose fitted step sets the plateau "
                                                   "windows and range (without it: 1 and 3 nm)")
    p.add_argument("--keep-edge", action="store_true", help="keep ions beyond the rim of an open surface")
    p.add_argument("--iso", type=number("(0, 1000]"), default=None, help="iso-value as a fraction, marked on the plot")
    p.add_argument("--solute", metavar="B", help="element or ion species whose interfacial excess to compute")
    p.add_argument("--efficiency", type=number("(0, 1]"), default=0.5, help="detection efficiency (default 0.5)")
    p.add_argument("--instrument", choices=INSTRUMENTS,
                   help="take the detection efficiency of this instrument instead of --efficiency")
    p.add_argument("--inner", type=number("[0, 1000]", "nm"), default=None,
                   help="plateau windows start this far from the interface, nm (default: beyond the interface "
                        "width fitted on the proxigram)")
    p.add_argument("--outer", type=number("(0, 1000]", "nm"), default=None,
                   help="plateau windows end here, nm (default: --range-nm)")
    p.add_argument("--force", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)
