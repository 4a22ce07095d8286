#!/usr/bin/env bash
# Set up apt-filters on a bare Debian machine: system libraries, a virtual environment in
# .venv, the package (editable) with its runtime dependencies.
#   bash scripts/setup.sh          runtime only (enough for `apt-filters demo`)
#   bash scripts/setup.sh --dev    plus tests and benchmark peers (pytest, hypothesis,
#                                  scikit-image, vtk, pyacvd, apav; Debian's meshlab and xvfb)
set -euo pipefail
cd "$(dirname "$0")/.."

dev=0
[ "${1:-}" = "--dev" ] && dev=1

# System libraries: libusb-1.0 for open3d, libOpenGL/libGL for pymeshlab's meshing filters,
# libgomp for open3d's OpenMP and numba's OpenMP threading layer (compiled kernels launched from several
# threads at once). Installed only where missing, and only when we may.
need=()
ldconfig -p | grep -q 'libusb-1.0.so.0' || need+=(libusb-1.0-0)
ldconfig -p | grep -q 'libOpenGL.so.0' || need+=(libopengl0)
ldconfig -p | grep -q 'libGL.so.1' || need+=(libgl1)
ldconfig -p | grep -q 'libgomp.so.1' || need+=(libgomp1)
ldconfig -p | grep -q 'libGLU.so.1' || need+=(libglu1-mesa)
# Tests only: Debian's meshlab (2020.09) still ships meshlabserver, which replays our .mlx
# scripts headless under xvfb-run, a second MeshLab client besides pymeshlab; chromium renders
# report.html headless.
if [ $dev = 1 ]; then
  command -v meshlabserver >/dev/null || need+=(meshlab)
  command -v xvfb-run >/dev/null || need+=(xvfb xauth)
  command -v chromium >/dev/null || need+=(chromium)  # the report's render test
fi
if [ ${#need[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "setup: installing system libraries: ${need[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq && apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null \
      || echo "setup: apt-get failed; libusb falls back to the pip package libusb-package" \
              "(without meshlab the meshlabserver replay test is skipped)" >&2
  else
    echo "setup: missing system libraries ${need[*]} (not root): libusb falls back to libusb-package;" \
         "pymeshlab's meshing filters need libopengl0" >&2
  fi
fi

python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
if [ $dev = 1 ]; then
  .venv/bin/python -m pip install -q -e ".[dev,bench]"
else
  .venv/bin/python -m pip install -q -e .
fi
.venv/bin/python -c "import apt_filters.core.deps as d; d.check_runtime()"
