"""`make exercises`: generate the student notebooks `exercises/NN_topic.ipynb` from the masters.

For every master `solutions/NN_topic.ipynb` this checks the authoring rules
(`course/AUTHORING.md`), runs otter assign into `build/otter/NN_topic/` (the autograder version,
with the hidden tests, stays there: git-ignored) and writes the student version, with solutions
and hidden tests stripped and content-derived cell ids, to `exercises/NN_topic.ipynb`.
Exercises without a master are removed.

    python tools/make_exercises.py [--solutions DIR] [--exercises DIR] [--build DIR] [--check]
                                   [NN_topic ...]

With `--check` nothing is written: the exit status is 1 when `exercises/` is out of date.
Naming masters (file stems) limits the run to them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import diffnurbs_course as dc


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--solutions", type=Path, default=Path("solutions"))
    parser.add_argument("--exercises", type=Path, default=Path("exercises"))
    parser.add_argument("--build", type=Path, default=Path("build/otter"))
    parser.add_argument("--check", action="store_true", help="only report drift")
    parser.add_argument("names", nargs="*", help="only these masters (file stems)")
    return parser


def _generate(master: Path, exercises: Path, build: Path) -> bool:
    """Check one master and write its exercise; `False` when the master breaks the rules."""
    problems = dc.master_problems(master)
    if problems:
        print(f"{master}: not generated, the master breaks the authoring rules:")
        for problem in problems:
            print(f"  - {problem}")
        return False
    target = exercises / master.name
    dc.generate_exercise(master, target, build / master.stem)
    print(f"{master} -> {target}")
    return True


def _check(master: Path, exercises: Path) -> bool:
    """Report whether one exercise is in sync with its master."""
    drift = dc.exercise_drift(master, exercises / master.name)
    for line in drift:
        print(f"{exercises / master.name}: {line}")
    return not drift


def main(argv: list[str] | None = None) -> int:
    """Generate (or check) every exercise; return the exit status."""
    args = _parser().parse_args(argv)
    masters = [p for p in dc.notebooks(args.solutions) if not args.names or p.stem in args.names]
    stale = [p for p in dc.notebooks(args.exercises) if not (args.solutions / p.name).exists()]
    ok = True
    for master in masters:
        if args.check:
            ok &= _check(master, args.exercises)
        else:
            ok &= _generate(master, args.exercises, args.build)
    for path in stale:
        if args.check:
            print(f"{path}: no master {args.solutions / path.name}")
            ok = False
        else:
            path.unlink()
            print(f"{path}: removed (no master)")
    if not masters:
        print(f"no masters in {args.solutions}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
