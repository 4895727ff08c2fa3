"""Flags: why the teacher should read a submission's code, one short sentence per reason.

A flag is not a verdict: honest work gets none (the masters and their exercises are checked),
and a flagged notebook still keeps its score. Static flags come from the AST of the student's
code cells (IPython magics included, as the kernel would run them): code that touches the
grading machinery, other processes, the network, native code, the import system, signal
handlers or `/proc`, that patches the libraries the tests use, opens paths outside its folder,
or runs code built from strings. Runtime flags come from the grading result: a kernel death
next to a high score, full marks from answers that still raise "not answered yet", scores the
master does not allow, and (`batch_flags`) runs much shorter than the rest of the class's.
"""

from __future__ import annotations

import ast
import re
import statistics
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import nbformat
from IPython.core.inputtransformer2 import TransformerManager

from ._otter import ANSWER_TAG

if TYPE_CHECKING:  # only annotations: `_masters` may import `handed_out_code` without a cycle
    from ._grading import GradeResult

_GRADING = "the grading machinery"
_PROCESSES = "other programs"
_NETWORK = "the network"
_NATIVE = "native code"
_IMPORTS = "the import system"
_INTERNALS = "the interpreter's internals"
_SIGNALS = "signal handlers"
_PROC = "other processes' data"
_PATCH = "the libraries the tests use"
_PATHS = "files outside its folder"
_DYNAMIC = "code built from strings"
_SHELL = "the shell"
_IPYTHON = "the IPython shell"

# Qualified names (after resolving the notebook's imports) and what they touch.
_RULES = [
    (re.compile(pattern), concern)
    for pattern, concern in [
        (r"otter(\.|$)", _GRADING),
        (r"diffnurbs_course\.(?!Notebook$)", _GRADING),
        (r"(Checker|OKTestFile)(\.|$)|(\w+\.)*_diffnurbs", _GRADING),
        (r"grader\.(?!check$)", _GRADING),
        (r"(subprocess|pty|multiprocessing)(\.|$)", _PROCESSES),
        (r"os\.(system|popen|fork|forkpty|kill|killpg)$", _PROCESSES),
        (r"os\.(exec|spawn|posix_spawn)\w*$", _PROCESSES),
        (r"(socket|socketserver|ssl|http|urllib|urllib3|requests)(\.|$)", _NETWORK),
        (r"(httpx|aiohttp|ftplib|smtplib|telnetlib|xmlrpc)(\.|$)", _NETWORK),
        (r"(ctypes|cffi)(\.|$)", _NATIVE),
        (r"(builtins|__builtins__|importlib)(\.|$)", _IMPORTS),
        (r"sys\.(modules|meta_path|path_hooks)(\.|$)", _IMPORTS),
        (r"sys\.(_getframe|settrace|setprofile)$", _INTERNALS),
        (r"gc\.get_(objects|referrers|referents)$|inspect\.(currentframe|stack)$", _INTERNALS),
        (r"signal(\.|$)", _SIGNALS),
        (r"(eval|exec|compile|__import__)$", _DYNAMIC),
    ]
]

# The libraries the tests compare with: the modules and the names the masters give them.
_LIBRARIES = re.compile(r"(numpy|jax|diffnurbs)(\.|$)")
_DEFAULT_ALIASES = {"np": "numpy", "jnp": "jax.numpy", "dn": "diffnurbs"}

# Calls that take a path first, so a literal absolute path there is read or written.
_PATH_CALLS = re.compile(
    r"(open|io\.open|os\.\w+|os\.path\.\w+|shutil\.\w+|glob\.\w+|pathlib\.\w+"
    r"|numpy\.(load|save|savez\w*|loadtxt|savetxt|genfromtxt|fromfile))$"
)
_OUTSIDE = re.compile(r"(/|~|\.\.(/|$))")

# IPython magics that only time, plot or print (anything else is named in a flag).
_HARMLESS_MAGICS = frozenset(
    {"matplotlib", "time", "timeit", "precision", "pprint", "who", "whos", "xmode", "capture"}
    | {"pinfo", "pinfo2", "psearch", "pdoc", "pdef", "psource"}
)
_SHELL_MAGICS = frozenset(
    {"system", "sx", "sc", "bash", "sh", "script", "perl", "ruby", "python", "python3", "pypy"}
)

# For cells that do not parse: the same concerns, by text.
_TEXT_RULES = [
    (re.compile(pattern, re.MULTILINE), concern)
    for pattern, concern in [
        (r"\b(otter|_diffnurbs\w*|Checker|OKTestFile)\b", _GRADING),
        (r"\b(subprocess|pty|multiprocessing)\b", _PROCESSES),
        (r"\bos\.(system|popen|fork|exec\w*|spawn\w*)", _PROCESSES),
        (r"\b(socket|urllib|requests|httpx|aiohttp)\b|\bimport\s+http\b", _NETWORK),
        (r"\b(ctypes|cffi)\b", _NATIVE),
        (r"\b(importlib|builtins|__builtins__)\b|\bsys\.(modules|meta_path)", _IMPORTS),
        (r"\b(import\s+signal|from\s+signal)\b", _SIGNALS),
        (r"/proc\b", _PROC),
        (r"\b(setattr|delattr)\s*\(\s*(np|numpy|jnp|jax|dn)\b", _PATCH),
        (r"\b(np|jnp|jax|dn)(\.\w+)+\s*=[^=]", _PATCH),
        (r"\b(eval|exec|compile|__import__)\s*\(", _DYNAMIC),
        (r"^\s*!|^\s*%%?(system|sx|bash|sh|script)\b", _SHELL),
    ]
]

# Names that mean something without an import: builtins, and what the exercise defines.
_KNOWN_ROOTS = frozenset(
    {"eval", "exec", "compile", "__import__", "__builtins__", "open", "setattr", "delattr"}
    | {"grader", "Checker", "OKTestFile"}
)

_TRANSFORMER = TransformerManager()


def _parse(source: str) -> ast.Module:
    """A cell's AST as the kernel runs it (magics become `get_ipython()` calls)."""
    return ast.parse(_TRANSFORMER.transform_cell(source))


def _aliases(trees: Iterable[ast.Module]) -> dict[str, str]:
    """What each imported name stands for, over the whole notebook (`sp` -> `subprocess`)."""
    aliases = dict(_DEFAULT_ALIASES)
    for tree in trees:
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.asname:
                        aliases[alias.asname] = alias.name
                    else:
                        top = alias.name.split(".")[0]
                        aliases[top] = top
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                for alias in node.names:
                    aliases[alias.asname or alias.name] = f"{node.module}.{alias.name}"
    return aliases


def _is_get_ipython(node: ast.AST) -> bool:
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "get_ipython"
    )


def _literal(node: ast.AST) -> str | None:
    """A string literal's text, or the literal start of an f-string."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr) and node.values:
        return _literal(node.values[0])
    return None


class _CellScan(ast.NodeVisitor):
    """Collects one reason per concern in one cell's statements."""

    def __init__(self, aliases: dict[str, str]):
        self.aliases = aliases
        self.reasons: dict[str, str] = {}

    def add(self, concern: str, what: str) -> None:
        self.reasons.setdefault(concern, f"{what} ({concern})")

    def resolve(self, node: ast.AST) -> str | None:
        """The qualified name of a name or attribute chain (`o.system` -> `os.system`), if
        its root is imported or one of `_KNOWN_ROOTS` (a student's own `signal` is not)."""
        if isinstance(node, ast.Name):
            if node.id in _KNOWN_ROOTS or node.id.startswith("_diffnurbs"):
                return node.id
            return self.aliases.get(node.id)
        if isinstance(node, ast.Attribute):
            base = self.resolve(node.value)
            return None if base is None else f"{base}.{node.attr}"
        return None

    def check_name(self, qualified: str, what: str) -> None:
        for pattern, concern in _RULES:
            if pattern.match(qualified):
                self.add(concern, what)

    def check_target(self, node: ast.AST, verb: str = "assigns") -> None:
        """An assignment or deletion target: patching a library, or rebinding its name."""
        if isinstance(node, ast.Tuple | ast.List | ast.Starred):
            for element in node.elts if not isinstance(node, ast.Starred) else [node.value]:
                self.check_target(element, verb)
            return
        if isinstance(node, ast.Subscript):
            node = node.value
        qualified = self.resolve(node)
        if qualified is None or not _LIBRARIES.match(qualified):
            return
        if isinstance(node, ast.Name):
            self.add(_PATCH, f"rebinds {node.id}")
        else:
            self.add(_PATCH, f"{verb} {ast.unparse(node)}")

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self.check_name(alias.name, f"imports {alias.name}")

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.module and not node.level:
            for alias in node.names:
                qualified = f"{node.module}.{alias.name}"
                self.check_name(node.module, f"imports {qualified}")
                self.check_name(qualified, f"imports {qualified}")

    def visit_Name(self, node: ast.Name) -> None:
        qualified = self.resolve(node)
        if qualified is not None:
            self.check_name(qualified, f"uses {node.id}")

    def visit_Attribute(self, node: ast.Attribute) -> None:
        if _is_get_ipython(node.value):
            self.add(_IPYTHON, f"uses get_ipython().{node.attr}")
            return
        qualified = self.resolve(node)
        if qualified is None:
            self.generic_visit(node)
        else:
            self.check_name(qualified, f"uses {qualified}")

    def visit_Constant(self, node: ast.Constant) -> None:
        if isinstance(node.value, str):
            if "/proc" in node.value:
                self.add(_PROC, "mentions /proc")
            if node.value.startswith("_diffnurbs"):
                self.add(_GRADING, f"mentions {node.value[:40]}")

    def visit_Call(self, node: ast.Call) -> None:
        if isinstance(node.func, ast.Attribute) and _is_get_ipython(node.func.value):
            self.ipython_call(node.func.attr, node.args)
            for arg in [*node.args, *node.keywords]:
                self.visit(arg)
            return
        if _is_get_ipython(node):
            self.add(_IPYTHON, "uses get_ipython()")
        function = self.resolve(node.func)
        if function in ("setattr", "delattr") and node.args:
            target = self.resolve(node.args[0])
            if target is not None and _LIBRARIES.match(target):
                self.add(_PATCH, f"calls {function} on {ast.unparse(node.args[0])}")
        if function is not None and _PATH_CALLS.match(function) and node.args:
            path = _literal(node.args[0])
            if path is not None and _OUTSIDE.match(path):
                self.add(_PATHS, f"opens the path {path[:60]}")
        self.generic_visit(node)

    def ipython_call(self, method: str, args: list[ast.expr]) -> None:
        """`get_ipython().method(...)`: what the transformed `!cmd` and `%magic` lines call."""
        first = _literal(args[0]) if args else None
        if method in ("system", "getoutput"):
            self.add(_SHELL, f"runs the shell command !{(first or '')[:60]}")
        elif method in ("run_line_magic", "run_cell_magic") and first is not None:
            prefix = "%" if method == "run_line_magic" else "%%"
            if first in _SHELL_MAGICS:
                self.add(_SHELL, f"runs the shell magic {prefix}{first}")
            elif first not in _HARMLESS_MAGICS:
                self.add(_IPYTHON, f"uses the IPython magic {prefix}{first}")
        else:
            self.add(_IPYTHON, f"uses get_ipython().{method}")

    def visit_Assign(self, node: ast.Assign) -> None:
        for target in node.targets:
            self.check_target(target)
        self.generic_visit(node)

    def visit_AugAssign(self, node: ast.AugAssign) -> None:
        self.check_target(node.target)
        self.generic_visit(node)

    def visit_AnnAssign(self, node: ast.AnnAssign) -> None:
        self.check_target(node.target)
        self.generic_visit(node)

    def visit_Delete(self, node: ast.Delete) -> None:
        for target in node.targets:
            self.check_target(target, "deletes")
        self.generic_visit(node)


def handed_out_code(exercise: nbformat.NotebookNode) -> list[str]:
    """The code an exercise hands out: its code cells that are not answer cells.

    **Arguments:**

    - `exercise`: the student notebook otter assign generates from a master.

    **Returns:**

    The cells' sources, for `submission_flags(..., provided=...)`.
    """
    return [
        cell.source
        for cell in exercise.cells
        if cell.cell_type == "code" and ANSWER_TAG not in cell.metadata.get("tags", [])
    ]


def _statement_keys(sources: Iterable[str]) -> set[str]:
    keys = set()
    for source in sources:
        try:
            keys.update(ast.dump(statement) for statement in _parse(source).body)
        except SyntaxError:
            continue  # handed-out code that does not parse cannot match a statement
    return keys


def static_flags(nb: nbformat.NotebookNode, provided: Iterable[str] = ()) -> list[str]:
    """The reasons found in a notebook's code, one per concern per code cell.

    **Arguments:**

    - `nb`: the submitted notebook.
    - `provided`: the code the exercise hands out (`handed_out_code`); top-level statements
        equal to one of its statements (formatting and comments aside) are not the student's
        and are not scanned, so the masters' own helpers (which switch library functions off
        during a test) are not flagged.

    **Returns:**

    Sentences such as `"code cell 7 imports subprocess (other programs)"`.
    """
    skip = _statement_keys(provided)
    sources = [cell.source for cell in nb.cells if cell.cell_type == "code"]
    trees: list[ast.Module | None] = []
    for source in sources:
        try:
            trees.append(_parse(source))
        except SyntaxError:
            trees.append(None)
    aliases = _aliases(tree for tree in trees if tree is not None)
    flags = []
    for number, (source, tree) in enumerate(zip(sources, trees, strict=True), start=1):
        if tree is None:
            concerns = dict.fromkeys(c for pattern, c in _TEXT_RULES if pattern.search(source))
            flags += [f"code cell {number} (which does not parse) touches {c}" for c in concerns]
            continue
        scan = _CellScan(aliases)
        for statement in tree.body:
            if ast.dump(statement) not in skip:
                scan.visit(statement)
        flags += [f"code cell {number} {reason}" for reason in scan.reasons.values()]
    return flags


def _number(value: float) -> str:
    return f"{round(value, 4):g}"


def runtime_flags(nb: nbformat.NotebookNode, result: GradeResult) -> list[str]:
    """The reasons found in a grading result (see the module's docstring).

    **Arguments:**

    - `nb`: the submitted notebook (to name cells).
    - `result`: its grade.

    **Returns:**

    Short sentences, empty for an ordinary result.
    """
    flags = []
    score = f"{_number(result.total)}/{_number(result.max_points)}"
    high = result.max_points > 0 and result.total >= result.max_points / 2
    if high and any("kernel died" in note for note in result.notes):
        flags.append(f"the kernel died, yet the notebook scored {score}")
    full = bool(result.possible) and all(
        result.scores.get(q, 0.0) >= points for q, points in result.possible.items()
    )
    unanswered = [e for e in result.errors if e.get("ename") == "NotImplementedError"]
    if full and unanswered:
        sources = [cell.source for cell in nb.cells if cell.cell_type == "code"]
        source = unanswered[0].get("source")
        where = f"code cell {sources.index(source) + 1}" if source in sources else "a cell"
        flags.append(f"every question passed, yet {where} raised NotImplementedError")
    for question, earned in result.scores.items():
        if question not in result.possible:
            flags.append(f"{question} is scored but is not a question of {result.master}")
        elif earned > result.possible[question]:
            flags.append(
                f"{question} scored {_number(earned)}, more than its "
                f"{_number(result.possible[question])} points"
            )
    return flags


def submission_flags(
    nb: nbformat.NotebookNode, result: GradeResult, *, provided: Iterable[str] = ()
) -> list[str]:
    """Why the teacher should read a submission's code.

    **Arguments:**

    - `nb`: the submitted notebook.
    - `result`: its grade.
    - `provided`: the code its exercise hands out (`handed_out_code`), not scanned.

    **Returns:**

    The static reasons (`static_flags`), then the runtime ones (`runtime_flags`).
    """
    return static_flags(nb, provided) + runtime_flags(nb, result)


SHORT_RUN_FRACTION = 1 / 3
"""A run shorter than this fraction of its master's median run is unusually short."""

SHORT_RUN_MINIMUM = 4
"""How many graded runs of a master `batch_flags` needs before it compares their times."""


def batch_flags(results: Sequence[GradeResult]) -> None:
    """Flag runs much shorter than the other runs of the same master (in place).

    A submission that scores well in a fraction of the time its classmates' take may not
    compute its answers. Runs that did not execute (unreadable notebooks, no master) are left
    out of the median.

    **Arguments:**

    - `results`: the graded batch; each flagged result gets one sentence in its `flags`.
    """
    by_master: dict[str, list[GradeResult]] = {}
    for result in results:
        if result.master is not None and result.seconds > 0:
            by_master.setdefault(result.master, []).append(result)
    for master, runs in by_master.items():
        if len(runs) < SHORT_RUN_MINIMUM:
            continue
        median = statistics.median(r.seconds for r in runs)
        for r in runs:
            if r.seconds < SHORT_RUN_FRACTION * median and r.total > r.max_points / 2:
                r.flags.append(
                    f"unusually short run: {r.seconds:.1f} s against a median of "
                    f"{median:.1f} s for {master}, with {_number(r.total)}/"
                    f"{_number(r.max_points)}"
                )
