"""The grading session inside a submission's kernel (`diffnurbs-grade` injects it)."""

from __future__ import annotations

import json
import os
from typing import Any


class KernelSession:
    """Grading session inside the submission's kernel (created by the injected first cell).

    Switches otter to grading mode with the master's tests and keeps a JSON file with the
    result of every question checked so far, so nothing is lost if the kernel has to be killed.

    **Arguments:**

    - `tests_dir`: folder with one OK-format test file per question (`q1.py`, ...).
    - `results_path`: the JSON file to keep up to date.
    """

    def __init__(self, tests_dir: str, results_path: str):
        from otter import Notebook
        from otter.execute import Checker

        self._tests_dir = tests_dir
        self._results_path = results_path
        self._checker = Checker
        Notebook.init_grading_mode(tests_dir)
        original = Checker.check.__func__
        session = self

        def check_and_save(cls, *args, **kwargs):
            result = original(cls, *args, **kwargs)
            session.save()
            return result

        Checker.check = classmethod(check_and_save)
        self.save()

    def check(self, question: str, global_env: dict[str, Any]) -> None:
        """Run a question's tests against `global_env` unless the student's cells already did.

        **Arguments:**

        - `question`: the question name, e.g. `"q1"`.
        - `global_env`: the notebook's globals.
        """
        path = os.path.join(self._tests_dir, f"{question}.py")
        self._checker.check_if_not_already_checked(path, global_env)

    def save(self) -> None:
        """Write the latest result of every question checked so far (atomically)."""
        results = {}
        for test_file in self._checker.get_results():
            results[test_file.name] = {
                "score": float(test_file.score),
                "possible": float(test_file.possible),
                "cases": [
                    {
                        "hidden": r.test_case.hidden,
                        "passed": r.passed,
                        "points": r.test_case.points,
                        "message": r.message,
                    }
                    for r in test_file.test_case_results
                ],
            }
        tmp = self._results_path + ".tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(results, f)
        os.replace(tmp, self._results_path)
