"""``DIR/report.html``: one self-contained file (inline CSS and SVG figures, no script, no
link to anything outside it): the ranked units to look at, the fleet table, the logs that
failed, and a trend figure per vehicle and parameter."""

from __future__ import annotations

import math
from html import escape
from pathlib import Path
from typing import Any

from ..atomic import write_text_atomic
from .trends import key_of, label

#: Figure size in CSS pixels, and its margins.
FIG_W, FIG_H, MARGIN_L, MARGIN_R, MARGIN_T, MARGIN_B = 340, 170, 58, 10, 22, 26

CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}
th,td{border:1px solid #bbb;padding:2px 8px;text-align:left;font-size:13px}
th{background:#eee}
tr.look td{background:#fde8e8}
.figs{display:flex;flex-wrap:wrap;gap:8px}
figure{margin:0;border:1px solid #ddd}
figcaption{font-size:12px;padding:2px 4px}
svg text{font-size:10px;font-family:sans-serif}
.small{color:#666;font-size:12px}
"""


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}g}" if math.isfinite(v) else "-"
    return str(v)


def _when(start: str | None) -> str:
    """An ISO 8601 start shown to the minute, UTC (``2026-01-06 19:15Z``), or ``-``."""
    if not start:
        return "-"
    return f"{start[:10]} {start[11:16]}Z" if len(start) >= 16 else start


def trend_svg(trend: dict[str, Any], flagged: bool) -> str:
    """An inline SVG of one parameter's deviation from the certificate per log (points with
    2-std bars), its limits (dashed) and the weighted line when fitted."""
    pts = trend["points"]
    limit = float(trend["limit"] or 0.0)
    xs = [p["index"] for p in pts]
    lo = [p["deviation"] - 2 * p["std"] for p in pts] + [-limit]
    hi = [p["deviation"] + 2 * p["std"] for p in pts] + [limit]
    y0, y1 = min(lo), max(hi)
    if not y1 > y0:
        y0, y1 = y0 - 1.0, y1 + 1.0
    pad = 0.05 * (y1 - y0)
    y0, y1 = y0 - pad, y1 + pad
    x0, x1 = -0.5, max(xs) + 0.5
    pw, ph = FIG_W - MARGIN_L - MARGIN_R, FIG_H - MARGIN_T - MARGIN_B

    def X(x: float) -> float:
        return MARGIN_L + (x - x0) / (x1 - x0) * pw

    def Y(y: float) -> float:
        return MARGIN_T + (y1 - y) / (y1 - y0) * ph

    colour = "#c0392b" if flagged else "#2c6fbb"
    unit = escape(str(trend["unit"]))
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{FIG_W}" height="{FIG_H}" '
        f'viewBox="0 0 {FIG_W} {FIG_H}" role="img">',
        f'<rect x="{MARGIN_L}" y="{MARGIN_T}" width="{pw}" height="{ph}" fill="#fafafa" '
        'stroke="#999"/>',
    ]
    for lim in (-limit, limit):
        if y0 < lim < y1:
            parts.append(
                f'<line x1="{MARGIN_L}" x2="{MARGIN_L + pw}" y1="{Y(lim):.1f}" y2="{Y(lim):.1f}" '
                'stroke="#e67e22" stroke-dasharray="4 3"/>'
            )
    if y0 < 0 < y1:
        parts.append(
            f'<line x1="{MARGIN_L}" x2="{MARGIN_L + pw}" y1="{Y(0):.1f}" y2="{Y(0):.1f}" '
            'stroke="#bbb"/>'
        )
    if trend.get("slope_per_log") is not None and trend.get("deviation_last") is not None:
        last = xs[-1]
        first = trend["deviation_last"] - trend["slope_per_log"] * (last - xs[0])
        parts.append(
            f'<line x1="{X(xs[0]):.1f}" x2="{X(last):.1f}" y1="{Y(first):.1f}" '
            f'y2="{Y(trend["deviation_last"]):.1f}" stroke="{colour}" stroke-width="1.5"/>'
        )
    for p in pts:
        cx, cy = X(p["index"]), Y(p["deviation"])
        parts.append(
            f'<line x1="{cx:.1f}" x2="{cx:.1f}" y1="{Y(p["deviation"] - 2 * p["std"]):.1f}" '
            f'y2="{Y(p["deviation"] + 2 * p["std"]):.1f}" stroke="#555"/>'
            f'<circle cx="{cx:.1f}" cy="{cy:.1f}" r="2.5" fill="{colour}">'
            f"<title>{escape(Path(p['path']).name)}: {p['estimate']:.6g} {unit} "
            f"(std {p['std']:.3g})</title></circle>"
        )
    parts += [
        f'<text x="{MARGIN_L}" y="14">{escape(label(trend))}: estimate - certificate, '
        f"{unit}</text>",
        f'<text x="4" y="{Y(y1 - pad) + 4:.1f}">{_fmt(y1 - pad, 3)}</text>',
        f'<text x="4" y="{Y(y0 + pad) + 4:.1f}">{_fmt(y0 + pad, 3)}</text>',
        f'<text x="{MARGIN_L + pw / 2 - 20:.0f}" y="{FIG_H - 8}">log (time order)</text>',
        "</svg>",
    ]
    return "".join(parts)


def _reason_text(reasons: list[dict[str, Any]]) -> str:
    return "<br>".join(f"{escape(label(r))}: {escape(r['why'])}" for r in reasons)


def render(summary: dict[str, Any], records: list[dict[str, Any]]) -> str:
    """The report's HTML text."""
    vehicles = summary["vehicles"]
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        "<title>imudiag fleet report</title>",
        f"<style>{CSS}</style></head><body>",
        "<h1>imudiag fleet report</h1>",
        f'<p id="counts">{summary["logs"]} logs, {summary["ok"]} diagnosed, '
        f"{len(summary['errors'])} errors; {len(vehicles)} vehicles, "
        f"{len(summary['look_at'])} to look at.</p>",
        "<h2>Look at these units</h2>",
    ]
    look = [v for v in vehicles if v["look_at"]]
    if look:
        out.append('<ol id="look-at">')
        for v in look:
            out.append(
                f'<li><a href="#v-{escape(v["vehicle"])}">{escape(v["vehicle"])}</a>: '
                f"{_reason_text(v['reasons'])}</li>"
            )
        out.append("</ol>")
    else:
        out.append('<p id="look-at">None: no parameter beyond its limit or drifting toward it.</p>')
    kinds = summary.get("error_kinds") or []
    if kinds:  # why logs failed, the commonest first
        out.append('<h2>Why logs failed</h2><ul id="error-kinds">')
        for k in kinds:
            out.append(
                f"<li>{k['logs']} x {escape(k['reason'])} "
                f'<span class="small">(first: {escape(k["first"])})</span></li>'
            )
        out.append("</ul>")
    out += [
        "<h2>Fleet</h2>",
        '<table id="fleet"><thead><tr><th>vehicle</th><th>logs</th><th>diagnosed</th>'
        "<th>errors</th><th>first</th><th>last</th><th>look at</th><th>why</th></tr>"
        "</thead><tbody>",
    ]
    for v in vehicles:
        cls = ' class="look"' if v["look_at"] else ""
        out.append(
            f"<tr{cls}><td>{escape(v['vehicle'])}</td><td>{v['logs']}</td><td>{v['logs_ok']}"
            f"</td><td>{v['errors']}</td><td>{escape(_when(v['first']))}</td>"
            f"<td>{escape(_when(v['last']))}</td><td>{'yes' if v['look_at'] else 'no'}</td>"
            f"<td>{_reason_text(v['reasons'])}</td></tr>"
        )
    out.append("</tbody></table>")
    out += [
        "<h2>Logs</h2>",
        '<table id="logs"><thead><tr><th>log</th><th>vehicle</th><th>start</th><th>status</th>'
        "<th>accel</th><th>gyro</th><th>certificate</th><th>reason</th></tr></thead><tbody>",
    ]
    from .trends import attach_unreadable

    shown = sorted(
        attach_unreadable(records),
        key=lambda r: (str(r.get("vehicle")), r.get("start") or "~", r["path"]),
    )
    for r in shown:
        verdict = (r.get("report") or {}).get("verdict") or {}
        out.append(
            f"<tr><td>{escape(r['path'])}</td><td>{escape(str(r.get('vehicle')))}</td>"
            f"<td>{escape(_when(r.get('start')))}</td><td>{escape(r['status'])}</td>"
            f"<td>{escape(_fmt(verdict.get('accel')))}</td>"
            f"<td>{escape(_fmt(verdict.get('gyro')))}</td>"
            f"<td>{escape(_fmt(r.get('certificate_source')))}</td>"
            f"<td>{escape(_fmt(r.get('reason')))}</td></tr>"
        )
    out.append("</tbody></table>")
    out.append("<h2>Trends per vehicle</h2>")
    out.append(
        "<p class=\"small\">Each parameter's estimate minus the certificate's value per log "
        "(bars: 2 std), its limit (dashed) and the weighted line of the drift test.</p>"
    )
    for v in vehicles:
        flagged = {key_of(r) for r in v["reasons"]}
        out.append(f'<h3 id="v-{escape(v["vehicle"])}">{escape(v["vehicle"])}</h3>')
        figs = sorted(  # the parameters that name the unit first
            (t for t in v["trends"] if t["points"]),
            key=lambda t: key_of(t) not in flagged,
        )
        if not figs:
            out.append('<p class="small">No parameter estimated in any log.</p>')
            continue
        out.append('<div class="figs">')
        for t in figs:
            key = key_of(t)
            caption = (
                f"slope {_fmt(t['slope_per_log'])} &plusmn; {_fmt(t['slope_std_per_log'], 2)} "
                f"{escape(str(t['unit']))}/log"
            )
            out.append(
                f"<figure>{trend_svg(t, key in flagged)}<figcaption>{caption}</figcaption></figure>"
            )
        out.append("</div>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def write_report(summary: dict[str, Any], records: list[dict[str, Any]], path: Path) -> None:
    """Write ``report.html`` atomically."""
    write_text_atomic(path, render(summary, records))


__all__ = ["render", "trend_svg", "write_report"]
