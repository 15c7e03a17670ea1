"""One round of the gap loop, timed (issue 20): a change of model.yaml through to a new gap.json.

Part 1, the Panda demo through Snakemake: after a cold build of ``results/panda/gap.json``, four kinds of
round (:func:`demo_rounds`): ``model.yaml`` edited without a change of its effects, one line added, as
a user following the verdicts does, that line removed again, and the line-added round once more with its new rungs
read back (what the new model's diagnosis, replays and figures cost alone); the rule times of ``sysid`` and ``gap_report``
come from their ``benchmark:`` files (the runs are prepared once, by ``prepare_runs``, which a round does not rerun).
Median of ``--repeats``.

Part 2, where a round spends its time and how that grows with the log: the lab's ``real_arm_like`` arm is
logged for each ``--lengths`` (seconds; default 20 s, 2 min, 10 min), and one round (``sysid.run_sysid`` +
``gap.build_gap_report``, the two rules' functions, after ``prepare_for_model``) runs under cProfile. Stages are the
cumulative time of the functions that do them (nested stages overlap: the diagnosis holds its candidates'
fits; on the one thread of this round the gap report draws its figures inside compute_gap, before the
replays). Each rule runs in its own fresh process, as in the DAG; its peak memory is the maximum resident set
of that process and of the workers it forked. ``--against REV``: the same cold rounds also with the package as it
was at the commit REV (its ``src/``, on the same prepared runs, alternating with this code's, ``--cold-repeats``
times each), and the ratio of the medians: issue 32 measures a cold 20 s round against its filing (ce27dde).

    python benchmarks/bench_loop.py [--repeats 3] [--lengths 20 120 600] [--skip-demo] [--against ce27dde]
"""

from __future__ import annotations

import argparse
import cProfile
import csv
import json
import multiprocessing
import pstats
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from harness import ROOT

from buildtree import copy_repo, edit_yaml, make_fast, rules_run, run_snakemake  # noqa: E402

# Stage -> (module file suffix, function name): cumulative time of that function in one round.
STAGES = {
    "prepare runs (rule prepare_runs, not in a round)": [("measurements/prepare.py", "prepare_for_model")],
    "read the prepared runs": [("measurements/store.py", "read_prepared_runs")],
    "regressors": [("assets/dynamics.py", "regressor")],
    "nominal inverse dynamics": [("assets/dynamics.py", "inverse_dynamics")],
    "ladder (all rungs)": [("identification/side_ladder.py", "fit_ladder")],
    "  rung fit (incl. consistency, bootstrap)": [("identification/fitting/rung.py", "fit")],
    "  nonlinear refinement": [("identification/fitting/refine.py", "_refine_nonlinear")],
    "  consistent fit (SDP)": [("identification/fitting/consistent.py", "_consistent_fit")],
    "  prior weight (held-out CV)": [("identification/inertial/prior.py", "choose_prior_weight")],
    "  bootstrap": [("identification/fitting/bootstrap.py", "_block_bootstrap")],
    "  diagnosis (candidate trials)": [("identification/diagnosis/candidates.py", "diagnose")],
    "  model-free ceiling": [("identification/diagnosis/ceiling.py", "model_free_ceiling")],
    "gap: compute (replay, metrics, figures)": [("report/gap.py", "compute_gap")],
    "  replay in MuJoCo": [("report/replay.py", "replay")],
    "  figures (drawn from the torque domain's part)": [("report/figures.py", "_draw_all")],
    "writing": [("files.py", "write_json"), ("files.py", "write_yaml"), ("files.py", "write_text")],
}


def stage_times(stats: pstats.Stats) -> dict[str, float]:
    out = {stage: 0.0 for stage in STAGES}
    for (filename, _, function), (_, _, _, cumulative, _) in stats.stats.items():  # type: ignore[attr-defined]
        for stage, targets in STAGES.items():
            if any(filename.endswith(f"sim2real/{suffix}") and function == name for suffix, name in targets):
                out[stage] += cumulative
    return out


RULES = ("prepare_runs", "sysid", "gap_report")


def one_rule(rule: str, tree: str, measurements: str, out: str, queue: multiprocessing.Queue, src: str | None) -> None:
    """In a fresh process, as the DAG runs it: one rule's function under cProfile; stage times, wall time and
    the peak resident set of the process and of the workers it forked. ``src``: the package from there (another
    commit's) instead of the installed one."""
    if src is not None:
        sys.path.insert(0, src)
    from sim2real.report import gap as report
    from sim2real.measurements import prepare_for_model, write_prepared_runs
    from sim2real.report.figures import FIGURES
    from sim2real.identification import sysid

    t = Path(tree)
    o = Path(out)
    prepared = o / "prepared_runs.npz"
    profiler = cProfile.Profile()
    started = time.perf_counter()
    profiler.enable()
    if rule == "prepare_runs":  # once per log: a round reads the prepared runs
        write_prepared_runs(prepared, prepare_for_model(measurements, t / "results/panda/panda.urdf", t))
    elif rule == "sysid":
        paths = (t / "results/panda/panda.urdf", t / "configs/panda/robot.yaml", t / "configs/panda/model.yaml",
                 prepared, o / "ladder.json", o / "params.yaml", o / "calibration.yaml")
        if hasattr(sysid, "SysidFiles"):
            sysid.run_sysid("panda", sysid.SysidFiles(*paths, root=t, residuals=o / "residuals.npz"))
        else:  # a commit before SysidFiles
            sysid.run_sysid("panda", *paths, root=t, residuals_npz=o / "residuals.npz")
    else:
        urdf, mjcf = t / "results/panda/panda.urdf", t / "results/panda/mjcf/panda.xml"
        figures = {k: o / f"{k}.png" for k in FIGURES}
        if hasattr(report, "GapInputs"):
            inputs = report.GapInputs("panda", urdf, mjcf, prepared, root=t, ladder=o / "ladder.json",
                                      residuals=o / "residuals.npz")
            report.build_gap_report(inputs, o / "gap.json", o / "gap.md", figures)
        else:  # a commit before GapInputs
            report.build_gap_report("panda", urdf, mjcf, prepared, o / "gap.json", o / "gap.md", figures,
                                    precomputed_path=o / "ladder.json", root=t, residuals_path=o / "residuals.npz")
    profiler.disable()
    seconds = time.perf_counter() - started
    peak_mib = max(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)) / 1024.0
    queue.put({"seconds": seconds, "stages": stage_times(pstats.Stats(profiler)), "peak_mib": peak_mib})


def profiled_round(tree: Path, measurements: Path, out: Path, src: Path | None = None, prepare: bool = True) -> dict:
    """The runs prepared (unless ``prepare`` is false: they are in ``out`` already), then one cold round (sysid,
    gap report, nothing kept from an earlier one), each rule in its own fresh process; ``src``: another commit's
    package (:func:`one_rule`)."""
    out.mkdir(parents=True, exist_ok=True)
    context = multiprocessing.get_context("spawn")
    rules = {"prepare_runs": {"seconds": 0.0, "stages": dict.fromkeys(STAGES, 0.0), "peak_mib": 0.0}}
    for rule in RULES if prepare else RULES[1:]:
        queue = context.Queue()
        process = context.Process(target=one_rule, args=(rule, str(tree), str(measurements), str(out), queue,
                                                          None if src is None else str(src)))
        process.start()
        rules[rule] = queue.get()
        process.join()
    return {"prepare_s": rules["prepare_runs"]["seconds"], "sysid_s": rules["sysid"]["seconds"],
            "gap_s": rules["gap_report"]["seconds"],
            "stages": {stage: sum(r["stages"][stage] for r in rules.values()) for stage in STAGES},
            "peak_mib": {rule: rules[rule]["peak_mib"] for rule in RULES}}


def demo_rounds(tree: Path, repeats: int) -> None:
    """Four kinds of round, each timed ``repeats`` times: ``model.yaml`` edited without touching its effects (a
    comment: every rung and diagnosis is read back from results/panda/sysid/fits/), the loop's own round: the line
    the verdict named added (the demo's last effect, after two rounds without it, so that nothing of the model with it
    is in the cache, which keeps two rounds' work), that line removed again (undone: read back), and the line added
    once more with only its new rungs read back (the new model's diagnoses, replays and figures removed from the
    caches): what a line-added round costs even where its rung costs nothing."""
    run_snakemake(tree, "results/panda/gap.json", timeout=3600)
    model = tree / "configs/panda/model.yaml"
    original = model.read_text()
    last = yaml.safe_load(original)["effects"][-1]
    without_last = original.replace(f"  - {last}\n", "")
    assert without_last != original, f"no line '  - {last}' in {model}"

    def round_(text: str) -> dict[str, float]:
        model.write_text(text)
        started = time.perf_counter()
        jobs = sorted(rules_run(run_snakemake(tree, "results/panda/gap.json", timeout=3600)))
        times = {"jobs": ", ".join(jobs), "command": time.perf_counter() - started}
        for rule in ("sysid", "gap_report"):
            with open(tree / f"results/panda/benchmarks/{rule}.tsv") as handle:
                times[rule] = float(next(csv.DictReader(handle, delimiter="\t"))["s"])
        return times

    added, removed = f"one line added ({last})", f"the line removed again ({last})"
    rung_free = f"one line added ({last}), its rungs read back"
    rows: dict[str, list[dict]] = {"model.yaml edited, same effects": [], added: [], removed: [], rung_free: []}
    fits, kept = tree / "results/panda/sysid/fits", tree / "results/panda/gap/kept"
    for k in range(repeats):
        rows["model.yaml edited, same effects"].append(round_(original + f"# bench_loop round {k}\n"))
        # Two rounds without the line (the cache keeps two rounds' work): the line is then new to the cache, as
        # it is to a user adding it for the first time; the last of them names it.
        round_(without_last)
        round_(without_last + f"# bench_loop round {k}\n")
        before = {path for folder in (fits, kept) for path in folder.iterdir()}
        rows[added].append(round_(original))
        new = {path for folder in (fits, kept) for path in folder.iterdir()} - before
        rows[removed].append(round_(without_last))  # undone: read back from the round before
        # What a line-added round costs beyond its new rungs (issue 32's floor): that round again with its new rungs
        # read back, and the new model's diagnoses (their trials' refinements too), replays and figures computed again.
        for path in new:
            if not path.name.startswith("rung-"):
                path.unlink(missing_ok=True)
        rows[rung_free].append(round_(original + f"# bench_loop rung read back {k}\n"))
    model.write_text(original)
    for kind, times in rows.items():
        print(f"  {kind}: jobs run: {times[-1]['jobs']}")
        for k, t in enumerate(times):
            print(f"    round {k + 1}: sysid {t['sysid']:.1f} s + gap_report {t['gap_report']:.1f} s = "
                  f"{t['sysid'] + t['gap_report']:.1f} s (the command: {t['command']:.1f} s)")
        print(f"    median round (sysid + gap_report): "
              f"{statistics.median(t['sysid'] + t['gap_report'] for t in times):.1f} s (target: under 5 s)")
    medians = [statistics.median(t["sysid"] + t["gap_report"] for t in times) for times in rows.values()]
    print(f"  a round that adds the line / a round that changes nothing: {medians[1] / medians[0]:.2f}x "
          "(issue 32: at most 1.5x)")
    print(f"  a round that removes it again / a round that changes nothing: {medians[2] / medians[0]:.2f}x")
    print(f"  a round that adds the line with its rungs read back / a round that changes nothing: "
          f"{medians[3] / medians[0]:.2f}x (what the new model's diagnosis, replays and figures cost alone)")
    # What the user waits for: Snakemake's start, DAG and checks too (the same in every kind of round).
    commands = [statistics.median(t["command"] for t in times) for times in rows.values()]
    print(f"  the command `snakemake results/panda/gap.json`, median: {commands[0]:.1f} s, {commands[1]:.1f} s, "
          f"{commands[2]:.1f} s, {commands[3]:.1f} s; line added / unchanged {commands[1] / commands[0]:.2f}x")


def lab_runs(tree: Path, length_s: float) -> Path:
    """real_arm_like fit and holdout runs of ``length_s`` each, through the DAG's own lab rule."""
    scenario = f"real_arm_like_{int(length_s)}s"

    def add(data: dict) -> None:
        data["scenarios"][scenario] = {**data["scenarios"]["real_arm_like"], "duration_s": float(length_s)}

    edit_yaml(tree / "configs/panda/lab.yaml", add)
    run_snakemake(tree, *(f"results/panda/lab/{scenario}/{run}.parquet" for run in ("fit", "holdout")),
                  timeout=7200)
    listing = tree / f"{scenario}.measurements.yaml"
    listing.write_text(yaml.safe_dump({"runs": [
        {"name": run, "path": f"results/panda/lab/{scenario}/{run}.parquet", "role": run}
        for run in ("fit", "holdout")]}))
    return listing


def compare_cold(tree: Path, listing: Path, out: Path, src: Path, rev: str, length: float, repeats: int,
                 first: dict) -> None:
    """Cold rounds on the same prepared runs, this code's and ``rev``'s in turn (``first``: this code's first), and
    the ratio of their medians (sysid + gap report, each rule in a fresh process, cProfile on in both)."""
    ours = [first["sysid_s"] + first["gap_s"]]
    theirs = []
    for k in range(repeats):
        old = profiled_round(tree, listing, out / f"{rev}_{k}", src)  # its own prepared runs, timed apart
        theirs.append(old["sysid_s"] + old["gap_s"])
        if k + 1 < repeats:
            (out / f"ours_{k}").mkdir(parents=True, exist_ok=True)
            shutil.copy(out / "prepared_runs.npz", out / f"ours_{k}" / "prepared_runs.npz")
            again = profiled_round(tree, listing, out / f"ours_{k}", prepare=False)
            ours.append(again["sysid_s"] + again["gap_s"])
    print(f"\ncold round on the {length:g} s log (sysid + gap report, cProfile on): this code "
          f"{', '.join(f'{t:.1f}' for t in ours)} s, {rev} {', '.join(f'{t:.1f}' for t in theirs)} s; "
          f"ratio of medians {statistics.median(ours) / statistics.median(theirs):.2f}x (issue 32: at most 0.5x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--lengths", type=float, nargs="+", default=[20.0, 120.0, 600.0])
    parser.add_argument("--skip-demo", action="store_true")
    parser.add_argument("--against", metavar="REV", help="also time the cold rounds with the package of this commit")
    parser.add_argument("--cold-repeats", type=int, default=1, help="cold rounds of each code with --against")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tree = copy_repo(ROOT, Path(tmp) / "project")
        make_fast(tree)  # coarse CoACD parts only: the loop's own settings stay the demo's
        if not args.skip_demo:
            print("Panda demo through Snakemake (rule times after a change of model.yaml):")
            demo_rounds(tree, args.repeats)
        else:
            run_snakemake(tree, "results/panda/mjcf/panda.xml", "results/panda/panda.urdf", timeout=3600)
        against = None
        if args.against:
            against = Path(tmp) / "against"
            against.mkdir()
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.against, "src", "schemas"], check=True,
                                     capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", str(against)], input=archive, check=True)
        results = {}
        for length in args.lengths:
            listing = lab_runs(tree, length)
            out = Path(tmp) / f"round_{int(length)}"
            results[length] = profiled_round(tree, listing, out)
            if against is not None:
                compare_cold(tree, listing, out, against / "src", args.against, length, args.cold_repeats,
                             results[length])
            r = results[length]
            peaks = r["peak_mib"]
            print(f"\nreal_arm_like, {length:g} s fit + {length:g} s holdout at 1 kHz: prepare runs {r['prepare_s']:.1f} s, "
                  f"sysid {r['sysid_s']:.1f} s, gap report {r['gap_s']:.1f} s; peak memory: prepare runs "
                  f"{peaks['prepare_runs']:.0f} MiB, sysid {peaks['sysid']:.0f} MiB, gap report {peaks['gap_report']:.0f} MiB "
                  f"(each rule's process with its workers, cProfile on; target: a round under 2048 MiB)")
        lengths = list(results)
        print("\nstage [s]" + "".join(f"{f'{L:g} s log':>14s}" for L in lengths)
              + (f"{'x ' + f'{lengths[-1]:g}/{lengths[-2]:g}':>12s}" if len(lengths) > 1 else ""))
        for stage in STAGES:
            values = [results[L]["stages"][stage] for L in lengths]
            ratio = (f"{values[-1] / values[-2]:12.1f}" if len(values) > 1 and values[-2] > 0 else "")
            print(f"{stage:42s}" + "".join(f"{v:14.2f}" for v in values) + ratio)
        totals = [results[L]["sysid_s"] + results[L]["gap_s"] for L in lengths]
        print(f"{'round (sysid + gap report)':42s}" + "".join(f"{v:14.2f}" for v in totals)
              + (f"{totals[-1] / totals[-2]:12.1f}" if len(totals) > 1 else "") + "   (target: 10 min < 5x 2 min)")
        print(json.dumps({f"{L:g}": {k: round(v, 3) for k, v in results[L]["stages"].items()} for L in lengths}),
              file=sys.stderr)


if __name__ == "__main__":
    main()
