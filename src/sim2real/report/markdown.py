"""gap.md: the first screen a reviewer reads in a pull request (:mod:`sim2real.report.first_screen`: the verdict, the
ladder, the current model joint by joint), then the diagnosis's reasons, where the model fails, the torque and state
domains, the inertias, the other link, the runs and the figures (:func:`render_gap_markdown`); long explanations in
collapsible ``<details>`` blocks, which GitHub renders."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sim2real.identification.diagnosis.ceiling_records import ModelFreeCeiling
from sim2real.identification.diagnosis.result import Candidate
from sim2real.identification.ladder_rows import Rung
from sim2real.measurements.runs import DEFAULT_TORQUE_SENSOR, SensorPlacement
from sim2real.report import details
from sim2real.report.first_screen import (
    SideView, actuator_view, first_screen, joints_table, ladder_table, leading_side, model_name, sides,
)
from sim2real.report.gap_document import GapReport, LinkSection
from sim2real.report.regimes import REGIME_LABELS
from sim2real.report.runs_section import runs_lines
from sim2real.report.verdicts import BOUND_TEXT, bounds_text, floor_sentences, not_judged_text

# Where the runs' tau is measured (run metadata `torque_sensor`), as gap.md says it.
SENSOR_TEXT = {
    SensorPlacement.MOTOR_SIDE: "The torque sensor is taken to be motor-side (run metadata `torque_sensor: motor`, "
    "the default): `tau` is the torque the drive applies, so the rotor inertia and joint friction are the body "
    "link's. If `tau` is measured after the gearbox (the Panda's tau_J), set `torque_sensor: link`.",
    SensorPlacement.LINK_SIDE: "The torque sensor is link-side (run metadata `torque_sensor: link`): `tau` is measured "
    "after the gearbox, so the rotor inertia and joint friction are expected between the command and `tau`, on the "
    "actuator link, and the body link to be the rigid body alone.",
}


def _fmt(x: float | None, digits: int = 3) -> str:
    return "n/a" if x is None else f"{x:.{digits}g}"


def _inertia_prior_text(prior: Any) -> str | None:
    """One sentence on the entropic prior's weight and how it was chosen (rung ``consistency.inertia_prior``)."""
    if not isinstance(prior, Mapping) or not isinstance(prior.get("weight"), (int, float)):
        return None
    text = (f"The inertial prior (the entropic pull of every link towards its CAD inertials) has weight "
            f"{prior['weight']:.3g}, chosen by {prior.get('chosen_by') or 'an unstated rule'}")
    grid, scores = prior.get("grid"), prior.get("scores")
    if isinstance(grid, Sequence) and grid and all(isinstance(g, (int, float)) for g in grid):
        if isinstance(scores, Sequence) and len(scores) == len(grid) and len(grid) <= 8 and all(
                isinstance(v, (int, float)) for v in scores):
            text += " among " + ", ".join(f"{g:.3g} (score {v:.3g})" for g, v in zip(grid, scores))
        else:
            text += f" among {len(grid)} weights from {min(grid):.3g} to {max(grid):.3g}"
    return text + "."


ILL_CONDITIONED = 1000.0  # a link-inertia condition number above this: the data pin the parameters poorly


def _identified_markdown(rung: Rung, robot: str) -> list[str]:
    """What the data identified of the link inertias (last rung): a richer excitation is needed when little;
    which bodies moved beyond plausible (a missing effect soaked up) and the CAD prior's weight."""
    link = rung.values.get("link_inertia")
    if not link:
        return []
    bodies = link.get("bodies", {})
    moved = [name for name, b in bodies.items() if b["moved"]]
    stayed = [name for name, b in bodies.items() if not b["moved"]]
    lines = ["", "### What the data identified (link inertias)", "",
             f"{link['base_parameters']} base parameters (identifiable combinations of the "
             f"{10 * len(bodies)} inertial parameters); condition number of the excitation "
             f"{link['condition_number']:.3g} (the scaled regressor's largest over smallest singular value on those "
             "directions: above ~1000 a richer excitation trajectory would pin them down better).", "",
             *([f"**These data pin the link inertias poorly** (condition number above {ILL_CONDITIONED:g}): record a "
                f"run designed for them, `snakemake results/{robot}/excitation/identification.csv` (a design of "
                f"configs/{robot}/excitation.yaml, optimised for this model within the arm's limits), and add it "
                "to the fit runs.", ""] if link["condition_number"] > ILL_CONDITIONED else []),
             f"Moved from the URDF: {', '.join(moved) or 'none'}. Stayed at the URDF values (not seen or not "
             f"needed by these data): {', '.join(stayed) or 'none'}.", ""]
    prior = _inertia_prior_text(rung.inertia_prior)
    if prior:
        lines += [prior, ""]
    lines += ["| body | moved | mass change [kg] | COM shift [mm] | divergence from CAD | plausible | held at |",
              "|---|---|---|---|---|---|---|"]
    for name, b in bodies.items():
        plausible = "; ".join(b["implausible"]) or "yes"
        held = ", ".join(BOUND_TEXT[k] for k in b["binding"]) or "–"
        lines.append(f"| {name} | {'yes' if b['moved'] else 'no'} | {b['mass_change_kg']:+.3g} | "
                     f"{b['com_shift_mm']:.3g} | {_fmt(b['divergence'])} | {plausible} | {held} |")
    held_at = {name: b["binding"] for name, b in bodies.items() if b.get("binding")}
    if held_at:
        lines += ["", f"**Held at their bounds:** {bounds_text(held_at)}. The fit holds every link inside its bands "
                  f"(mass around CAD, centre of mass inside the link's hull, divergence from CAD: `inertia_bands` in "
                  f"configs/{robot}/robot.yaml), and the data push these as far as the bands let them: something the "
                  "model lacks acts there like mass or a shifted centre of mass (friction, rotor inertia, a payload or "
                  "tool, a torque sensor's offset or gain...). Read the diagnosis, whose candidates are judged on "
                  "whether they release these bounds, before trusting these inertias."]
    flagged = ["{} ({})".format(name, ", ".join(b["implausible"])) for name, b in bodies.items() if b.get("implausible")]
    if flagged:
        lines += ["", f"**Moved beyond plausible:** {'; '.join(flagged)}. "
                  "Real links are rarely this far from their CAD: the fit is bending these inertias to soak up "
                  "an effect the model lacks (friction, rotor inertia, a payload or tool, a torque sensor's "
                  "offset or gain...). Read the diagnosis and the per-joint residuals, and add the missing effect, "
                  "before trusting these inertias or writing them into a calibrated URDF."]
    return lines


def _line_of(cand: Candidate) -> str:
    """What the candidate list says of a candidate's line: to add it (and the lines it replaces), or that it is
    withheld because its trial raises joints beyond the noise (diagnosis.raises), which and by how much."""
    raised = cand.evidence.raised
    if raised and not cand.kept_to:
        return "withheld: it raises " + ", ".join(
            f"{j} from {before:.2f}x to {after:.2f}x its floor" for j, (before, after) in raised.items())
    return f"add `{cand.add}`" + "".join(f", remove `- {r}`" for r in cand.replaces)


def _diagnosis_markdown(diagnosis: Mapping[str, Any], side: SideView | None = None) -> list[str]:
    """The three best candidates and their evidence, the effects not tried and why, the diagnosis's verdict in full and
    the model-free ceiling's reasoning (collapsed); joint by joint where the first screen does not show ``side``."""
    lines = []
    for cand in (Candidate.from_document(c) for c in diagnosis["candidates"][:3]):
        lines.append(f"- `{cand.effect}` on {', '.join(cand.joints) or 'no joint in particular'}: explains "
                     f"{100 * cand.explained:.0f}% of the residual ({100 * cand.explained_beyond_noise:.0f}% of what "
                     f"lies above the noise floor), holdout RMSE after {_fmt(cand.evidence.rmse_after)} N m "
                     f"({cand.evidence.x_floor_after:.2f}x the floor); " + _line_of(cand))
    lines += [""] if lines else []
    skipped = [f"- `{skip['effect']}` not tried: {skip['reason']}" for skip in diagnosis.get("skipped", [])]
    if skipped:
        lines += details("Effects not tried, and why", skipped)
    if side is not None:
        lines += joints_table(side).markdown() + [""]
    lines += details("The diagnosis in full (gap.json's verdict)", [diagnosis["verdict"]])
    ceiling = diagnosis.get("model_free")
    if ceiling:
        # The verdict holds the ceiling's reading where nothing is named: then only the learner is added here.
        reading = "" if ceiling.get("text") and ceiling["text"] in diagnosis["verdict"] else " " + (
            ceiling.get("text") or "Nothing is left above the floors that a function of the motion, the time or the "
            "history explains.")
        learner = ModelFreeCeiling.from_document(ceiling).learner
        lines += details("The model-free ceiling", [f"Model-free ceiling: {learner}.{reading}"])
    return lines


def _per_run_lines(effects: Sequence[str]) -> list[str]:
    """What gap.md says of a model's effects estimated on every run itself (a sensor's drift): its figures are of
    what is left once each run's own is removed."""
    from sim2real.identification.effects import get_effect
    from sim2real.identification.effects.sensor_drift import SHAPE

    per_run = [name for name in effects if get_effect(name).per_run]
    if not per_run:
        return []
    return [f"Each run's sensor drift (`{per_run[0]}`: {SHAPE}) is estimated on that "
            "run itself, the holdout runs included, and removed before judging: these figures are of what is left. "
            "The replay below never uses it.", ""]


def _where_nominal_text(where: Mapping[str, Any]) -> str:
    """One line on where the nominal URDF failed, for reference beside the current model."""
    if not where["findings"]:
        return "The nominal URDF's error stood out in no regime."
    return (f"For reference, the nominal URDF's error concentrated in "
            f"{', '.join(REGIME_LABELS[r] for r in where['summary']['regimes'])} on {', '.join(where['summary']['joints'])}.")


def render_gap_markdown(gap: GapReport | Mapping[str, Any], figures: Mapping[str, str]) -> str:
    """gap.md: the first screen (the verdict, the ladder, the current model joint by joint), then the rest."""
    gap = GapReport.of(gap)
    model = gap.model
    lines = first_screen(gap).markdown()
    if gap.not_judged is not None:
        lines += [not_judged_text(gap.not_judged), ""]
    shown = leading_side(gap).name
    if gap.diagnosis is not None:
        body = None if shown == "body link" else sides(gap)[0]  # its joints, where the first screen shows the other
        lines += ["## Diagnosis", ""] + _diagnosis_markdown(gap.diagnosis, body)
    lines += _where_lines(gap, model)
    lines += _torque_domain_lines(gap, model)
    lines += _state_domain_lines(gap, model)
    if gap.ladder is not None:
        lines += _ladder_lines(gap, figures["ladder"])
    if gap.actuator is not None:
        lines += _actuator_lines(gap.actuator, shown=shown == "actuator link")
    if gap.links is not None:
        lines += _links_lines(gap.links)
    lines += runs_lines(gap.runs or ())
    lines += _figures_lines(model, figures)
    return "\n".join(lines)


def _torque_domain_lines(gap: GapReport, model: Mapping[str, Any] | None) -> list[str]:
    """The torque domain: the current model's error against the noise floor (with the nominal URDF's, for
    reference, once a ladder calibrates it), then joint by joint what the per-joint table (on the first screen, or
    the diagnosis's where the first screen shows the other link) does not say."""
    m = gap.metrics
    floor = gap.floor
    nominal_rung = gap.ladder[0].metrics.torque_rmse if model and gap.ladder else None
    lines = ["", "## Torque domain (inverse dynamics on measured motion)", ""]
    if model:
        lines += [f"The model of configs/{gap.robot}/model.yaml ({model_name(model)}), judged on the holdout runs "
                  f"as the ladder judges it: RMSE **{m['torque_rmse']['overall']:.3g} N m** against a noise floor of "
                  f"{floor['overall']:.3g} N m; relative RMSE {m['torque_relative_rmse']['overall']:.3g}, "
                  f"R^2 {m['torque_r2']['overall']:.4g}.", "",
                  f"For reference, the nominal URDF: {nominal_rung['overall']:.3g} N m on the same runs "
                  f"({gap.nominal_metrics['torque_rmse']['overall']:.3g} N m over every run at the log's rate).", ""]
        lines += _per_run_lines(model["effects"])
    else:
        lines += [f"Overall RMSE **{m['torque_rmse']['overall']:.3g} N m** against a noise floor of "
                  f"{floor['overall']:.3g} N m; relative RMSE {m['torque_relative_rmse']['overall']:.3g}, "
                  f"R^2 {m['torque_r2']['overall']:.4g}.", ""]
    lines += [" ".join(floor_sentences(gap.noise_floor)), ""]
    return lines + _torque_table(gap.joints, m)


def _torque_table(joints: Sequence[str], m: Mapping[str, Any]) -> list[str]:
    """Each joint's relative torque error and R^2 (its N m and x its own floor are the per-joint table's)."""
    lines = ["Each joint is judged in its own units, x its own noise floor: a wrist residual 8x its floor weighs "
             "what a shoulder residual 8x its floor weighs, although its N m are ten times smaller.", "",
             "| joint | relative RMSE | R^2 |", "|---|---|---|"]
    for j in joints:
        lines.append(f"| {j} | {m['torque_relative_rmse']['per_joint'][j]:.3g} | {m['torque_r2']['per_joint'][j]:.4g} |")
    return lines


def _state_domain_lines(gap: GapReport, model: Mapping[str, Any] | None) -> list[str]:
    """The replay of the commanded torques: skipped and why, or its errors, score and fidelity, joint by joint."""
    sd = gap.metrics["state_domain"]
    lines = ["", "## State domain (replay of the commanded torques)", ""]
    if sd["status"] == "skipped":
        lines.append(f"Skipped: {sd['reason']}.")
        return lines
    g = sd["reality_gap"]
    if model:
        lines += [f"The commands of the holdout runs replayed on {model_name(model)}, its fitted effects "
                  "written into the MJCF."]
        nominal_sd = gap.nominal_metrics["state_domain"]
        if nominal_sd.get("status") == "computed":
            lines[-1] += (f" The nominal MJCF, for reference: position RMSE {nominal_sd['position_rmse']['overall']:.3g}"
                          f" rad, reality-gap score {nominal_sd['reality_gap']['score']:.3f}.")
        lines.append("")
    lines += [f"Multiple shooting, reset to the measured state every {sd['horizon_s']:g} s. "
              f"Position RMSE {sd['position_rmse']['overall']:.3g} rad, velocity RMSE "
              f"{sd['velocity_rmse']['overall']:.3g} rad/s, correlation {sd['correlation']['overall']:.4g}, "
              f"spectral divergence {sd['spectral_divergence']:.3g}; {sd['contact_note']}.", "",
              f"Reality-gap score **{g['score']:.3f}** ({g['grade'].replace('_', ' ')} gap), "
              f"fidelity **{sd['fidelity']}** (mean joint error {sd['mean_abs_position_error']:.3g} rad). "
              f"Recommendation: {g['recommendation']}.", "",
              "| joint | position RMSE [rad] | velocity RMSE [rad/s] | correlation |", "|---|---|---|---|"]
    for j in gap.joints:
        lines.append(f"| {j} | {sd['position_rmse']['per_joint'][j]:.3g} | "
                     f"{sd['velocity_rmse']['per_joint'][j]:.3g} | {sd['correlation']['per_joint'][j]:.4g} |")
    return lines


def _where_lines(gap: GapReport, model: Mapping[str, Any] | None) -> list[str]:
    """Where the model fails: the regimes and joints its error concentrates in, and the worst time windows."""
    w = gap.where
    lines = ["", "## Where the model fails", ""]
    if model:
        lines += [f"The model of model.yaml ({model_name(model)}) on the holdout runs. "
                  + _where_nominal_text(gap.nominal_where), ""]
    if w["findings"]:
        lines.append(f"The error concentrates in **{', '.join(REGIME_LABELS[r] for r in w['summary']['regimes'])}** "
                     f"on **{', '.join(w['summary']['joints'])}**:")
        lines += ["", "| joint | regime | step [N m] | explained |", "|---|---|---|---|"]
        for fnd in w["findings"]:
            lines.append(f"| {fnd['joint']} | {fnd['label']} | {fnd['step']:.3g} | {fnd['explained']:.2f} |")
    else:
        lines.append("No regime stands out: the residual is not concentrated in slow motion, hard accelerations, "
                     "gravity-loaded poses or near the limits.")
    lines += ["", "Worst time windows:", "", "| run | from [s] | to [s] | RMSE [N m] | worst joint |",
              "|---|---|---|---|---|"]
    for win in w["worst_windows"]:
        lines.append(f"| {win['run']} | {win['t_start']:.2f} | {win['t_end']:.2f} | {win['rmse']:.3g} | "
                     f"{win['worst_joint']} ({win['worst_joint_rmse']:.3g}) |")
    return lines


def _ladder_lines(gap: GapReport, figure: str) -> list[str]:
    """The body link's ladder beyond its table (on the first screen): the rungs' physical-consistency notes, what the
    data identified of the link inertias, and its figure."""
    separate = (gap.links or {}).get("mode") == "separate"
    lines = ["", "## Model ladder" + (" (body link: measured torque against the motion)" if separate else ""), "",
             "Each rung is the physically consistent fit (every body's pseudo-inertia positive definite, "
             "friction, damping and armature >= 0); the unconstrained column of the ladder is the same rung without "
             "those constraints, for comparison."]
    ladder = gap.ladder
    if leading_side(gap).name != "body link":
        lines += ["", *ladder_table(ladder, gap.floor["overall"], True).markdown()]
    for k, rung in enumerate(ladder):
        for note in rung.notes:
            if note.startswith("physical consistency"):
                lines += ["", f"**Rung {k}:** {note}."]
    lines += _identified_markdown(ladder[-1], gap.robot)
    return lines + ["", f"![Model ladder]({figure})"]


def _actuator_lines(link: LinkSection, shown: bool) -> list[str]:
    """The actuator link: what it judges, its floor, its ladder and its diagnosis (``shown``: its ladder and joints
    are on the first screen)."""
    link_floor = link.floor["overall"]
    lines = ["", "## Actuator link (measured against commanded torque)", "",
             f"The {link.judged}. Noise floor {link_floor:.3g} N m: the sensor's white noise, what no "
             "filter of the command explains. Replay: the commands replayed in MuJoCo on the body link's "
             "last rung with each actuator rung's effects.", ""]
    side = None if shown else actuator_view(link)
    if side is not None:
        lines += ladder_table(side.ladder, link_floor, unconstrained=False).markdown()
    return lines + ["", "### Diagnosis of the actuator link", ""] + _diagnosis_markdown(link.diagnosis, side)


def _links_lines(links: Mapping[str, Any]) -> list[str]:
    """What these runs can tell apart: the sensor's placement, a contradiction of the metadata, the lines kept on
    one link, and each pair of effects told apart or not."""
    lines = ["", "## What these runs can tell apart", "", f"{links['text'][0].upper()}{links['text'][1:]}.", ""]
    if links["mode"] != "commands_only":
        lines += [SENSOR_TEXT[links.get("torque_sensor", DEFAULT_TORQUE_SENSOR)], ""]
    if links.get("metadata_note"):
        lines += [f"**The data contradict the metadata:** {links['metadata_note']}", ""]
    if links.get("kept_on"):
        lines += ["Kept on one link by model.yaml (neither fitted nor tried on the other): " + ", ".join(
            f"`{name}` on the {link} link" for name, link in links["kept_on"].items()) + ".", ""]
    for fact in links["can_tell"]:
        lines.append(f"- Told apart: {', '.join(f'`{e}`' for e in fact['effects'])}: {fact['why']}.")
    for fact in links["cannot_tell"]:
        lines.append(f"- **Not told apart:** {', '.join(f'`{e}`' for e in fact['effects'])}: {fact['why']}.")
    return lines


def _figures_lines(model: Mapping[str, Any] | None, figures: Mapping[str, str]) -> list[str]:
    """The figures of the current model (the ladder's is in its section)."""
    lines = ["", "## Figures", ""]
    if model:
        lines += [f"The model of model.yaml ({model_name(model)}) on the holdout runs.", ""]
    return lines + [f"![Measured vs model torque]({figures['torque']})", "",
                    f"![Residual vs velocity]({figures['residual_velocity']})", "",
                    f"![Residual vs time]({figures['residual_time']})", "",
                    f"![Error by regime]({figures['regimes']})", ""]
