"""The report of `ares reproduce`: each experiment's table (the paper beside ARES), its notes and
its picture, in one Markdown file."""

from __future__ import annotations

from pathlib import Path

from ares.tools.reproduce.experiment import ExperimentResult


def cell(value) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value + 0.0:.4g}"  # (+ 0.0: no "-0")
    return str(value)


def write_report(path: Path, results: list[ExperimentResult], seconds: float) -> Path:
    lines = [
        "# The papers' experiments on ARES",
        "",
        f"`ares reproduce`: {len(results)} experiments in {seconds:.0f} s.",
        "",
    ]
    for r in results:
        lines += [f"## {r.title} ({r.paper_ref})", "", f"`{r.id}`, {r.seconds:.0f} s.", ""]
        lines += ["| figure | paper | ARES | unit |", "|---|---|---|---|"]
        lines += [f"| {row.figure} | {cell(row.paper)} | {cell(row.ares)} | {row.unit} |" for row in r.rows]
        lines.append("")
        lines += [f"- {note}" for note in r.notes]
        if r.picture is not None:
            lines += ["", f"![{r.title}]({Path(r.picture).name})"]
        lines.append("")
    path.write_text("\n".join(lines))
    return path
