"""Scoring with trusted code: the master's tests run in the grader's process, not the kernel.

A `Scorer` runs a question's OK-format tests (public and hidden) with otter's own runner in a
namespace built from the master's init cell (its imports and helpers). A name a test uses that
this namespace does not define and that is not a builtin is the student's: it is fetched from
the submission's kernel (`_remote`) as data (`_wire`). The student's functions come back as
`RemoteFunction` proxies, which call into the kernel with encoded arguments; values the wire
cannot carry come back as `RemoteObject`s, which fail every use with a readable message. So
the comparisons (`assert`, `np.allclose`, otter's runner) are trusted code on decoded data.

Trusted functions passed to the student's (a test's `lambda`, `np.sin`, a helper of the init
cell) travel as their source or importable name with the values they use (`_encode_function`);
lists and dicts they use are written back after the call (a test's `calls.append(...)`).
Decorators of a trusted `def` are not sent; a numpy `Generator` goes as its state (the trusted
one does not advance); library values go as data (a bound method with its value). While a
test has switched library functions or student globals off (`without_basis_functions` in the
init cells), every call switches the same names off in the kernel. A proxy called with JAX
tracers (`jax.grad` or `jax.jit` through a student function) becomes a `jax.pure_callback`
whose derivative the kernel computes.
"""

from __future__ import annotations

import ast
import builtins
import functools
import json
import linecache
import queue
import time
import types
import weakref
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jupyter_client.blocking import BlockingKernelClient

import diffnurbs as dn

from ._masters import Master
from ._wire import MAX_MESSAGE, MIME, VALUE_TYPES, Codec

RECOVERY_TIMEOUT = 5.0
"""Seconds an interrupted kernel gets to answer again before it counts as lost."""

MAX_CODE_DEPTH = 16
"""Cap on trusted functions sent inside one another (their globals and closures)."""

_BUILTIN_NAMES = frozenset(dir(builtins))
_DONT_RERAISE = (StopIteration, StopAsyncIteration, GeneratorExit)
_READABLE = "return numbers, arrays, strings, lists, dicts or diffnurbs curves/surfaces"


class KernelLost(Exception):
    """The kernel died or ignored an interrupt; `result` is the question's result so far.

    **Arguments:**

    - `message`: what happened.
    - `result`: the question's result dict, the case that lost the kernel failed.
    """

    def __init__(self, message: str, result: dict[str, Any] | None = None):
        super().__init__(message)
        self.result = result


class StudentError(Exception):
    """An exception the student's code raised in the kernel (type and message as data)."""


class TimedOut(AssertionError):
    """A call into the kernel did not answer in time (the kernel was interrupted)."""


class RemoteFunction:
    """A student's callable in the kernel; calling it calls it there.

    **Arguments:**

    - `scorer`: the `Scorer` that owns the channel.
    - `handle`: the kernel's handle (`id`, `type`, `name`).
    """

    def __init__(self, scorer: Scorer, handle: dict[str, Any]):
        self._scorer = scorer
        self._id = handle["id"]
        name = handle.get("name")
        self.__name__ = name[:100] if isinstance(name, str) else f"<{handle.get('type')}>"[:100]

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        leaves = jax.tree_util.tree_leaves((args, kwargs))
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return self._scorer._traced_call(self, args, kwargs)
        return self._scorer._call("call", self, args, kwargs)

    def __repr__(self) -> str:
        return f"<your function {self.__name__}>"


class RemoteObject:
    """A value from the kernel that the wire cannot carry: every use fails with a message.

    **Arguments:**

    - `origin`: where it came from ("your my_x returned", "your global x is").
    - `type_name`: the name of its type in the kernel.
    - `id`: the kernel's handle.
    """

    __slots__ = ("__weakref__", "_id", "_origin", "_type")

    def __init__(self, origin: str, type_name: str, id: int):
        object.__setattr__(self, "_origin", origin)
        object.__setattr__(self, "_type", type_name)
        object.__setattr__(self, "_id", id)

    def _refuse(self, *args: Any, **kwargs: Any) -> Any:
        raise AssertionError(
            f"{self._origin} a {self._type} that the grader cannot read: {_READABLE}"
        )

    def __getattr__(self, name: str) -> Any:
        self._refuse()

    def __repr__(self) -> str:
        return f"<a {self._type} from the submission>"

    __setattr__ = __eq__ = __ne__ = __lt__ = __le__ = __gt__ = __ge__ = _refuse
    __bool__ = __float__ = __int__ = __index__ = __complex__ = __len__ = __iter__ = _refuse
    __array__ = __getitem__ = __contains__ = __call__ = __neg__ = __abs__ = _refuse
    __add__ = __radd__ = __sub__ = __rsub__ = __mul__ = __rmul__ = _refuse
    __truediv__ = __rtruediv__ = __pow__ = __rpow__ = __matmul__ = __rmatmul__ = _refuse
    __hash__ = object.__hash__


class _Namespace(dict):
    """The tests' globals: the master's init cell, then the student's names on first use.

    doctest runs each test case in a `copy()` of the globals: a copy looks the names it lacks
    up in the namespace it was copied from, where the init cell's functions live.
    """

    def __init__(self, scorer: Scorer, parent: _Namespace | None = None):
        super().__init__()
        self._scorer = scorer
        self._parent = parent

    def copy(self) -> _Namespace:
        child = _Namespace(self._scorer, self._parent or self)
        dict.update(child, self)
        return child

    def __missing__(self, name: str) -> Any:
        if name in _BUILTIN_NAMES or name.startswith("__"):
            raise KeyError(name)
        value = self._parent[name] if self._parent is not None else self._scorer._fetch(name)
        self[name] = value
        return value

    def __contains__(self, name: object) -> bool:
        return dict.__contains__(self, name) or name in self._scorer._student_names()


class Scorer:
    """Scores a submission's questions with the master's tests, run in this process.

    **Arguments:**

    - `master`: the master (its tests and init cell).
    - `client`: a started client of the kernel that ran the submission's cells.
    - `interrupt`: interrupts the kernel (e.g. `KernelManager.interrupt_kernel`).
    - `call_timeout`: seconds one call into the kernel may take (the question's budget also
      bounds it).
    - `max_message`: cap on the characters of one answer from the kernel.

    A scorer belongs to one kernel: after `KernelLost`, restart the kernel, run the
    submission's cells again and score the remaining questions with a new `Scorer`.
    `round_trips` counts the requests sent to the kernel.
    """

    def __init__(
        self,
        master: Master,
        client: BlockingKernelClient,
        interrupt: Callable[[], None],
        *,
        call_timeout: float = 60.0,
        max_message: int = MAX_MESSAGE,
    ):
        self.master = master
        self.client = client
        self.interrupt = interrupt
        self.call_timeout = call_timeout
        self.round_trips = 0
        self._codec = Codec(self._encode_other, self._decode_tag, max_message=max_message)
        self._namespace: _Namespace | None = None
        self._student: dict[str, Any] = {}
        self._names: frozenset[str] | None = None
        self._handles: dict[int, Any] = {}
        self._released: list[int] = []
        self._refs: dict[int, Any] = {}
        self._code_depth = 0
        self._deadline = float("inf")
        self._lost: str | None = None
        self._notes: list[str] = []
        self._origin = "the submission gave"

    def score(self, question: str, *, timeout: float) -> dict[str, Any]:
        """Run one question's tests (public and hidden) against the submission.

        **Arguments:**

        - `question`: the question's name, e.g. `"q1"`.
        - `timeout`: seconds the question's tests may take, all together.

        **Returns:**

        `{"score", "possible", "cases", "notes"}`: one case per test case, `{"hidden",
        "passed", "points", "message"}`; `score <= possible`.

        **Raises:**

        `KernelLost` (with this question's result) when the kernel died or ignored an
        interrupt: restart it, run the submission's cells again and go on with the next
        question.
        """
        from otter.test_files import OKTestFile

        if question not in self.master.tests:
            raise ValueError(f"{question!r} is not a question of {self.master.name}")
        namespace = self._trusted_namespace()
        test_file = OKTestFile.from_spec(self.master.tests[question])
        self._notes, self._names = [], None
        self._deadline = time.monotonic() + timeout
        try:
            test_file.run(namespace)
        finally:
            self._deadline = float("inf")
        possible = float(test_file.possible)
        result = {
            "score": min(float(test_file.score), possible),
            "possible": possible,
            "cases": [
                {
                    "hidden": bool(r.test_case.hidden),
                    "passed": bool(r.passed),
                    "points": r.test_case.points,
                    "message": r.message,
                }
                for r in test_file.test_case_results
            ],
            "notes": [f"{question}: {note}" for note in self._notes],
        }
        if self._lost:
            raise KernelLost(self._lost, result)
        self._release()
        return result

    # -- the trusted namespace -------------------------------------------------------------

    def _trusted_namespace(self) -> _Namespace:
        if self._namespace is None:
            namespace = _Namespace(self)
            filename = f"<diffnurbs master {self.master.name} init>"
            source = _without_grader(self.master.init)
            # inspect.getsource (and so `_encode_function`) finds the init cell's functions
            lines = source.splitlines(keepends=True)
            linecache.cache[filename] = (len(source), None, lines, filename)
            exec(compile(source, filename, "exec"), namespace)
            self._namespace = namespace
            self._dn = dict(vars(dn))
        return self._namespace

    def _student_names(self) -> frozenset[str]:
        if self._names is None:
            self._names = frozenset(self._request({"op": "names"}, "the list of your names"))
        return self._names

    def _fetch(self, name: str) -> Any:
        answer = self._request({"op": "get", "name": name}, name, origin=f"your {name} is")
        if answer is _MISSING:
            raise KeyError(name)
        self._student[name] = answer
        return answer

    # -- calls -----------------------------------------------------------------------------

    def _switched(self) -> dict[str, Any]:
        """What the running test switched off: library functions and student globals."""
        switch_dn = {k: v for k, v in vars(dn).items() if k in self._dn and v is not self._dn[k]}
        namespace = self._namespace
        switch_ns = {
            k: dict.__getitem__(namespace, k)
            for k, v in self._student.items()
            if dict.__contains__(namespace, k) and dict.__getitem__(namespace, k) is not v
        }
        return {
            "switch_dn": self._switched_values(switch_dn),
            "switch_ns": self._switched_values(switch_ns),
        }

    def _switched_values(self, values: dict[str, Any]) -> dict[str, Any]:
        items = {}
        for name, value in values.items():
            try:
                items[name] = self._codec.encode(value)
            except ValueError:  # a replacement that cannot travel: a plain switched-off stub
                items[name] = {"$t": "code", "kind": "off", "name": name}
        return {"$t": "dict", "items": items}

    def _call(self, op: str, function: RemoteFunction, args: Any, kwargs: Any, **extra) -> Any:
        self._refs = {}
        message = {
            "op": op,
            "target": {"$t": "handle", "id": function._id},
            "args": self._codec.encode(list(args)),
            "kwargs": self._codec.encode(dict(kwargs)),
            **self._switched(),
            **extra,
        }
        return self._request(
            message, function.__name__, origin=f"your {function.__name__} returned"
        )

    def _traced_call(self, function: RemoteFunction, args: tuple, kwargs: dict) -> Any:
        """A call under a JAX transformation: a `pure_callback` with a kernel-side VJP."""
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(kwargs)):
            raise TypeError(
                f"the grader differentiates {function.__name__} in positional arguments only"
            )
        positions = [i for i, a in enumerate(args) if isinstance(a, jax.core.Tracer)]
        if any(jax.tree_util.tree_leaves(args[i]) != [args[i]] for i in positions):
            raise TypeError(
                f"the grader differentiates {function.__name__} in array arguments only"
            )

        def full(traced: tuple) -> list[Any]:
            merged = list(args)
            for i, value in zip(positions, traced, strict=True):
                merged[i] = value
            return merged

        specs = tuple((list(args[i].shape), args[i].dtype.name) for i in positions)
        shape = self._call("shape", function, full(specs), kwargs, positions=positions)
        if not (isinstance(shape, list) and len(shape) == 1):
            raise TypeError(
                f"the grader differentiates {function.__name__} with one array result only"
            )
        out = jax.ShapeDtypeStruct(tuple(shape[0][0]), np.dtype(shape[0][1]))

        def forward(*traced):
            value = self._call("call", function, full(traced), kwargs)
            return np.asarray(value, dtype=out.dtype).reshape(out.shape)

        def backward(cotangent, *traced):
            grads = self._call(
                "vjp",
                function,
                full(traced),
                kwargs,
                positions=positions,
                cotangent=self._codec.encode(np.asarray(cotangent)),
            )
            return tuple(
                np.asarray(g, dtype=t.dtype).reshape(t.shape)
                for g, t in zip(grads, traced, strict=True)
            )

        @jax.custom_vjp
        def remote(*traced):
            return jax.pure_callback(forward, out, *traced, vmap_method="sequential")

        def remote_fwd(*traced):
            return remote(*traced), traced

        def remote_bwd(traced, cotangent):
            shapes = tuple(jax.ShapeDtypeStruct(t.shape, t.dtype) for t in traced)
            return jax.pure_callback(backward, shapes, cotangent, *traced, vmap_method="sequential")

        remote.defvjp(remote_fwd, remote_bwd)
        return remote(*[args[i] for i in positions])

    # -- the channel -----------------------------------------------------------------------

    def _request(self, message: dict[str, Any], what: str, *, origin: str = "") -> Any:
        """Send one request (its fields encoded already) and decode the answer.

        **Returns:**

        The answer's value, `_MISSING` for a global the student does not have.
        """
        if self._lost:
            raise StudentError(f"not run: {self._lost}")
        timeout = min(self.call_timeout, self._deadline - time.monotonic())
        if timeout <= 0:
            raise TimedOut(f"not run: the question's time ran out before {what}")
        sent, self._refs = self._refs, {}
        payload = self._exchange(json.dumps(message, allow_nan=False), timeout, what)
        self.round_trips += 1
        self._origin = origin
        answer = self._codec.loads(payload)
        if not isinstance(answer, dict):
            raise ValueError(f"the kernel answered a {type(answer).__name__}, expected a dict")
        _write_back(sent, answer.get("refs", {}))
        if "error" in answer:
            raise _student_error(answer["error"])
        if answer.get("missing") is True:
            return _MISSING
        return answer.get("ok")

    def _exchange(self, message: str, timeout: float, what: str) -> str:
        """Run `serve(message)` in the kernel; the last answer it published, as text."""
        code = f'__import__("diffnurbs_course._remote", fromlist=["serve"]).serve({message!r})'
        msg_id = self.client.execute(code, silent=True, store_history=False)
        deadline = time.monotonic() + timeout
        payload, failure = None, ""
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._recover(msg_id, f"timed out after {timeout:.3g} s in {what}")
                raise TimedOut(f"timed out after {timeout:.3g} s in {what}")
            try:
                msg = self.client.get_iopub_msg(timeout=min(remaining, 1.0))
            except queue.Empty:
                if not self.client.is_alive():  # dead: no need to wait for the time-out
                    self._lost = f"the kernel died in {what}"
                    raise StudentError(self._lost) from None
                continue
            if msg["parent_header"].get("msg_id") != msg_id:
                continue
            if msg["msg_type"] == "display_data":
                data = msg["content"].get("data", {}).get(MIME)
                payload = data if isinstance(data, str) else payload
            elif msg["msg_type"] == "error":  # `serve` itself failed (an import, a bad name)
                failure = f": {msg['content'].get('ename')}: {msg['content'].get('evalue')}"
            elif msg["msg_type"] == "status" and msg["content"]["execution_state"] == "idle":
                break
        _drain(self.client)
        if payload is None:
            raise StudentError(f"the kernel gave the grader no answer for {what}{failure[:500]}")
        return payload

    def _recover(self, msg_id: str, note: str) -> None:
        """Interrupt the kernel; if it does not answer within `RECOVERY_TIMEOUT`, it is lost."""
        self._notes.append(note)
        self.interrupt()
        deadline = time.monotonic() + RECOVERY_TIMEOUT
        for wanted in (msg_id, self.client.execute("pass", silent=True, store_history=False)):
            while True:
                remaining = deadline - time.monotonic()
                try:
                    msg = self.client.get_iopub_msg(timeout=max(remaining, 0.01))
                except queue.Empty:
                    if remaining > 0:
                        continue
                    self._lost = f"the kernel ignored the interrupt after: {note}"
                    return
                if (
                    msg["parent_header"].get("msg_id") == wanted
                    and msg["msg_type"] == "status"
                    and msg["content"]["execution_state"] == "idle"
                ):
                    break
        _drain(self.client)

    def _release(self) -> None:
        """Tell the kernel to forget the handles whose proxies are gone."""
        if self._released and not self._lost:
            ids, self._released = self._released, []
            self._deadline = time.monotonic() + RECOVERY_TIMEOUT
            try:
                self._request({"op": "release", "ids": ids}, "releasing handles")
            finally:
                self._deadline = float("inf")

    # -- encoding --------------------------------------------------------------------------

    def _decode_tag(self, tag: str, obj: dict[str, Any]) -> Any:
        if tag != "handle":
            raise ValueError(f"the kernel may not send {tag!r} values: refused")
        id = obj["id"]
        if not isinstance(id, int):
            raise ValueError(f"a handle id must be an int, got {id!r}")
        if id in self._handles and self._handles[id]() is not None:
            return self._handles[id]()
        if obj.get("callable") is True:
            value = RemoteFunction(self, obj)
        else:
            value = RemoteObject(self._origin, str(obj.get("type"))[:100], id)
        self._handles[id] = weakref.ref(value)
        weakref.finalize(value, self._released.append, id)
        return value

    def _encode_other(self, value: Any) -> dict[str, Any]:
        """A trusted value the wire does not carry as data: a handle or a function."""
        if isinstance(value, RemoteFunction | RemoteObject):
            return {"$t": "handle", "id": object.__getattribute__(value, "_id")}
        if isinstance(value, types.ModuleType):
            return {"$t": "code", "kind": "import", "module": value.__name__}
        if isinstance(value, functools.partial):
            return {
                "$t": "code",
                "kind": "partial",
                "func": self._codec.encode(value.func),
                "args": self._codec.encode(list(value.args)),
                "keywords": self._codec.encode(dict(value.keywords)),
            }
        if isinstance(value, np.random.Generator):
            state = self._codec.encode(value.bit_generator.state)
            return {"$t": "code", "kind": "rng", "state": state}
        if isinstance(value, types.MethodType) and type(value.__self__) in VALUE_TYPES.values():
            method = {"self": self._codec.encode(value.__self__), "name": value.__name__}
            return {"$t": "code", "kind": "method", **method}
        name = _import_name(value)
        if name is not None:
            return {"$t": "code", "kind": "import", "module": name[0], "qualname": name[1]}
        if isinstance(value, types.FunctionType):
            return self._encode_function(value)
        raise ValueError(f"the grader cannot send a {type(value).__name__} to the submission")

    def _encode_function(self, function: types.FunctionType) -> dict[str, Any]:
        """A trusted function as source, with the globals and closure values it uses."""
        if self._code_depth >= MAX_CODE_DEPTH:
            raise ValueError(f"{function.__qualname__}: trusted functions nested too deep")
        source, kind = function_source(function)
        code, scope = function.__code__, function.__globals__
        used = {}
        for name in _names(code):
            if dict.__contains__(scope, name):
                value = dict.__getitem__(scope, name)
                if value is not function:  # a recursive def defines itself
                    used[name] = value
        for name, cell in zip(code.co_freevars, function.__closure__ or (), strict=True):
            try:
                used[name] = cell.cell_contents
            except ValueError:  # an empty cell: the enclosing function has not set it yet
                continue
        self._code_depth += 1
        try:
            return {
                "$t": "code",
                "kind": kind,
                "name": code.co_name,  # what the source defines (`wraps` changes __name__)
                "source": source,
                "globals": {"$t": "dict", "items": {k: self._shared(v) for k, v in used.items()}},
                "defaults": self._codec.encode(function.__defaults__),
                "kwdefaults": self._codec.encode(function.__kwdefaults__),
            }
        finally:
            self._code_depth -= 1

    def _shared(self, value: Any) -> Any:
        """A list or dict a trusted function uses goes as a `ref`, written back after the call."""
        if type(value) in (list, dict):
            self._refs[id(value)] = value
            return {"$t": "ref", "id": id(value), "value": self._codec.encode(value)}
        return self._codec.encode(value)


_MISSING = object()


def _write_back(sent: dict[int, Any], refs: Any) -> None:
    """Update the lists and dicts trusted functions used with their values after the call."""
    if not isinstance(refs, dict):
        raise ValueError("the kernel's refs are not a dict")
    for key, value in refs.items():
        original = sent.get(int(key)) if str(key).isdigit() else None
        if type(original) is list and type(value) is list:
            original[:] = value
        elif type(original) is dict and type(value) is dict:
            original.clear()
            original.update(value)


def _drain(client: BlockingKernelClient) -> None:
    """Drop the kernel's execute replies (the grader reads the answers on iopub)."""
    while True:
        try:
            client.get_shell_msg(timeout=0)
        except queue.Empty:
            return


def _student_error(error: Any) -> Exception:
    """The exception a student's code raised, rebuilt: a builtin type as itself."""
    if not isinstance(error, dict):
        return StudentError("the kernel reported an unreadable error")
    name, message = str(error.get("type"))[:100], str(error.get("message"))
    cls = getattr(builtins, name, None)
    if isinstance(cls, type) and issubclass(cls, Exception) and not issubclass(cls, _DONT_RERAISE):
        try:
            return cls(message)
        except TypeError:  # an exception class with other constructor arguments
            pass
    return StudentError(f"{name}: {message}")


def _without_grader(source: str) -> str:
    """The init cell without a `grader = ...Notebook(...)` statement (otter's, in the kernel)."""
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == "grader" for t in node.targets)
            and isinstance(node.value, ast.Call)
            and "Notebook" in ast.unparse(node.value.func)
        ):
            for i in range(node.lineno - 1, node.end_lineno):
                lines[i] = "\n"
    return "".join(lines)


def _names(code: types.CodeType) -> set[str]:
    """The global (and attribute) names a code object and the ones nested in it use."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _names(const)
    return names


def _import_name(value: Any) -> tuple[str, str] | None:
    """`(module, qualname)` that imports exactly `value`, if there is one."""
    module = getattr(value, "__module__", None)
    qualname = getattr(value, "__qualname__", None) or getattr(value, "__name__", None)
    if not isinstance(module, str) or not isinstance(qualname, str):
        return None
    if module == "__main__" or "<" in qualname:
        return None
    try:
        found = __import__(module, fromlist=["_"])
        for part in qualname.split("."):
            found = getattr(found, part)
    except (ImportError, AttributeError):
        return None
    return (module, qualname) if found is value else None


def _inside(span: tuple[int, int, int, int], node: ast.AST) -> bool:
    start, end = (span[0], span[1]), (span[2], span[3])
    return (node.lineno, node.col_offset) <= start and end <= (node.end_lineno, node.end_col_offset)


def _extent(node: ast.AST) -> tuple[int, int]:
    return (node.end_lineno - node.lineno, node.end_col_offset - node.col_offset)


def function_source(function: types.FunctionType) -> tuple[str, str]:
    """The exact source of a function or lambda, from `linecache` (doctest registers the
    examples it runs; `Scorer` registers the init cell).

    **Arguments:**

    - `function`: a Python function.

    **Returns:**

    `(source, kind)`: the source (a `def` without its decorators, indented as in its file,
    or a lambda expression) and `"def"` or `"lambda"`.
    """
    code = function.__code__
    text = "".join(linecache.getlines(code.co_filename, function.__globals__))
    if not text:
        raise ValueError(f"the source of {function.__qualname__} is not available")
    try:
        tree = ast.parse(text)
    except SyntaxError:
        raise ValueError(f"the source of {function.__qualname__} does not parse") from None
    first = code.co_firstlineno
    if code.co_name == "<lambda>":
        kind = "lambda"
        found = [n for n in ast.walk(tree) if isinstance(n, ast.Lambda) and n.lineno == first]
        if len(found) > 1:
            # several lambdas start on the line: the innermost one around all of the code's
            # positions (an outer lambda's include the inner one's; RESUME's is (0, 0))
            spans = [(p[0], p[2], p[1], p[3]) for p in code.co_positions() if p[0] and p[3]]
            found = [n for n in found if all(_inside(s, n) for s in spans)]
            found = [min(found, key=_extent)] if found else []
    else:
        kind = "def"
        found = [
            n
            for n in ast.walk(tree)
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
            and n.name == code.co_name
            and (n.decorator_list[0].lineno if n.decorator_list else n.lineno) == first
        ]
    if len(found) != 1:
        raise ValueError(
            f"cannot tell the source of {function.__qualname__} ({len(found)} matches)"
        )
    return ast.get_source_segment(text, found[0], padded=True), kind
