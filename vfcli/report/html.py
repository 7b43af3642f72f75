"""Small HTML building blocks for self-contained pages (everything inline, no script, no network)."""
from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any, Iterable

import numpy as np

CSS = """
body{font:14px/1.45 system-ui,-apple-system,'Segoe UI',sans-serif;margin:0 auto;max-width:1100px;padding:0 18px 40px;color:#222}
h1{font-size:22px;margin:18px 0 4px}h2{font-size:18px;border-bottom:1px solid #ccc;margin-top:28px}h3{font-size:15px;margin:18px 0 6px}
table{border-collapse:collapse;margin:6px 0 10px;font-size:13px}td,th{border:1px solid #ddd;padding:3px 7px;text-align:left;vertical-align:top}
th{background:#f3f3f3}img,video{max-width:100%;height:auto;display:block;margin:6px 0}figure{margin:8px 0 16px}
figcaption{font-size:12px;color:#555}.warn{color:#8a4b00}.muted{color:#777}.grid{display:flex;flex-wrap:wrap;gap:8px}
.grid figure{flex:1 1 240px;margin:0}code{font-size:12px;background:#f6f6f6;padding:0 3px}
"""

MIME = {".png": "image/png", ".svg": "image/svg+xml", ".mp4": "video/mp4", ".webm": "video/webm", ".jpg": "image/jpeg"}


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def data_uri(path: str | Path) -> str:
    """The file as a ``data:`` URI (base64)."""
    p = Path(path)
    return f"data:{MIME[p.suffix.lower()]};base64," + base64.b64encode(p.read_bytes()).decode("ascii")


def fmt(value: Any) -> str:
    """A short readable text of an attribute value."""
    if isinstance(value, (bytes, np.bytes_)):
        value = value.decode()
    if isinstance(value, np.ndarray):
        if value.size > 8:
            return f"array {value.shape} {value.dtype}"
        value = value.tolist()
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    if isinstance(value, list):
        return "[" + ", ".join(fmt(v) for v in value) + "]"
    return str(value)


def table(rows: Iterable[Iterable[Any]], header: Iterable[str] | None = None, raw: bool = False) -> str:
    """An HTML table; cells are escaped unless ``raw``."""
    cell = (lambda v: str(v)) if raw else (lambda v: esc(fmt(v)))
    head = "<tr>" + "".join(f"<th>{esc(h)}</th>" for h in header) + "</tr>" if header else ""
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table>{head}{body}</table>"


def kv_table(d: dict[str, Any]) -> str:
    return table(((k, v) for k, v in d.items()), ("field", "value"))


def figure(path: str | Path, caption: str, width: int = 900) -> str:
    """An embedded image (PNG) with its caption, at most ``width`` px wide."""
    return (f'<figure><img src="{data_uri(path)}" alt="{esc(caption)}" style="max-width:min(100%,{width}px)">'
            f"<figcaption>{esc(caption)}</figcaption></figure>")


def video_tag(path: str | Path, caption: str) -> str:
    """An embedded video that plays in the page (muted, looping, controls)."""
    return (f'<figure><video controls muted loop playsinline preload="auto" src="{data_uri(path)}"></video>'
            f"<figcaption>{esc(caption)}</figcaption></figure>")


def page(title: str, body: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<link rel="icon" href="data:,">'
            f"<title>{esc(title)}</title><style>{CSS}</style></head><body>\n{body}\n</body></html>\n")


def pretty_json(text: str | None) -> str:
    if not text:
        return '<p class="muted">none stored</p>'
    try:
        return f"<pre>{esc(json.dumps(json.loads(text), indent=2))}</pre>"
    except ValueError:
        return f"<pre>{esc(text)}</pre>"
