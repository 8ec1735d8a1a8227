"""The report as one self-contained HTML page: the figure inlined (base64 PNG), the numbers as a
table, what the recording lacks, every line of the event and error logs, the plan's text and the
run's summary as JSON. No script, no external file: it opens anywhere, offline."""
from __future__ import annotations

import base64
import html
import json
from typing import Any

from armbridge.report.data import RunData
from armbridge.report.figure import log_lines
from armbridge.report.numbers import summary_rows

STYLE = """
body { font-family: system-ui, sans-serif; font-size: 16px; margin: 1.5em auto; max-width: 1800px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.4em; }
img { max-width: 100%; box-sizing: border-box; border: 1px solid #ddd; }
table { border-collapse: collapse; max-width: 100%; }
td { padding: 0.15em 0.8em; border-bottom: 1px solid #eee; overflow-wrap: anywhere; }
code { overflow-wrap: anywhere; }
td.v { text-align: right; font-family: ui-monospace, monospace; }
.missing { color: #a61e1e; } pre { font-size: 0.9em; background: #f6f6f6; padding: 0.6em; overflow-x: auto; }
.ERROR { color: #c92a2a; } .WARN { color: #b25e00; }
"""


def page(data: RunData, doc: dict[str, Any], png: bytes) -> str:
    """The page's text (module docstring)."""
    e = html.escape
    title = f"run of {doc.get('plan') or '(plan unknown)'} ({doc.get('robot') or 'robot unknown'})"
    parts = [f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{e(title)}</title>",
             f"<style>{STYLE}</style></head><body>", f"<h1>{e(title)}</h1>",
             f"<p>recording <code>{e(str(data.path))}</code>"
             + (f"; status <b>{e(doc['status'])}</b>" if doc.get("status") else "") + "</p>"]
    if doc["missing"]:
        items = "".join(f"<li>{e(m)}</li>" for m in doc["missing"])
        parts.append(f"<div class=\"missing\"><p>Not in this recording:</p><ul>{items}</ul></div>")
    b64 = base64.b64encode(png).decode("ascii")
    parts.append(f"<img alt=\"{e(title)}: workspace, joints, numbers and logs\" src=\"data:image/png;base64,{b64}\">")
    parts.append("<h2>Numbers</h2><table>")
    parts += [f"<tr><td>{e(a)}</td><td class=\"v\">{e(b)}</td></tr>" for a, b in summary_rows(doc)]
    parts.append("</table>")
    parts.append("<h2>Joints</h2><table><tr><td>joint</td><td>unit</td><td>samples</td><td>last measured</td>"
                 "<td>last set point</td><td>set point error rms / max</td></tr>")
    for name, j in doc["joints"].items():
        cells = [name, j["unit"], str(j["samples"]), _g(j["final_q"]), _g(j["final_target"]),
                 f"{_g(j['setpoint_error_rms'])} / {_g(j['setpoint_error_max'])}"]
        parts.append("<tr>" + "".join(f"<td class=\"v\">{e(c)}</td>" for c in cells) + "</tr>")
    parts.append("</table>")
    lines = log_lines(data, limit=None)
    parts.append(f"<h2>Events and errors ({len(lines)} lines, board time)</h2><pre>")
    parts += [f"<span class=\"{e(lv)}\">{e(text)}</span>" for lv, text in lines]
    parts.append("</pre>")
    if data.plan_info:
        parts.append(f"<h2>Plan</h2><pre>{e(data.plan_info)}</pre>")
    if doc["summary"] is not None:
        parts.append("<h2>Run summary (as <code>armbridge run --json</code> wrote it)</h2>"
                     f"<pre>{e(json.dumps(doc['summary'], indent=2))}</pre>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def _g(x: Any) -> str:
    return "-" if x is None else f"{x:.4g}"
