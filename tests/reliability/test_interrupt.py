"""Ctrl-C while ``jaxslam run`` compiles: exit status 130, one line, the folder marked.

Each try runs the command line in a subprocess on the built-in landmark simulator
with the compilation cache off (so that compilation takes seconds) and sends SIGINT
once ``compiling`` is printed, after a random delay of up to a second."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest


def interrupt_while_compiling(out: Path, delay: float) -> tuple[int, str]:
    """Start a run, SIGINT it ``delay`` s after ``compiling`` appears; (status, stderr)."""
    command = [sys.executable, "-m", "jaxslam.app.cli", "run", "--algorithm", "erb-upf", "--particles", "5",
               "--max-steps", "200", "--no-cache", "--no-plots", "--out", str(out)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "JAX_PLATFORMS": "cpu"})
    seen = []
    for line in process.stderr:
        seen.append(line)
        if "compiling" in line:
            break
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    _, rest = process.communicate(timeout=120)
    return process.returncode, "".join(seen) + rest


def check_interrupted(out: Path, status: int, stderr: str) -> None:
    assert status == 130, f"exit status {status}, stderr:\n{stderr}"
    assert "Traceback" not in stderr and "Fatal Python error" not in stderr, stderr
    assert [line for line in stderr.splitlines() if "interrupted" in line] == ["jaxslam run: interrupted"], stderr
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    assert not (out / "summary.json").exists()


GC_INTERRUPT = """
import gc, os, signal, sys
from jaxslam.app import cli

fired = []

def interrupt(phase, info):  # as JAX's gc callback: Python code the signal can land in
    if phase == "start" and not fired:
        fired.append(True)
        os.kill(os.getpid(), signal.SIGINT)

def armed(args, command=cli.COMMANDS["datasets"]):  # the command starts, then a collection
    gc.callbacks.append(interrupt)
    gc.set_threshold(1)
    return command(args)

cli.COMMANDS["datasets"] = armed
sys.argv = ["jaxslam", "datasets"]
cli.console_main()
"""


def test_interrupt_inside_a_gc_callback_is_not_lost():
    """Python drops a KeyboardInterrupt raised inside a gc callback ("Exception
    ignored"), and the command went on to exit 0; the handler exits 130 there too."""
    done = subprocess.run([sys.executable, "-c", GC_INTERRUPT], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "JAX_PLATFORMS": "cpu"})
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip().splitlines() == ["jaxslam datasets: interrupted"], done.stderr


@pytest.mark.parametrize("delay", [0.0, 0.6])
def test_interrupt_while_compiling_exits_130(tmp_path, delay):
    out = tmp_path / "run"
    check_interrupted(out, *interrupt_while_compiling(out, delay))


@pytest.mark.long
def test_interrupt_while_compiling_many_times(tmp_path):
    rng = random.Random(0)
    for attempt in range(20):
        out = tmp_path / f"run{attempt}"
        check_interrupted(out, *interrupt_while_compiling(out, rng.uniform(0.0, 1.5)))


@pytest.mark.long
def test_interrupted_loop_resumes_to_the_uninterrupted_result(tmp_path):
    """Ctrl-C in the filter loop of a checkpointed run: exit 130, run.json interrupted,
    and ``--resume`` finishes it with the trajectory of a run never interrupted."""
    command = [sys.executable, "-m", "jaxslam.app.cli", "run", "--algorithm", "erb-upf", "--particles", "50",
               "--checkpoint-every", "20", "--chunk", "20", "--no-plots"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    subprocess.run(command + ["--out", str(whole), "--no-progress"], check=True, capture_output=True, timeout=300)
    stderr = tmp_path / "stderr.txt"
    with stderr.open("w") as sink:
        process = subprocess.Popen(command + ["--out", str(cut)], stdout=subprocess.DEVNULL, stderr=sink)
        # Interrupted once its first checkpoint is on disk: the progress bar's
        # "scan/s" appears before the first chunk has run, so it tells nothing.
        deadline = time.monotonic() + 300
        while not (cut / "checkpoint.npz").exists():
            assert process.poll() is None, stderr.read_text()
            assert time.monotonic() < deadline, stderr.read_text()
            time.sleep(0.01)
        process.send_signal(signal.SIGINT)
        process.wait(timeout=120)
    assert process.returncode == 130, stderr.read_text()
    assert json.loads((cut / "run.json").read_text())["status"] == "interrupted"
    assert (cut / "checkpoint.npz").exists() and not (cut / "trajectory.tum").exists()
    subprocess.run([sys.executable, "-m", "jaxslam.app.cli", "run", "--resume", str(cut), "--no-progress"],
                   check=True, capture_output=True, timeout=300)
    assert json.loads((cut / "run.json").read_text())["status"] == "complete"
    assert (cut / "trajectory.tum").read_bytes() == (whole / "trajectory.tum").read_bytes()
