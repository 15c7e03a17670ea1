"""No function of the package runs over MAX_LINES lines or takes more than MAX_PARAMETERS parameters (issue 61):
a long one is split along its steps, a long parameter list becomes a small frozen dataclass."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "sim2real"
MAX_LINES = 80  # the def line to the last line, inclusive (decorators not counted)
MAX_PARAMETERS = 8  # positional and keyword-only; self, cls, *args and **kwargs not counted


def parameters(function: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    arguments = function.args
    names = [a.arg for a in arguments.posonlyargs + arguments.args + arguments.kwonlyargs]
    return len([name for name in names if name not in ("self", "cls")])


def oversized(source: str, label: str) -> list[str]:
    """``label:line name lines/params`` of every function (methods and nested ones too) of ``source`` over a limit.
    A dataclass's generated ``__init__`` is not in the source, so never counted."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
            count = parameters(node)
            if lines > MAX_LINES or count > MAX_PARAMETERS:
                out.append(f"{label}:{node.lineno} {node.name} {lines} lines/{count} params")
    return out


def package_offenders() -> list[str]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        out += oversized(path.read_text(encoding="utf-8"), str(path.relative_to(PACKAGE.parents[1])))
    return out


def test_no_function_is_too_long_or_takes_too_many_parameters():
    offenders = package_offenders()
    assert not offenders, (f"functions over {MAX_LINES} lines or {MAX_PARAMETERS} parameters (split them along their "
                           "steps; group parameters in a frozen dataclass):\n" + "\n".join(offenders))


def test_the_size_check_sees_a_long_function_and_a_long_parameter_list():
    body = "".join(f"    x{k} = {k}\n" for k in range(79))  # def line + 79 + return: 81 lines
    source = (
        "def wide(a, b, c, d, e, f, g, h, *, i):\n    return a\n\n\n"
        "def narrow(self, a, b, c, d, e, f, g, h, *args, **kwargs):\n    return a\n\n\n"
        f"def long():\n{body}    return x0\n\n\n"
        f"def short():\n{body[: body.index('    x78')]}    return x0\n\n\n"
        "class Holder:\n    def method(cls, a, b, c, d, e, f, g, h, i):\n        return a\n"
    )
    assert oversized(source, "x.py") == ["x.py:1 wide 2 lines/9 params", "x.py:9 long 81 lines/0 params",
                                         "x.py:175 method 2 lines/9 params"]
