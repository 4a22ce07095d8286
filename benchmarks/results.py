"""The results file every benchmark writes: a summary block for RESULTS.md, then its detailed tables.

``benchmarks/results_<name>.md`` starts with its title and a summary block of 1-4 rows, the
figures a user compares (ours and the named peer side by side, or ours against the target
named in "measure" where no peer exists)::

    <!-- summary -->
    | step | measure | ours | peer | ours / peer |
    |---|---|---:|---:|---:|
    | voxel | Gaussian voxelization, 10M ions, 2 cores | 1.9 s | 3.1 s (APAV RangedGrid) | 0.61 |
    <!-- /summary -->

followed by the current detailed tables, one ``## `` section each. ``python -m benchmarks``
gathers the blocks into RESULTS.md. The history of what was tried lives in
``benchmarks/notebook/``, never here.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

from apt_filters.core.atomic import atomic_write_text

HERE = Path(__file__).resolve().parent
SUMMARY = re.compile(r"<!-- summary -->\s*\n(.*?)\n\s*<!-- /summary -->", re.S)
HEADER = ["| step | measure | ours | peer | ours / peer |", "|---|---|---:|---:|---:|"]

Row = tuple[str, str, str, str, str]
"""(step, measure, ours, peer, ours / peer); peer and ratio are "-" where there is no peer."""


def best_of(fn: Callable[[], object], repeat: int = 3) -> tuple[float, object]:
    """The shortest wall time (s) of ``repeat`` calls of ``fn`` and the last call's result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def child_result(script: str, work: Path, code: Path, environment: dict[str, str], what: str) -> dict:
    """Run ``script --child --work WORK`` in a fresh process with ``code`` first on the path: its last line's JSON.

    ``script`` is the benchmark's own file, run by path, so a baseline checkout need not have it;
    ``environment`` is the one the benchmark saw before importing ``apt_filters`` (whose import
    changes it), so that every code runs under the same settings. A failed child ends the benchmark
    with ``what`` and the child's last lines.
    """
    done = subprocess.run([sys.executable, script, "--child", "--work", str(work)], cwd=code,
                          env={**environment, "PYTHONPATH": str(code)}, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"{what} with {code} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def ratio(ours: float, peer: float) -> str:
    """``ours / peer`` as the summary prints it."""
    return f"{ours / peer:.2f}" if peer else "-"


def summary_rows(text: str) -> list[str]:
    """The table rows of a results file's summary block (its header and rule left out)."""
    match = SUMMARY.search(text)
    if not match:
        return []
    rows = [line.strip() for line in match.group(1).splitlines() if line.strip().startswith("|")]
    return rows[2:]


def _row_key(line: str) -> tuple[str, str]:
    cells = [c.strip() for c in line.strip().strip("|").split("|")]
    return cells[0], cells[1]


def write_results(name: str, title: str, rows: list[Row], sections: list[str], *, intro: str = "",
                  merge: bool = False) -> Path:
    """Write ``benchmarks/results_<name>.md``: the title, the summary block, the sections.

    Parameters
    ----------
    name : str
        The benchmark's name (``bench_<name>.py`` writes ``results_<name>.md``).
    title : str
        First line of the file, without the leading ``# ``.
    rows : list of Row
        Summary rows of this run.
    sections : list of str
        Detailed tables of this run, each starting with its ``## `` heading.
    intro : str, optional
        What is measured and how (data, peers), between the summary block and the sections.
    merge : bool, optional
        Keep the previous file's summary rows whose (step, measure) this run did not measure
        and its sections whose heading this run did not write (for benchmarks run in parts or
        at several sizes, e.g. 10M and 100M ions). Default False: the file is this run alone.

    Returns
    -------
    Path
        The file written (atomically).
    """
    path = HERE / f"results_{name}.md"
    new_lines = ["| " + " | ".join(r) + " |" for r in rows]
    if merge and path.is_file():
        old = path.read_text()
        done = {_row_key(ln) for ln in new_lines}
        new_lines = [ln for ln in summary_rows(old) if _row_key(ln) not in done] + new_lines
        headings = {s.splitlines()[0] for s in sections}
        old_sections = ["## " + s.strip() for s in old.split("\n## ")[1:]]
        sections = [s for s in old_sections if s.splitlines()[0] not in headings] + list(sections)
    body = ([intro.strip()] if intro else []) + [s.strip() for s in sections]
    text = "\n".join([f"# {title}", "", "<!-- summary -->", *HEADER, *new_lines, "<!-- /summary -->", "",
                      "\n\n".join(body)]) + "\n"
    atomic_write_text(path, text, overwrite=True)
    return path
