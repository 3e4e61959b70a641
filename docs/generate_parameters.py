"""The parameter reference page, generated from the code.

:func:`jaxslam.app.params.parameter_reference` is the one source of every parameter's
name, unit, meaning and default per algorithm; it also feeds ``jaxslam run
--list-params`` and ``--set``'s validation. :func:`write` turns it into
``docs/_generated/parameters.md``. A jaxslam without that function fails the build.
"""

from __future__ import annotations

from pathlib import Path

GENERATED = Path(__file__).resolve().parent / "_generated"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def parameter_table() -> str:
    """One row per parameter: name, unit, its default and the algorithms that use it
    (one default per algorithm where they differ), and its meaning."""
    try:
        from jaxslam.app.params import parameter_reference
    except ImportError as error:
        raise RuntimeError(
            "docs: jaxslam.app.params.parameter_reference() is needed for the parameter reference "
            f"page and cannot be imported ({error})") from error
    rows = list(parameter_reference())
    if not rows:
        raise RuntimeError("docs: parameter_reference() returned no parameters")
    lines = ["| name | unit | default | meaning |", "|---|---|---|---|"]
    for row in sorted(rows, key=lambda r: r.name):
        if not row.unit or not row.meaning or not row.defaults:
            raise RuntimeError(f"docs: parameter {row.name!r} has no unit, meaning or default")
        values = set(row.defaults.values())
        if len(values) == 1:
            default = f"`{_cell(next(iter(values)))}` ({', '.join(sorted(row.defaults))})"
        else:
            default = "; ".join(f"`{_cell(v)}` ({a})" for a, v in sorted(row.defaults.items()))
        lines.append(f"| `{row.name}` | {_cell(row.unit)} | {default} | {_cell(row.meaning)} |")
    return "\n".join(lines) + "\n"


def write(folder: Path = GENERATED) -> Path:
    """Write ``folder/parameters.md``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "parameters.md"
    text = parameter_table()
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


if __name__ == "__main__":
    print(write())
