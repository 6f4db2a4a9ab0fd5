"""A self-contained HTML report plus a JSON summary, written atomically.

A report is a list of sections; each has a title, paragraphs, tables (rows of key/value or a header
and rows) and figures (PNG files saved next to the report). No physics here.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Section", "Report", "jsonable"]


def jsonable(obj: Any) -> Any:
    """``obj`` with NumPy scalars and arrays, paths and non-finite floats made JSON-serialisable."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        obj = float(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None  # JSON has no inf/nan: null means "no finite value" (e.g. unconditionally stable)
    if isinstance(obj, Path):
        return str(obj)
    return obj


@dataclass
class Section:
    """One part of the report."""

    title: str
    paragraphs: list[str] = field(default_factory=list)
    tables: list[tuple[list[str], list[list[Any]]]] = field(default_factory=list)
    figures: list[tuple[str, str]] = field(default_factory=list)  # (file name, caption)

    def text(self, paragraph: str) -> "Section":
        self.paragraphs.append(paragraph)
        return self

    def table(self, header: list[str], rows: list[list[Any]]) -> "Section":
        self.tables.append((header, rows))
        return self

    def figure(self, file_name: str, caption: str) -> "Section":
        self.figures.append((file_name, caption))
        return self


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
table { border-collapse: collapse; margin: 1em 0; } td, th { border: 1px solid #ccc; padding: 3px 8px; }
th { background: #eee; } td { text-align: right; } td:first-child { text-align: left; }
figure { margin: 1em 0; } figure img { max-width: 100%; } figcaption { font-size: 90%; color: #555; }
.warn { color: #a40; }
"""


class Report:
    """Collects sections and writes ``report.html`` and ``summary.json`` into a directory."""

    def __init__(self, title: str, directory: Path):
        self.title = title
        self.directory = Path(directory)
        self.sections: list[Section] = []
        self.summary: dict[str, Any] = {}

    @property
    def figure_dir(self) -> Path:
        d = self.directory / "figures"
        d.mkdir(parents=True, exist_ok=True)
        return d

    def section(self, title: str) -> Section:
        s = Section(title)
        self.sections.append(s)
        return s

    def save_figure(self, fig, name: str) -> str:
        """Save a matplotlib figure as ``figures/NAME.png``; returns the path relative to the report."""
        import matplotlib.pyplot as plt

        path = self.figure_dir / f"{name}.png"
        tmp = path.with_suffix(".tmp.png")
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
        tmp.replace(path)
        plt.close(fig)
        return f"figures/{name}.png"

    def to_html(self) -> str:
        out = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>",
               f"<style>{_CSS}</style></head><body><h1>{html.escape(self.title)}</h1>"]
        for s in self.sections:
            out.append(f"<h2>{html.escape(s.title)}</h2>")
            out.extend(f"<p>{p}</p>" for p in s.paragraphs)  # paragraphs may carry simple markup
            for header, rows in s.tables:
                out.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>")
                out.extend("<tr>" + "".join(f"<td>{_cell(c)}</td>" for c in row) + "</tr>" for row in rows)
                out.append("</table>")
            for file_name, caption in s.figures:
                out.append(f"<figure><img src='{html.escape(file_name)}' alt='{html.escape(caption)}'>"
                           f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        out.append("</body></html>")
        return "\n".join(out)

    def write(self) -> Path:
        """Write ``report.html`` and ``summary.json`` (temporary names, then rename)."""
        self.directory.mkdir(parents=True, exist_ok=True)
        report = self.directory / "report.html"
        summary = self.directory / "summary.json"
        for path, text in ((report, self.to_html()), (summary, json.dumps(jsonable(self.summary), indent=2))):
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(text, encoding="utf-8")
            tmp.replace(path)
        return report
