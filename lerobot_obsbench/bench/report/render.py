"""A built report written out: its tables as Markdown and HTML, `report.md` and a self-contained `report.html`
with the PNGs beside them, and the JSON summary."""

from __future__ import annotations

import base64
import html
from pathlib import Path

LEGEND = (
    "Best per row in bold, second underlined. Mean Rank: competition ranking per task (ties share the "
    "best rank), averaged over tasks; * = the method lacks some tasks (means over its tasks). ▲: the "
    "method's 95% interval lies entirely above its blind control's (obs_space none, same policy type), both "
    "over at least two training seeds; △: the same, but one of them rests on one training seed, so the "
    "intervals cover evaluation episodes only."
)
STYLE = (
    "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
    "padding:4px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
)


def markdown_table(header, rows) -> str:
    def fmt(text, mark):
        return f"**{text}**" if mark == "best" else f"<u>{text}</u>" if mark == "second" else text

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join([task, *(fmt(*c) for c in cells)]) + " |" for task, cells in rows]
    return "\n".join(lines)


def html_table(header, rows) -> str:
    def fmt(text, mark):
        text = html.escape(text)
        return f"<b>{text}</b>" if mark == "best" else f"<u>{text}</u>" if mark == "second" else text

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr><td>" + html.escape(task) + "</td>" + "".join(f"<td>{fmt(*c)}</td>" for c in cells) + "</tr>"
        for task, cells in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def write_report(report: dict, out: Path, title: str = "OBSBench report", notes: str = "") -> dict[str, Path]:
    """`report.md`, `report.html` and the figures' PNGs of `build_report`'s report in `out`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, (_, png) in report["figures"].items():
        (out / name).write_bytes(png)
    md = [f"# {title}", "", notes, ""] if notes else [f"# {title}", ""]
    body = [f"<h1>{html.escape(title)}</h1>"] + ([f"<p>{html.escape(notes)}</p>"] if notes else [])
    for warning in report.get("warnings", []):
        md += [f"> **Note:** {warning}", ""]
        body.append(f"<p><b>Note:</b> {html.escape(warning)}</p>")
    for section in report["sections"]:
        md += [f"## {section.title}", "", markdown_table(section.header, section.rows), ""]
        body += [f"<h2>{html.escape(section.title)}</h2>", html_table(section.header, section.rows)]
    md += [LEGEND, ""]
    body.append(f"<p>{html.escape(LEGEND)}</p>")
    for name, (caption, png) in report["figures"].items():
        md += [f"## {caption}", "", f"![{caption}]({name})", ""]
        data = base64.b64encode(png).decode()
        body += [
            f"<h2>{html.escape(caption)}</h2>",
            f'<img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">',
        ]
    (out / "report.md").write_text("\n".join(md))
    (out / "report.html").write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
        f"</title><style>{STYLE}</style></head><body>{''.join(body)}</body></html>\n"
    )
    return {"markdown": out / "report.md", "html": out / "report.html"}


def summary_json(report: dict) -> dict:
    """Mean S.R. / Mean Rank per method and source, plus the blind-control and agreement checks."""
    out = {
        source: {
            m: {"mean_sr": round(s["mean_sr"], 4), "mean_rank": round(s["mean_rank"], 4), "tasks": s["tasks"]}
            for m, s in summary.items()
        }
        for source, summary in report["summary"].items()
    }
    if report.get("checks"):
        out["checks"] = report["checks"]
    return out
