"""The page's HTML: the Jinja2 templates (templates/) and the few calls Python makes into them.

All markup lives in templates/: kit.html.j2 (macros), sections/*.html.j2 (one per section) and
report.html.j2 (the page). Python hands them values; Jinja2 escapes every value that is not
already markup (a macro's output, or `Markup`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, StrictUndefined, select_autoescape
from markupsafe import Markup

TEMPLATES = Path(__file__).resolve().parent / "templates"


def number_text(value: Any) -> tuple[str | None, bool]:
    """(shown, numeric) for a table cell: 4 significant digits and thousands separators for a
    number, None for a missing or non-finite one, yes / no for a bool, other values as text.
    The `number` macro adds the unit to numbers only."""
    if value is None or (isinstance(value, str) and value == ""):
        return None, False
    if isinstance(value, bool):
        return ("yes" if value else "no"), False
    if isinstance(value, int):
        return f"{value:,}", True
    if isinstance(value, float):
        if not math.isfinite(value):
            return None, False
        if value != 0 and abs(value) < 1e-4:
            return f"{value:.2g}", True
        if abs(value) >= 1000:
            return f"{value:,.0f}", True
        if abs(value) >= 100:
            return f"{value:.1f}", True
        return f"{value:.4g}", True
    return str(value), False


@cache
def environment() -> Environment:
    env = Environment(
        loader=FileSystemLoader(TEMPLATES),
        autoescape=select_autoescape(["html", "j2"], default_for_string=True),
        undefined=StrictUndefined,
        keep_trailing_newline=True,
    )
    env.filters["number_text"] = number_text
    return env


def macro(template: str, name: str) -> Callable[..., Markup]:
    """One macro of a template, to call from Python (its output is markup)."""
    return getattr(environment().get_template(template).module, name)


def render(template: str, **context: Any) -> Markup:
    """A template of templates/ (e.g. "sections/depth.html.j2"), as markup to place in a page."""
    return Markup(environment().get_template(template).render(**context).strip())


def page(**context: Any) -> str:
    """The whole page: title, subtitle, generated, version, sections [{key, title, body}]."""
    sections = [dict(s, body=Markup(s["body"])) for s in context.pop("sections")]
    return environment().get_template("report.html.j2").render(sections=sections, **context)


def not_available(reason: str) -> Markup:
    return macro("kit.html.j2", "not_available")(reason)


def fmt(value: Any, unit: str = "") -> Markup:
    """A value as the page's tables show it (the `number` macro), for code that needs it."""
    return macro("kit.html.j2", "number")(value, unit)


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
