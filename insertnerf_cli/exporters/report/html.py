"""Small HTML building blocks for the pages: escaping, relative links, tables, the page frame."""
from __future__ import annotations

import html
from typing import Iterable, Sequence
from urllib.parse import quote

STYLE = """
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 24px auto;
       max-width: 1200px; padding: 0 16px; color: #1d232a; background: #fafbfc; }
h1 { font-size: 22px; margin: 0 0 4px; } h2 { font-size: 17px; margin: 28px 0 8px; }
.sub { color: #5b6673; margin: 0 0 16px; word-break: break-all; }
table { border-collapse: collapse; margin: 4px 0 8px; }
td, th { border-bottom: 1px solid #e1e5ea; padding: 4px 12px 4px 0; text-align: left; vertical-align: top; }
th { color: #5b6673; font-weight: 600; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.pair { display: flex; gap: 16px; flex-wrap: wrap; } .pair figure { margin: 0; flex: 1 1 360px; }
.drawings { display: flex; gap: 16px; flex-wrap: wrap; }
.pair video { width: 100%; height: 420px; object-fit: contain; background: #000; border-radius: 4px; }
figcaption { color: #5b6673; font-size: 13px; margin-top: 2px; }
.strip { display: flex; gap: 6px; flex-wrap: wrap; } .strip figure { margin: 0; width: 132px; }
.strip img { width: 132px; display: block; border-radius: 3px; }
.thumb { height: 200px; max-width: 100%; object-fit: contain; display: block; border-radius: 3px; }
svg { background: #fff; border: 1px solid #e1e5ea; border-radius: 4px; }
"""


def esc(value: object) -> str:
    """Any value as HTML text (quotes escaped too, so it is safe in attributes)."""
    return html.escape(str(value), quote=True)


def link(relative: str) -> str:
    """A relative POSIX path inside the page's folder as an escaped URL (spaces and the like %-encoded)."""
    if relative.startswith("/") or ".." in relative.split("/") or ":" in relative:
        raise ValueError(f"pages link only to files in their own folder, got {relative!r}")
    return esc(quote(relative))


def table(header: Sequence[str], rows: Iterable[Sequence[str]], numeric: Sequence[int] = ()) -> str:
    """A table whose cells are given as ready HTML (escape them first); columns in ``numeric`` align right."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f'<td class="num">{c}</td>' if j in numeric else f"<td>{c}</td>"
                                    for j, c in enumerate(row)) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def settings_table(items: Sequence[tuple[str, object]]) -> str:
    """Two columns: setting, value (both escaped)."""
    return table(("setting", "value"), ((esc(k), esc(v)) for k, v in items))


def options_table(options: dict) -> str:
    """The render options (config_to_json of a RenderOptions) as a settings table, one row per number, named by
    its path, e.g. "blend.margin"."""
    def rows(prefix: str, value: object) -> list[tuple[str, object]]:
        if isinstance(value, dict):
            return [row for key, sub in value.items() for row in rows(f"{prefix}.{key}" if prefix else key, sub)]
        return [(prefix, value)]

    return settings_table(rows("", options))


def page(title: str, subtitle: str, body: str) -> str:
    """A whole page; ``title`` and ``subtitle`` are escaped here, ``body`` is ready HTML."""
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{esc(title)}</title><style>{STYLE}</style></head>\n<body><h1>{esc(title)}</h1>"
            f'<p class="sub">{esc(subtitle)}</p>\n{body}\n'
            f'<p class="sub">Written by insertnerf. Everything on this page is in this folder.</p></body></html>\n')


def duration(seconds: float) -> str:
    """"42 s", "3 min 05 s" or "1 h 02 min"."""
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"
