"""The gap report's figures (:data:`FIGURES`), drawn as soon as what each shows is known (:class:`GapFigures`),
reproducible byte for byte (fixed PNG metadata; matplotlib imported only when a figure is drawn)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.files import atomic_path
from sim2real.identification.ladder_rows import Rung, RungMetrics
from sim2real.report.gap_document import GapReport
from sim2real.report import rung_label
from sim2real.report.regimes import REGIME_LABELS, REGIMES

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PNG_METADATA = {"Software": None}


MAX_PLOT_S = 10.0


SCATTER_POINTS = 2500


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


# A grid's margins in inches (left, right, bottom, top; between axes across, down), for its fixed font sizes: laid
# out once instead of by tight_layout, which draws every tick label of every axes to measure it (half a figure's time).
GRID_MARGINS_IN = (0.72, 0.12, 0.42, 0.5, 0.74, 0.62)


def _margins(fig: Figure, left: float, right: float, bottom: float, top: float) -> None:
    """A single axes' margins in inches, for its fixed font sizes (tight_layout measured them by drawing every label:
    a third of such a figure's time)."""
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height)


def _grid(n: int) -> tuple[Figure, np.ndarray]:
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    width, height = 3.6 * cols, 2.6 * rows
    fig = _pyplot().figure(figsize=(width, height))
    grid = fig.add_gridspec(rows, cols)
    axes = np.array([fig.add_subplot(grid[k // cols, k % cols]) for k in range(n)])  # no axes for the empty cells
    left, right, bottom, top, across, down = GRID_MARGINS_IN
    cell_w = (width - left - right - across * (cols - 1)) / cols
    cell_h = (height - bottom - top - down * (rows - 1)) / rows
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height,
                        wspace=across / cell_w, hspace=down / cell_h)
    return fig, axes


def _label(ax: Any, joint: str, xlabel: str, ylabel: str) -> None:
    """One joint's axes of a grid: its name, its units."""
    ax.set_title(joint, fontsize=9)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.tick_params(labelsize=7)
    ax.locator_params(nbins=4)  # a few labelled ticks read as well in a small panel, and each costs its drawing


def _finish(fig: Figure, title: str, target: str | Path) -> None:
    fig.suptitle(title, fontsize=10)
    _save(fig, target)


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
        _label(ax, joint, "time [s]", "torque [N m]")
    axes[0].legend(fontsize=7)
    _finish(fig, f"Measured vs model torque, run '{run.name}'", target)


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
        _label(ax, joint, "velocity [rad/s]", "residual [N m]")
    _finish(fig, "Torque residual (measured - model) vs velocity", target)


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
        _label(ax, joint, "time in run [s]", "residual [N m]")
    axes[0].legend(fontsize=6)
    _finish(fig, f"Torque residual (measured - model) against time, {SMOOTH_S:g} s moving mean", target)


def figure_regimes(gap: GapReport, target: str | Path) -> None:
    """Per joint and regime: the residual step between the regime's two sides, against the noise floor."""
    joints = list(gap.joints)
    per_joint = gap.where["per_joint"]
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
    _margins(fig, 0.65, 0.12, 0.5, 0.32)
    _save(fig, target)


def figure_ladder(gap: GapReport, target: str | Path) -> None:
    """Holdout torque RMSE rung by rung (overall and per joint) against the noise floor."""
    ladder = gap.ladder or [Rung((), RungMetrics(gap.metrics["torque_rmse"]))]
    floor = gap.floor
    x = np.arange(len(ladder))
    fig, ax = _pyplot().subplots(figsize=(max(4.5, 1.6 * len(ladder) + 2.5), 3.4))
    for j, joint in enumerate(gap.joints):
        per_joint = [rung.metrics.torque_rmse["per_joint"][joint] for rung in ladder]
        ax.plot(x, per_joint, marker=".", lw=0.8, alpha=0.6, color=f"C{j % 10}", label=joint)
    overall = [rung.metrics.torque_rmse["overall"] for rung in ladder]
    ax.plot(x, overall, marker="o", lw=2.2, color="black", label="overall")
    ax.axhline(floor["overall"], color="black", ls="--", lw=1.0, label="noise floor (overall)")
    ax.set_xticks(x, [rung_label(rung.effects) for rung in ladder], fontsize=8)
    ax.set_xlim(-0.6, len(ladder) - 0.4)  # the first and last rungs' labels inside the figure
    ax.set_yscale("log")
    ax.set_ylabel("holdout torque RMSE [N m]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6, ncol=2, loc="upper right")
    ax.set_title("Model ladder: the error falls as effects are added", fontsize=10)
    _margins(fig, 0.72, 0.12, 0.38, 0.32)
    _save(fig, target)


def _draw(name: str, gap: GapReport, comparisons: Sequence[Any], figures: Mapping[str, str | Path]) -> bytes:
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


def _figure_inputs(name: str, gap: GapReport, comparisons: Sequence[Any] | None) -> Any:
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
        return (list(gap.joints), gap.where["per_joint"]) if gap.where is not None else None
    if gap.ladder:
        shown: Any = [(list(rung.effects), rung.metrics.torque_rmse) for rung in gap.ladder]
    elif gap.metrics is not None:
        shown = gap.metrics["torque_rmse"]  # no ladder: the nominal model's error alone
    else:
        return None
    return list(gap.joints), shown, gap.floor


def _draw_all(names: Sequence[str], gap: GapReport, comparisons: Sequence[Any] | None,
              figures: Mapping[str, str | Path]) -> list[bytes]:
    return [_draw(name, gap, comparisons, figures) for name in names]


class GapFigures:
    """The figures of a gap report (:data:`FIGURES`), each drawn as soon as what it shows is known
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

    def show(self, gap: GapReport | Mapping[str, Any], comparisons: Sequence[Any] | None = None) -> None:
        """Start every figure not started yet whose inputs ``gap`` (the report so far) and ``comparisons`` hold."""
        from importlib.metadata import version

        from sim2real.forked import Forked

        gap = GapReport.of(gap)
        ready = []
        for name in FIGURES:
            inputs = None if name in self.keys else _figure_inputs(name, gap, comparisons)
            if inputs is not None:
                self.keys[name] = self.cache.key(name, inputs, version("matplotlib"))
                self.kept[name] = self.cache.get("figure", self.keys[name])
                if self.kept[name] is None:
                    ready.append(name)
        if self.workers > 1:
            if ready:
                _pyplot()  # imported once, here, for every forked drawer (~0.7 s of CPU each otherwise)
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
