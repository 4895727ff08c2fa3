"""What a student sees after `grader.check("q1")`: what is wrong, in a few lines.

otter shows a failed check as its doctest transcript ("Trying: … Expecting nothing … ok" for
every statement, then a traceback through numpy), some 25 lines around the one useful
message, and an unanswered question as the `TypeError` that `...` causes. `Notebook.check`
returns the same result, shown as: the question passed; or not answered yet; or, for each
failed test, the statement that failed and its message.
"""

from __future__ import annotations

import ast
import html
import inspect
import json
import re
from typing import Any

import otter

NOT_ANSWERED = "not answered yet"
"""The message of the `NotImplementedError` that an exercise's empty answer raises."""

ANSWERS_KEY = "diffnurbs_answers"
"""Notebook metadata of an exercise: the names each question's answer cells define."""

# A TypeError about `...` (an answer left as `x = ...`) or the NotImplementedError of a
# function body left as generated: the question is not answered, whatever the test.
_UNANSWERED = re.compile(rf"NotImplementedError: {NOT_ANSWERED}|'ellipsis'|ellipsis object")


def _failure(message: str) -> tuple[str, str]:
    """`(statement, reason)` of the first failed example of a doctest transcript: the
    statement and the last line of its exception (or what it printed against what was
    expected). doctest goes on after a failure, so the transcript's own last line may belong
    to a later statement ("ok", or an error that only follows from the first one)."""
    lines = message.splitlines()
    if "Failed example:" not in lines:
        reasons = [line.strip() for line in lines if line.strip()]
        return "", reasons[-1] if reasons else "failed"
    start = lines.index("Failed example:")
    end = next((i for i in range(start, len(lines)) if lines[i] == "Trying:"), len(lines))
    block = lines[start:end]
    statement = block[1].strip() if len(block) > 1 else ""
    if "Expected:" in block and "Got:" in block:
        expected = block[block.index("Expected:") + 1].strip()
        got = block[block.index("Got:") + 1].strip()
        return statement, f"expected {expected}, got {got}"
    reasons = [line.strip() for line in block[2:] if line.strip()]
    return statement, reasons[-1] if reasons else "failed"


def answer_names(source: str) -> list[str]:
    """The names an answer cell defines at its top level (functions, classes, assignments)."""
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return []
    names = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            names.append(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names += [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
    return names


class Feedback:
    """The result of one question's checks (otter's `TestFile`), shown in a few lines.

    Attributes not defined here are otter's (`passed_all`, `grade`, `test_case_results`).
    """

    def __init__(self, result: Any, unanswered: bool = False):
        """**Arguments:**

        - `result`: what `otter.Notebook.check` returned.
        - `unanswered`: whether a name the question's answer defines is still `...`.
        """
        self.result = result
        self.unanswered = unanswered

    def __getattr__(self, name: str) -> Any:
        return getattr(self.result, name)

    def lines(self) -> list[str]:
        """The feedback, one line per fact."""
        name, cases = self.result.name, self.result.test_case_results
        if self.result.passed_all:
            return [f"{name}: passed ({len(cases)} of {len(cases)} tests)"]
        failed = [case for case in cases if not case.passed]
        if self.unanswered or any(_UNANSWERED.search(case.message or "") for case in failed):
            return [f"{name}: {NOT_ANSWERED}"]
        lines = [f"{name}: {len(failed)} of {len(cases)} tests failed"]
        for case in failed:
            statement, reason = _failure(case.message or "")
            lines += [f"  in: {statement}" if statement else "", f"  {reason}"]
        return [line for line in lines if line]

    def __repr__(self) -> str:
        return "\n".join(self.lines())

    def _repr_html_(self) -> str:
        colour = "#1a7f37" if self.result.passed_all else "#b42318"
        text = html.escape("\n".join(self.lines()))
        return f"<pre style='color: {colour}; white-space: pre-wrap'>{text}</pre>"


class Notebook(otter.Notebook):
    """otter's notebook checker whose `check` answers in a few lines (`Feedback`)."""

    def check(self, question: str, global_env: dict | None = None) -> Feedback:
        """Run the public tests of `question` against the caller's globals.

        **Arguments:**

        - `question`: the question's name, e.g. `"q1"`.
        - `global_env`: where the answers are; the calling cell's globals by default.

        **Returns:**

        The result, shown as a few lines of feedback.
        """
        if global_env is None:
            global_env = inspect.currentframe().f_back.f_globals
        names = self._answer_names().get(question, [])
        unanswered = any(global_env.get(name, ...) is ... for name in names)
        return Feedback(super().check(question, global_env), unanswered)

    def _answer_names(self) -> dict[str, list[str]]:
        """The names each question's answer defines, from the exercise's metadata."""
        try:
            with open(self._notebook, encoding="utf-8") as handle:
                return json.load(handle)["metadata"].get(ANSWERS_KEY, {})
        except (OSError, TypeError, ValueError, KeyError):
            return {}  # a notebook saved elsewhere: the messages alone decide
