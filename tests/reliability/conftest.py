"""Helpers of the reliability tests: the command line called in-process."""

from __future__ import annotations

import pytest

from jaxslam.app import cli


@pytest.fixture
def run_cli(capsys):
    """``run_cli(*argv) -> (status, stdout, stderr)`` of ``jaxslam`` in this process."""

    def call(*argv):
        capsys.readouterr()
        try:
            status = cli.main([str(arg) for arg in argv])
        except SystemExit as exc:
            status = exc.code
        captured = capsys.readouterr()
        return status, captured.out, captured.err

    return call


def assert_one_line_error(status, err, *fragments):
    """Exit status 2 and one line on stderr holding every fragment, no traceback."""
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxslam run: error: "), err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
