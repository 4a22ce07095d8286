"""Loading the heavy optional-looking runtime dependencies the same way everywhere.

open3d links against the system library libusb-1.0, which a bare Debian machine lacks; the
pip package ``libusb-package`` ships a copy that we preload (RTLD_GLOBAL) before the first
``import open3d`` when the system has none.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from types import ModuleType

from apt_filters.core.errors import AptFiltersError


def _preload_libusb() -> None:
    if ctypes.util.find_library("usb-1.0"):
        return
    try:
        import libusb_package
    except ImportError as exc:  # pragma: no cover - depends on the machine
        raise AptFiltersError(
            "open3d needs libusb-1.0: install the system package libusb-1.0-0 or pip install libusb-package"
        ) from exc
    path = libusb_package.get_library_path()
    if path is None:  # pragma: no cover
        raise AptFiltersError("libusb-package ships no libusb-1.0 for this platform; install libusb-1.0-0")
    ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


@functools.lru_cache(maxsize=None)
def open3d() -> ModuleType:
    """Return the ``open3d`` module, providing libusb-1.0 first if the system lacks it."""
    _preload_libusb()
    try:
        import open3d as o3d
    except ImportError as exc:
        raise AptFiltersError(f"cannot import open3d: {exc}") from exc
    return o3d


def check_runtime() -> None:
    """Import every runtime dependency once, so that set-up fails early and clearly."""
    import fast_simplification  # noqa: F401
    import numpy  # noqa: F401
    import pymeshlab  # noqa: F401
    import scipy  # noqa: F401

    o3d = open3d()
    print(f"apt-filters runtime ok (open3d {o3d.__version__})")
