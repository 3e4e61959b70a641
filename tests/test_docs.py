"""README.md and docs/: the set-up commands are the ones CI runs, every `jaxslam`
command in the README parses, the headline table is the one generated from
benchmarks/results/, and no page speaks of work sessions, suite versions or run tags."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
SETUP = ["pip install . && jaxslam run --out runs/demo", 'pip install ".[test]" && python -m pytest']


def bash_blocks(text: str) -> list[str]:
    """The bodies of the fenced ```bash blocks, in order."""
    return [m.group(1).strip() for m in re.finditer(r"^```bash\n(.*?)^```", text, re.S | re.M)]


def jaxslam_commands(text: str) -> list[list[str]]:
    """Every `jaxslam ...` line of the bash blocks (after a leading `pip install ... &&`)."""
    commands = []
    for block in bash_blocks(text):
        for line in block.splitlines():
            line = line.split("#", 1)[0].strip()
            for part in line.split("&&"):
                words = shlex.split(part)
                if words and words[0] == "jaxslam":
                    commands.append(words[1:])
    return commands


def test_the_first_two_bash_blocks_are_the_set_up_commands_ci_runs():
    assert bash_blocks(README)[:2] == SETUP
    ci = (ROOT / ".ci" / "run").read_text()
    assert SETUP[1] in ci
    assert 'pip install ".[docs]"' in ci and "sphinx-build -W --keep-going -n -b html docs docs/_build/html" in ci


def test_every_readme_command_parses():
    from jaxslam.app.cli import build_parser

    parser = build_parser()
    commands = jaxslam_commands(README)
    assert len(commands) >= 6
    for argv in commands:
        args = parser.parse_args(argv)  # an unknown option or a bad value exits with status 2
        assert args is not None, argv


DOC_PAGES = sorted((ROOT / "docs").glob("*.md"))


@pytest.mark.parametrize("path", DOC_PAGES, ids=lambda p: p.name)
def test_every_documented_command_parses(path):
    from jaxslam.app.cli import build_parser

    parser = build_parser()
    for argv in jaxslam_commands(path.read_text()):
        assert parser.parse_args(argv) is not None, argv


def test_a_bad_command_would_fail_the_check():
    from jaxslam.app.cli import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "--no-such-option"])


def test_the_headline_table_is_the_generated_one():
    sys.path.insert(0, str(ROOT / "docs"))
    import generate_tables

    assert generate_tables.headline_table() in README


def test_a_table_of_runs_from_two_cpus_names_both():
    sys.path.insert(0, str(ROOT / "docs"))
    import generate_tables

    machine = {"cores": 2, "cpu": "AMD EPYC", "cpu_family_model": "26/2", "jax": "0.10.2"}
    runs = [{"cpu": "AMD EPYC 26/2"}] * 3 + [{"cpu": "Intel(R) Xeon(R) Processor 6/207"}]
    assert generate_tables.machine_line({"machine": machine, "runs": runs}) == (
        "Measured on 2-core machines: AMD EPYC (family/model 26/2, 3 runs) and "
        "Intel(R) Xeon(R) Processor (family/model 6/207, 1 run); jax 0.10.2.")
    assert generate_tables.machine_line({"machine": machine, "runs": runs[:3]}) == (
        "Measured on a 2-core AMD EPYC (family/model 26/2), jax 0.10.2.")


def test_a_runs_first_closure_is_measured_against_the_drift_since_the_start():
    """The earliest closure of each run, whatever the order of the list; its jump over
    ``rate`` x the path since the start, and over the floor where that is shorter."""
    sys.path.insert(0, str(ROOT / "docs"))
    import generate_tables

    closures = [{"run": "a_s1", "scan": 900, "jump_m": 9.0, "travelled_m": 40.0, "verdict": "R"},
                {"run": "a_s1", "scan": 300, "jump_m": 3.0, "travelled_m": 100.0, "verdict": "W"},
                {"run": "a_s2", "scan": 50, "jump_m": 0.25, "travelled_m": 5.0, "verdict": "?"}]
    first = {c["run"]: c for c in generate_tables.first_closures(closures, 0.02, 0.5)}
    assert first["a_s1"]["scan"] == 300 and first["a_s1"]["drift_ratio"] == pytest.approx(1.5)
    assert first["a_s2"]["drift_ratio"] == pytest.approx(0.5)  # 0.25 m over the 0.5 m floor


def test_paired_arms_compare_the_seeds_both_variants_ran_per_log_and_code_split():
    """Seeds run by one arm only are left out, and a code split only one arm ran; the
    worst seed and the seeds over twice the median are each arm's own; code splits are
    separate rows; the changed seeds are those whose mean differs."""
    sys.path.insert(0, str(ROOT / "docs"))
    import generate_tables

    def run(variant, seed, mean, split=None):
        return {"log": "loop", "filter": f"srupf-gm[{variant}]", "seed": seed, "mean_m": mean, "max_m": 10 * mean,
                **({"code_split": split} if split else {})}

    runs = [run("off", 0, 0.1), run("off", 1, 0.1), run("off", 2, 0.9), run("off", 3, 5.0),
            run("first", 0, 0.1), run("first", 1, 0.1), run("first", 2, 0.25),
            run("off", 0, 0.3, 32), run("first", 0, 0.3, 32), run("other", 0, 7.0), run("off", 0, 0.4, 16)]
    plain, split = generate_tables.paired_arms(runs, "off", "first")
    assert plain["seeds"] == 3 and plain["code_split"] is None and split["code_split"] == 32
    assert plain["off"]["worst_seed"] == 2 and plain["off"]["over_2x"] == 1
    assert plain["off"]["worst_max_m"] == pytest.approx(9.0)
    assert plain["first"]["worst_seed"] == 2 and plain["first"]["over_2x"] == 1 and plain["first"]["median_m"] == 0.1
    assert plain["changed"] == [(2, 0.9, 0.25)] and split["changed"] == []


def test_readme_is_short():
    assert len(README.splitlines()) <= 210


WORDS = re.compile(r"\bsession|\bsuite v\d|\bv5\.\d|\bissue\s*#?\d|\bs\d\d_[a-z]|_s\d\d\b", re.I)


@pytest.mark.parametrize("path", [ROOT / "README.md", ROOT / "benchmarks" / "README.md",
                                  *sorted((ROOT / "docs").glob("*.*"))], ids=lambda p: p.name)
def test_no_diary_words(path):
    hits = [line for line in path.read_text().splitlines() if WORDS.search(line)]
    assert not hits, f"{path.name}: {hits[:3]}"


def test_no_run_tags_in_benchmark_file_names():
    names = [p.name for p in (ROOT / "benchmarks").rglob("*") if "__pycache__" not in p.parts]
    assert not [n for n in names if WORDS.search(n) or n.endswith(".patch")]


def test_every_kept_result_is_cited():
    """benchmarks/results/ keeps only what the documentation reads or names."""
    cited = "".join(p.read_text() for p in [ROOT / "docs" / "generate_tables.py", *DOC_PAGES,
                                             *sorted((ROOT / "notebooks").glob("*.ipynb"))])
    kept = sorted(p.name for p in (ROOT / "benchmarks" / "results").iterdir())
    assert kept and not [name for name in kept if name not in cited]


SENTENCE_END = re.compile(r"\.\s+")


def summary_sentence(doc: str) -> str:
    """The first sentence of a docstring's first paragraph, cut where the API page's
    summary table cuts it (a period followed by white space)."""
    paragraph = " ".join(doc.strip().split("\n\n", 1)[0].split())
    return SENTENCE_END.split(paragraph, 1)[0]


def public_docstrings():
    """(name, docstring) of every module and every public function or class it defines."""
    import importlib
    import inspect
    import pkgutil

    import jaxslam
    for info in pkgutil.walk_packages(jaxslam.__path__, "jaxslam."):
        module = importlib.import_module(info.name)
        yield info.name, inspect.getdoc(module) or ""
        for name, member in vars(module).items():
            if (not name.startswith("_") and (inspect.isfunction(member) or inspect.isclass(member))
                    and getattr(member, "__module__", None) == info.name):
                yield f"{info.name}.{name}", inspect.getdoc(member) or ""


def test_summary_sentences_close_their_literals():
    """A literal cut open by the summary table's first sentence is a Sphinx warning, which
    fails the documentation build."""
    bad = [name for name, doc in public_docstrings() if summary_sentence(doc).count("``") % 2]
    assert not bad, bad


def test_an_open_literal_in_a_summary_is_caught():
    assert summary_sentence("Rows ``a .. b`` of a draw.").count("``") % 2
    assert not summary_sentence("Rows ``a`` to ``b`` of a draw. More.").count("``") % 2
