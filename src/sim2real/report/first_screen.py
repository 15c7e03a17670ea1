"""The first screen of gap.md (:func:`first_screen`): the verdict in at most three sentences, the ladder, and the
current model joint by joint: what a reviewer reads in a pull request's file view without scrolling, and what the
Snakemake HTML report shows first (:meth:`FirstScreen.html`). Its words are :mod:`sim2real.report.verdicts`'."""

from __future__ import annotations

import html
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sim2real.identification.diagnosis.ceiling_records import ModelFreeCeiling
from sim2real.identification.diagnosis.result import JointStanding
from sim2real.identification.ladder_rows import Rung
from sim2real.report.gap_document import GapReport, LinkSection
from sim2real.report.verdicts import first_screen_verdict, left_text


def fmt(x: float | None, digits: int = 3) -> str:
    return "n/a" if x is None else f"{x:.{digits}g}"


def _inline_html(text: str) -> str:
    """A Markdown cell or sentence as HTML: escaped, its `code` and **bold** spans kept."""
    escaped = html.escape(text, quote=False)
    escaped = re.sub(r"`([^`]+)`", r"<code>\1</code>", escaped)
    return re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", escaped)


@dataclass(frozen=True)
class Table:
    """A table as gap.md and the HTML report write it."""

    head: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]

    def markdown(self) -> list[str]:
        return ["| " + " | ".join(self.head) + " |", "|" + "---|" * len(self.head),
                *("| " + " | ".join(row) + " |" for row in self.rows)]

    def html(self) -> str:
        head = "".join(f"<th>{_inline_html(h)}</th>" for h in self.head)
        rows = "".join("<tr>" + "".join(f"<td>{_inline_html(c)}</td>" for c in row) + "</tr>\n" for row in self.rows)
        return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n{rows}</tbody>\n</table>"


@dataclass(frozen=True)
class FirstScreen:
    """The title, the verdict's sentences, and two captioned tables: the ladder and the joints."""

    title: str
    verdict: tuple[str, ...]
    ladder_caption: str
    ladder: Table | None
    joints_caption: str
    joints: Table

    def markdown(self) -> list[str]:
        lines = [f"# {self.title}", ""]
        if self.verdict:
            lines += ["**Verdict.** " + " ".join(self.verdict), ""]
        if self.ladder is not None:
            lines += [self.ladder_caption, "", *self.ladder.markdown(), ""]
        return lines + [self.joints_caption, "", *self.joints.markdown(), ""]

    def html(self) -> str:
        parts = [f"<h1>{_inline_html(self.title)}</h1>"]
        if self.verdict:
            parts.append("<p><strong>Verdict.</strong> " + _inline_html(" ".join(self.verdict)) + "</p>")
        if self.ladder is not None:
            parts += [f"<p>{_inline_html(self.ladder_caption)}</p>", self.ladder.html()]
        parts += [f"<p>{_inline_html(self.joints_caption)}</p>", self.joints.html()]
        style = ("body{font-family:sans-serif;font-size:14px} table{border-collapse:collapse} "
                 "td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}")
        return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>" + _inline_html(self.title)
                + f"</title><style>{style}</style></head>\n<body>\n" + "\n".join(parts) + "\n</body></html>\n")


def ladder_table(ladder: Sequence[Rung], floor: float, unconstrained: bool) -> Table:
    """One link's ladder: holdout error per rung, its fall, against the floor (arm-wide: each joint x its own
    floor, and the worst joint), and the replay's position error."""
    first = ladder[0].metrics.torque_rmse["overall"]
    head = ("rung", "effects", "holdout torque RMSE [N m]", "change from nominal", "x noise floor (worst joint)",
            *(("unconstrained fit [N m]",) if unconstrained else ()), "replay position RMSE [rad]")
    rows = []
    for k, rung in enumerate(ladder):
        value = rung.metrics.torque_rmse["overall"]
        change = f"{100 * (value - first) / first:+.0f}%" if k and first else "–"
        position = (rung.metrics.position_rmse or {}).get("overall")
        x_floor = rung.metrics.torque_x_floor
        if x_floor:
            worst = max(x_floor["per_joint"], key=x_floor["per_joint"].get)
            ratio = f"{x_floor['overall']:.2f} ({worst} {x_floor['per_joint'][worst]:.2f})"
        else:
            ratio = f"{value / floor:.2f}"
        row = [str(k), ", ".join(rung.effects) or "nominal", f"{value:.3g}", change, ratio]
        if unconstrained:
            free = (rung.metrics.unconstrained_torque_rmse or {}).get("overall")
            physical = (rung.consistency or {}).get("unconstrained_physical")
            row.append(fmt(free) + (" (non-physical)" if physical is False else ""))
        rows.append((*row, fmt(position)))
    return Table(head, tuple(rows))


@dataclass(frozen=True)
class SideView:
    """One link as the first screen shows it: its diagnosis, ladder, noise floor, the current model's holdout RMSE per
    joint, and (the body link's) the nominal URDF's on the same runs."""

    name: str
    diagnosis: Mapping[str, Any] | None
    ladder: Sequence[Rung]
    floor: Mapping[str, Any]
    rmse: Mapping[str, float]
    nominal: Mapping[str, float] | None


def sides(gap: GapReport | Mapping[str, Any]) -> list[SideView]:
    """The report's links as the first screen may show them: the body link, then the actuator link where there is
    one."""
    gap = GapReport.of(gap)
    ladder = gap.ladder or ()
    nominal = ladder[0].metrics.torque_rmse["per_joint"] if gap.model else None
    sides = [SideView("body link", gap.diagnosis, ladder, gap.floor, gap.metrics["torque_rmse"]["per_joint"], nominal)]
    if gap.actuator is not None and gap.actuator.ladder:
        sides.append(actuator_view(gap.actuator))
    return sides


def actuator_view(link: LinkSection) -> SideView:
    """The actuator link (gap.json ``actuator``) as the report shows it, judged by its ladder's last rung."""
    return SideView("actuator link", link.diagnosis, link.ladder, link.floor,
                    link.ladder[-1].metrics.torque_rmse["per_joint"], None)


def leading_side(gap: GapReport | Mapping[str, Any]) -> SideView:
    """The link the first screen shows: the body link, or the actuator link where only it has something left."""
    links = sides(gap)
    for side in links:
        if side.diagnosis and side.diagnosis.get("status") != "at_noise_floor":
            return side
    return links[0]


def _floors(side: SideView) -> dict[str, tuple[float | None, float]]:
    """Each joint's (x its floor, the floor): the ladder's figure, measured against the floor of the holdout runs the
    ladder judges on (its RMSE over it, so that a row reads RMSE / floor = x floor); else the report's floor."""
    ladder_x = (side.ladder[-1].metrics.torque_x_floor or {}).get("per_joint") if side.ladder else None
    floors = side.floor["per_joint"]
    out: dict[str, tuple[float | None, float]] = {}
    for joint, value in side.rmse.items():
        x = ladder_x.get(joint) if ladder_x else None
        if x:
            out[joint] = (x, value / x)
        else:
            out[joint] = (value / floors[joint] if floors[joint] > 0 else None, floors[joint])
    return out


def joints_table(side: SideView) -> Table:
    """The current model joint by joint: its holdout RMSE, floor and x floor (the nominal URDF's beside it), what
    comes closest there and what it leaves, and what kind of thing is left (the model-free ceiling)."""
    floors = _floors(side)
    diagnosis = side.diagnosis or {}
    per_joint = {j: JointStanding.from_document(row) for j, row in (diagnosis.get("per_joint") or {}).items()}
    ceiling = ModelFreeCeiling.from_document(diagnosis["model_free"]) if diagnosis.get("model_free") else None
    head = ["joint", "RMSE [N m]", "noise floor [N m]", "x floor"]
    head += ["nominal URDF [N m]"] if side.nominal else []
    head += ["closest candidate there", "share of its excess removed", "x floor after"] if per_joint else []
    head += ["model-free ceiling [N m] (x floor)", "what is left"] if ceiling else []
    rows = []
    for joint, value in side.rmse.items():
        row = [joint, f"{value:.3g}", f"{floors[joint][1]:.3g}", fmt(floors[joint][0])]
        row += [f"{side.nominal[joint]:.3g}"] if side.nominal else []
        if per_joint:
            r = per_joint.get(joint)
            row += [r.closest or "none", f"{100 * r.closest_explained_beyond_noise:.0f}%",
                    fmt(r.closest_x_floor_after)] if r else ["–", "–", "–"]
        if ceiling:
            c = ceiling.per_joint.get(joint)
            row += [f"{c.ceiling_rmse:.3g} ({fmt(c.ceiling_x_floor)})", left_text(c)] if c else ["–", "–"]
        rows.append(tuple(row))
    return Table(tuple(head), tuple(rows))


def model_name(model: Mapping[str, Any]) -> str:
    """The current model as gap.md names it (gap.json ``metrics.model``)."""
    if not model["effects"]:
        return "the nominal URDF, no effect added yet"
    return f"rung {model['rung']}: the URDF + {', '.join(model['effects'])}"


def first_screen(gap: GapReport | Mapping[str, Any]) -> FirstScreen:
    """gap.md's first screen (the HTML report's too): the verdict of the leading link (:func:`leading_side`) in at most
    three sentences, its ladder, and the current model joint by joint."""
    gap = GapReport.of(gap)
    side = leading_side(gap)
    model = gap.model
    verdict: tuple[str, ...] = ()
    if side.diagnosis:
        floors = _floors(side)
        x_floor = {j: x for j, (x, _) in floors.items() if x is not None}
        verdict = tuple(first_screen_verdict(side.diagnosis, gap.robot, x_floor, side.rmse,
                                             {j: floor for j, (_, floor) in floors.items()}))
    ladder = ladder_table(side.ladder, side.floor["overall"], unconstrained=side.name == "body link") \
        if side.ladder else None
    caption = (f"**Model ladder** ({side.name}): the effects of configs/{gap.robot}/model.yaml added one by one, "
               "each rung fitted on the `fit` runs and judged on the `holdout` runs.")
    current = f"{model_name(model)}, on the holdout runs" if model else "the URDF, on every run"
    joints_caption = f"**Per joint**, {current} ({side.name}), each joint in units of its own noise floor:"
    return FirstScreen(f"Reality gap: {gap.robot}", verdict, caption, ladder, joints_caption, joints_table(side))
