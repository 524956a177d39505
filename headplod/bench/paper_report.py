"""The report of ``headplod bench paper`` from its rows: the goals, Table 1, the findings, the text and the charts.

A row (:func:`headplod.bench.paper_tables.paper_tables` makes them, one per condition, viewpoint, scenario,
hysteresis and gaze prior) is a dict of figures: ``changes`` and ``flicker`` per frame, ``fps``, median
``triangles``, PSNRs within ``DISC_DEG`` of the tracked POI, the true POI and the true gaze (dB), the
tracker's share of the POI's variance, and ``per_frame`` lists of them. From a condition's rows:
:func:`table1` (the means over the viewpoints), :func:`true_poi_goals` (the figures at the true POI); from
the report: :func:`goal_verdicts`, :func:`findings`, :func:`format_tables` (the text),
:func:`plot_tables` and :func:`plot_true_poi` (the charts, PNG).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .harness import DISC_DEG, pyplot, save_figure

__all__ = ["SCENARIOS", "GOAL_PSNR_DB", "GOAL_FRACTION", "GOAL_JOD_LOSS", "PRIOR_DEFAULT", "PRIOR_HEAD_ONLY",
           "default_rows", "table1", "true_poi_goals", "goal_verdicts", "findings", "format_tables", "plot_tables",
           "true_poi_chart_path", "plot_true_poi"]

#: The paper's scenarios and ours (``smoothed``).
SCENARIOS = ("none", "fixed", "adaptive", "smoothed")
#: PSNR within ``DISC_DEG`` of the true POI that a frame must keep, dB ("nothing lost").
GOAL_PSNR_DB = 45.0
#: The fraction of ``none``'s lost frames ``adaptive`` must keep under an honest covariance.
GOAL_FRACTION = 0.95
#: JOD within which of ``full`` a frame also counts as kept (FovVideoVDP, fixated at the true POI).
GOAL_JOD_LOSS = 0.05
#: ``prior`` of a row: the run with the configured (or the mode's own) prior, and the extra head-only run.
PRIOR_DEFAULT, PRIOR_HEAD_ONLY = "default", "head only"


def default_rows(rows) -> list:
    """The rows run with the default prior (``prior`` absent: a report of before the head-only runs)."""
    return [r for r in rows if r.get("prior", PRIOR_DEFAULT) == PRIOR_DEFAULT]


def true_poi_goals(rows, warmup: int, threshold_db: float = GOAL_PSNR_DB) -> dict:
    """The true-POI figures of one condition's rows (:func:`_run_group`; those of the default prior), per
    viewpoint and pooled (``"all"``).

    Over the frames from ``warmup`` on, per hysteresis (``on``, ``off``): ``frames`` counted, ``none_below``
    (frames where ``none``'s PSNR within the disc about the true POI is below ``threshold_db``, dB), ``kept``
    and ``kept_fraction`` per scenario (of those frames, the ones where the scenario is at or above it; the
    fraction None over no frames), with JOD (hysteresis on, when judged) ``kept_psnr_or_jod`` and
    ``kept_fraction_psnr_or_jod`` (also kept: within :data:`GOAL_JOD_LOSS` of ``full``'s 10). And the median
    ``triangles`` per scenario (hysteresis on; pooled: their mean over the viewpoints),
    ``adaptive_fewer_triangles_than_fixed``.
    """
    def per_frame(row, key):
        values = row["per_frame"].get(key)
        if values is None:
            return None
        return np.array([np.nan if v is None else v for v in values], dtype=np.float64)[warmup:]

    rows = default_rows(rows)
    table = {(r["viewpoint"], r["scenario"], r["hysteresis"]): r for r in rows if r["scenario"] != "full"}
    viewpoints = list(dict.fromkeys(r["viewpoint"] for r in rows))
    out = {}
    for vp in viewpoints + ["all"]:
        mine = viewpoints if vp == "all" else [vp]
        entry = {}
        for hysteresis in (True, False):
            if any((v, "none", hysteresis) not in table for v in mine):
                continue
            psnr = {sc: np.concatenate([per_frame(table[v, sc, hysteresis], "psnr_true_db") for v in mine])
                    for sc in SCENARIOS}
            below = psnr["none"] < threshold_db                       # NaN (no true POI on the image): not counted
            n = int(below.sum())
            kept = {sc: int((psnr[sc][below] >= threshold_db).sum()) for sc in SCENARIOS[1:]}
            figures = {"frames": int(psnr["none"].size), "none_below": n, "kept": kept,
                       "kept_fraction": {sc: (kept[sc] / n if n else None) for sc in kept}}
            jods = [per_frame(table[v, sc, hysteresis], "jod_true") for v in mine for sc in SCENARIOS]
            if all(j is not None for j in jods):
                jod = {sc: np.concatenate([per_frame(table[v, sc, hysteresis], "jod_true") for v in mine])
                       for sc in SCENARIOS}
                either = {sc: int(((psnr[sc][below] >= threshold_db) | (jod[sc][below] >= 10 - GOAL_JOD_LOSS)).sum())
                          for sc in SCENARIOS[1:]}
                figures["kept_psnr_or_jod"] = either
                figures["kept_fraction_psnr_or_jod"] = {sc: (either[sc] / n if n else None) for sc in either}
            entry["on" if hysteresis else "off"] = figures
        triangles = {sc: float(np.mean([table[v, sc, True]["triangles"] for v in mine]))
                     for sc in SCENARIOS if all((v, sc, True) in table for v in mine)}
        entry["triangles"] = triangles
        if "adaptive" in triangles and "fixed" in triangles:
            entry["adaptive_fewer_triangles_than_fixed"] = bool(triangles["adaptive"] < triangles["fixed"])
        out[vp] = entry
    return out


def goal_verdicts(report: dict) -> list:
    """The issue's goals, per condition and viewpoint (and pooled, ``all``), hysteresis on, from
    ``report["conditions"][c]["true_poi"]``: one dict per goal (``condition``, ``viewpoint``, ``goal``,
    ``figure``, ``frames``: ``none``'s frames below the threshold, ``status``: ``met``, ``not met``,
    ``no frames``, ``shown``, ``not shown`` or ``reported``)."""
    conditions = report["conditions"]
    honest = conditions.get("honest", {}).get("true_poi", {})
    out = []
    for condition, c in conditions.items():
        for vp, g in c.get("true_poi", {}).items():
            on = g.get("on")
            if on is None:
                continue
            n, fraction = on["none_below"], on["kept_fraction"]["adaptive"]
            base = {"condition": condition, "viewpoint": vp, "frames": n}
            kept_goal = (f"adaptive keeps >= {GOAL_PSNR_DB:g} dB within {DISC_DEG:g} deg of the true POI on "
                         f"frames where none falls below")
            if condition == "honest":
                status = "no frames" if not n else ("met" if fraction >= GOAL_FRACTION else "not met")
                out.append({**base, "goal": f"{kept_goal}: >= {GOAL_FRACTION:.0%}", "figure": fraction,
                            "status": status})
                fewer = g.get("adaptive_fewer_triangles_than_fixed")
                if fewer is not None:
                    out.append({**base, "goal": "adaptive draws fewer triangles than fixed (median per frame)",
                                "figure": [g["triangles"]["adaptive"], g["triangles"]["fixed"]],
                                "status": "met" if fewer else "not met"})
            elif condition == "overconfident":
                ref = honest.get(vp, {}).get("on", {})
                ref_fraction = ref.get("kept_fraction", {}).get("adaptive")
                if not n:
                    status = "no frames"
                elif ref_fraction is None:
                    status = "reported"                   # no honest run (or no frames there) to compare with
                else:
                    status = "shown" if fraction < ref_fraction else "not shown"
                out.append({**base, "goal": f"{kept_goal}: lower than under honest ({ref_fraction})",
                            "figure": fraction, "status": status})
            else:
                out.append({**base, "goal": kept_goal, "figure": fraction,
                            "status": "no frames" if not n else "reported"})
    return out


def _mean(values) -> float:
    """Mean of the non-NaN values (NaN when there are none)."""
    a = np.asarray(values, dtype=np.float64)
    a = a[~np.isnan(a)]
    return float(np.mean(a)) if a.size else float("nan")


def table1(rows) -> list:
    """Table 1: each scenario's figures averaged over the viewpoints (test cases): the default prior's rows
    (hysteresis on, off), then the head-only ones; each with its ``prior`` and ``gaze_prior_deg``."""
    out = []
    keys = ("changes", "flicker", "fps", "fps_ratio_to_full", "triangles", "psnr_tracked_disc_db",
            "psnr_true_disc_db", "psnr_gaze_disc_db", "tracker_cov_share", "jod_true")
    for prior in (PRIOR_DEFAULT, PRIOR_HEAD_ONLY):
        for hysteresis in (True, False):
            for scenario in SCENARIOS:
                mine = [r for r in rows if r["scenario"] == scenario and r["hysteresis"] == hysteresis
                        and r.get("prior", PRIOR_DEFAULT) == prior]
                if mine:
                    extra = {"gaze_prior_deg": mine[0]["gaze_prior_deg"]} if "gaze_prior_deg" in mine[0] else {}
                    out.append({"scenario": scenario, "hysteresis": hysteresis, "prior": prior, **extra,
                                **{k: _mean([r[k] for r in mine]) for k in keys if k in mine[0]}})
    return out


def _fraction(x) -> str:
    return "-" if x is None else f"{100 * x:.0f}%"


def findings(report) -> list:
    """Whether 'adaptive is worse than fixed because of jitter' holds, per condition (no hysteresis: the
    paper's), and what the true POI shows (hysteresis on)."""
    lines = []
    for condition, c in report["conditions"].items():
        t = {(r["scenario"], r["hysteresis"]): r for r in default_rows(c["table1"])}
        a, f, n = t[("adaptive", False)], t[("fixed", False)], t[("none", False)]
        worse = a["flicker"] > 1.2 * f["flicker"] + 0.5
        sigma = c["sigma_deg_median"]
        lines.append(
            f"{condition} (σ {sigma if sigma is None else format(sigma, '.3g')}°, frame-to-frame change of σ "
            f"{100 * (c['sigma_deg_change_median'] or 0):.0f}%), no hysteresis: flicker per frame "
            f"none {n['flicker']:.1f}, fixed {f['flicker']:.1f}, adaptive {a['flicker']:.1f}: "
            + ("adaptive flickers more than fixed: the paper's finding holds here"
               if worse else "adaptive does not flicker more than fixed: the paper's finding does not hold here"))
        pooled = c["true_poi"].get("all", {}).get("on")
        if pooled:
            k = pooled["kept_fraction"]
            lines.append(
                f"{condition}, hysteresis on, at the true POI: none below {GOAL_PSNR_DB:g} dB on "
                f"{pooled['none_below']}/{pooled['frames']} frames; of those kept by fixed {_fraction(k['fixed'])}, "
                f"adaptive {_fraction(k['adaptive'])}, smoothed {_fraction(k['smoothed'])}")
        gaze = {(r.get("prior", PRIOR_DEFAULT), r["scenario"]): r for r in c["table1"] if r["hysteresis"]}
        if c.get("true_gaze_frames"):
            parts = []
            for prior in (PRIOR_DEFAULT, PRIOR_HEAD_ONLY):
                row = gaze.get((prior, "adaptive"))
                if row is not None and "psnr_gaze_disc_db" in row:
                    parts.append(f"{_prior_name(row)} {row['psnr_gaze_disc_db']:.1f} dB "
                                 f"(tracker's share of the variance {row.get('tracker_cov_share', float('nan')):.3f})")
            if parts:
                lines.append(f"{condition}, hysteresis on, adaptive, median PSNR within {DISC_DEG:g}° of the true "
                             f"gaze (head and eyes, {c['true_gaze_frames']} frames): " + "; ".join(parts))
    return lines


def _prior_name(row) -> str:
    """A row's gaze prior for the tables: ``head only`` or ``prior H×V°``."""
    prior = row.get("gaze_prior_deg")
    if prior is None:
        return "-"
    return "head only" if not any(prior) else f"prior {prior[0]:g}×{prior[1]:g}°"


def _prior_short(row) -> str:
    """A row's gaze prior in a column: ``head`` or ``HxV`` σ deg (``-`` in a report without priors)."""
    prior = row.get("gaze_prior_deg")
    return "-" if prior is None else ("head" if not any(prior) else f"{prior[0]:g}x{prior[1]:g}")


def format_tables(report: dict) -> str:
    """The tables as text: per condition Table 1 (mean over viewpoints), then per viewpoint; then the goals.

    Columns: the gaze prior (σ deg, ``head``: none), PSNR within the disc about the tracked POI, the true POI
    (head) and the true gaze (head and eyes), and the tracker's share of the POI's variance (medians)."""
    lines = []
    judged = any("jod_true" in r for c in report["conditions"].values() for r in c["table1"])
    head = (f"{'scenario':9} {'hyst':4} {'prior':>9} {'changes':>8} {'flicker':>8} {'fps':>6} {'x full':>7} "
            f"{'triangles':>9} {'PSNR trk':>8} {'PSNR true':>9} {'PSNR gaze':>9} {'trk share':>9}"
            + (f" {'JOD true':>8}" if judged else ""))
    for condition, c in report["conditions"].items():
        sigma, mean_nees = c["sigma_deg_median"], c.get("nees_mean")
        lines.append(f"\n{condition}: {c['poses']}; pose in {c['frames_with_pose']}/{c['frames']} frames, "
                     + (f"median σ of V {sigma:.3g}°" if sigma is not None else "no covariance")
                     + (f", mean NEES of V {mean_nees:.3g} ({c['nees_frames']} frames)" if mean_nees is not None
                        else "")
                     + (f"; true gaze on {c['true_gaze_frames']} frames" if c.get("true_gaze_frames")
                        else "; no gaze truth (PSNR gaze: nan)" if "true_gaze_frames" in c else ""))
        blocks = [("Table 1 (mean over viewpoints)", c["table1"])]
        for vp in dict.fromkeys(r["viewpoint"] for r in c["rows"]):
            blocks.append((vp, [r for r in c["rows"] if r["viewpoint"] == vp and r["scenario"] != "full"]))
        for title, rows in blocks:
            lines.append(f"  {title}")
            lines.append("  " + head)
            for r in rows:
                lines.append(f"  {r['scenario']:9} {'on' if r['hysteresis'] else 'off':4} {_prior_short(r):>9} "
                             f"{r['changes']:8.1f} {r['flicker']:8.1f} {r['fps']:6.1f} {r['fps_ratio_to_full']:6.1f}x "
                             f"{r['triangles']:9.0f} {r['psnr_tracked_disc_db']:8.1f} {r['psnr_true_disc_db']:9.1f} "
                             f"{r.get('psnr_gaze_disc_db', float('nan')):9.1f} "
                             f"{r.get('tracker_cov_share', float('nan')):9.3f}"
                             + (f" {r.get('jod_true', float('nan')):8.2f}" if judged else ""))
    lines.append(f"\nAt the true POI, hysteresis on, frames after the warm-up: of the frames where none is below "
                 f"{GOAL_PSNR_DB:g} dB within {DISC_DEG:g}°, the share each scenario keeps at or above it")
    lines.append(f"  {'condition':14} {'NEES':>6} {'viewpoint':10} {'none<45':>9} {'fixed':>6} {'adaptive':>8} "
                 f"{'smoothed':>8}   {'triangles adaptive / fixed':>26}")
    for condition, c in report["conditions"].items():
        mean_nees = c.get("nees_mean")
        for vp, g in c["true_poi"].items():
            on = g.get("on")
            if on is None:
                continue
            k, tri = on["kept_fraction"], g["triangles"]
            lines.append(f"  {condition:14} {'-' if mean_nees is None else format(mean_nees, '6.3g'):>6} {vp:10} "
                         f"{on['none_below']:>4}/{on['frames']:<4} {_fraction(k['fixed']):>6} "
                         f"{_fraction(k['adaptive']):>8} {_fraction(k['smoothed']):>8}   "
                         f"{tri.get('adaptive', float('nan')):12.0f} / {tri.get('fixed', float('nan')):<12.0f}")
    lines.append("\nGoals:")
    for g in report.get("goals", []):
        figure = g["figure"]
        shown = (_fraction(figure) if isinstance(figure, float) else
                 " / ".join(f"{v:.0f}" for v in figure) if isinstance(figure, list) else "-")
        lines.append(f"  [{g['status']}] {g['condition']}, {g['viewpoint']}: {g['goal']}: {shown}"
                     + ("" if isinstance(figure, list) else f" ({g['frames']} frames with none below)"))
    lines.append("")
    lines += report.get("findings", [])
    return "\n".join(lines)


def plot_tables(report: dict, path) -> None:
    """Bars of flicker per frame and median PSNR within the disc about the tracked and the true POI per
    scenario, one column per condition."""
    plt = pyplot()
    conditions = list(report["conditions"])
    panels = (("flicker", "level reversals per frame"),
              ("psnr_tracked_disc_db", f"PSNR within {DISC_DEG:g}° of the tracked POI, dB"),
              ("psnr_true_disc_db", f"PSNR within {DISC_DEG:g}° of the true POI, dB"))
    fig, axes = plt.subplots(len(panels), len(conditions), figsize=(4.2 * len(conditions), 9.2), squeeze=False)
    x = np.arange(len(SCENARIOS))
    for j, condition in enumerate(conditions):
        c = report["conditions"][condition]
        for i, (key, label) in enumerate(panels):
            ax = axes[i, j]
            for off, hysteresis, colour in ((-0.2, False, "tab:red"), (0.2, True, "tab:blue")):
                t = {r["scenario"]: r for r in default_rows(c["table1"]) if r["hysteresis"] == hysteresis}
                ax.bar(x + off, [t[s][key] for s in SCENARIOS], 0.4, color=colour,
                       label=f"hysteresis {'on' if hysteresis else 'off'}")
            ax.set_xticks(x, SCENARIOS)
            ax.set_ylabel(label, fontsize=8)
            if i == 0:
                sigma, mean_nees = c["sigma_deg_median"], c.get("nees_mean")
                ax.set_title(condition + (f"\nσ of V {sigma:.2g}°" if sigma is not None else "")
                             + (f", NEES {mean_nees:.3g}" if mean_nees is not None else ""))
            if key != "flicker":
                finite = [r[key] for r in default_rows(c["table1"]) if math.isfinite(r[key])]
                if finite:
                    ax.set_ylim(min(finite) - 3, max(finite) + 3)
                ax.axhline(GOAL_PSNR_DB, color="k", lw=0.8, ls=":")
            ax.grid(alpha=0.3, axis="y")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Martinez et al.'s scenarios under tracker conditions (mean over the viewpoints; "
                 f"mode {report['config'].get('mode', '')})")
    save_figure(fig, path, dpi=110)


def true_poi_chart_path(path) -> Path:
    """Where :func:`plot_true_poi`'s chart goes beside ``path``: ``STEM_truepoi.png``."""
    path = Path(path)
    return path.with_name(path.stem + "_truepoi" + (path.suffix or ".png"))


def plot_true_poi(report: dict, path) -> None:
    """Per condition (columns), hysteresis on, frames after the warm-up, pooled over the viewpoints: the share of
    frames with PSNR ≥ :data:`GOAL_PSNR_DB` within the disc about the true POI (and the tracked one) per scenario,
    and the CDF of the true-POI PSNR per scenario."""
    plt = pyplot()
    conditions = list(report["conditions"])
    warmup = report["config"]["warmup"]
    colours = dict(zip(SCENARIOS, ("tab:gray", "tab:orange", "tab:blue", "tab:green")))
    # Scenarios often coincide (a steady covariance makes fixed and adaptive alike): widths and dashes keep
    # each curve visible under the next.
    styles = dict(zip(SCENARIOS, ({"lw": 1.5}, {"lw": 4.5, "alpha": 0.6}, {"lw": 2.5}, {"lw": 1.2, "ls": "--"})))
    fig, axes = plt.subplots(2, len(conditions), figsize=(4.4 * len(conditions), 7.6), squeeze=False)
    x = np.arange(len(SCENARIOS))
    for j, condition in enumerate(conditions):
        c = report["conditions"][condition]
        rows = [r for r in default_rows(c["rows"]) if r["scenario"] != "full" and r["hysteresis"]]
        pooled = {}
        for key in ("psnr_true_db", "psnr_tracked_db"):
            for sc in SCENARIOS:
                values = [v for r in rows if r["scenario"] == sc for v in r["per_frame"][key][warmup:]]
                pooled[key, sc] = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
        ax = axes[0, j]
        for off, key, colour, label in ((-0.2, "psnr_tracked_db", "tab:gray", "tracked POI"),
                                        (0.2, "psnr_true_db", "tab:purple", "true POI")):
            share = []
            for sc in SCENARIOS:
                v = pooled[key, sc]
                v = v[~np.isnan(v)]
                share.append(100 * float(np.mean(v >= GOAL_PSNR_DB)) if v.size else np.nan)
            ax.bar(x + off, share, 0.4, color=colour, label=label)
        ax.set_xticks(x, SCENARIOS)
        ax.set_ylim(0, 105)
        ax.set_ylabel(f"frames ≥ {GOAL_PSNR_DB:g} dB within {DISC_DEG:g}°, %", fontsize=8)
        mean_nees = c.get("nees_mean")
        on = c["true_poi"].get("all", {}).get("on", {})
        ax.set_title(condition + (f"  (NEES {mean_nees:.3g})" if mean_nees is not None else "")
                     + f"\nnone below on {on.get('none_below', 0)}/{on.get('frames', 0)} frames; adaptive keeps "
                     + _fraction(on.get("kept_fraction", {}).get("adaptive")), fontsize=9)
        ax.grid(alpha=0.3, axis="y")
        ax = axes[1, j]
        for sc in SCENARIOS:
            v = pooled["psnr_true_db", sc]
            v = np.sort(v[~np.isnan(v)])
            if v.size:
                shown = np.minimum(v, 80.0)                  # identical discs (inf) drawn at the right edge
                ax.step(np.concatenate([[shown[0]], shown]), np.arange(v.size + 1) / v.size, where="post",
                        color=colours[sc], label=sc, **styles[sc])
        ax.axvline(GOAL_PSNR_DB, color="k", lw=0.8, ls=":")
        ax.set_xlabel(f"PSNR within {DISC_DEG:g}° of the true POI, dB (identical: drawn at 80)", fontsize=8)
        ax.set_ylabel("fraction of frames at or below", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=8)
    fig.suptitle("Where the viewer really looks: PSNR about the true POI (hysteresis on, after the warm-up, "
                 "all viewpoints)")
    save_figure(fig, path, dpi=110)
