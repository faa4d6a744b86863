"""The fidelity guard's tables: every gait of every setting, and each setting's worst gait and verdict."""

from __future__ import annotations

from typing import Any


def format_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table: setting, gait, displacement, errors, pass."""
    lines = [
        "| setting | gait | displacement (m) | ref (m) | disp. error % | heading error deg | pass |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        dx, dy = r["displacement_m"]
        lines.append(
            f"| {r['setting']} | {r['gait']} | ({dx:+.3f}, {dy:+.3f}) {r['distance_m']:.3f} | "
            f"{r['reference_distance_m']:.3f} | {r['displacement_error_pct']:.1f} | "
            f"{r['heading_error_deg']:.1f} | {'yes' if r['pass'] else 'NO'} |"
        )
    return "\n".join(lines)


def summary(rows: list[dict[str, Any]]) -> dict[str, bool]:
    """Setting -> passes every gait."""
    verdict: dict[str, bool] = {}
    for r in rows:
        verdict[r["setting"]] = verdict.get(r["setting"], True) and r["pass"]
    return verdict


def summary_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of the worst gait per setting: displacement error, heading error, verdict."""
    lines = [
        "| setting | worst disp. error % (gait) | worst heading error deg (gait) | new failures | pass |",
        "|---|---|---|---|---|",
    ]
    for setting, ok in summary(rows).items():
        mine = [r for r in rows if r["setting"] == setting]
        disp = max(mine, key=lambda r: r["displacement_error_pct"])
        head = max(mine, key=lambda r: r["heading_error_deg"])
        fails = sorted({f for r in mine for f in r["failures_not_in_reference"]})
        lines.append(
            f"| {setting} | {disp['displacement_error_pct']:.1f} ({disp['gait']}) | "
            f"{head['heading_error_deg']:.1f} ({head['gait']}) | {', '.join(fails) or '-'} | "
            f"{'yes' if ok else 'NO'} |"
        )
    return "\n".join(lines)
