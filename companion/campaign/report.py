"""Campaign results: the Parquet table of every run, summary.json and report.html (plots as
embedded PNGs: tracking-error CDFs, success rate vs wind speed and vs mass error)."""

from __future__ import annotations

import base64
import html
import io
import itertools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Worst runs listed in the summary and the HTML page.
N_WORST = 10


def _sort_key(r: dict[str, Any]) -> tuple[str, str, int]:
    return (str(r["file"]), str(r["mode"]), int(r["run_index"]))


def write_table(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Every run as one Parquet row (columns as in the rows; written atomically)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist(sorted(rows, key=_sort_key))
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(table, tmp)
    tmp.replace(path)


def _stats(values: list[float]) -> dict[str, float | None]:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if len(v) == 0:
        return {"p50": None, "p90": None, "p99": None, "max": None}
    return {
        "p50": float(np.percentile(v, 50)),
        "p90": float(np.percentile(v, 90)),
        "p99": float(np.percentile(v, 99)),
        "max": float(np.max(v)),
    }


def summarize(
    rows: Sequence[dict[str, Any]], require: float, meta: dict[str, Any]
) -> dict[str, Any]:
    """Success rate per mission and mode, error distributions, the worst runs with the command
    that replays each; `passed` is False if any mission/mode is below `require` (0..1)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in sorted(rows, key=_sort_key):
        groups.setdefault((r["mission"], r["mode"]), []).append(r)
    out_groups = []
    passed = True
    for (mission, mode), rs in groups.items():
        n_ok = sum(1 for r in rs if r["ok"])
        rate = n_ok / len(rs)
        meets = rate >= require
        passed &= meets
        out_groups.append({
            "mission": mission,
            "mode": mode,
            "runs": len(rs),
            "successes": n_ok,
            "success_rate": rate,
            "meets_require": meets,
            "rms_error_m": _stats([r["rms_error_m"] for r in rs]),
            "max_error_m": _stats([r["max_error_m"] for r in rs]),
            "min_waypoint_margin_m": _stats([r["min_waypoint_margin_m"] for r in rs]),
        })
    worst = sorted(
        rows,
        key=lambda r: (bool(r["ok"]), -(r["max_error_m"] if r["max_error_m"] is not None
                                        else math.inf)),
    )[:N_WORST]
    return {
        "campaign": meta,
        "require": require,
        "passed": passed,
        "runs": len(rows),
        "successes": sum(1 for r in rows if r["ok"]),
        "groups": out_groups,
        "worst": [
            {k: r[k] for k in ("run_id", "result", "ok", "max_error_m", "rms_error_m",
                               "waypoints_reached", "waypoints_total", "wind_m_s",
                               "mass_error", "command", "tlog")}
            for r in worst
        ],
    }


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return base64.b64encode(buf.getvalue()).decode()


def _binned_success(x: np.ndarray, ok: np.ndarray, edges: np.ndarray) -> tuple[Any, Any]:
    centres, rates = [], []
    for lo, hi in itertools.pairwise(edges):
        sel = (x >= lo) & (x <= hi if hi == edges[-1] else x < hi)
        if sel.any():
            centres.append(0.5 * (lo + hi))
            rates.append(100.0 * ok[sel].mean())
    return centres, rates


def figures(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The report's matplotlib figures (name -> Figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in sorted(rows, key=_sort_key):
        groups.setdefault((r["mission"], r["mode"]), []).append(r)
    figs: dict[str, Any] = {}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for (mission, mode), rs in groups.items():
        for ax, key in zip(axes, ("rms_error_m", "max_error_m"), strict=True):
            v = np.sort([r[key] for r in rs if r[key] is not None])
            if len(v):
                ax.step(v, np.arange(1, len(v) + 1) / len(v), where="post",
                        label=f"{mission} {mode}")
    for ax, title in zip(axes, ("RMS tracking error", "max tracking error"), strict=True):
        ax.set_xscale("log")
        ax.set_xlabel("m")
        ax.set_ylabel("fraction of runs")
        ax.set_title(f"CDF of the {title}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    figs["error_cdf"] = fig
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for (mission, mode), rs in groups.items():
        ok = np.array([bool(r["ok"]) for r in rs])
        for ax, key in zip(axes, ("wind_m_s", "mass_error"), strict=True):
            x = np.array([r[key] for r in rs], dtype=float)
            lo, hi = float(x.min()), float(x.max())
            if hi <= lo:
                hi = lo + 1e-9
            c, rate = _binned_success(x, ok, np.linspace(lo, hi, 7))
            ax.plot(c, rate, "o-", label=f"{mission} {mode}")
    axes[0].set_xlabel("steady wind speed [m/s]")
    axes[1].set_xlabel("mass error (true / assumed - 1)")
    for ax in axes:
        ax.set_ylabel("success rate [%]")
        ax.set_ylim(-5, 105)
        ax.grid(True, alpha=0.3)
    axes[0].set_title("success vs wind")
    axes[1].set_title("success vs mass error")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    figs["success"] = fig
    return figs


def write_html(path: Path, summary: dict[str, Any], rows: Sequence[dict[str, Any]],
               png_dir: Path | None = None) -> None:
    """One self-contained page: the summary tables and the figures (PNGs inline).
    `png_dir` also saves the figures as PNG files there."""
    import matplotlib.pyplot as plt

    figs = figures(rows)
    imgs = {}
    for name, fig in figs.items():
        imgs[name] = _png(fig)
        if png_dir is not None:
            fig.savefig(png_dir / f"{name}.png", dpi=90)
        plt.close(fig)
    e = html.escape
    meta = summary["campaign"]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>Replay campaign</title>",
        "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}"
        ".bad{color:#b00}.good{color:#070}code{font-size:11px}</style></head><body>",
        "<h1>Replay campaign</h1>",
        f"<p>{summary['runs']} runs, {summary['successes']} successful; seed {meta.get('seed')},"
        f" required success rate {100 * summary['require']:.1f} %: "
        + ("<b class='good'>passed</b>" if summary["passed"] else "<b class='bad'>FAILED</b>")
        + "</p>",
        "<h2>Success per mission and mode</h2><table><tr><th>mission</th><th>mode</th>"
        "<th>runs</th><th>success</th><th>RMS err p50 / p90 / max [m]</th>"
        "<th>max err p50 / p90 / max [m]</th></tr>",
    ]

    def fmt(s: dict[str, float | None]) -> str:
        return " / ".join("-" if s[k] is None else f"{s[k]:.2f}" for k in ("p50", "p90", "max"))

    for g in summary["groups"]:
        cls = "good" if g["meets_require"] else "bad"
        parts.append(
            f"<tr><td>{e(g['mission'])}</td><td>{e(g['mode'])}</td><td>{g['runs']}</td>"
            f"<td class='{cls}'>{100 * g['success_rate']:.1f} %</td>"
            f"<td>{fmt(g['rms_error_m'])}</td><td>{fmt(g['max_error_m'])}</td></tr>"
        )
    parts.append("</table>")
    for name, title in (("error_cdf", "Tracking error"), ("success", "Success rate")):
        parts.append(f"<h2>{title}</h2><img alt='{name}' src='data:image/png;base64,"
                     f"{imgs[name]}'>")
    parts.append("<h2>Worst runs</h2><table><tr><th>run</th><th>result</th>"
                 "<th>max err [m]</th><th>waypoints</th><th>wind [m/s]</th><th>mass err</th>"
                 "<th>replay command</th></tr>")
    for w in summary["worst"]:
        mx = "-" if w["max_error_m"] is None else f"{w['max_error_m']:.2f}"
        parts.append(
            f"<tr><td>{e(w['run_id'])}</td><td>{e(str(w['result']))}</td><td>{mx}</td>"
            f"<td>{w['waypoints_reached']}/{w['waypoints_total']}</td>"
            f"<td>{w['wind_m_s']:.1f}</td><td>{w['mass_error']:+.3f}</td>"
            f"<td><code>{e(w['command'])}</code></td></tr>"
        )
    parts.append("</table></body></html>")
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("\n".join(parts), encoding="utf-8")
    tmp.replace(path)


def write_outputs(out_dir: Path, rows: Sequence[dict[str, Any]], require: float,
                  meta: dict[str, Any]) -> dict[str, Any]:
    """runs.parquet, summary.json and report.html in `out_dir`; returns the summary."""
    write_table(out_dir / "runs.parquet", rows)
    summary = summarize(rows, require, meta)
    tmp = out_dir / ".summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2, allow_nan=False), encoding="utf-8")
    tmp.replace(out_dir / "summary.json")
    if rows:
        write_html(out_dir / "report.html", summary, rows)
    return summary


__all__ = ["figures", "summarize", "write_html", "write_outputs", "write_table"]
