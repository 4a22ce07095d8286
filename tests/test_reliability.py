"""Never lose a user's data: output folders, signals, concurrent runs, numbers at the door, strict JSON.

Each test reproduces a failure an adversarial run found (the old behaviour is named in its
docstring); the small synthetic specimen keeps the end-to-end ones to seconds, because every
refusal comes before any work.
"""

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from apt_filters.cli.main import main
from apt_filters.core import atomic, jsontext
from apt_filters.core.atomic import TMP_TAG, Interrupted, atomic_write_text, host_tag, scratch_path
from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.pipeline import config as cfg
from apt_filters.pipeline.report import write_json
from apt_filters.pipeline.staging import CLAIM_SUFFIX, MARKER, staged_folder
from apt_filters.synth import preset, write_specimen
from apt_filters.voxel.grid import BLOCK, Grid, check_budget

ROOT = Path(__file__).resolve().parents[1]
RUN = ["--species", "Al", "--iso", "0.15", "-q"]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """A folder holding the small synthetic specimen (specimen.pos, specimen.rrng, ...)."""
    out = tmp_path_factory.mktemp("data") / "data"
    out.mkdir()
    write_specimen(out, preset("small"), seed=2, keep_ions=False)
    return out


def _digest(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _cli(*args: str, cwd: Path | None = None, **kwargs) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "apt_filters", *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=120, **kwargs)


def _one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    return lines[0]


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ---- output folders -------------------------------------------------------------------------------------------

def test_force_never_replaces_the_folder_holding_the_inputs(data, capsys):
    """Was: ``run data/x.pos -r data/x.rrng -o data --force`` exited 0 and deleted both inputs."""
    before = _digest(data)
    assert main(["run", str(data / "specimen.pos"), "-r", str(data / "specimen.rrng"), "-o", str(data),
                 "--force", *RUN]) == 2
    assert "holds the input" in _one_line(capsys.readouterr().err)
    assert _digest(data) == before


@pytest.mark.parametrize("out", [".", "./", "..", "sub/.."])
def test_the_current_folder_is_refused_before_any_work(data, tmp_path, monkeypatch, capsys, out):
    """Was: ``-o . --force`` ran the whole pipeline, then died on a ValueError (staging.py) and lost the output."""
    (tmp_path / "work" / "sub").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "work")
    start = time.perf_counter()
    assert main(["run", str(data / "specimen.pos"), "-r", str(data / "specimen.rrng"), "-o", out, "--force",
                 *RUN]) == 2
    assert "current folder" in _one_line(capsys.readouterr().err)
    assert time.perf_counter() - start < 5, "refused before reading"
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["sub"]


def test_force_replaces_only_a_folder_apt_filters_wrote(data, tmp_path, capsys):
    """Was: ``--force`` replaced any non-empty folder (a thesis folder named by mistake)."""
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "chapter1.tex").write_text("years of work")
    assert main(["run", str(data / "specimen.pos"), "-r", str(data / "specimen.rrng"), "-o", str(mine),
                 "--force", *RUN]) == 2
    assert "--force replaces only folders apt-filters wrote" in _one_line(capsys.readouterr().err)
    assert (mine / "chapter1.tex").read_text() == "years of work"
    # a folder apt-filters wrote is replaced, whole
    target = tmp_path / "out"
    with staged_folder(target) as stage:
        (stage / "a.txt").write_text("1")
    with staged_folder(target, force=True) as stage:
        (stage / "b.txt").write_text("2")
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "thesis"]


def test_a_configuration_file_inside_the_output_folder_is_an_input(data, tmp_path, capsys):
    folder = tmp_path / "out"
    with staged_folder(folder) as stage:
        (stage / "config.toml").write_text(f'[input]\nions = "{data / "specimen.pos"}"\n'
                                           f'ranges = "{data / "specimen.rrng"}"\n[[surface]]\nspecies = "Al"\n'
                                           'iso = 0.1\n')
    assert main(["run", "--config", str(folder / "config.toml"), "-o", str(folder), "--force", "-q"]) == 2
    assert "holds the input" in _one_line(capsys.readouterr().err)


def test_an_output_folder_that_cannot_be_made_is_one_line(tmp_path):
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(AptFiltersError, match="cannot create the output folder"):
        with staged_folder(tmp_path / "file.txt" / "out"):
            pass


def test_output_folders_get_ordinary_permissions(tmp_path):
    """Was: output folders were created mode 0700 (tempfile.mkdtemp)."""
    umask = os.umask(0o022)
    try:
        with staged_folder(tmp_path / "out") as stage:
            atomic_write_text(stage / "a.txt", "x")
    finally:
        os.umask(umask)
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o755
    assert (tmp_path / "out" / "a.txt").stat().st_mode & 0o777 == 0o644


def test_a_second_run_to_the_same_new_folder_refuses(tmp_path):
    """Was: two runs writing to the same new folder both exited 0; one's output silently replaced the other's."""
    target = tmp_path / "out"
    with staged_folder(target) as stage:
        (stage / "first.txt").write_text("1")
        with pytest.raises(AptFiltersError, match="another apt-filters run"):
            with staged_folder(target):
                pass
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "first.txt"]


HOLD = """
import sys, time
from apt_filters.pipeline.staging import staged_folder
with staged_folder(sys.argv[1]) as stage:
    (stage / "partial.txt").write_text("x")
    print("claimed", flush=True)
    time.sleep(60)
"""


def test_concurrent_processes_and_a_killed_one(tmp_path):
    """A run in another process holds the folder; once it is killed (-9), the next run tidies its claim."""
    target = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(target)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert holder.stdout.readline().strip() == "claimed"
        with pytest.raises(AptFiltersError, match=f"process {holder.pid}"):
            with staged_folder(target):
                pass
    finally:
        holder.kill()
        holder.wait()
    assert (tmp_path / f".out{CLAIM_SUFFIX}").is_dir(), "kill -9 cannot clean up"
    with staged_folder(target) as stage:
        (stage / "second.txt").write_text("2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_run_killed_while_replacing_puts_the_old_folder_back(tmp_path):
    """Killed between moving the old folder aside and moving the new one in: the next run restores it."""
    target = tmp_path / "out"
    with staged_folder(target) as stage:
        (stage / "old.txt").write_text("old")
    claim = tmp_path / f".out{CLAIM_SUFFIX}"
    claim.mkdir()
    (claim / "owner").write_text(f"{host_tag()} {_dead_pid()}\n")
    target.rename(claim / "old")
    (claim / "out").mkdir()
    with pytest.raises(AptFiltersError, match="not empty"):
        with staged_folder(target):
            pass
    assert (target / "old.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_leftover_temporary_files_of_dead_processes_are_tidied(tmp_path):
    """Temporary names carry host and pid; a later write into the folder removes those of dead processes."""
    dead = tmp_path / f".a.ply.{TMP_TAG}.{host_tag()}-{_dead_pid()}.0123abcd.ply"
    dead.write_text("half")
    alive = scratch_path(tmp_path / "b.ply", ".ply")  # ours: this process runs
    alive.write_text("in use")
    atomic_write_text(tmp_path / "c.txt", "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, "c.txt"])


POOL_RACE = """
import os, signal, threading
from apt_filters.core.atomic import raise_on_signal
from apt_filters.core.threads import on_threads

signal.signal(signal.SIGTERM, raise_on_signal)
start = threading.Thread.start


def start_then_signal(thread):
    start(thread)
    os.kill(os.getpid(), signal.SIGTERM)  # arrives before the pool has registered the thread it started


threading.Thread.start = start_then_signal
try:
    on_threads(abs, [(1,), (2,)])
except KeyboardInterrupt:
    print("interrupted", flush=True)
"""


def test_a_signal_while_a_pool_starts_its_threads_does_not_hold_the_exit():
    """Was: CI's SIGTERM right after the claim printed 'interrupted' and the process never ended: the signal
    came while the reader's thread pool started a thread it had not yet registered, and the interpreter's
    exit waited for that thread forever."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", POOL_RACE], capture_output=True, text=True, env=env, timeout=60)
    assert (done.returncode, done.stdout.strip()) == (0, "interrupted"), done.stderr


@pytest.mark.parametrize("signum, after", [(signal.SIGTERM, "claim"), (signal.SIGINT, "read"),
                                           (signal.SIGHUP, "audit")])
def test_an_interrupted_run_leaves_nothing(data, tmp_path, signum, after):
    """Was: SIGTERM was not handled: 11 of 14 interrupted runs left ``.OUT.tmp.*`` or ``.OUT.old.<pid>``."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "apt_filters", "run", str(data / "specimen.pos"), "-r", str(data / "specimen.rrng"),
           "-o", str(tmp_path / "out"), "--species", "Al", "--iso", "0.15"]
    # a shell's background job (`cmd &` without job control) starts with SIGINT ignored, and Python keeps that, so
    # Ctrl-C's handler is asked for explicitly: the suite run in the background must still test the interactive case
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        if after == "claim":
            deadline = time.monotonic() + 60
            while not (tmp_path / f".out{CLAIM_SUFFIX}").exists() and time.monotonic() < deadline:
                time.sleep(0.02)
        else:
            for line in proc.stderr:  # the step summaries
                if line.lstrip("[ ").startswith(after):
                    break
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err and err.strip().splitlines()[-1].endswith(
        f"interrupted ({signal.Signals(signum).name})"), err
    assert list(tmp_path.iterdir()) == [], "no output, no staging or claim folder"


def _stopped_in_a_kernel(*args, **kwargs):
    try:
        raise Interrupted(signal.SIGTERM)
    except Interrupted as exc:
        raise SystemError("CPUDispatcher(<function _sums>) returned a result with an exception set") from exc


def _stopped_compiling(*args, **kwargs):
    atomic._received.append(signal.SIGTERM)  # the handler ran in a ctypes callback, its exception swallowed
    raise RuntimeError("no compiled object yet for <Library '_scan'>")


@pytest.mark.parametrize("stopped", [_stopped_in_a_kernel, _stopped_compiling])
def test_an_interrupt_numba_turned_into_another_error_ends_the_command_as_interrupted(data, monkeypatch, capsys,
                                                                                      stopped):
    """Was: of 220 runs sent SIGTERM in their first seconds on a loaded machine, 3 ended with a traceback and
    status 1: the signal landed while a numba kernel was called ("SystemError: CPUDispatcher(...) returned a
    result with an exception set", the interrupt its cause) or compiled (the handler's exception swallowed
    in numba's callback, then "RuntimeError: no compiled object yet")."""
    import apt_filters.io.summary as summary

    monkeypatch.setattr(atomic, "_received", [])
    monkeypatch.setattr(summary, "summarize", stopped)
    assert main(["info", str(data / "specimen.pos")]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip() == "apt-filters info: interrupted (SIGTERM)"


def test_an_error_with_no_signal_behind_it_is_not_an_interrupt(data, monkeypatch):
    import apt_filters.io.summary as summary

    monkeypatch.setattr(atomic, "_received", [])
    monkeypatch.setattr(summary, "summarize", lambda *a, **k: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        main(["info", str(data / "specimen.pos")])


FINALIZE_CRASH = """
import sys
from apt_filters.cli import main as cli

class Finalized:
    def __del__(self):  # runs in the interpreter's finalization, as the crashing library's state did
        print("finalized", flush=True)

sys.modules["stopped_halfway"] = Finalized()
cli.main = lambda: int(sys.argv[1])
cli.run()
"""


@pytest.mark.parametrize("status, finalized", [(0, True), (2, True), (143, False), (130, False)])
def test_a_command_ended_by_a_signal_skips_the_interpreters_finalization(status, finalized):
    """Was: 1 of ~100 runs stopped by SIGTERM on a loaded machine printed "interrupted" after its clean-up and
    then crashed in the interpreter's finalization (SIGSEGV, or abort on "double free"), finalizing a library
    the signal had stopped halfway; CI saw status -11 for 143."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", FINALIZE_CRASH, str(status)], capture_output=True, text=True,
                          env=env, timeout=60)
    assert (done.returncode, "finalized" in done.stdout) == (status, finalized), done.stderr


# ---- numbers at the door --------------------------------------------------------------------------------------

@pytest.mark.parametrize("option, value", [("--voxel", "1e300"), ("--voxel", "nan"), ("--voxel", "-1"),
                                           ("--voxel", "inf"), ("--efficiency", "nan"), ("--efficiency", "2"),
                                           ("--density", "nan"), ("--iso", "1e300"), ("--blur", "nan")])
def test_numbers_are_refused_before_any_file_is_read(tmp_path, capsys, option, value):
    """Was: ``--voxel 1e300`` raised OverflowError (voxel/transfer.py) after reading and auditing (~3 s)."""
    args = [option, value] if option != "--blur" else [option, value, "0"]
    if option not in ("--density", "--iso"):
        args += ["--species", "Al", "--iso", "0.15"]
    elif option == "--iso":
        args += ["--species", "Al"]
    # the ion file does not exist: only a check before reading can name the number instead
    assert main(["run", str(tmp_path / "missing.pos"), "-r", str(tmp_path / "missing.rrng"),
                 "-o", str(tmp_path / "o"), *args]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "missing" not in line and "outside" in line, line


def test_configuration_files_are_held_to_the_same_limits(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[voxel]\nsize = nan\n')
    with pytest.raises(AptFiltersError, match=r"size = nan is outside \[0.01, 1000\] nm"):
        cfg.load(path)
    path.write_text('[voxel]\ndelocalization = ["a", 1, 2]\n')
    with pytest.raises(AptFiltersError, match="list of float"):
        cfg.load(path)
    path.write_text('[voxel]\nsize = 4.0\n')  # the default 1.5 nm depth delocalization is below half of it
    with pytest.raises(AptFiltersError, match="must exceed half the voxel"):
        cfg.load(path)
    path.write_text('[proxigram]\nbin = 1e-6\nextent = 1000\n')
    with pytest.raises(AptFiltersError, match="bins"):
        cfg.load(path)


@pytest.mark.parametrize("argv", [
    ["proxigram", "i.pos", "-r", "r.rrng", "-m", "m.ply", "-o", "o", "--bin", "nan"],
    ["proxigram", "i.pos", "-r", "r.rrng", "-m", "m.ply", "-o", "o", "--range-nm", "1e300"],
    ["remesh", "m.ply", "-o", "o.ply", "--edge-length", "-1"],
    ["audit", "i.pos", "-r", "r.rrng", "--resolution", "inf"],
])
def test_every_numeric_option_is_checked_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert "is outside" in _one_line(capsys.readouterr().err)


@pytest.mark.parametrize("far", [2e7, 1e9])
def test_the_memory_budget_counts_far_away_ions_without_wrapping(far):
    """Was: one ion at 2e7 nm wrapped int64 (negative estimate, the check passed, numpy failed); at 1e9 nm the
    refusal printed a wrapped size."""
    grid = Grid.covering(np.zeros(3), np.full(3, far), 1.0, margin=4)
    blocks = -(-(int(np.ceil(far)) + 9) // BLOCK)  # exact, in Python ints
    need = blocks**3 * BLOCK**3 * 8 * (2 * 3 + 2)
    assert grid.n_voxels == (int(np.ceil(far)) + 9) ** 3
    with pytest.raises(AptFiltersError) as refused:
        check_budget(grid, 3, 1 << 30)
    assert f"may need {need / 1e9:.3g} GB" in str(refused.value)
    with pytest.raises(AptFiltersError, match="over the memory budget"):  # float32's largest coordinate
        check_budget(Grid.covering(np.zeros(3), np.full(3, 3e38), 0.01, margin=4), 3, 1 << 30)


def test_the_voxel_api_refuses_absurd_sizes_without_overflow():
    """Was: ``voxel=1e300`` raised OverflowError in voxel/transfer.py."""
    from apt_filters.voxel.transfer import second_pass_sigma

    with pytest.raises(AptFiltersError, match="must exceed half the voxel"):
        second_pass_sigma(1e300, (3.0, 3.0, 1.5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the one-line refusal, not numpy's overflow warning as well
        with pytest.raises(AptFiltersError, match="too many voxels"):
            Grid.covering(np.zeros(3), np.full(3, 100.0), 1e-310)


# ---- what is written ------------------------------------------------------------------------------------------

def test_json_is_strict_with_the_reason_beside_each_null(tmp_path):
    """Was: report.json held NaN, which strict JSON parsers refuse."""
    write_json(tmp_path / "r.json", {"excess": float("nan"), "ratio": np.float32(np.inf),
                                     "profile": [1.0, float("nan")], "nested": {"se": -np.inf}})

    def refuse(word):
        raise ValueError(f"not strict JSON: {word}")

    data = json.loads((tmp_path / "r.json").read_text(), parse_constant=refuse)
    assert data == {"excess": None, "excess_null": "NaN: not defined", "ratio": None, "ratio_null": "+infinity",
                    "profile": [1.0, None], "profile_null": "1 non-finite entries written as null",
                    "nested": {"se": None, "se_null": "-infinity"}}
    assert jsontext.dumps(float("nan")) == "null"


def test_relative_paths_in_a_configuration_are_relative_to_its_folder(tmp_path, monkeypatch):
    """Was: ``--config`` worked only from the folder the first run started in."""
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "c.toml").write_text('[input]\nions = "data/x.pos"\nranges = "/abs/x.rrng"\n')
    monkeypatch.chdir(tmp_path)
    config = cfg.load("a/c.toml")
    assert Path(config.input.ions).resolve() == tmp_path / "a" / "data" / "x.pos"
    assert config.input.ranges == "/abs/x.rrng"


def test_error_lines_have_a_readable_length():
    """Was: a 1 MB bad token gave a 1 MB error line."""
    text = str(InputError("bad token " + "x" * 1_000_000 + " in line 3", "f.rrng"))
    assert len(text) < 400 and text.startswith("f.rrng: bad token xxx") and text.endswith("in line 3")
    assert "999800 more characters" in text


@pytest.mark.parametrize("command", [["info", "{pos}", "--json"], ["info", "{pos}", "-r", "{rrng}"]])
def test_a_closed_pipe_ends_quietly(data, command):
    """Was: ``info --json | true`` ended in a BrokenPipeError traceback."""
    argv = [a.format(pos=data / "specimen.pos", rrng=data / "specimen.rrng") for a in command]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "apt_filters", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    proc.stdout.close()  # the reader is gone before the command writes anything
    _, err = proc.communicate(timeout=120)
    assert err == b"" and proc.returncode == 141


def test_a_swallowed_interrupt_ends_the_run_at_the_next_step(monkeypatch, capsys):
    """Was: SIGTERM arriving inside numba's cache callback (a ctypes callback) printed "Exception
    ignored" with a traceback and the run went on to write its output."""
    import ctypes

    from apt_filters.pipeline.steps import StepLog

    monkeypatch.setattr(atomic, "_received", [])
    monkeypatch.setattr(sys, "unraisablehook", atomic.unraisable_hook)
    callback = ctypes.CFUNCTYPE(None)(lambda: atomic.raise_on_signal(signal.SIGTERM, None))
    callback()  # ctypes cannot propagate the exception: it goes to the unraisable hook
    assert "Traceback" not in capsys.readouterr().err
    with pytest.raises(atomic.Interrupted) as caught:
        with StepLog(quiet=True).step("next"):
            pass
    assert caught.value.signum == signal.SIGTERM
