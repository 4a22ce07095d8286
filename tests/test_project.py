"""The project's promises about itself: README's two commands, CI calling them, imports."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def test_readme_opens_with_two_commands():
    text = (ROOT / "README.md").read_text()
    assert text.index("```bash") < text.index("\n## "), "the commands come before any section"
    cmds = readme_commands()
    assert len(cmds) == 2
    assert cmds[0].endswith("apt-filters demo")
    assert "pytest" in cmds[1]


def test_ci_runs_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert readme_commands()[1] in [line.strip() for line in ci]


def test_open3d_imports_with_libusb_provided():
    from apt_filters.core import deps

    o3d = deps.open3d()
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0)
    assert len(mesh.triangles) > 0


def test_libusb_fallback_preloads_the_pip_copy(monkeypatch):
    """On a machine without the system libusb-1.0, the copy from libusb-package is loaded."""
    import ctypes

    from apt_filters.core import deps

    loaded = []
    monkeypatch.setattr(deps.ctypes.util, "find_library", lambda name: None)
    monkeypatch.setattr(deps.ctypes, "CDLL", lambda path, mode=0: loaded.append((path, mode)))
    deps._preload_libusb()
    assert len(loaded) == 1 and loaded[0][0].endswith(".so") and loaded[0][1] == ctypes.RTLD_GLOBAL
