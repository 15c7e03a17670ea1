"""Figures and Markdown of the gap report (results/{robot}/gap.md), reproducible byte for byte."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.files import atomic_path
from sim2real.regimes import REGIME_LABELS, REGIMES

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PNG_METADATA = {"Software": None}
MAX_PLOT_S = 10.0
SCATTER_POINTS = 2500

# Where the runs' tau is measured (run metadata `torque_sensor`), as gap.md says it.
SENSOR_TEXT = {
    "motor": "The torque sensor is taken to be motor-side (run metadata `torque_sensor: motor`, the default): "
    "`tau` is the torque the drive applies, so the rotor inertia and joint friction are the body link's. "
    "If `tau` is measured after the gearbox (the Panda's tau_J), set `torque_sensor: link`.",
    "link": "The torque sensor is link-side (run metadata `torque_sensor: link`): `tau` is measured after the "
    "gearbox, so the rotor inertia and joint friction are expected between the command and `tau`, on the actuator "
    "link, and the body link to be the rigid body alone.",
}


def _pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend, imported when a figure is drawn (~0.3 s; the Markdown needs none)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Figure, target: str | Path) -> None:
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=90, metadata=PNG_METADATA)
    _pyplot().close(fig)


def _grid(n: int) -> tuple[Figure, np.ndarray]:
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    fig, axes = _pyplot().subplots(rows, cols, figsize=(3.6 * cols, 2.6 * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, axes.flat


def _pick_run(comparisons: Sequence[Any]) -> Any:
    holdout = [c for c in comparisons if c.role == "holdout"]
    return (holdout or list(comparisons))[0]


def figure_torque(comparisons: Sequence[Any], target: str | Path) -> None:
    """Measured vs model torque per joint (first holdout run, first seconds)."""
    c = _pick_run(comparisons)
    run = c.run
    n_show = min(run.time.size, int(MAX_PLOT_S / run.dt))
    stride = max(1, n_show // 2000)  # a line of 2000 points per joint reads the same and draws fast
    t = run.time[:n_show:stride]
    fig, axes = _grid(len(run.joint_names))
    for j, (ax, joint) in enumerate(zip(axes, run.joint_names)):
        ax.plot(t, run.tau[:n_show:stride, j], lw=0.6, color="0.35", label=f"measured ({run.torque_source})")
        ax.plot(t, c.model_tau[:n_show:stride, j], lw=0.9, color="C3", label="model")
        ax.set_title(joint, fontsize=9)
        ax.set_xlabel("time [s]", fontsize=8)
        ax.set_ylabel("torque [N m]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Measured vs model torque, run '{run.name}'", fontsize=10)
    fig.tight_layout()
    _save(fig, target)


def figure_residual_velocity(comparisons: Sequence[Any], target: str | Path) -> None:
    """Torque residual against joint velocity: friction shows as a step at zero velocity."""
    qd = np.concatenate([c.run.qd for c in comparisons])
    res = np.concatenate([c.residual for c in comparisons])
    step = max(1, qd.shape[0] // SCATTER_POINTS)
    joints = comparisons[0].run.joint_names
    fig, axes = _grid(len(joints))
    for j, (ax, joint) in enumerate(zip(axes, joints)):
        ax.scatter(qd[::step, j], res[::step, j], s=1.5, color="C0", alpha=0.5, rasterized=True)
        ax.axhline(0, color="0.5", lw=0.5)
        ax.axvline(0, color="0.5", lw=0.5)
        ax.set_title(joint, fontsize=9)
        ax.set_xlabel("velocity [rad/s]", fontsize=8)
        ax.set_ylabel("residual [N m]", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.suptitle("Torque residual (measured - model) vs velocity", fontsize=10)
    fig.tight_layout()
    _save(fig, target)


SMOOTH_S = 1.0  # the residual against time is drawn with its moving mean over this window: a drift shows


def figure_residual_time(comparisons: Sequence[Any], target: str | Path) -> None:
    """Torque residual against time within each run, with its moving mean: a warm-up or a drifting offset shows
    as a slow trend, an offset between runs as lines at different heights."""
    joints = comparisons[0].run.joint_names
    fig, axes = _grid(len(joints))
    for k, c in enumerate(comparisons):
        t = c.run.time - c.run.time[0]
        window = max(1, int(round(SMOOTH_S / c.run.dt))) if c.run.dt > 0 else 1
        stride = max(1, t.size // 1000)
        kernel = np.ones(window) / window
        for j, ax in enumerate(axes[: len(joints)]):
            ax.plot(t[::stride], c.residual[::stride, j], lw=0.4, alpha=0.35, color=f"C{k % 10}")
            if t.size >= window:
                mean = np.convolve(c.residual[:, j], kernel, mode="valid")
                ax.plot(t[window // 2: window // 2 + mean.size][::stride], mean[::stride], lw=1.4, color=f"C{k % 10}",
                        label=f"{c.run.name} ({c.role})")
    for ax, joint in zip(axes, joints):
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_title(joint, fontsize=9)
        ax.set_xlabel("time in run [s]", fontsize=8)
        ax.set_ylabel("residual [N m]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=6)
    fig.suptitle(f"Torque residual (measured - model) against time, {SMOOTH_S:g} s moving mean", fontsize=10)
    fig.tight_layout()
    _save(fig, target)


def figure_regimes(gap: Mapping[str, Any], target: str | Path) -> None:
    """Per joint and regime: the residual step between the regime's two sides, against the noise floor."""
    joints = gap["joints"]
    per_joint = gap["where"]["per_joint"]
    x = np.arange(len(joints))
    width = 0.8 / (len(REGIMES) + 1)
    fig, ax = _pyplot().subplots(figsize=(max(6.0, 1.1 * len(joints)), 3.4))
    rmse = [per_joint[j]["rmse"] for j in joints]
    ax.bar(x - 0.4 + width / 2, rmse, width, color="0.6", label="overall RMSE")
    for k, regime in enumerate(REGIMES):
        steps = [per_joint[j]["regimes"][regime].get("step", 0.0) for j in joints]
        ax.bar(x - 0.4 + width * (k + 1.5), steps, width, label=f"step: {REGIME_LABELS[regime]}", color=f"C{k}")
    floor = [per_joint[j]["noise_floor"] for j in joints]
    ax.scatter(x, floor, marker="_", s=300, color="k", label="noise floor", zorder=3)
    ax.set_xticks(x, [j.replace("_joint", "\n") for j in joints], fontsize=7)
    ax.set_ylabel("N m", fontsize=8)
    ax.legend(fontsize=6, ncol=2)
    ax.set_title("Error by regime: residual step between the regime's two sides", fontsize=10)
    fig.tight_layout()
    _save(fig, target)


def _rung_label(effects: Sequence[str]) -> str:
    return "nominal" if not effects else "+ " + effects[-1]


def figure_ladder(gap: Mapping[str, Any], target: str | Path) -> None:
    """Holdout torque RMSE rung by rung (overall and per joint) against the noise floor."""
    ladder = gap.get("ladder") or [
        {"effects": [], "metrics": {"torque_rmse": gap["metrics"]["torque_rmse"]}}
    ]
    floor = gap["noise_floor"]["torque_rmse"]
    x = np.arange(len(ladder))
    fig, ax = _pyplot().subplots(figsize=(max(4.5, 1.6 * len(ladder) + 2.5), 3.4))
    for j, joint in enumerate(gap["joints"]):
        per_joint = [rung["metrics"]["torque_rmse"]["per_joint"][joint] for rung in ladder]
        ax.plot(x, per_joint, marker=".", lw=0.8, alpha=0.6, color=f"C{j % 10}", label=joint)
    overall = [rung["metrics"]["torque_rmse"]["overall"] for rung in ladder]
    ax.plot(x, overall, marker="o", lw=2.2, color="black", label="overall")
    ax.axhline(floor["overall"], color="black", ls="--", lw=1.0, label="noise floor (overall)")
    ax.set_xticks(x, [_rung_label(rung["effects"]) for rung in ladder], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("holdout torque RMSE [N m]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6, ncol=2, loc="upper right")
    ax.set_title("Model ladder: the error falls as effects are added", fontsize=10)
    fig.tight_layout()
    _save(fig, target)


def _draw(name: str, gap: Mapping[str, Any], comparisons: Sequence[Any], figures: Mapping[str, str | Path]) -> bytes:
    """One figure of :class:`GapFigures` by its key; its PNG's bytes."""
    if name == "torque":
        figure_torque(comparisons, figures[name])
    elif name == "residual_velocity":
        figure_residual_velocity(comparisons, figures[name])
    elif name == "residual_time":
        figure_residual_time(comparisons, figures[name])
    elif name == "regimes":
        figure_regimes(gap, figures[name])
    else:
        figure_ladder(gap, figures[name])
    return Path(figures[name]).read_bytes()


FIGURES = ("torque", "residual_velocity", "residual_time", "regimes", "ladder")


def _figure_inputs(name: str, gap: Mapping[str, Any], comparisons: Sequence[Any] | None) -> Any:
    """What the figure ``name`` is drawn from (:func:`_draw`): the same inputs draw the same bytes; None while
    part of it is not known yet (:meth:`GapFigures.show`)."""
    if name in ("torque", "residual_velocity", "residual_time"):
        if comparisons is None:
            return None
        if name == "residual_time":
            return [(c.run.name, c.role, c.run.time, c.run.dt, c.residual, c.run.joint_names) for c in comparisons]
        return (_pick_run(comparisons) if name == "torque"
                else [(c.run.qd, c.residual, c.run.joint_names) for c in comparisons])
    if name == "regimes":
        return (gap["joints"], gap["where"]["per_joint"]) if "where" in gap else None
    if gap.get("ladder"):
        shown: Any = [(rung["effects"], rung["metrics"]["torque_rmse"]) for rung in gap["ladder"]]
    elif "metrics" in gap:
        shown = gap["metrics"]["torque_rmse"]  # no ladder: the nominal model's error alone
    else:
        return None
    return gap["joints"], shown, gap["noise_floor"]["torque_rmse"]


def _draw_all(names: Sequence[str], gap: Mapping[str, Any], comparisons: Sequence[Any] | None,
              figures: Mapping[str, str | Path]) -> list[bytes]:
    return [_draw(name, gap, comparisons, figures) for name in names]


class GapFigures:
    """The four figures of a gap report (:data:`FIGURES`), each drawn as soon as what it shows is known
    (:meth:`show`): the ladder's from the ladder and the noise floor, the others from the torque domain, all
    before the replays. On ``workers`` > 1 they are drawn by forked processes while the report goes on;
    :meth:`finish` waits for them. ``cache``: a :class:`sim2real.cache.FitCache` holding the figures of an
    earlier report: a figure drawn from the same inputs is written from it instead of drawn (same bytes)."""

    def __init__(self, figures: Mapping[str, str | Path], workers: int = 1, cache: Any = None) -> None:
        from sim2real.cache import FitCache

        self.cache = cache or FitCache(None)
        self.figures = figures
        self.workers = max(1, int(workers))
        self.keys: dict[str, str] = {}
        self.kept: dict[str, tuple[Any] | None] = {}
        self.drawing: list[tuple[list[str], Callable[[], list[bytes]]]] = []

    def show(self, gap: Mapping[str, Any], comparisons: Sequence[Any] | None = None) -> None:
        """Start every figure not started yet whose inputs ``gap`` (the report so far) and ``comparisons`` hold."""
        from importlib.metadata import version

        from sim2real.forked import Forked

        ready = []
        for name in FIGURES:
            inputs = None if name in self.keys else _figure_inputs(name, gap, comparisons)
            if inputs is not None:
                self.keys[name] = self.cache.key(name, inputs, version("matplotlib"))
                self.kept[name] = self.cache.get("figure", self.keys[name])
                if self.kept[name] is None:
                    ready.append(name)
        if self.workers > 1:
            # the two time-series grids in different processes: they take the longest
            for group in (ready[k::self.workers] for k in range(min(self.workers, len(ready)))):
                self.drawing.append((group, Forked(_draw_all, group, gap, comparisons, self.figures).result))
        elif ready:
            pngs = _draw_all(ready, gap, comparisons, self.figures)
            self.drawing.append((ready, lambda: pngs))

    def finish(self) -> None:
        """Wait for the figures being drawn, keep them, and write those read back from the cache."""
        from sim2real.files import write_bytes

        assert set(self.keys) == set(FIGURES), f"figures never shown: {sorted(set(FIGURES) - set(self.keys))}"
        for group, drawn in self.drawing:
            for name, png in zip(group, drawn(), strict=True):
                self.cache.put("figure", self.keys[name], png)
        for name, found in self.kept.items():
            if found is not None:
                write_bytes(self.figures[name], found[0])


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


def _identified_markdown(rung: Mapping[str, Any], robot: str) -> list[str]:
    """What the data identified of the link inertias (last rung): a richer excitation is needed when little;
    which bodies moved beyond plausible (a missing effect soaked up) and the CAD prior's weight."""
    link = rung.get("params", {}).get("link_inertia")
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
    prior = _inertia_prior_text((rung.get("consistency") or {}).get("inertia_prior"))
    if prior:
        lines += [prior, ""]
    lines += ["| body | moved | mass change [kg] | COM shift [mm] | divergence from CAD | plausible |",
              "|---|---|---|---|---|---|"]
    for name, b in bodies.items():
        # Documents written before the plausibility checks have no "implausible" key: n/a.
        reasons = b.get("implausible")
        plausible = "n/a" if reasons is None else "; ".join(reasons) if reasons else "yes"
        lines.append(f"| {name} | {'yes' if b['moved'] else 'no'} | {b['mass_change_kg']:+.3g} | "
                     f"{b['com_shift_mm']:.3g} | {_fmt(b['divergence'])} | {plausible} |")
    flagged = ["{} ({})".format(name, ", ".join(b["implausible"])) for name, b in bodies.items() if b.get("implausible")]
    if flagged:
        lines += ["", f"**Moved beyond plausible:** {'; '.join(flagged)}. "
                  "Real links are rarely this far from their CAD: the fit is bending these inertias to soak up "
                  "an effect the model lacks (friction, rotor inertia, a payload or tool, a torque sensor's "
                  "offset or gain...). Read the diagnosis and the per-joint residuals, and add the missing effect, "
                  "before trusting these inertias or writing them into a calibrated URDF."]
    return lines


def _ladder_table(ladder: Sequence[Mapping[str, Any]], floor: float, unconstrained: bool) -> list[str]:
    """One link's ladder: holdout error per rung, its fall, against the floor (arm-wide: each joint x its own
    floor, and the worst joint), and the replay's position error."""
    first = ladder[0]["metrics"]["torque_rmse"]["overall"]
    head = "| rung | effects | holdout torque RMSE [N m] | change from nominal | x noise floor (worst joint) | "
    head += "unconstrained fit [N m] | " if unconstrained else ""
    lines = [head + "replay position RMSE [rad] |", "|---|---|---|---|---|" + ("---|" if unconstrained else "") + "---|"]
    for k, rung in enumerate(ladder):
        value = rung["metrics"]["torque_rmse"]["overall"]
        change = f"{100 * (value - first) / first:+.0f}%" if k and first else "–"
        position = rung["metrics"].get("position_rmse", {}).get("overall")
        x_floor = rung["metrics"].get("torque_x_floor")
        if x_floor:
            worst = max(x_floor["per_joint"], key=x_floor["per_joint"].get)
            ratio = f"{x_floor['overall']:.2f} ({worst} {x_floor['per_joint'][worst]:.2f})"
        else:
            ratio = f"{value / floor:.2f}"
        row = f"| {k} | {', '.join(rung['effects']) or 'nominal'} | {value:.3g} | {change} | {ratio} | "
        if unconstrained:
            free = rung["metrics"].get("unconstrained_torque_rmse", {}).get("overall")
            physical = rung.get("consistency", {}).get("unconstrained_physical")
            row += _fmt(free) + (" (non-physical)" if physical is False else "") + " | "
        lines.append(row + f"{_fmt(position)} |")
    return lines


def _diagnosis_markdown(diagnosis: Mapping[str, Any]) -> list[str]:
    """The verdict, the three best candidates and the effects not tried, with why."""
    lines = [diagnosis["verdict"], ""]
    for cand in diagnosis["candidates"][:3]:
        beyond = cand.get("explained_beyond_noise")
        beyond_text = f" ({100 * beyond:.0f}% of what lies above the noise floor)" if beyond is not None else ""
        after = cand["evidence"].get("x_floor_after")
        lines.append(f"- `{cand['effect']}` on {', '.join(cand['joints']) or 'no joint in particular'}: explains "
                     f"{100 * cand['explained']:.0f}% of the residual{beyond_text}, holdout RMSE after "
                     f"{_fmt(cand['evidence'].get('rmse_after'))} N m"
                     + (f" ({after:.2f}x the floor)" if after is not None else "") + f"; add `{cand['add']}`")
    for skip in diagnosis.get("skipped", []):
        lines.append(f"- `{skip['effect']}` not tried: {skip['reason']}")
    per_joint = diagnosis.get("per_joint")
    ceiling = diagnosis.get("model_free")
    if per_joint and (diagnosis.get("status") != "at_noise_floor" or ceiling):
        # Joint by joint: how far above its own floor each joint sits, what comes closest there, and how far any
        # function of the motion would go (the model-free ceiling).
        head = "| joint | x its noise floor | closest candidate there | share of its excess removed | x floor after |"
        rule = "|---|---|---|---|---|"
        if ceiling:
            head += " model-free ceiling [N m] (x floor) | what is left |"
            rule += "---|---|"
        lines += ["", head, rule]
        for joint, row in per_joint.items():
            line = (f"| {joint} | {row['x_floor']:.2f} | {row['closest'] or 'none'} | "
                    f"{100 * row['closest_explained_beyond_noise']:.0f}% | {row['closest_x_floor_after']:.2f} |")
            if ceiling:
                c = ceiling["per_joint"][joint]
                line += f" {c['ceiling_rmse']:.3g} ({_fmt(c.get('ceiling_x_floor'))}) | {_left_text(c)} |"
            lines.append(line)
        if ceiling:
            lines += ["", f"Model-free ceiling: {ceiling['learner']}. " + (ceiling["text"] or
                      "Nothing is left above the floors that a function of the motion, the time or the history explains.")]
    return lines


LEFT_TEXT = {"at_floor": "at its floor", "motion": "a function of the motion the library lacks"}
FOLLOWS_TEXT = {"time": "not the motion: drifts with time", "run": "not the motion: an offset per run",
                "history": "not the motion: follows the history since a reversal", None: "not the motion, nor time"}


def _left_text(row: Mapping[str, Any]) -> str:
    """What kind of thing is left on a joint (the ceiling's ``kind`` and ``follows``), in a few words."""
    if row["kind"] == "motion":
        with_ = row.get("gains_most_with") or []
        return LEFT_TEXT["motion"] + (f" ({', '.join(with_)})" if with_ else "")
    return LEFT_TEXT.get(row["kind"]) or FOLLOWS_TEXT[row.get("follows")]


def _model_name(model: Mapping[str, Any]) -> str:
    """The current model as gap.md names it (gap.json ``metrics.model``)."""
    if not model["effects"]:
        return "the nominal URDF, no effect added yet"
    return f"rung {model['rung']}: the URDF + {', '.join(model['effects'])}"


def _where_nominal_text(where: Mapping[str, Any]) -> str:
    """One line on where the nominal URDF failed, for reference beside the current model."""
    if not where["findings"]:
        return "The nominal URDF's error stood out in no regime."
    return (f"For reference, the nominal URDF's error concentrated in "
            f"{', '.join(REGIME_LABELS[r] for r in where['summary']['regimes'])} on {', '.join(where['summary']['joints'])}.")


def render_gap_markdown(gap: Mapping[str, Any], figures: Mapping[str, str]) -> str:
    """gap.md: numbers a reviewer reads in a pull request, then the figures."""
    joints = gap["joints"]
    m = gap["metrics"]
    floor = gap["noise_floor"]["torque_rmse"]
    lines = [f"# Reality gap: {gap['robot']}", ""]
    lines += ["## Runs", "", "| run | role | torque judged | samples | duration [s] | commands |",
              "|---|---|---|---|---|---|"]
    for r in gap["runs"]:
        lines.append(f"| {r['name']} | {r['role']} | `{r['torque_source']}` | {r['samples']} | "
                     f"{r['duration_s']:.2f} | {'yes' if r['has_commands'] else 'no'} |")
    f = gap["runs"][0]["filter"]
    lines += ["", f"Preparation: {f['resampling']} at {f['resampled_to_hz']:g} Hz "
              f"(raw steps {f['raw_step_ms']['min']:.2f}-{f['raw_step_ms']['max']:.2f} ms, "
              f"{f['repeated_samples_dropped']} repeated samples dropped); q filtered by a {f['type']}, "
              f"order {f['order']}, cutoff {f['cutoff_hz']:g} Hz; velocity: {f['velocity']}; "
              f"acceleration: {f['acceleration']}; {f['applied_to']}; "
              f"{f['trimmed_s_each_end']:g} s trimmed at each end.", ""]
    model = m.get("model")
    nominal_rung = gap["ladder"][0]["metrics"]["torque_rmse"] if model and gap.get("ladder") else None
    lines += ["## Torque domain (inverse dynamics on measured motion)", ""]
    if model:
        lines += [f"The model of configs/{gap['robot']}/model.yaml ({_model_name(model)}), judged on the holdout runs "
                  f"as the ladder judges it: RMSE **{m['torque_rmse']['overall']:.3g} N m** against a noise floor of "
                  f"{floor['overall']:.3g} N m; relative RMSE {m['torque_relative_rmse']['overall']:.3g}, "
                  f"R^2 {m['torque_r2']['overall']:.4g}.", "",
                  f"For reference, the nominal URDF: {nominal_rung['overall']:.3g} N m on the same runs "
                  f"({gap['nominal']['metrics']['torque_rmse']['overall']:.3g} N m over every run at the log's rate).", ""]
    else:
        lines += [f"Overall RMSE **{m['torque_rmse']['overall']:.3g} N m** against a noise floor of "
                  f"{floor['overall']:.3g} N m; relative RMSE {m['torque_relative_rmse']['overall']:.3g}, "
                  f"R^2 {m['torque_r2']['overall']:.4g}.", ""]
    lines += ["Each joint is judged in its own units, x its own noise floor: a wrist residual 8x its floor weighs "
              "what a shoulder residual 8x its floor weighs, although its N m are ten times smaller.", "",
              "| joint | RMSE [N m] | noise floor [N m] | x floor | relative RMSE | R^2 |"
              + (" nominal URDF [N m] |" if nominal_rung else ""),
              "|---|---|---|---|---|---|" + ("---|" if nominal_rung else "")]
    for j in joints:
        value, noise = m["torque_rmse"]["per_joint"][j], floor["per_joint"][j]
        lines.append(f"| {j} | {value:.3g} | {noise:.3g} | {_fmt(value / noise if noise > 0 else None)} | "
                     f"{m['torque_relative_rmse']['per_joint'][j]:.3g} | {m['torque_r2']['per_joint'][j]:.4g} |"
                     + (f" {nominal_rung['per_joint'][j]:.3g} |" if nominal_rung else ""))
    sd = m["state_domain"]
    lines += ["", "## State domain (replay of the commanded torques)", ""]
    if sd["status"] == "skipped":
        lines.append(f"Skipped: {sd['reason']}.")
    else:
        g = sd["reality_gap"]
        if model:
            lines += [f"The commands of the holdout runs replayed on {_model_name(model)}, its fitted effects "
                      "written into the MJCF."]
            nominal_sd = gap["nominal"]["metrics"]["state_domain"]
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
        for j in joints:
            lines.append(f"| {j} | {sd['position_rmse']['per_joint'][j]:.3g} | "
                         f"{sd['velocity_rmse']['per_joint'][j]:.3g} | {sd['correlation']['per_joint'][j]:.4g} |")
    w = gap["where"]
    lines += ["", "## Where the model fails", ""]
    if model:
        lines += [f"The model of model.yaml ({_model_name(model)}) on the holdout runs. "
                  + _where_nominal_text(gap["nominal"]["where"]), ""]
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
    if "ladder" in gap:
        separate = gap.get("links", {}).get("mode") == "separate"
        lines += ["", "## Model ladder" + (" (body link: measured torque against the motion)" if separate else ""), "",
                  "Effects of configs/{robot}/model.yaml added one by one, each rung fitted on the `fit` runs and "
                  "judged on the `holdout` runs.".replace("{robot}", gap["robot"]), ""]
        lines += _ladder_table(gap["ladder"], floor["overall"], unconstrained=True)
        lines += ["", "Each rung is the physically consistent fit (every body's pseudo-inertia positive definite, "
                  "friction, damping and armature >= 0); the unconstrained column is the same rung without those "
                  "constraints, for comparison."]
        for k, rung in enumerate(gap["ladder"]):
            for note in rung.get("notes", []):
                if note.startswith("physical consistency"):
                    lines += ["", f"**Rung {k}:** {note}."]
        lines += _identified_markdown(gap["ladder"][-1], gap["robot"])
        lines += ["", f"![Model ladder]({figures['ladder']})"]
    if "diagnosis" in gap:
        lines += ["", "## Diagnosis", ""] + _diagnosis_markdown(gap["diagnosis"])
    if "actuator" in gap:
        link = gap["actuator"]
        link_floor = link["noise_floor"]["torque_rmse"]["overall"]
        lines += ["", "## Actuator link (measured against commanded torque)", "",
                  f"The {link['judged']}. Noise floor {link_floor:.3g} N m: the sensor's white noise, what no "
                  "filter of the command explains. Replay: the commands replayed in MuJoCo on the body link's "
                  "last rung with each actuator rung's effects.", ""]
        lines += _ladder_table(link["ladder"], link_floor, unconstrained=False)
        lines += ["", "### Diagnosis of the actuator link", ""] + _diagnosis_markdown(link["diagnosis"])
    if "links" in gap:
        links = gap["links"]
        lines += ["", "## What these runs can tell apart", "", f"{links['text'][0].upper()}{links['text'][1:]}.", ""]
        if links["mode"] != "commands_only":
            lines += [SENSOR_TEXT[links.get("torque_sensor", "motor")], ""]
        if links.get("metadata_note"):
            lines += [f"**The data contradict the metadata:** {links['metadata_note']}", ""]
        for fact in links["can_tell"]:
            lines.append(f"- Told apart: {', '.join(f'`{e}`' for e in fact['effects'])}: {fact['why']}.")
        for fact in links["cannot_tell"]:
            lines.append(f"- **Not told apart:** {', '.join(f'`{e}`' for e in fact['effects'])}: {fact['why']}.")
    lines += ["", "## Figures", ""]
    if model:
        lines += [f"The model of model.yaml ({_model_name(model)}) on the holdout runs.", ""]
    lines += [f"![Measured vs model torque]({figures['torque']})", "",
              f"![Residual vs velocity]({figures['residual_velocity']})", "",
              f"![Residual vs time]({figures['residual_time']})", "",
              f"![Error by regime]({figures['regimes']})", ""]
    return "\n".join(lines)
