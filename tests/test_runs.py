"""mdgs.runs: the run-folder lock (one writer per folder, also across machines sharing the folder)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from mdgs.data.io import host_tag
from mdgs.runs import LOCK_NAME, RunError, folder_lock


def _dead_pid() -> int:
    """A process id that existed and is gone (a finished child)."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _plant(folder, host: str, pid: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / LOCK_NAME).write_text(json.dumps({"host": host, "pid": pid, "command": "mdgs train (mdgs)",
                                                 "since": "2026-01-01 00:00:00"}))


def test_lock_is_held_and_released_and_a_second_holder_is_refused(tmp_path):
    run = tmp_path / "run"
    with folder_lock(run, "test") as path:
        doc = json.loads(path.read_text())
        assert doc["host"] == host_tag() and doc["pid"] == os.getpid()
        (run / "config.json").write_text("{}")
        # another process on this machine (its own pid) holds it: refused, naming pid and folder
        _plant(tmp_path / "other", host_tag(), os.getppid())
        with pytest.raises(RunError, match=rf"in use by .*process {os.getppid()} on this machine"):
            with folder_lock(tmp_path / "other", "test"):
                pass
    assert not path.exists() and (run / "config.json").exists()


def test_stale_lock_of_this_host_is_taken_over(tmp_path):
    run = tmp_path / "run"
    _plant(run, host_tag(), _dead_pid())  # a killed train left its lock behind
    with folder_lock(run, "test") as path:
        assert json.loads(path.read_text())["pid"] == os.getpid()
    assert not path.exists()


def test_lock_of_another_host_is_never_judged_stale(tmp_path, monkeypatch):
    """On a shared (network) folder a pid means nothing on another machine: even a pid that is dead
    here is refused, with the way out named (delete the lock if that host no longer runs it)."""
    run = tmp_path / "run"
    _plant(run, "node-17", _dead_pid())
    with pytest.raises(RunError, match=r"on host node-17.*delete .*\.lock"):
        with folder_lock(run, "test"):
            pass
    assert (run / LOCK_NAME).exists()
    monkeypatch.setenv("MDGS_HOST", "node-17")  # the same folder seen from node-17: stale there
    with folder_lock(run, "test"):
        pass


def test_refused_lock_leaves_a_new_folder_absent_and_an_unreadable_lock_is_refused(tmp_path):
    with pytest.raises(RunError):
        with folder_lock(tmp_path / "new", "test"):
            raise RunError("refused after taking the lock")
    assert not (tmp_path / "new").exists()
    run = tmp_path / "run"
    run.mkdir()
    (run / LOCK_NAME).write_text("garbage")
    with pytest.raises(RunError, match="names no process"):
        with folder_lock(run, "test"):
            pass


def test_two_processes_never_hold_one_folder(tmp_path):
    """Real concurrency: a child holds the lock; this process is refused until the child exits."""
    run = tmp_path / "run"
    code = ("import sys, time; from mdgs.runs import folder_lock\n"
            f"with folder_lock({str(run)!r}, 'child'):\n    print('held', flush=True); sys.stdin.readline()\n")
    child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        assert child.stdout.readline().strip() == "held"
        with pytest.raises(RunError, match=f"process {child.pid}"):
            with folder_lock(run, "test"):
                pass
    finally:
        child.communicate("\n", timeout=60)
    with folder_lock(run, "test"):
        pass
