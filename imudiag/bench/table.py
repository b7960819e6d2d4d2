"""The bench report as a printed table (the JSON report is the machine-readable form)."""

from __future__ import annotations

from typing import Any

_COLUMNS = ("#", "t [s]", "injected", "expected", "detected", "latency", "bound", "result")


def _expected_text(r: dict[str, Any]) -> str:
    if r["category"] == "sensor":
        parts = [
            " ".join(p for p in (e["triad"], e.get("sensor"), e["cause"]) if p)
            for e in r["expected"]
        ]
        pend = [
            " ".join(p for p in (e["triad"], e.get("sensor"), e["cause"]) if p)
            for e in r.get("pending", [])
        ]
        text = " | ".join(parts)
        if pend:
            text += (" | " if text else "") + "(" + " | ".join(pend) + ": needs diagnosis)"
        return text
    if r["category"] == "outage":
        return "no_data, then samples"
    return " ".join(f"{k}+{v}" for k, v in r.get("expected", {}).items())


def _detected_text(r: dict[str, Any]) -> str:
    if r["category"] == "sensor":
        m = r.get("matched")
        return " ".join(p for p in (m["triad"], m.get("sensor"), m["cause"]) if p) if m else "-"
    if r["category"] == "outage":
        if not r.get("detected"):
            return "-"
        rec = r.get("recover_wall_s")
        back = f", back {rec:.2f} s wall" if rec is not None else ""
        return f"no_data {r.get('wall_latency_s', 0):.2f} s wall{back}"
    obs = r.get("observed")
    if obs is None:
        return "-"
    return " ".join(f"{k}+{v}" for k, v in obs.items()) or "+0"


def _latency_text(r: dict[str, Any]) -> str:
    lat = r.get("latency_s")
    return "-" if lat is None else f"{lat:.3f}"


def _bound_text(r: dict[str, Any]) -> str:
    if r["category"] == "outage":
        return f"{r['expected']['within_wall_s']:g} wall"
    b = r.get("bound_s")
    return "-" if b is None else f"{b:g}"


def format_table(report: dict[str, Any]) -> str:
    """Human-readable summary: one row per injection, then false alarms and counters."""
    rows = [
        (
            str(r["number"]),
            f"{r['t']:.3f}",
            _describe(r),
            _expected_text(r),
            _detected_text(r),
            _latency_text(r),
            _bound_text(r),
            r["result"],
        )
        for r in report["faults"]
    ]
    widths = [
        max(len(c), *(len(row[i]) for row in rows)) if rows else len(c)
        for i, c in enumerate(_COLUMNS)
    ]
    lines = [
        f"bench scenario {report['scenario']}: {report['duration_s']:g} s of samples at "
        f"{report['speed']:g}x, seed {report['seed']}, diagnosis "
        f"{'on' if report['diagnosis'] else 'off'}, {report['wall_s']:g} s wall, "
        f"{report['status_lines']} status lines",
        "  ".join(c.ljust(w) for c, w in zip(_COLUMNS, widths, strict=True)),
        "  ".join("-" * w for w in widths),
    ]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) for row in rows]
    lines.append("latency: sample time from injection to the first status showing it, s")
    if report.get("max_status_delay_wall_s") is not None:
        lines.append(
            f"longest delay from a board write to a status line showing it: "
            f"{report['max_status_delay_wall_s']:.3f} s wall"
        )
    fa = report["false_alarms"]
    if fa:
        lines.append("false alarms:")
        for f in fa:
            name = " ".join(p for p in (f["triad"], f.get("sensor"), f["cause"]) if p)
            lines.append(
                f"  {name}: t {f['t_first']:.3f} .. {f['t_last']:.3f} s ({f['lines']} status lines)"
            )
    else:
        lines.append("false alarms: none")
    c = report["counters"]
    diff = [k for k in c["expected"] if c["expected"][k] not in ("any", c["observed"].get(k))]
    expected = ", ".join(f"{k}={c['expected'][k]}" for k in diff)
    lines.append(
        "counters: "
        + " ".join(f"{k}={c['observed'].get(k)}" for k in c["expected"])
        + (
            "  (exact)"
            if c["exact"]
            else "  (not checkable: unplug without drain)"
            if c["exact"] is None
            else f"  (expected {expected})"
        )
        + ("" if c["monotonic"] else "  NOT MONOTONIC")
    )
    a = report.get("aiding")
    if a:
        fin = a["final"]
        first = a["t_first_in_use"]
        lines.append(
            f"aiding: {a['source']}, "
            + ("never in use" if first is None else f"in use from t = {first:.1f} s")
            + f" (bound {a['in_use_within']:g} s); at the end {fin['link']}, "
            f"{fin['fixes']} fixes, F0 {fin['f0']['checked']} epochs checked / "
            f"{fin['f0']['failed']} failed, {fin['windows']} isolation windows"
        )
        for p in a["problems"]:
            lines.append(f"aiding: {p}")
    for p in report["daemon"]["problems"]:
        lines.append(f"daemon: {p}")
    pending = report["summary"].get("pending", 0)
    lines.append(
        "verdict: "
        + ("PASS" if report["passed"] else "FAIL")
        + (f" ({pending} pending the window diagnosis)" if pending else "")
    )
    return "\n".join(lines)


def _describe(r: dict[str, Any]) -> str:
    kind = r["kind"]
    if r["category"] == "sensor":
        value = r.get("value")
        return f"{kind} {r['sensor']}" + ("" if value is None else f" {value:g}")
    if kind == "garbage":
        return f"garbage {r['bytes']} B" + (" random" if r.get("random") else "")
    if r["category"] == "outage":
        return f"{kind} {r['outage_s']:g} s"
    return f"{kind} {r['frames']} fr"


__all__ = ["format_table"]
