"""Feedback files to hand back: one readable page per submission, for its student.

Each page gives the assignment, the total, and for each question its score and what failed:
a public test's failed statement and message (the student has that test already), a hidden
test's message only (the masters write their `assert` messages to be read; the test's code is
never shown, nor the expected value of a doctest comparison), "not answered yet" for questions
left as handed out, and time-outs or a crashed kernel in plain words. Teacher-only data stays
out: no flags, no paths, no other notes. Everything that comes from the submission (messages,
the file name) is escaped in HTML and fenced in Markdown, and long messages are shortened.
"""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ._feedback import _UNANSWERED, NOT_ANSWERED, _failure
from ._grading import GradeResult
from ._scores import _number

FORMATS = ("md", "html")
"""The formats `write_feedback` writes."""

MESSAGE_LIMIT = 500
"""Characters of a failure message kept in a feedback file."""

_CELL_TIMEOUT = re.compile(r"timed out after (\S+) s in code cell (\d+)")
_CHECK_TIMEOUT = re.compile(r"^(\S+): tests timed out after (\S+) s")


def _shorten(text: str) -> str:
    text = text.strip()
    return text if len(text) <= MESSAGE_LIMIT else text[: MESSAGE_LIMIT - 1] + "…"


def _general_notes(result: GradeResult) -> list[str]:
    """What went wrong with the whole run, in the student's words (other notes are dropped)."""
    if result.master is None:
        return ["This file did not match any assignment: hand in the exercise notebook itself."]
    lines = []
    for note in result.notes:
        cell_timeout = _CELL_TIMEOUT.search(note)
        if note.startswith("unreadable notebook"):
            lines.append("This file could not be read as a notebook, so nothing was graded.")
        elif cell_timeout:
            seconds, cell = cell_timeout.groups()
            lines.append(
                f"Code cell {cell} was still running when the time limit ({seconds} s) ran "
                "out, and was stopped."
            )
        elif "kernel died" in note:
            lines.append(
                "Python stopped while running this notebook (it crashed, or used more memory "
                "than allowed); questions not graded by then score 0."
            )
        elif "ignored the interrupt" in note:
            lines.append("The notebook did not stop when its time ran out, and was ended.")
    return lines


def _question_timeouts(result: GradeResult) -> dict[str, str]:
    timeouts = {}
    for note in result.notes:
        match = _CHECK_TIMEOUT.match(note)
        if match:
            timeouts[match[1]] = f"Its tests did not finish within {match[2]} s."
    return timeouts


def _outcome(result: GradeResult, question: str, timeouts: dict[str, str]):
    """A question's summary line and its failures as `(label, statement, reason)`."""
    detail = result.details.get(question)
    if question in timeouts:
        return timeouts[question], []
    if not detail or not detail.get("cases"):
        return "Not graded: its tests did not run.", []
    cases = detail["cases"]
    failed = [case for case in cases if not case.get("passed")]
    if not failed:
        return f"Passed ({len(cases)} of {len(cases)} tests).", []
    if any(_UNANSWERED.search(str(case.get("message") or "")) for case in failed):
        return f"{NOT_ANSWERED.capitalize()}.", []
    failures = []
    for case in failed:
        statement, reason = _failure(str(case.get("message") or ""))
        if case.get("hidden"):
            # A doctest comparison's reason quotes the expected value: part of the test.
            compared = reason.startswith("expected ") and ", got " in reason
            failures.append(("A hidden test failed", "", "" if compared else _shorten(reason)))
        else:
            failures.append(("A public test failed", _shorten(statement), _shorten(reason)))
    return f"{len(failed)} of {len(cases)} tests failed.", failures


def _sections(result: GradeResult) -> list[dict[str, Any]]:
    """Per question: `title`, `summary`, `passed` and `failures`."""
    timeouts = _question_timeouts(result)
    sections = []
    for question, points in result.possible.items():
        summary, failures = _outcome(result, question, timeouts)
        score = _number(result.scores.get(question, 0.0))
        sections.append(
            {
                "title": f"{question}: {score} / {_number(points)}",
                "summary": summary,
                "passed": summary.startswith("Passed"),
                "failures": failures,
            }
        )
    return sections


def _fence(text: str, inline: bool) -> str:
    """Markdown code that `text` cannot break out of: a fence longer than its backtick runs."""
    longest = max((len(run) for run in re.findall(r"`+", text)), default=0)
    if inline:
        ticks = "`" * (longest + 1)
        return f"{ticks} {text} {ticks}"
    ticks = "`" * max(3, longest + 1)
    return f"{ticks}text\n{text}\n{ticks}"


def _markdown(result: GradeResult) -> str:
    lines = [f"# Feedback: {result.master or 'no assignment'}", ""]
    lines.append(f"File: {_fence(Path(result.file).name, inline=True)}  ")
    if result.master is not None:
        lines.append(f"Total: **{_number(result.total)} / {_number(result.max_points)}**")
    notes = _general_notes(result)
    if notes:
        lines += ["", *(f"- {note}" for note in notes)]
    for section in _sections(result):
        lines += ["", f"## {section['title']}", "", section["summary"]]
        for label, statement, reason in section["failures"]:
            lines += ["", f"{label}" + (":" if statement or reason else ".")]
            if statement:
                lines += ["", "in:", "", _fence(statement, inline=False)]
            if reason:
                lines += ["", _fence(reason, inline=False)]
    return "\n".join(lines) + "\n"


_STYLE = (
    "body{font-family:sans-serif;max-width:50em;margin:2em auto;padding:0 1em}"
    "pre{background:#f6f8fa;padding:.5em;white-space:pre-wrap}"
    ".passed{color:#1a7f37}.failed{color:#b42318}"
)


def _html(result: GradeResult) -> str:
    e = html.escape
    title = e(f"Feedback: {result.master or 'no assignment'}")
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{title}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{title}</h1>",
        f"<p>File: <code>{e(Path(result.file).name)}</code></p>",
    ]
    if result.master is not None:
        total = f"{_number(result.total)} / {_number(result.max_points)}"
        parts.append(f"<p>Total: <strong>{e(total)}</strong></p>")
    notes = _general_notes(result)
    if notes:
        parts.append("<ul>" + "".join(f"<li>{e(note)}</li>" for note in notes) + "</ul>")
    for section in _sections(result):
        status = "passed" if section["passed"] else "failed"
        parts.append(f"<h2>{e(section['title'])}</h2>")
        parts.append(f'<p class="{status}">{e(section["summary"])}</p>')
        for label, statement, reason in section["failures"]:
            parts.append(f"<p>{e(label)}{':' if statement or reason else '.'}</p>")
            if statement:
                parts.append(f"<p>in:</p><pre>{e(statement)}</pre>")
            if reason:
                parts.append(f"<pre>{e(reason)}</pre>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _file_stem(label: str) -> str:
    """A safe file stem from a submission's label (`alice/02 x.ipynb` -> `alice__02_x`)."""
    parts = [re.sub(r"[^A-Za-z0-9._-]+", "_", part) for part in Path(label).with_suffix("").parts]
    stem = "__".join(part.strip("._") for part in parts if part.strip("._"))
    return stem[:150] or "submission"


def write_feedback(
    results: Sequence[GradeResult], directory: Path, *, format: str = "md"
) -> list[Path]:
    """Write one feedback file per graded submission, to hand back to its student.

    **Arguments:**

    - `results`: the graded submissions (with their `details`).
    - `directory`: where to write the files (created if needed).
    - `format`: `"md"` (Markdown) or `"html"`.

    **Returns:**

    The written files, in the order of `results`; each is named after its submission's file
    (folders joined by `__`, unsafe characters replaced, a number added to repeated names).
    """
    if format not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, got {format!r}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    render = _markdown if format == "md" else _html
    taken: set[str] = set()
    written = []
    for result in results:
        stem, number = _file_stem(result.file), 1
        name = f"{stem}.{format}"
        while name.lower() in taken:
            number += 1
            name = f"{stem}-{number}.{format}"
        taken.add(name.lower())
        path = directory / name
        path.write_text(render(result), encoding="utf-8")
        written.append(path)
    return written
