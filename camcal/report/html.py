"""HTML building blocks of the dive report: escaping, numbers, tables, figures, sections, the CSS."""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime

#: The report's sections, in order: (anchor, title).
SECTIONS = (
    ("summary", "Summary"),
    ("timeline", "Timeline"),
    ("quality", "Frame quality"),
    ("linearity", "Linearity"),
    ("attitude", "Attitude"),
    ("attenuation", "Attenuation length λ_att"),
    ("absorption-scattering", "Absorption and scattering"),
    ("calibration", "Calibration inputs"),
    ("software", "Software and provenance"),
)

CSS = """
:root { --ink: #1d2330; --muted: #5b6474; --rule: #d5dae3; --bg: #f6f8fb; --ok: #1e7b34; --bad: #b3261e; }
* { box-sizing: border-box; }
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial, sans-serif;
       color: var(--ink); margin: 0; background: #fff; }
main { max-width: 1040px; margin: 0 auto; padding: 1.2rem 1.4rem 3rem; }
header { border-bottom: 3px solid var(--ink); padding-bottom: .6rem; margin-bottom: 1rem; }
h1 { font-size: 1.6rem; margin: 0 0 .2rem; }
h2 { font-size: 1.25rem; margin: 2.2rem 0 .6rem; padding-top: .4rem; border-top: 1px solid var(--rule); }
h3 { font-size: 1.02rem; margin: 1.2rem 0 .4rem; }
.muted, figcaption { color: var(--muted); font-size: .88rem; }
nav ol { columns: 3; margin: .4rem 0 0; padding-left: 1.3rem; }
table { border-collapse: collapse; margin: .4rem 0 .8rem; font-size: .9rem; }
th, td { border-bottom: 1px solid var(--rule); padding: .25rem .6rem; text-align: right;
         vertical-align: top; }
th { background: var(--bg); font-weight: 600; }
th:first-child, td:first-child, td.text, th.text { text-align: left; }
td.num { font-variant-numeric: tabular-nums; white-space: nowrap; }
.scroll { overflow-x: auto; }
figure { margin: .6rem 0 1rem; page-break-inside: avoid; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--rule); }
.ok { color: var(--ok); font-weight: 600; } .bad { color: var(--bad); font-weight: 600; }
.note { background: var(--bg); border-left: 4px solid var(--muted); padding: .5rem .8rem; margin: .6rem 0; }
code, pre { font-family: ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; font-size: .86rem; }
pre { background: var(--bg); padding: .5rem .8rem; overflow-x: auto; }
details { margin: .4rem 0; } summary { cursor: pointer; color: var(--muted); }
@media print { nav { display: none; } h2 { page-break-after: avoid; } main { max-width: none; } }
"""


def esc(x: object) -> str:
    return html.escape(str(x), quote=True)


def num(x: float | None, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{digits}f}"


def iso(t: float | None) -> str:
    if t is None:
        return "—"
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def table(headers: Sequence[str] | None, rows: Iterable[Sequence[object]], *, text_cols: int = 1) -> str:
    """A table (no header row if ``headers`` is None); cells are escaped unless wrapped in `Raw`; the
    first ``text_cols`` columns align left."""

    def cell(i: int, v: object) -> str:
        cls = "text" if i < text_cols else "num"
        return f'<td class="{cls}">{v.html if isinstance(v, Raw) else esc(v)}</td>'

    body = "".join("<tr>" + "".join(cell(i, v) for i, v in enumerate(r)) + "</tr>" for r in rows)
    if headers is None:
        return f'<div class="scroll"><table><tbody>{body}</tbody></table></div>'
    head = "".join(
        f'<th class="{"text" if i < text_cols else ""}">{esc(h)}</th>' for i, h in enumerate(headers)
    )
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


class Raw:
    """Trusted HTML for a table cell."""

    def __init__(self, html_text: str) -> None:
        self.html = html_text


def figure(uri: str, caption: str, alt: str) -> str:
    return f'<figure><img src="{uri}" alt="{esc(alt)}"><figcaption>{esc(caption)}</figcaption></figure>'


def note(text_html: str) -> str:
    return f'<p class="note">{text_html}</p>'


def section(sid: str, body: str) -> str:
    title = dict(SECTIONS)[sid]
    return f'<section id="{sid}"><h2>{esc(title)}</h2>{body}</section>'


# ---------------------------------------------------------------- sections
