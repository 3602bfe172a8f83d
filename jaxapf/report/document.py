"""The report as a document: headings, paragraphs, lists, tables and figures, rendered to
Markdown (figures as files) and to one self-contained HTML page (figures embedded)."""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import itertools
import pathlib
import re
from typing import Any, Sequence

import pandas as pd

from ..io.lock import write_atomic
from ..io.names import subfolder
from ..simulate.figures import DPI

__all__ = ["FigureFile", "Document", "VERDICT_COLORS", "render_markdown", "render_html", "save_figure"]

#: One colour per verdict (:data:`jaxapf.stats.VERDICTS`), in every figure and in the page's verdict matrix.
VERDICT_COLORS = {"better": "#2ca02c", "worse": "#d62728", "equivalent": "#1f77b4", "inconclusive": "#8c8c8c"}
#: The verdict matrix's mark of each verdict.
VERDICT_MARKS = {"better": "▲", "worse": "▼", "equivalent": "=", "inconclusive": "·"}
_MARK_VERDICT = {m: v for v, m in VERDICT_MARKS.items()}


@dataclasses.dataclass
class FigureFile:
    """A rendered figure: file stem, caption, image bytes (``format``: png, or gif for an animation), and
    whether an SVG was written beside it."""

    name: str
    caption: str
    png: bytes
    svg: bool = False
    format: str = "png"


@dataclasses.dataclass
class Document:
    """The report's blocks in order; rendered by :func:`render_markdown` and :func:`render_html`."""

    blocks: list[tuple[str, Any]] = dataclasses.field(default_factory=list)

    def h(self, level: int, text: str) -> None:
        self.blocks.append(("h", (level, text)))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def items(self, items: Sequence[str]) -> None:
        if items:
            self.blocks.append(("ul", list(items)))

    def table(self, frame: pd.DataFrame) -> None:
        self.blocks.append(("table", frame))

    def figure(self, fig: FigureFile) -> None:
        self.blocks.append(("figure", fig))

    def matrix(self, frame: pd.DataFrame) -> None:
        """A table whose cells are verdict words (or empty), each cell coloured by its verdict."""
        self.blocks.append(("matrix", frame))

    def contents(self) -> None:
        """A table of contents of the level-2 headings, placed here."""
        self.blocks.append(("contents", None))

    def anchors(self) -> dict[int, str]:
        """A unique id per heading block (its index), made from its text as GitHub makes a heading's anchor
        (lower case, punctuation dropped, spaces as ``-``, ``-1``, ``-2`` for repeats), so the contents'
        links work in report.md on GitHub as in report.html."""
        ids, used = {}, {}
        for i, (kind, value) in enumerate(self.blocks):
            if kind == "h":
                base = re.sub(r"[^\w\- ]", "", value[1].lower()).replace(" ", "-")
                n = used.get(base, 0)
                used[base] = n + 1
                ids[i] = base if n == 0 else f"{base}-{n}"
        return ids

    def headings(self, level: int = 2) -> list[tuple[str, str]]:
        """(text, id) of the headings of ``level``, but the contents' own."""
        ids = self.anchors()
        own = {i - 1 for i, (k, _) in enumerate(self.blocks) if k == "contents"}
        return [(v[1], ids[i]) for i, (k, v) in enumerate(self.blocks) if k == "h" and v[0] == level and i not in own]


#: What Markdown would read as HTML (a tag, comment, declaration or entity) or as a link's target.
_MD_ACTIVE = re.compile(r"<(?=[A-Za-z/!?])|&(?=[A-Za-z#])|\](?=\()")


def _md_text(text: Any) -> str:
    """``text`` as Markdown shows it literally: no raw HTML (a sweep's tags are user text), no link."""
    return _MD_ACTIVE.sub(lambda m: {"<": "&lt;", "&": "&amp;", "]": "]\\"}[m[0]], str(text))


def _md_cell(v: Any) -> str:
    return _md_text(v).replace("|", "\\|").replace("\n", " ")


def render_markdown(doc: Document) -> str:
    """The document as Markdown; all text is shown literally (:func:`_md_text`), as the HTML page escapes it."""
    out = []
    for kind, value in doc.blocks:
        if kind == "contents":
            out.append("\n".join(f"- [{_md_cell(text)}](#{slug})" for text, slug in doc.headings()) + "\n")
        elif kind == "h":
            out.append(f"{'#' * value[0]} {_md_text(value[1])}\n")
        elif kind == "p":
            out.append(f"{_md_text(value)}\n")
        elif kind == "ul":
            out.append("\n".join(f"- {_md_cell(i)}" for i in value) + "\n")
        elif kind in ("table", "matrix"):
            cols = [" ".join(c).strip() if isinstance(c, tuple) else c for c in value.columns]
            lines = ["| " + " | ".join(_md_cell(c) for c in cols) + " |", "|" + "---|" * len(cols)]
            lines += ["| " + " | ".join(_md_cell(v) for v in row) + " |" for row in value.itertuples(index=False)]
            out.append("\n".join(lines) + "\n")
        elif kind == "figure":
            vector = f" (vector: `figures/{value.name}.svg`)" if value.svg else ""
            caption = _md_text(value.caption).replace("\n", " ")
            out.append(f"![{caption}](figures/{value.name}.{value.format})\n\n*{caption}*{vector}\n")
    return "\n".join(out)


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:1250px;padding:0 1em;
color:#222;line-height:1.4}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;font-size:0.82em;margin:0.8em 0;display:block;overflow-x:auto;max-width:100%}
th,td{border:1px solid #ccc;padding:3px 6px;text-align:right;overflow-wrap:anywhere}
table.sortable td{min-width:3.5em}table.sortable td:first-child{min-width:8em}
p,li,figcaption,h1,h2,h3{overflow-wrap:anywhere}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
tr:nth-child(even){background:#fafafa}
figure{margin:1.2em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:0.9em;color:#444}code{background:#f4f4f4;padding:0 3px}
th.sort{cursor:pointer}th.sort:after{content:" \\2195";color:#999}
nav.contents ul{columns:2;font-size:0.9em}
td.v{text-align:center;padding:1px 3px}table.matrix th{padding:2px 3px}th.group{text-align:center}
th.up span{writing-mode:vertical-rl;transform:rotate(180deg);font-weight:normal}
""" + "".join(f"td.v-{v}{{background:{c}33;color:{c};font-weight:700}}" for v, c in VERDICT_COLORS.items())

#: Click a column's header to sort the table by it (numbers as numbers, a second click reverses). ``sortKey``
#: reads a cell as its first number: a bound ``<0.001`` just below 0.001 (``>x`` just above), an interval
#: ``[lo, hi]`` by ``lo``, ``1,234`` as 1234, ``±∞`` as infinities; a cell without a number sorts as text,
#: after every number.
_SORT = """
function sortKey(text){var s=text.trim().replace(/\u2212/g,'-').replace(/^[\\[(]\\s*/,'');
  if(/^[-+]?\u221e/.test(s))return s.charAt(0)==='-'?-Infinity:Infinity;
  var below=/^(<|\u2264)/.test(s),above=/^(>|\u2265)/.test(s);
  s=s.replace(/^(<|>|\u2264|\u2265|~|\u2248)\\s*/,'').replace(/(\\d),(?=\\d{3}(\\D|$))/g,'$1');
  var n=parseFloat(s.replace(/[^0-9eE+.-].*$/,''));if(isNaN(n))return text.trim();
  var nudge=Math.abs(n)*1e-9+1e-300;return below?n-nudge:above?n+nudge:n;}
document.querySelectorAll('table.sortable').forEach(function(t){
  t.querySelectorAll('th').forEach(function(th,col){
    th.classList.add('sort');
    th.addEventListener('click',function(){
      var body=t.tBodies[0],rows=Array.prototype.slice.call(body.rows),up=th.dataset.up!=='1';
      var key=function(r){return sortKey(r.cells[col].textContent);};
      rows.sort(function(a,b){var x=key(a),y=key(b);
        var c=(typeof x===typeof y)?(x<y?-1:x>y?1:0):(typeof x==='number'?-1:1);return up?c:-c;});
      th.dataset.up=up?'1':'0';rows.forEach(function(r){body.appendChild(r);});
    });
  });
});
"""


def render_html(doc: Document, title: str) -> str:
    esc = html.escape
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>{esc(title)}</title>", f"<style>{_CSS}</style></head><body>"]
    ids = doc.anchors()
    for i, (kind, value) in enumerate(doc.blocks):
        if kind == "contents":
            out.append('<nav class="contents"><ul>' + "".join(f'<li><a href="#{slug}">{esc(text)}</a></li>'
                                                              for text, slug in doc.headings()) + "</ul></nav>")
        elif kind == "h":
            out.append(f'<h{value[0]} id="{ids[i]}">{esc(value[1])}</h{value[0]}>')
        elif kind == "p":
            out.append(f"<p>{esc(value)}</p>")
        elif kind == "ul":
            out.append("<ul>" + "".join(f"<li>{esc(str(i))}</li>" for i in value) + "</ul>")
        elif kind == "table":
            head = "".join(f"<th>{esc(str(c))}</th>" for c in value.columns)
            body = "".join("<tr>" + "".join(f"<td>{esc(str(v))}</td>" for v in row) + "</tr>"
                           for row in value.itertuples(index=False))
            out.append(f'<table class="sortable"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>')
        elif kind == "matrix":
            spans = [(g, sum(1 for _ in n)) for g, n in itertools.groupby(c[0] for c in value.columns)]
            head = ("<tr>" + "".join(f'<th colspan="{n}" class="group">{esc(g)}</th>' for g, n in spans)
                    + "</tr><tr>" + "".join(f'<th class="{"up" if c[0] else ""}"><span>{esc(c[1])}</span></th>'
                                            for c in value.columns) + "</tr>")
            body = "".join("<tr>" + "".join(
                f'<td class="v v-{_MARK_VERDICT[v]}" title="{_MARK_VERDICT[v]}">{esc(v)}</td>'
                if v in _MARK_VERDICT else f"<td>{esc(str(v))}</td>" for v in row) + "</tr>"
                for row in value.itertuples(index=False))
            out.append(f'<table class="matrix"><thead>{head}</thead><tbody>{body}</tbody></table>')
        elif kind == "figure":
            data = base64.b64encode(value.png).decode("ascii")
            out.append(f'<figure><img alt="{esc(value.caption)}" src="data:image/{value.format};base64,{data}">'
                       f"<figcaption>{esc(value.caption)}</figcaption></figure>")
    out.append(f"<script>{_SORT}</script></body></html>")
    return "\n".join(out)




def save_figure(fig: Any, name: str, caption: str, figdir: pathlib.Path, svg: bool = False) -> FigureFile:
    """Write ``fig`` to ``figdir/name.png`` and, with ``svg``, ``.svg`` (deterministic ids, no date; a
    second full draw, so only on request) and clear it."""
    import matplotlib

    subfolder(figdir)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    png = buf.getvalue()
    write_atomic(figdir / f"{name}.png", png, durable=False)
    if svg:
        with matplotlib.rc_context({"svg.hashsalt": "jaxapf-report"}):
            write_atomic(figdir / f"{name}.svg",
                         lambda fh: fig.savefig(fh, format="svg", metadata={"Date": None}), durable=False)
    fig.clear()
    return FigureFile(name, caption, png, svg)
