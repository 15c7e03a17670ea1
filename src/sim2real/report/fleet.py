"""The fleet view: which arm drifted since its last campaign, and in what.

The fleet view (``results/fleet.json``, ``fleet.md``, a figure) reads every campaign's
(:mod:`sim2real.measurements.campaigns`) sysid ``ladder.json`` (holdout error per rung of each link) and
``params.yaml`` (identified values and their bootstrap intervals). Between consecutive dated campaigns of the same
arm, a value counts as changed only when its two intervals do not overlap.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from sim2real.errors import InputError
from sim2real.identification.ladder_rows import LadderDocument, SideRows
from sim2real.report import rung_label

UNIT_TEXT = {"N*m": "N·m", "N*m*s/rad": "N·m·s/rad", "kg*m^2": "kg·m²", "1": ""}


# Names of the components of vector parameters (payload and link centres of mass, link inertias).
COMPONENTS = {"com": ("x", "y", "z"), "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}


def _units() -> dict[tuple[str, str], str]:
    from sim2real.identification.effects import EFFECTS

    return {(e.name, p.name): p.unit for e in EFFECTS.values() for p in e.parameters}


def _is_interval(x: Any) -> bool:
    return (isinstance(x, list) and len(x) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                        for v in x))


def _leaves(
    value: Any, interval: Any, joint: str | None, component: int | None
) -> Iterator[tuple[str | None, int | None, float, list[float]]]:
    """(joint, component, value, [lo, hi]) of every number that has an interval."""
    if isinstance(value, Mapping) and isinstance(interval, Mapping):
        for key in sorted(value):
            if key in interval:
                yield from _leaves(value[key], interval[key], str(key), component)
    elif isinstance(value, list) and isinstance(interval, list) and len(value) == len(interval):
        for k, (v, i) in enumerate(zip(value, interval, strict=True)):
            yield from _leaves(v, i, joint, k)
    elif isinstance(value, (int, float)) and not isinstance(value, bool) and _is_interval(interval):
        yield joint, component, float(value), [float(interval[0]), float(interval[1])]


def identified_values(params: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The physical parameters of params.yaml (``effects`` with their ``intervals``), one row per number.

    Only parameters the effect library declares (with a unit) and whose interval has a width: the
    nonlinear shape parameters (e.g. friction smoothing) are held fixed by the bootstrap, so their
    zero-width intervals say nothing about a change.
    """
    units = _units()
    effects = params.get("effects") or {}
    intervals = params.get("intervals") or {}
    rows = []

    def add(effect: str, parameter: str, value: Any, interval: Any, where: str | None) -> None:
        for joint, component, v, (lo, hi) in _leaves(value, interval, where, None):
            if math.isfinite(lo) and math.isfinite(hi) and hi > lo:
                rows.append({"effect": effect, "parameter": parameter, "joint": joint, "component": component,
                             "unit": units[(effect, parameter)], "value": v, "interval": [lo, hi]})

    for effect in sorted(effects):
        values = effects[effect] or {}
        bounds = intervals.get(effect) or {}
        for parameter in sorted(values):
            if (effect, parameter) in units and parameter in bounds:
                add(effect, parameter, values[parameter], bounds[parameter], None)
        # per-body parameters (link inertias): {links: {link: {mass, com, inertia}}}, one row per link
        links, link_bounds = values.get("links"), bounds.get("links")
        if isinstance(links, Mapping) and isinstance(link_bounds, Mapping):
            for link in sorted(links):
                for parameter in sorted(links[link] or {}):
                    if (effect, parameter) in units and parameter in (link_bounds.get(link) or {}):
                        add(effect, parameter, links[link][parameter], link_bounds[link][parameter], link)
    return rows


def _key(row: Mapping[str, Any]) -> tuple[str, str, str, int]:
    return (row["effect"], row["parameter"], row["joint"] or "", -1 if row["component"] is None else row["component"])


def overlaps(a: Sequence[float], b: Sequence[float]) -> bool:
    """Closed intervals [a0, a1] and [b0, b1] share a point."""
    return a[0] <= b[1] and b[0] <= a[1]


def _num(x: float) -> str:
    """Three significant digits, as a person writes them (0.61, 0.0523, 12.4)."""
    return f"{x:.3g}"


def _where(row: Mapping[str, Any]) -> str:
    parts = []
    if row["joint"]:
        parts.append(f"on {row['joint']}")
    if row["component"] is not None:
        names = COMPONENTS.get(row["parameter"], ())
        parts.append(f"({names[row['component']] if row['component'] < len(names) else row['component']})")
    return (" " + " ".join(parts)) if parts else ""


def _unit(unit: str) -> str:
    text = UNIT_TEXT.get(unit, unit)
    return f" {text}" if text else ""


def change_text(arm: str, change: Mapping[str, Any]) -> str:
    """'panda_2: coulomb_friction on panda_joint4 rose from 0.61 [0.58, 0.64] to 0.83 [0.79, 0.86] N·m
    between 2026-10 and 2026-11'."""
    name = change["effect"] if change["parameter"] in ("friction", "bias", "gain", "damping", "armature") \
        else f"{change['effect']}.{change['parameter']}"
    b, a = change["before"], change["after"]
    return (
        f"{arm}: {name}{_where(change)} {change['direction']} from {_num(b['value'])} "
        f"[{_num(b['interval'][0])}, {_num(b['interval'][1])}] to {_num(a['value'])} "
        f"[{_num(a['interval'][0])}, {_num(a['interval'][1])}]{_unit(change['unit'])} "
        f"between {change['from']} and {change['to']}"
    )


def compare_campaigns(
    before: Sequence[Mapping[str, Any]], after: Sequence[Mapping[str, Any]]
) -> tuple[list[dict[str, Any]], int]:
    """Values identified in both campaigns whose intervals do not overlap, and how many were compared."""
    old = {_key(r): r for r in before}
    changes = []
    compared = 0
    for row in after:
        prev = old.get(_key(row))
        if prev is None:
            continue
        compared += 1
        if overlaps(prev["interval"], row["interval"]):
            continue
        changes.append({
            "effect": row["effect"], "parameter": row["parameter"], "joint": row["joint"],
            "component": row["component"], "unit": row["unit"],
            "direction": "rose" if row["value"] > prev["value"] else "fell",
            "before": {"value": prev["value"], "interval": list(prev["interval"])},
            "after": {"value": row["value"], "interval": list(row["interval"])},
        })
    return changes, compared


def holdout_summary(side: SideRows) -> dict[str, Any]:
    """Holdout torque RMSE per rung of one side of a sysid ladder.json, with the noise floor."""
    rungs = []
    for rung in side.rungs:
        rungs.append({
            "effects": list(rung.effects),
            "label": rung_label(rung.effects),
            "torque_rmse": float(rung.metrics.torque_rmse["overall"]),
        })
    floor = side.floor.get("overall")
    return {"rungs": rungs, "noise_floor": None if floor is None else float(floor)}


def fleet_document(campaigns: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The fleet view from every campaign's metadata, ladder.json and params.yaml content.

    Each item: ``robot``, ``campaign``, ``arm``, ``date`` (or None), ``measurements``, ``report``,
    ``ladder`` (dict), ``params`` (dict). Campaigns of an arm are ordered by date; consecutive dated
    campaigns are compared (undated ones, e.g. a default campaign without ``campaign.date``, are listed
    but never compared).
    """
    by_arm: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for item in campaigns:
        by_arm.setdefault((item["arm"], item["robot"]), []).append(item)
    arms_out = []
    n_changes = 0
    for (arm, robot), items in sorted(by_arm.items()):
        seen: dict[str, str] = {}
        for item in items:
            if item["date"] is not None:
                if item["date"] in seen:
                    raise InputError(
                        item["measurements"], "campaign/date",
                        f"arm '{arm}' already has a campaign dated {item['date']} ({seen[item['date']]})",
                        "give each campaign of an arm its own date (YYYY-MM-DD tells two in one month apart)",
                    )
                seen[item["date"]] = item["measurements"]
        ordered = sorted(items, key=lambda i: (i["date"] is not None, i["date"] or "", i["campaign"]))
        campaigns_out = []
        for item in ordered:
            ladder = LadderDocument.from_document(item["ladder"])
            campaigns_out.append({
                "campaign": item["campaign"], "date": item["date"], "measurements": item["measurements"],
                "report": item["report"], "holdout": holdout_summary(ladder.body),
                "actuator_holdout": holdout_summary(ladder.actuator) if ladder.actuator is not None else None,
                "identified": identified_values(item["params"]),
            })
        comparisons = []
        changes = []
        dated = [c for c in campaigns_out if c["date"] is not None]
        for prev, nxt in zip(dated, dated[1:]):
            found, compared = compare_campaigns(prev["identified"], nxt["identified"])
            for change in found:
                change.update({"from": prev["date"], "to": nxt["date"],
                               "from_campaign": prev["campaign"], "to_campaign": nxt["campaign"]})
                change["text"] = change_text(arm, change)
            comparisons.append({"from": prev["date"], "to": nxt["date"], "from_campaign": prev["campaign"],
                                "to_campaign": nxt["campaign"], "values_compared": compared,
                                "changed": len(found)})
            changes.extend(found)
        n_changes += len(changes)
        arms_out.append({"arm": arm, "robot": robot, "campaigns": campaigns_out,
                         "comparisons": comparisons, "changes": changes})
    return {
        "rule": "a value changed between consecutive campaigns of an arm only when its two bootstrap "
                "intervals (params.yaml `intervals`) do not overlap",
        "arms": arms_out,
        "summary": {"arms": len(arms_out), "campaigns": sum(len(a["campaigns"]) for a in arms_out),
                    "changes": n_changes, "drifted_arms": sorted(a["arm"] for a in arms_out if a["changes"])},
    }


def _actuator_table(campaigns: Sequence[Mapping[str, Any]]) -> list[str]:
    """The actuator link's holdout RMSE per rung, for the campaigns whose runs log tau and tau_cmd."""
    linked = [c for c in campaigns if c.get("actuator_holdout")]
    if not linked:
        return []
    labels = list(dict.fromkeys(r["label"] for c in linked for r in c["actuator_holdout"]["rungs"]))
    lines = ["", "| campaign | date | " + " | ".join(labels) + " | noise floor |",
             "|---|---|" + "---|" * len(labels) + "---|"]
    for c in linked:
        by_label = {r["label"]: r["torque_rmse"] for r in c["actuator_holdout"]["rungs"]}
        floor = c["actuator_holdout"]["noise_floor"]
        lines.append(f"| {c['campaign']} | {c['date'] or '–'} | "
                     + " | ".join(f"{by_label[label]:.3f}" if label in by_label else "–" for label in labels)
                     + f" | {'–' if floor is None else f'{floor:.3f}'} |")
    lines += ["", "Holdout torque RMSE [N·m] per rung, actuator link (measured against commanded torque)."]
    return lines


def render_fleet_markdown(fleet: Mapping[str, Any], figure: str | None = None) -> str:
    lines = ["# Fleet", ""]
    s = fleet["summary"]
    lines.append(f"{s['arms']} arm(s), {s['campaigns']} campaign(s). A value counts as changed between two "
                 "consecutive campaigns of an arm only when its two intervals do not overlap.")
    lines.append("")
    lines.append("## What changed")
    lines.append("")
    any_change = False
    for arm in fleet["arms"]:
        for change in arm["changes"]:
            lines.append(f"- {change['text']}")
            any_change = True
        for comp in arm["comparisons"]:
            if not comp["changed"]:
                lines.append(f"- {arm['arm']}: no identified value changed between {comp['from']} and {comp['to']} "
                             f"({comp['values_compared']} values compared, every interval overlaps)")
        if not arm["comparisons"]:
            lines.append(f"- {arm['arm']}: fewer than two dated campaigns, nothing to compare yet")
    if not any_change:
        lines += ["", "No drift: no identified value moved beyond its interval between consecutive campaigns."]
    if figure:
        lines += ["", f"![Identified values over campaigns]({figure})"]
    for arm in fleet["arms"]:
        lines += ["", f"## {arm['arm']} ({arm['robot']})", ""]
        rung_labels: list[str] = []
        for c in arm["campaigns"]:
            for r in c["holdout"]["rungs"]:
                if r["label"] not in rung_labels:
                    rung_labels.append(r["label"])
        lines.append("| campaign | date | " + " | ".join(rung_labels) + " | noise floor | report |")
        lines.append("|---|---|" + "---|" * len(rung_labels) + "---|---|")
        for c in arm["campaigns"]:
            by_label = {r["label"]: r["torque_rmse"] for r in c["holdout"]["rungs"]}
            cells = [f"{by_label[label]:.3f}" if label in by_label else "–" for label in rung_labels]
            floor = c["holdout"]["noise_floor"]
            lines.append(f"| {c['campaign']} | {c['date'] or '–'} | " + " | ".join(cells)
                         + f" | {'–' if floor is None else f'{floor:.3f}'} | {c['report']} |")
        lines.append("")
        lines.append("Holdout torque RMSE [N·m] per rung of configs/" + arm["robot"] + "/model.yaml"
                     + (", body link." if any(c.get("actuator_holdout") for c in arm["campaigns"]) else "."))
        lines += _actuator_table(arm["campaigns"])
        rows = {}
        for c in arm["campaigns"]:
            for r in c["identified"]:
                rows.setdefault(_key(r), (r, {}))[1][c["campaign"]] = r
        if rows:
            lines += ["", "| identified value | unit | " + " | ".join(c["campaign"] for c in arm["campaigns"]) + " |",
                      "|---|---|" + "---|" * len(arm["campaigns"])]
            for key in sorted(rows):
                first, per = rows[key]
                label = f"{first['effect']}.{first['parameter']}{_where(first)}"
                cells = []
                for c in arm["campaigns"]:
                    r = per.get(c["campaign"])
                    cells.append("–" if r is None else
                                 f"{_num(r['value'])} [{_num(r['interval'][0])}, {_num(r['interval'][1])}]")
                lines.append(f"| {label} | {UNIT_TEXT.get(first['unit'], first['unit'])} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def figure_parameters(fleet: Mapping[str, Any], target: str | Path) -> None:
    """One panel per identified parameter over the campaign dates: colour = joint (or component),
    marker = arm, bars = intervals; values that changed (intervals apart) are ringed in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from sim2real.files import atomic_path

    dates = sorted({c["date"] for a in fleet["arms"] for c in a["campaigns"] if c["date"]})
    columns = (["undated"] if any(c["date"] is None for a in fleet["arms"] for c in a["campaigns"]) else []) + dates
    x_of = {d: i for i, d in enumerate(columns)}
    panels: dict[tuple[str, str], dict[tuple[str, str], list[tuple[float, float, float, float, bool]]]] = {}
    series_labels: list[str] = []
    for arm in fleet["arms"]:
        changed = {(c["to"], c["effect"], c["parameter"], c["joint"] or "", -1 if c["component"] is None else
                    c["component"]) for c in arm["changes"]}
        for c in arm["campaigns"]:
            x = float(x_of[c["date"] or "undated"])
            for r in c["identified"]:
                key = _key(r)
                label = key[2] + ("" if key[3] < 0 else f"[{key[3]}]") or key[1]
                if label not in series_labels:
                    series_labels.append(label)
                moved = (c["date"], *key) in changed
                panels.setdefault(key[:2], {}).setdefault((arm["arm"], label), []).append(
                    (x, r["value"], r["interval"][0], r["interval"][1], moved))
    arms = [a["arm"] for a in fleet["arms"]]
    markers = "osD^v<>phX*"
    n = max(1, len(panels))
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.4 * cols, 3.2 * rows + 0.6), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    if not panels:
        axes.flat[0].text(0.5, 0.5, "no identified values yet\n(configs/{robot}/model.yaml lists no effect)",
                          ha="center", va="center", fontsize=8)
        axes.flat[0].set_axis_off()
    units = _units()
    for ax, (panel, lines) in zip(axes.flat, sorted(panels.items())):
        for (arm, label), points in sorted(lines.items()):
            color = f"C{series_labels.index(label) % 10}"
            marker = markers[arms.index(arm) % len(markers)]
            xs = [p[0] for p in points]
            ys = [p[1] for p in points]
            err = [[max(0.0, p[1] - p[2]) for p in points], [max(0.0, p[3] - p[1]) for p in points]]
            ax.errorbar(xs, ys, yerr=err, marker=marker, ms=3.5, lw=0.8, capsize=2, color=color)
            for p in points:
                if p[4]:
                    ax.plot([p[0]], [p[1]], marker="o", ms=11, mfc="none", mec="red", mew=1.4)
        ax.set_xticks(range(len(columns)), columns, fontsize=7, rotation=30)
        ax.set_xlim(-0.5, len(columns) - 0.5)
        ax.set_title(f"{panel[0]}.{panel[1]}", fontsize=9)
        ax.set_ylabel(UNIT_TEXT.get(units.get(panel, ""), units.get(panel, "")), fontsize=8)
        ax.tick_params(labelsize=7)
    handles = [Line2D([], [], color=f"C{i % 10}", lw=1.5, label=label) for i, label in enumerate(series_labels)]
    handles += [Line2D([], [], color="black", lw=0, marker=markers[i % len(markers)], label=arm)
                for i, arm in enumerate(arms)]
    handles += [Line2D([], [], color="red", lw=0, marker="o", mfc="none", ms=9, label="changed")]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 8), fontsize=6, frameon=False)
    fig.suptitle("Identified values per campaign (bars: bootstrap intervals)", fontsize=10)
    fig.tight_layout(rect=(0, 0.12 if len(handles) > 8 else 0.07, 1, 1))
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)


def build_fleet(
    campaigns: Sequence[Mapping[str, Any]], fleet_json: str | Path, fleet_md: str | Path, figure: str | Path
) -> dict[str, Any]:
    """Files in, files out. ``campaigns``: ``robot``, ``campaign``, ``arm``, ``date``, ``measurements``,
    ``report`` (gap.md), ``ladder`` (sysid ladder.json path), ``params`` (sysid params.yaml path)."""
    import json

    from sim2real.files import relative_path, validate, write_json, write_text
    from sim2real.identification.formats import read_ladder, read_params

    loaded = []
    for item in campaigns:
        loaded.append({**item, "ladder": read_ladder(item["ladder"]), "params": read_params(item["params"])})
    fleet = fleet_document(loaded)
    fleet = json.loads(json.dumps(fleet))
    validate(fleet, "fleet.schema.json", "fleet.json")
    figure_parameters(fleet, figure)
    write_text(fleet_md, render_fleet_markdown(fleet, relative_path(figure, Path(fleet_md).parent)))
    write_json(fleet_json, fleet)
    return fleet
