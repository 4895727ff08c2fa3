"""What `grader.check` shows a student: the first failed statement with its own message."""

from types import SimpleNamespace

import numpy as np
from otter.test_files.ok_test import run_doctest

import diffnurbs_course as dc

TEST = """\
>>> got = answer(2)
>>> assert np.isclose(got, 3), f"answer(2) = {got}, expected 3"
>>> assert got > 0
>>> assert later_name == 1
"""


def _feedback(answer, unanswered=False):
    passed, message = run_doctest("q1 - 1", TEST, {"np": np, "answer": answer})
    case = SimpleNamespace(passed=passed, message=message)
    result = SimpleNamespace(name="q1", passed_all=passed, test_case_results=[case])
    return dc.Feedback(result, unanswered)


def test_the_first_failure_is_shown_not_the_transcripts_last_line():
    # After the failed assert, doctest runs `got > 0` (ok) and a NameError: neither is shown.
    lines = _feedback(lambda x: 2.5).lines()
    assert lines == [
        "q1: 1 of 1 tests failed",
        '  in: assert np.isclose(got, 3), f"answer(2) = {got}, expected 3"',
        "  AssertionError: answer(2) = 2.5, expected 3",
    ]


def test_an_unanswered_question_says_so():
    def stub(x):
        raise NotImplementedError(dc.NOT_ANSWERED)

    assert _feedback(stub).lines() == ["q1: not answered yet"]
    assert _feedback(lambda x: ...).lines() == ["q1: not answered yet"]  # TypeError: ellipsis
    assert _feedback(lambda x: 2.5, unanswered=True).lines() == ["q1: not answered yet"]
