"""The evaluation report: ``report.md`` plus PNG figures, from ``tactus eval`` results.

Files written into the report folder:

- ``report.md``      results table (Table 1 style: chance, compared models, each run, mean ±
                     sample std when several runs), per-class top-1, top confusions, the
                     Spearman text-geometry test, phrasing robustness, K-sweep, examples
- ``confusion.png``  row-normalised confusion matrix (voted draws, like the paper's analysis);
                     off-diagonal cells >= 0.08 carry their rate
- ``ksweep.png``     top-1 vs distinct frames per window (1, 2, 4, 8; the rest repeat the last)
- ``examples/*.png`` a strip of held-out windows drawn by ``render.draw_window_png``
- ``results.json``   the JSON the report was made from
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.training.evaluate import CONFUSION_LABEL_MIN, EvalResult
from tactus_memory.training.metrics import KSWEEP, SCALAR_METRICS

COLUMNS = (
    ("top1", "top-1"),
    ("top3", "top-3"),
    ("top1_vote", "top-1 (vote)"),
    ("top3_vote", "top-3 (vote)"),
    ("recording_top1", "recording top-1"),
)


def _fmt(v: Any, nd: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def plot_confusion(
    confusion: np.ndarray,
    classes: Sequence[str],
    path: str | Path,
    *,
    title: str = "",
    label_min: float = CONFUSION_LABEL_MIN,
) -> Path:
    """Heat map of a row-normalised (C, C) matrix; off-diagonal cells >= label_min labelled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = np.asarray(confusion, dtype=np.float64)
    n = len(classes)
    fig, ax = plt.subplots(figsize=(0.36 * n + 3, 0.36 * n + 2.5), dpi=110)
    im = ax.imshow(c, cmap="Blues", vmin=0.0, vmax=1.0)
    ax.set_xticks(range(n), classes, rotation=90, fontsize=7)
    ax.set_yticks(range(n), classes, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    for i in range(n):
        for j in range(n):
            if i != j and c[i, j] >= label_min:
                ax.text(
                    j,
                    i,
                    f"{c[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=5.5,
                    color="white" if c[i, j] > 0.5 else "crimson",
                )
    fig.colorbar(im, ax=ax, fraction=0.04, pad=0.02)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_ksweep(series: dict[str, dict[str, float | None]], path: str | Path) -> Path:
    """``series``: label -> {"1": top1, "2": ..., ...}; one line per label."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.6, 3.2), dpi=120)
    for label, pts in series.items():
        xs = [int(n) for n in sorted(pts, key=int) if pts[n] is not None]
        ys = [pts[str(n)] for n in xs]
        ax.plot(xs, ys, marker="o", label=label)
        for x, y in zip(xs, ys, strict=True):
            ax.annotate(
                f"{y:.2f}",
                (x, y),
                textcoords="offset points",
                xytext=(0, 5),
                ha="center",
                fontsize=7,
            )
    ax.set_xscale("log", base=2)
    ax.set_xticks(list(KSWEEP), [str(k) for k in KSWEEP])
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("distinct frames per window (rest repeat the last)")
    ax.set_ylabel("tuple top-1")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def write_examples(
    out: Path, result: EvalResult, calibrated: np.ndarray, classes: Sequence[str], n: int = 8
) -> list[dict[str, Any]]:
    """Per class (in class order, up to ``n`` classes) the held-out tuple whose anchor frame is
    the most active (largest total calibrated pressure, as the paper's Fig. 1), as PNG strips."""
    from tactus_memory.touch.render import draw_window_png

    folder = out / "examples"
    folder.mkdir(parents=True, exist_ok=True)
    pred = np.argmax(result.scores_vote, axis=1) if len(result.y) else np.zeros(0, int)
    activity = calibrated[result.tuples[:, 0]].sum(axis=(1, 2)) if len(result.y) else None
    rows = []
    for c in np.unique(result.y)[:n]:
        cand = np.flatnonzero(result.y == c)
        t = int(cand[np.argmax(activity[cand])])
        name = f"example_{len(rows):02d}_{classes[int(c)]}.png"
        (folder / name).write_bytes(
            draw_window_png(calibrated[result.tuples[t]], calibrated=True, scale=2)
        )
        rows.append({"file": f"examples/{name}", "true": classes[int(c)], "pred": classes[pred[t]]})
    return rows


def _stem(m: dict[str, Any]) -> str:
    """The checkpoint's file stem, for table labels."""
    path = (
        (m.get("checkpoint") or {}).get("path") if isinstance(m.get("checkpoint"), dict) else None
    )
    return Path(path).stem if path else ""


def _table_row(label: str, m: dict[str, Any], std: dict[str, Any] | None = None) -> str:
    cells = []
    for key, _ in COLUMNS:
        v = m.get(key)
        s = (std or {}).get(key)
        cells.append(_fmt(v) + (f" ± {s:.3f}" if isinstance(s, float) else ""))
    return f"| {label} | " + " | ".join(cells) + " |"


def write_report(
    out_dir: str | Path,
    payload: dict[str, Any],
    first: EvalResult | None = None,
    calibrated: np.ndarray | None = None,
    compare: Sequence[dict[str, Any]] = (),
) -> list[Path]:
    """Write the report for ``payload`` (the ``tactus eval`` JSON); returns the files.

    ``first``/``calibrated``: the first run's raw result and frames, for the example strip;
    ``compare``: other eval JSONs (e.g. ``tactus baseline eval``) shown as table rows.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs: list[dict[str, Any]] = payload.get("runs") or [payload]
    m0 = runs[0]
    classes = m0["classes"]
    files: list[Path] = []
    lines: list[str] = ["# Tactus evaluation report", ""]
    lines += [
        f"- split / scope: `{m0['split']}`; {m0['n_tuples']} tuples (K={m0['k']}, fixed seed "
        f"{m0['seed']}), {m0['n_recordings']} recordings, {m0['n_frames']} valid frames",
        f"- voting: embeddings of {m0['votes']} independent cluster-tuple draws pooled",
        "- recording level: up to 64 valid frames per recording tiled into K-frame windows, "
        "window embeddings averaged (baseline: probabilities averaged)",
    ]
    for r in runs:
        ck = r.get("checkpoint", {})
        lines.append(
            f"- checkpoint `{ck.get('path')}` sha256 `{str(ck.get('sha256'))[:16]}…` "
            f"({ck.get('kind')}, {ck.get('model')}, steps {ck.get('steps')}, seed {ck.get('seed')})"
        )
    for r in runs:
        lk = r.get("leakage", {})
        if lk.get("status") == "overlap":
            lines.append(
                f"- **WARNING**: {lk['trained_on']} of {lk['scored_recordings']} scored "
                "recordings were in this checkpoint's training data: not a held-out score"
            )
        elif lk:
            lines.append(f"- held-out check: {lk.get('status')}")
    for d in m0.get("data", []):
        lines.append(
            f"- data `{d.get('source')}` fingerprint `{str(d.get('fingerprint'))[:16]}…` "
            f"({d.get('frames')} frames, {d.get('valid_frames')} valid, "
            f"{d.get('recordings')} recordings)"
        )

    # ---- results table
    lines += ["", "## Results", "", "| model | " + " | ".join(c for _, c in COLUMNS) + " |"]
    lines.append("|---" * (len(COLUMNS) + 1) + "|")
    chance = {k: m0["chance"] for k in ("top1", "top1_vote", "recording_top1")}
    chance.update({k: m0["chance_top3"] for k in ("top3", "top3_vote")})
    lines.append(_table_row("chance", chance))
    for c in compare:
        cr = c.get("runs") or [c]
        label = (
            f"{cr[0].get('model_kind', 'model')} {_stem(cr[0])} "
            f"({len(cr)} run{'s' if len(cr) > 1 else ''})"
        )
        if len(cr) > 1:
            agg = c["aggregate"]
            lines.append(
                _table_row(
                    label,
                    {k: agg[k]["mean"] for k in SCALAR_METRICS},
                    {k: agg[k]["std"] for k in SCALAR_METRICS},
                )
            )
        else:
            lines.append(
                _table_row(
                    label + f" `{str(cr[0].get('checkpoint', {}).get('sha256'))[:8]}`", cr[0]
                )
            )
    if len(runs) > 1:
        agg = payload["aggregate"]
        lines.append(
            _table_row(
                f"**{m0['model_kind']}, mean of {len(runs)}**",
                {k: agg[k]["mean"] for k in SCALAR_METRICS},
                {k: agg[k]["std"] for k in SCALAR_METRICS},
            )
        )
    for i, r in enumerate(runs):
        sha = str(r.get("checkpoint", {}).get("sha256"))[:8]
        lines.append(_table_row(f"{r['model_kind']} run {i}: {_stem(r)} `{sha}`", r))
    if len(runs) > 1:
        lines += ["", "Means ± sample standard deviation (ddof = 1) over the runs."]

    # ---- per class
    lines += [
        "",
        "## Per class (first run)",
        "",
        "| class | tuples | top-1 | top-3 | top-1 (vote) |",
        "|---|---|---|---|---|",
    ]
    for c in classes:
        lines.append(
            f"| {c} | {m0['per_class_tuples'].get(c, 0)} | {_fmt(m0['per_class'].get(c))} | "
            f"{_fmt(m0['per_class_top3'].get(c))} | {_fmt(m0['per_class_vote'].get(c))} |"
        )
    lines += [
        "",
        "Recording level (first run):",
        "",
        "| recording | true | predicted | rank of true | frames |",
        "|---|---|---|---|---|",
    ]
    for p in m0["per_recording"]:
        lines.append(
            f"| {p['recording']} | {classes[p['true']]} | {classes[p['pred']]} | "
            f"{p['true_rank']} | {p['frames']} |"
        )

    # ---- analysis
    an = m0.get("analysis", {})
    conf = np.asarray(m0["confusion_vote"])
    files.append(
        plot_confusion(
            conf,
            classes,
            out / "confusion.png",
            title=f"{an.get('protocol', 'voted')}; n={m0['n_tuples']} tuples",
        )
    )
    lines += ["", "## Errors", "", "![confusion](confusion.png)", ""]
    if an:
        lines.append(
            f"Classes at >= 0.80 top-1 (vote): {an.get('classes_ge_0.80')} of "
            f"{an.get('classes_scored')} scored; at >= 0.99: {an.get('classes_ge_0.99')}."
        )
        rows = an.get("pair_text_cosine") or an.get("top_confusions", [])
        if rows:
            lines += [
                "",
                "| true | predicted | rate | text cosine (uncentred) |",
                "|---|---|---|---|",
            ]
            for r in rows:
                lines.append(
                    f"| {r['true']} | {r['pred']} | {r['rate']:.3f} | "
                    f"{_fmt(r.get('cos_uncentred'))} |"
                )
        sp = an.get("spearman")
        if sp:
            lines += [
                "",
                "### Is the text space the error source?",
                "",
                "Spearman correlation between the confusion rate of every ordered class "
                "pair and the cosine of the two class targets:",
                "",
                "| targets | rho | p | pairs |",
                "|---|---|---|---|",
            ]
            for key in ("uncentred", "centred"):
                s = sp[key]
                lines.append(f"| {key} | {_fmt(s['rho'])} | {_fmt(s['p'], 4)} | {s['n_pairs']} |")
            lines += ["", "(rho is undefined when no pair is ever confused.)"]
        ph = an.get("phrasing")
        if ph:
            lines += [
                "",
                "### Query phrasing",
                "",
                "The same voted embeddings ranked against six target constructions:",
                "",
                "| targets | top-1 | top-3 |",
                "|---|---|---|",
            ]
            for name, v in ph.items():
                lines.append(f"| {name} | {_fmt(v['top1'])} | {_fmt(v['top3'])} |")
        for note in an.get("notes", []):
            lines.append(f"\n_Note: {note}_")

    # ---- K-sweep
    series = {}
    if len(runs) > 1:
        agg = payload["aggregate"]
        series[f"{m0['model_kind']} mean of {len(runs)}"] = {
            str(n): agg.get(f"ksweep_{n}", {}).get("mean") for n in KSWEEP
        }
    else:
        series[f"{m0['model_kind']} {_stem(m0)}"] = m0["ksweep"]
    for c in compare:
        cr = c.get("runs") or [c]
        series[f"{cr[0].get('model_kind', 'compare')} {_stem(cr[0])}"] = cr[0].get("ksweep", {})
    files.append(plot_ksweep(series, out / "ksweep.png"))
    lines += [
        "",
        "## Frames per window (K-sweep)",
        "",
        "![ksweep](ksweep.png)",
        "",
        "| series | " + " | ".join(str(n) for n in KSWEEP) + " |",
        "|---" * (len(KSWEEP) + 1) + "|",
    ]
    for label, pts in series.items():
        lines.append(f"| {label} | " + " | ".join(_fmt(pts.get(str(n))) for n in KSWEEP) + " |")

    # ---- examples
    if first is not None and calibrated is not None:
        ex = write_examples(out, first, calibrated, classes)
        files += [out / e["file"] for e in ex]
        lines += [
            "",
            "## Example held-out windows",
            "",
            "Calibrated frames of one held-out tuple per class, the one whose anchor is the "
            "most active (anchor first; glove taxels only; colour 0..1 calibrated pressure).",
            "",
            "| true | predicted (vote) | window |",
            "|---|---|---|",
        ]
        for e in ex:
            lines.append(f"| {e['true']} | {e['pred']} | ![]({e['file']}) |")

    (out / "results.json").write_text(json.dumps(payload, indent=1) + "\n")
    files.append(out / "results.json")
    (out / "report.md").write_text("\n".join(lines) + "\n")
    files.insert(0, out / "report.md")
    return files
