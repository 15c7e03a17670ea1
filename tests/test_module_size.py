"""One job per module: no module of the package runs over MAX_MODULE_LINES lines and rules/common.smk over
MAX_COMMON_LINES (validation, wildcards, the targets, the input functions and the scheduling; where files are lives in
sim2real.workflow). A module that grows past it is split along its seams, as a package where it does several jobs.
And the code says why it is as it is today: no issue numbers in src/ or rules/."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "sim2real"
MAX_MODULE_LINES = 400
MAX_COMMON_LINES = 200


def line_count(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def oversized_files(paths: list[Path], limit: int, root: Path = ROOT) -> list[str]:
    """``path: lines`` of every file over ``limit`` lines, relative to ``root``."""
    return [f"{path.relative_to(root)}: {line_count(path)} lines" for path in paths if line_count(path) > limit]


def test_no_module_is_over_the_limit_and_common_smk_stays_short() -> None:
    modules = sorted(PACKAGE.rglob("*.py"))
    assert len(modules) > 50 and PACKAGE / "identification" / "sysid.py" in modules, "the walk sees the package"
    offenders = oversized_files(modules, MAX_MODULE_LINES)
    offenders += oversized_files([ROOT / "rules" / "common.smk"], MAX_COMMON_LINES)
    assert not offenders, "split along its seams:\n" + "\n".join(offenders)


def test_the_check_lists_a_file_over_its_limit(tmp_path: Path) -> None:
    long, short = tmp_path / "long.py", tmp_path / "short.py"
    long.write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    short.write_text("x = 1\n" * MAX_MODULE_LINES)
    assert oversized_files([long, short], MAX_MODULE_LINES, tmp_path) == [f"long.py: {MAX_MODULE_LINES + 1} lines"]


# An issue's number ("issue 71", "#71"); a colour ("#3182bd") is no number.
ISSUE_NUMBER = re.compile(r"\bissues?\s*#?\d+|#\d{2,}\b", re.IGNORECASE)


def issue_numbers(paths: list[Path], root: Path = ROOT) -> list[str]:
    """``path:line: text`` of every line naming an issue's number."""
    return [f"{path.relative_to(root)}:{number}: {line.strip()}" for path in paths
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if ISSUE_NUMBER.search(line)]


def test_the_code_names_no_issue_number() -> None:
    """Comments say why the code is as it is today; which issue asked for it is the history's (git log)."""
    files = sorted(PACKAGE.rglob("*.py")) + sorted((ROOT / "rules").glob("*.smk")) + [ROOT / "Snakefile"]
    assert not issue_numbers(files), "\n".join(issue_numbers(files))


def test_the_issue_check_sees_a_number_and_not_a_colour(tmp_path: Path) -> None:
    code = tmp_path / "code.py"
    code.write_text('# as issue 61 asked\nCOLOUR = "#3182bd"\nx = 1  # see #71\n')
    assert [row.split(":")[1] for row in issue_numbers([code], tmp_path)] == ["1", "3"]
