"""Figures and rows, the console table and ``bench/results.md``."""

from __future__ import annotations

from dataclasses import dataclass, field

from bench.timing import Stats


@dataclass(frozen=True)
class Goal:
    op: str  # "<=" or ">="
    value: float
    label: str = ""  # how the issue writes it, e.g. "1/20", shown instead of the value

    def met(self, measured: float) -> bool:
        return measured <= self.value if self.op == "<=" else measured >= self.value

    def text(self, unit: str) -> str:
        sign = "≤" if self.op == "<=" else "≥"
        return f"{sign} {self.label}" if self.label else f"{sign} {fmt(self.value, unit)}"


@dataclass(frozen=True)
class Row:
    case: str
    stats: Stats
    unit: str  # "x" (ratio), "s", "MB", "MB/s", "count"
    goal: Goal | None = None
    detail: str = ""
    why_missed: str = ""  # this case's numbers, shown next to the figure's note when missed
    check_ok: bool | None = None  # a side condition of the goal (e.g. "no mitsuba import")

    @property
    def status(self) -> str:
        if self.goal is None:
            return "info"
        ok = self.goal.met(self.stats.median) and self.check_ok is not False
        return "met" if ok else "MISSED"


@dataclass
class Figure:
    number: int
    title: str
    goal_text: str
    method: str
    rows: list[Row] = field(default_factory=list)
    why_missed: str = ""  # why a goal of this figure is missed and what would fix it
    remarks: list[str] = field(default_factory=list)  # shown in the notes whatever the outcome
    error: str = ""


def fmt(value: float, unit: str) -> str:
    if unit == "x":
        if value < 0.1:
            return f"{value:.4f}× (1/{1 / value:.0f})" if value > 0 else "0×"
        return f"{value:.2f}×"
    if unit == "speedup":
        return f"{value:,.0f}×" if value >= 100 else f"{value:.1f}×"
    if unit == "s":
        return f"{value:.3f} s" if value < 10 else f"{value:.1f} s"
    if unit == "MB":
        return f"{value:.1f} MB"
    if unit == "MB/s":
        return f"{value:.0f} MB/s"
    return f"{value:g}"


def console_table(figures: list[Figure]) -> str:
    header = ("fig", "case", "median", "min", "max", "goal", "status")
    lines = []
    for figure in figures:
        if figure.error:
            lines.append((str(figure.number), figure.title, "", "", "", "", "ERROR"))
        for row in figure.rows:
            lines.append(
                (
                    str(figure.number),
                    row.case,
                    fmt(row.stats.median, row.unit),
                    fmt(row.stats.min, row.unit),
                    fmt(row.stats.max, row.unit),
                    row.goal.text(row.unit) if row.goal else "—",
                    row.status,
                )
            )
    widths = [max(len(line[i]) for line in [header, *lines]) for i in range(len(header))]
    out = [
        "  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True))
        for line in [header, tuple("-" * w for w in widths), *lines]
    ]
    return "\n".join(out)


def markdown(figures: list[Figure], header: list[tuple[str, str]], settings: str) -> str:
    parts = [
        "# sensaov benchmark results",
        "",
        "Written by `make bench` (`python -m bench`); "
        "do not edit by hand. How each figure is measured: `bench/README.md`.",
        "",
    ]
    parts += ["| | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in header] + ["", settings, ""]
    parts += ["## Summary", "", *_summary(figures), ""]
    for figure in figures:
        parts += _figure_section(figure)
    parts += _notes(figures)
    return "\n".join(parts).rstrip() + "\n"


def _summary(figures: list[Figure]) -> list[str]:
    lines = ["| fig | case | median | goal | status |", "|---|---|---|---|---|"]
    for figure in figures:
        if figure.error:
            lines.append(f"| {figure.number} | {figure.title} | — | {figure.goal_text} | ERROR |")
        for row in figure.rows:
            goal = row.goal.text(row.unit) if row.goal else "—"
            lines.append(
                f"| {figure.number} | {row.case} | {fmt(row.stats.median, row.unit)} | {goal} "
                f"| {row.status} |"
            )
    return lines


def _figure_section(figure: Figure) -> list[str]:
    parts = [
        f"## {figure.number}. {figure.title}",
        "",
        f"Goal: {figure.goal_text}",
        "",
        figure.method,
        "",
    ]
    if figure.error:
        return parts + [f"**Not measured: {figure.error}**", ""]
    parts += [
        "| case | median | min | max | n | goal | status | detail |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in figure.rows:
        goal = row.goal.text(row.unit) if row.goal else "—"
        parts.append(
            f"| {row.case} | {fmt(row.stats.median, row.unit)} | {fmt(row.stats.min, row.unit)} "
            f"| {fmt(row.stats.max, row.unit)} | {row.stats.n} | {goal} | {row.status} "
            f"| {row.detail} |"
        )
    return parts + [""]


def _notes(figures: list[Figure]) -> list[str]:
    parts = ["## Notes", ""]
    for figure in figures:
        missed = [row for row in figure.rows if row.status == "MISSED"]
        if missed:
            cases = "; ".join(
                row.case + (f" ({row.why_missed})" if row.why_missed else "") for row in missed
            )
            why = figure.why_missed or "No explanation recorded for this figure."
            parts += [f"- **Figure {figure.number}, missed: {cases}.** {why}", ""]
    if not any(row.status == "MISSED" for figure in figures for row in figure.rows):
        parts += ["Every goal was met in this run.", ""]
    for figure in figures:
        parts += [f"- Figure {figure.number}: {remark}" for remark in figure.remarks]
    parts += [""] if any(f.remarks for f in figures) else []
    for figure in figures:
        if figure.error:
            parts += [f"- **Figure {figure.number} failed to run:** {figure.error}", ""]
    return parts
