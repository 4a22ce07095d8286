"""Terminal habits: one output option name, mistakes caught before heavy imports (the time itself is
measured in benchmarks/bench_cli.py, not here)."""

import subprocess
import sys

import pytest

from apt_filters.cli.main import build_parser

HEAVY = ("numba", "scipy", "pymeshlab", "open3d", "matplotlib")


def _subcommand_help(name: str) -> str:
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices[name].format_help()


@pytest.mark.parametrize("command", ["run", "demo", "proxigram", "remesh", "replay"])
def test_every_command_names_its_output_o_output(command):
    text = _subcommand_help(command)
    assert "-o OUT" in text.replace("OUTDIR", "OUT").replace("OUT.ply", "OUT") and "--output" in text
    assert "--outdir" not in text and "--out " not in text, "old spellings stay hidden"


@pytest.mark.parametrize("argv", [["run", "x.pos", "-r", "x.rrng", "--out", "o"],
                                  ["proxigram", "x.pos", "-r", "x.rrng", "-m", "m.ply", "--outdir", "o"]])
def test_old_output_spellings_still_work(argv):
    assert build_parser().parse_args(argv).output == "o"


def test_instrument_names_match_the_efficiency_table():
    from apt_filters.analysis.excess import INSTRUMENT_EFFICIENCY
    from apt_filters.cli.proxigram import INSTRUMENTS

    assert list(INSTRUMENTS) == sorted(INSTRUMENT_EFFICIENCY)


@pytest.mark.parametrize("argv, message", [
    (["run", "{tmp}/missing.pos", "-r", "{tmp}/r.rrng", "-o", "{tmp}/o", "--species", "Al", "--iso", "0.1"],
     "missing.pos: no such file"),
    (["run", "{tmp}/i.pos", "-r", "{tmp}/r.rrng", "-o", "{tmp}/o", "--species", "xe", "--iso", "0.1"],
     "unknown iso-surface species 'xe'; valid names: Al, Ni"),
    (["proxigram", "{tmp}/i.pos", "-r", "{tmp}/r.rrng", "-m", "{tmp}/m.ply", "-o", "{tmp}/p"],
     "m.ply: mesh file not found"),
    (["info", "{tmp}/i.xyz"], "unknown ion file extension"),
])
def test_mistakes_are_reported_before_heavy_libraries_load(tmp_path, argv, message):
    (tmp_path / "r.rrng").write_text("[Ions]\nNumber=2\nIon1=Al\nIon2=Ni\n[Ranges]\nNumber=2\n"
                                     "Range1=26.5000 27.5000 Vol:0.01661 Al:1 Color:33FFFF\n"
                                     "Range2=57.5000 58.5000 Vol:0.01094 Ni:1 Color:00FF00\n")
    (tmp_path / "i.pos").write_bytes(b"\x00" * 160)
    args = [a.format(tmp=tmp_path) for a in argv]
    code = ("import sys\nfrom apt_filters.cli.main import main\nrc = main(sys.argv[1:])\n"
            f"print(rc, sorted(m for m in {HEAVY!r} if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "2 []", proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0]
