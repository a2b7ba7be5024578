"""The page's HTML: the Jinja2 templates (templates/) and the building blocks sections use.

The markup lives in templates/kit.html.j2 (macros) and templates/report.html.j2 (the page);
this module only calls them. Values that are already HTML are marked as such (`Markup`),
everything else is escaped by Jinja2.
"""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, StrictUndefined, select_autoescape
from markupsafe import Markup, escape

TEMPLATES = Path(__file__).resolve().parent / "templates"


@cache
def environment() -> Environment:
    return Environment(
        loader=FileSystemLoader(TEMPLATES),
        autoescape=select_autoescape(["html", "j2"], default_for_string=True),
        undefined=StrictUndefined,
        keep_trailing_newline=True,
    )


@cache
def _macros() -> Any:
    return environment().get_template("kit.html.j2").module


def _call(name: str, *args: Any, **kwargs: Any) -> str:
    # plain str out: sections concatenate fragments, and Markup + str would escape the str
    return str(getattr(_macros(), name)(*args, **kwargs))


def page(**context: Any) -> str:
    """The whole page: title, subtitle, generated, version, sections [{key, title, body}]."""
    sections = [dict(s, body=Markup(s["body"])) for s in context.pop("sections")]
    return environment().get_template("report.html.j2").render(sections=sections, **context)


def not_available(reason: str) -> str:
    return _call("not_available", reason)


def badge(text: str, kind: str) -> str:
    return _call("badge", text, kind)


def kv_table(rows: list[tuple[str, str]], cls: str = "kv") -> str:
    """Rows of (label text, value HTML)."""
    return _call("kv_table", [(k, Markup(v)) for k, v in rows], cls)


def figure_html(uri: str, caption: str, cls: str = "") -> str:
    return _call("figure", uri, caption, cls)


def card(label: str, value: str, note: str = "") -> str:
    """A summary card; value and note are HTML."""
    return _call("card", label, Markup(value), Markup(note))


def details_json(summary: str, data: Any) -> str:
    return _call("details_text", summary, json.dumps(data, indent=2, default=str))


def grid(
    head: list[str],
    rows: list[list[str]],
    cls: str = "grid",
    num: tuple[int, ...] = (),
    row_head: bool = False,
) -> str:
    """A table of column titles (text) and cells (HTML); `num`: right-aligned columns (indices
    into `head`); `row_head`: each row starts with its label (HTML), under an empty corner."""
    cells = [[Markup(c) for c in row] for row in rows]
    return _call("grid", head, cells, cls, list(num), row_head)


def grouped_table(groups: list[tuple[str, list[tuple[str, str, str]]]]) -> str:
    """One table in titled groups of rows (label text, value HTML, note HTML); empty groups
    are left out."""
    shown = [
        (title, [(k, Markup(v), Markup(n)) for k, v, n in rows]) for title, rows in groups if rows
    ]
    return _call("grouped_table", shown)


def stages_table(rows: list[dict[str, Any]], total_wall: str, peak_mb: float) -> str:
    """The stage table; a row is {stage, folder, manifest: False} or, with a manifest, also
    {wall, share, peak_mb, files, size_mb, version, key, finished}."""
    return _call("stages_table", rows, total_wall, peak_mb)


def video(uri: str, note: str) -> str:
    return _call("video", uri, note)


def viewer(page_html: str, note: str) -> str:
    """An interactive page in an iframe (srcdoc: the page escaped as an attribute value)."""
    return _call("viewer", page_html, note)


def text(value: Any) -> str:
    """Escaped text, for the few places that assemble markup themselves."""
    return str(escape(value))


def fmt(value: Any, unit: str = "") -> str:
    """A number for a table: 4 significant digits, thousands separators, '—' for missing."""
    if value is None or value == "":
        return '<span class="muted">&mdash;</span>'
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        shown = f"{value:,}"
    elif isinstance(value, float):
        if not math.isfinite(value):
            return '<span class="muted">&mdash;</span>'
        if value != 0 and abs(value) < 1e-4:
            shown = f"{value:.2g}"
        elif abs(value) >= 1000:
            shown = f"{value:,.0f}"
        elif abs(value) >= 100:
            shown = f"{value:.1f}"
        else:
            shown = f"{value:.4g}"
    else:
        return text(value)
    return shown + (f'<span class="unit"> {text(unit)}</span>' if unit else "")


def duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {seconds % 60:.0f} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60)} min"


def one_line(e: BaseException) -> str:
    """An exception as one short line, for 'not available' notes."""
    shown = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return shown[:200]
