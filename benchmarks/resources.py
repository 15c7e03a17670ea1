"""What each rule declares it needs (threads, mem_mb, runtime) beside what its benchmark files measured.

Every rule of rules/*.smk declares ``threads`` and ``resources: mem_mb, runtime`` (runtime in
minutes, as Snakemake and its SLURM and Kubernetes executors read it); the figures come from the
``benchmark:`` files of a full build (``benchmarks/bench_resources.py`` prints them side by side,
``tests/test_scaleout.py`` checks the declarations with the same functions).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

_RULE = re.compile(r"^(?:rule|checkpoint) (\w+):", re.MULTILINE)
_LOCAL = re.compile(r"^localrules:\n((?:    \w+,?\n)+)", re.MULTILINE)


def declared_resources(rules_dir: str | Path) -> dict[str, dict[str, Any]]:
    """{rule: {threads, mem_mb, runtime, local}} as written in the rules files (None where missing)."""
    declared: dict[str, dict[str, Any]] = {}
    local: set[str] = set()
    for path in sorted(Path(rules_dir).glob("*.smk")):
        text = path.read_text(encoding="utf-8")
        for block in _LOCAL.finditer(text):
            local.update(name.strip().rstrip(",") for name in block.group(1).splitlines() if name.strip())
        starts = [(m.start(), m.group(1)) for m in _RULE.finditer(text)]
        for k, (start, name) in enumerate(starts):
            end = starts[k + 1][0] if k + 1 < len(starts) else len(text)
            body = text[start:end]

            def number(pattern: str, body: str = body) -> int | None:
                found = re.search(pattern, body, re.MULTILINE)
                return int(found.group(1)) if found else None

            declared[name] = {
                # a number, or a helper of rules/common.smk given the most it asks for (round_threads(2, ...))
                "threads": number(r"^    threads: (?:\w+\()?(\d+)(?:,.*\))?$"),
                "mem_mb": number(r"^        mem_mb=(\d+),?$"),
                "runtime": number(r"^        runtime=(\d+),?$"),
                "file": path.as_posix(),
            }
    for name in declared:
        declared[name]["local"] = name in local
    return declared


def _benchmark_rule(path: Path, rules: Iterable[str]) -> str | None:
    """The rule a benchmark file belongs to: the first part after 'benchmarks/' naming a rule."""
    parts = path.as_posix().split("/benchmarks/", 1)[-1].split("/")
    known = set(rules)
    for part in parts:
        name = part.removesuffix(".tsv")
        if name in known:
            return name
    return None


def measured_resources(results_dir: str | Path, rules: Iterable[str]) -> dict[str, dict[str, Any]]:
    """{rule: {jobs, max_s, max_rss_mb, max_cpu_s}} over every benchmark TSV under ``results_dir``."""
    rules = list(rules)
    measured: dict[str, dict[str, Any]] = {}
    for path in sorted(Path(results_dir).rglob("*.tsv")):
        if "benchmarks" not in path.parts:
            continue
        rule = _benchmark_rule(path, rules)
        if rule is None:
            continue
        with path.open(encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle, delimiter="\t"))
        if not rows or "max_rss" not in rows[-1]:
            continue
        row = rows[-1]

        def value(key: str, row: Mapping[str, str] = row) -> float:
            try:
                return float(row.get(key, "nan"))
            except ValueError:
                return math.nan

        entry = measured.setdefault(rule, {"jobs": 0, "max_s": 0.0, "max_rss_mb": 0.0, "max_cpu_s": 0.0})
        entry["jobs"] += 1
        for key, column in (("max_s", "s"), ("max_rss_mb", "max_rss"), ("max_cpu_s", "cpu_time")):
            if math.isfinite(value(column)):
                entry[key] = max(entry[key], value(column))
    return measured


def undeclared(declared: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """'rule: missing threads, runtime' for every rule that does not declare all three."""
    problems = []
    for name, d in sorted(declared.items()):
        missing = [k for k in ("threads", "mem_mb", "runtime") if d.get(k) is None]
        if missing:
            problems.append(f"{d['file']}: rule {name}: missing {', '.join(missing)}")
    return problems


def exceeded(declared: Mapping[str, Mapping[str, Any]], measured: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Rules whose measured peak memory or wall time is above what they declare."""
    problems = []
    for name, m in sorted(measured.items()):
        d = declared.get(name)
        if d is None or d.get("mem_mb") is None or d.get("runtime") is None:
            continue
        if m["max_rss_mb"] > d["mem_mb"]:
            problems.append(f"{d['file']}: rule {name}: measured {m['max_rss_mb']:.0f} MB > mem_mb={d['mem_mb']}")
        if m["max_s"] > 60 * d["runtime"]:
            problems.append(f"{d['file']}: rule {name}: measured {m['max_s']:.0f} s > runtime={d['runtime']} min")
    return problems


def resource_table(declared: Mapping[str, Mapping[str, Any]], measured: Mapping[str, Mapping[str, Any]]) -> str:
    """Markdown: declared threads/mem_mb/runtime beside the measured peaks, heaviest memory first."""
    lines = ["| rule | local | threads | mem_mb | runtime [min] | jobs measured | max wall [s] | max RSS [MB] |",
             "|---|---|---|---|---|---|---|---|"]
    for name, d in sorted(declared.items(), key=lambda kv: (-(kv[1].get("mem_mb") or 0), kv[0])):
        m = measured.get(name)
        lines.append(
            f"| {name} | {'yes' if d['local'] else ''} | {d['threads']} | {d['mem_mb']} | {d['runtime']} | "
            + (f"{m['jobs']} | {m['max_s']:.1f} | {m['max_rss_mb']:.0f} |" if m else "– | – | – |")
        )
    return "\n".join(lines) + "\n"
