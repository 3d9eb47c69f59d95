"""Render a report's blocks to Markdown and HTML.

A report is a list of blocks, each a tuple whose first item names its kind: ("h", level, text), ("p", text),
("warn", text), ("list", items), ("table", header, rows), ("images", [(path, caption), ...]). The build, batch and
localize reports all render through here."""
from __future__ import annotations

import base64
import html
from pathlib import Path


def to_markdown(blocks: list[tuple]) -> str:
    """The report's blocks as Markdown (images linked by file name, beside the report)."""
    lines = []
    for b in blocks:
        if b[0] == "h":
            lines += ["#" * b[1] + " " + b[2], ""]
        elif b[0] == "p":
            lines += [b[1], ""]
        elif b[0] == "warn":
            lines += [f"> **{b[1]}**", ""]
        elif b[0] == "list":
            lines += [f"- {x}" for x in b[1]] + [""]
        elif b[0] == "table":
            lines += ["| " + " | ".join(b[1]) + " |", "|" + "---|" * len(b[1])]
            lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in b[2]] + [""]
        elif b[0] == "images":
            for p, cap in b[1]:
                lines += [f"![{cap}]({Path(p).name})", f"*{cap}*", ""]
    return "\n".join(lines)


def _b64(p: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(p).read_bytes()).decode()


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1200px;color:#222;padding:0 16px}
h1{font-size:1.6em;margin-bottom:.3em} h2{border-bottom:1px solid #ddd;padding-bottom:4px;margin-top:1.6em}
table{border-collapse:collapse;margin:8px 0 14px} td,th{border:1px solid #ccc;padding:4px 10px;text-align:left}
th{background:#f3f3f3} td:not(:first-child){font-variant-numeric:tabular-nums}
.warn{background:#fde8e8;border:2px solid #c00;color:#900;padding:10px 14px;font-weight:600;border-radius:4px}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(340px,1fr));gap:14px;align-items:start}
.wide{grid-template-columns:1fr} figure{margin:0}
figure img{width:100%;border:1px solid #ccc;image-rendering:pixelated;background:#a0a0a0}
figcaption{font-size:.85em;color:#555;margin-top:3px}
"""


def to_html(blocks: list[tuple]) -> str:
    """The report's blocks as one self-contained HTML page (images inlined as base64)."""
    e = html.escape
    parts = []
    title = next((b[2] for b in blocks if b[0] == "h" and b[1] == 1), "kosmap report")
    for b in blocks:
        if b[0] == "h":
            parts.append(f"<h{b[1]}>{e(b[2])}</h{b[1]}>")
        elif b[0] == "p":
            parts.append(f"<p>{e(b[1])}</p>")
        elif b[0] == "warn":
            parts.append(f"<p class='warn'>{e(b[1])}</p>")
        elif b[0] == "list":
            parts.append("<ul>" + "".join(f"<li>{e(str(x))}</li>" for x in b[1]) + "</ul>")
        elif b[0] == "table":
            head = "".join(f"<th>{e(str(h))}</th>" for h in b[1])
            body = "".join("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in r) + "</tr>" for r in b[2])
            parts.append(f"<table><tr>{head}</tr>{body}</table>")
        elif b[0] == "images":
            figs = "".join(f"<figure><img alt='{e(cap)}' src='{_b64(p)}'><figcaption>{e(cap)}</figcaption></figure>"
                           for p, cap in b[1] if Path(p).is_file())
            wide = " wide" if len(b[1]) == 1 else ""
            parts.append(f"<div class='grid{wide}'>{figs}</div>")
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{e(title)}</title>"
            f"<style>{CSS}</style></head><body>{''.join(parts)}</body></html>\n")
