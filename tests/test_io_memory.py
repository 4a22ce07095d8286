"""Peak memory of reading: measured (VmHWM of a fresh subprocess), since tracemalloc cannot see maps."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
N = 8 * 2**20  # 8M ions: a 128 MiB POS
MIB = 2**20

WORKER = """
import json, sys
import numpy as np
from apt_filters.io import iter_ion_chunks, read_ions

def vm(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024

path, how = sys.argv[1], sys.argv[2]
start = vm("VmRSS")
if how == "read_ions":
    ions = read_ions(path)
    total = float(ions.mz.sum(dtype=np.float64))
else:
    total = sum(float(c.mz.sum(dtype=np.float64)) for c in iter_ion_chunks(path, 2**20))
print(json.dumps({"peak": vm("VmHWM") - start, "total": total}))
"""


@pytest.fixture(scope="module")
def big_pos(tmp_path_factory):
    path = tmp_path_factory.mktemp("mem") / "big.pos"
    rec = np.ones((N, 4), dtype=">f4")
    rec[:, 3] = 2
    rec.tofile(path)
    return path


def _peak(path: Path, how: str) -> int:
    proc = subprocess.run([sys.executable, "-c", WORKER, str(path), how], cwd=ROOT,
                          capture_output=True, text=True, check=True, timeout=120)
    out = json.loads(proc.stdout)
    assert out["total"] == 2.0 * N
    return out["peak"]


def test_read_ions_holds_one_native_copy(big_pos):
    # the result is 16 B/ion (positions 12 + m/z 4); one 1M-ion chunk of mapped pages (16 MiB)
    # and the interpreter's own growth may come on top; a second copy would add 128 MiB
    peak = _peak(big_pos, "read_ions")
    assert 16 * N <= peak < 16 * N + 40 * MIB, peak / MIB


def test_iter_ion_chunks_holds_about_one_chunk(big_pos):
    # 1M-ion chunks: the chunk being built, the one the loop still holds, its mapped pages
    peak = _peak(big_pos, "iter")
    assert peak < 3 * 16 * MIB + 24 * MIB, peak / MIB
