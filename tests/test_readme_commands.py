"""The README's quick starts run as written, in a fresh copy of the repository.

The commands are read from README.md itself, so that the test and the README cannot
drift apart: every line of the fenced ``bash`` blocks after the two set-up commands
(and the ``jaxslam`` half of the first one, the main job), each run by ``bash`` from
the copy's root with ``../shared`` beside it, then the ``python`` block. Each must
exit 0 and leave the files the README says it writes. docs/getting_started.md
repeats no command of its own: its quick-start commands are the README's.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_docs import ROOT, bash_blocks, jaxslam_commands

README = (ROOT / "README.md").read_text()
SHARED = ROOT.parent / "shared"

GRID_RUN_FILES = ["map.pgm", "map.yaml", "map.npz", "map.png", "map_trajectory.png", "trajectory.tum", "summary.json"]
# What the README says each output folder holds (a test below checks it says so).
EXPECTED = {
    "runs/demo": ["summary.json", "trajectory.tum", "landmarks.csv", "trajectory.png", "health.png"],
    "runs/sim-laser": GRID_RUN_FILES,
    "runs/intel": GRID_RUN_FILES,
    "runs/mit-csail": GRID_RUN_FILES,
    "runs/robot": GRID_RUN_FILES,
    "runs/intel-loc": ["summary.json", "trajectory.tum"],
}


def quick_start_lines(text: str = README) -> list[str]:
    """The commands of the README's quick starts, in order: the main job's ``jaxslam``
    half, then every line of the bash blocks after the two set-up blocks."""
    blocks = bash_blocks(text)
    lines = [blocks[0].split("&&", 1)[1].strip()]
    for block in blocks[2:]:
        lines += [line.strip() for line in block.splitlines() if line.strip() and not line.strip().startswith("#")]
    return lines


def python_blocks(text: str = README) -> list[str]:
    return [m.group(1) for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M)]


def out_folder(line: str) -> str | None:
    match = re.search(r"--out (\S+)", line)
    return match.group(1) if match else None


def test_every_quick_start_command_is_a_jaxslam_command_on_real_files():
    lines = quick_start_lines()
    assert len(lines) >= 8 and all(line.startswith("jaxslam ") for line in lines), lines
    assert not [line for line in lines if "path/to" in line], "a placeholder path is not a command one can run"
    for line in lines:
        if line.startswith("jaxslam run") or line.startswith("jaxslam localize"):
            assert out_folder(line) in EXPECTED, line


def test_the_readme_names_the_files_the_test_checks():
    for name in {name for names in EXPECTED.values() for name in names}:
        assert f"`{name}`" in README, name


def test_getting_started_runs_the_readme_commands():
    """docs/getting_started.md repeats the quick starts; its commands are the README's,
    so that the run below checks them too."""
    page = (ROOT / "docs" / "getting_started.md").read_text()
    readme = jaxslam_commands(README)
    own = [argv for argv in jaxslam_commands(page) if argv[0] in ("run", "localize", "export-bag", "evaluate")
           and "--out" in argv or argv[:2] == ["datasets", "--inspect"]]
    assert own and [argv for argv in own if argv not in readme] == []
    assert python_blocks(page) == python_blocks(README)


def fresh_copy(tmp_path: Path) -> Path:
    """The repository's tracked and not-ignored files (what a clone of the working tree
    holds) in ``tmp_path/jaxslam``, with ``tmp_path/shared`` the data beside it."""
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, check=True).stdout.decode().split("\0")
    copy = tmp_path / "jaxslam"
    for name in filter(None, files):
        source = ROOT / name
        if source.is_file():
            (copy / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, copy / name)
    (tmp_path / "shared").symlink_to(SHARED, target_is_directory=True)
    return copy


@pytest.mark.long
def test_the_quick_starts_run_verbatim(tmp_path):
    if not (SHARED / "datasets").is_dir():
        pytest.skip(f"the quick starts read ../shared/datasets; {SHARED} is not there")
    copy = fresh_copy(tmp_path)
    bin_dir = Path(sys.executable).parent
    if shutil.which("jaxslam", path=str(bin_dir)) is None:
        pytest.fail(f"no `jaxslam` command beside {sys.executable}; install the package (pip install .)")
    env = {k: v for k, v in os.environ.items() if k != "JAXSLAM_DATA"}  # the default: ../shared/datasets
    env.update(PATH=f"{bin_dir}{os.pathsep}{env.get('PATH', '')}", PYTHONPATH=str(copy))
    for line in quick_start_lines():
        result = subprocess.run(["bash", "-c", f"set -euo pipefail; {line}"], cwd=copy, env=env,
                                capture_output=True, text=True, timeout=1200)
        assert result.returncode == 0, f"{line}\n{result.stderr[-3000:]}"
        folder = out_folder(line)
        if folder in EXPECTED:
            missing = [name for name in EXPECTED[folder] if not (copy / folder / name).is_file()]
            assert not missing, f"{line}: no {missing} in {folder}"
        if line.startswith("jaxslam evaluate"):
            scores = json.loads(result.stdout)
            assert scores["trans_err_mean_m"] < 0.1 and "warning" not in result.stderr, result.stderr
        if line.startswith("jaxslam export-bag"):
            assert (copy / out_folder(line)).is_file()
        if line.startswith("jaxslam datasets --inspect"):
            assert "/scan" in result.stdout and "sensor_msgs/msg/LaserScan" in result.stdout
    (block,) = python_blocks()
    result = subprocess.run([sys.executable, "-c", block], cwd=copy, env=env, capture_output=True, text=True,
                            timeout=1200)
    assert result.returncode == 0, result.stderr[-3000:]
    first, second = result.stdout.splitlines()[-2:]
    assert first.startswith("(2000, 3)") and second.startswith("(2000,)"), result.stdout
