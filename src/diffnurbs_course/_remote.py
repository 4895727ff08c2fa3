"""The kernel's end of the grading channel: one operation per request, answered as data.

The grader (`_scoring.Scorer`) sends `serve(<json>)` as a one-line `execute_request`; `serve`
performs the operation on the student's globals and publishes the encoded answer as a
`display_data` of MIME type `_wire.MIME`. This module runs in the student's kernel, so nothing
it does is trusted: the grader decodes its answers as data only, and a student who forges one
only forges their own answer.

Operations (`{"op": ...}`):

- `get` `name`: the value of a student global (`{"missing": true}` if there is none);
- `names`: the names of the student's globals;
- `call` `target` `args` `kwargs` `switch`: call a handle or a global with decoded arguments,
  with the library functions and student globals in `switch` replaced for the call;
- `shape` `target` `args`: `jax.eval_shape` of a call, `args` as `[shape, dtype]` pairs;
- `vjp` `target` `args` `cotangent`: the cotangents of a call's arguments (`jax.vjp`);
- `release` `ids`: forget handles.
"""

from __future__ import annotations

import builtins
import functools
import json
import sys
import textwrap
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import diffnurbs as dn

from ._wire import MIME, Codec

MAX_ERROR = 2000
"""Characters kept of a student exception's message."""

_HANDLES: dict[int, Any] = {}
_NEXT = [0]


def _user_ns() -> dict[str, Any]:
    from IPython import get_ipython

    shell = get_ipython()
    return shell.user_ns if shell is not None else sys.modules["__main__"].__dict__


class _Globals(dict):
    """The globals of a trusted function rebuilt here: what it was sent with, then the
    student's globals (looked up when used), then the builtins."""

    def __missing__(self, name: str) -> Any:
        return _user_ns()[name]


def _handle(value: Any) -> dict[str, Any]:
    _NEXT[0] += 1
    _HANDLES[_NEXT[0]] = value
    name = getattr(value, "__name__", None)
    return {
        "$t": "handle",
        "id": _NEXT[0],
        "type": type(value).__name__,
        "callable": callable(value),
        "name": name if isinstance(name, str) else None,
    }


class _Request:
    """The decoding state of one request: the shared mutable values it carries (`ref`)."""

    def __init__(self):
        self.refs: dict[int, Any] = {}
        self.codec = Codec(_handle, self._tag, max_message=sys.maxsize)

    def _tag(self, tag: str, obj: dict[str, Any]) -> Any:
        if tag == "handle":
            if obj["id"] not in _HANDLES:
                raise ValueError(f"no handle {obj['id']!r} in the kernel")
            return _HANDLES[obj["id"]]
        if tag == "ref":
            if obj["id"] not in self.refs:
                self.refs[obj["id"]] = self.codec.decode(obj["value"])
            return self.refs[obj["id"]]
        return self._code(obj)

    def _code(self, obj: dict[str, Any]) -> Any:
        """A trusted callable, rebuilt from its description (see `_scoring`)."""
        kind = obj["kind"]
        if kind == "import":
            value = __import__(obj["module"], fromlist=["_"])
            for part in obj.get("qualname", "").split(".") if obj.get("qualname") else []:
                value = getattr(value, part)
            return value
        if kind == "partial":
            args, keywords = self.codec.decode(obj["args"]), self.codec.decode(obj["keywords"])
            return functools.partial(self.codec.decode(obj["func"]), *args, **keywords)
        if kind == "rng":
            state = self.codec.decode(obj["state"])
            generator = np.random.Generator(getattr(np.random, state["bit_generator"])())
            generator.bit_generator.state = state
            return generator
        if kind == "method":
            return getattr(self.codec.decode(obj["self"]), obj["name"])
        if kind == "off":
            return _switched_off(obj["name"])
        namespace = _Globals(np=np, jnp=jnp, jax=jax, dn=dn, __builtins__=builtins)
        namespace.update(self.codec.decode(obj["globals"]))
        source = obj["source"]
        if kind == "lambda":
            exec(compile(f"__fn__ = (\n{source}\n)", "<grader>", "exec"), namespace)
            function = namespace.pop("__fn__")
        else:
            exec(compile(textwrap.dedent(source), "<grader>", "exec"), namespace)
            function = namespace[obj["name"]]
        function.__defaults__ = self.codec.decode(obj["defaults"])
        function.__kwdefaults__ = self.codec.decode(obj["kwdefaults"])
        return function


def _switched_off(name: str) -> Callable[..., Any]:
    def switched_off(*args, **kwargs):
        raise AssertionError(f"the tests switched off {name} here")

    return switched_off


def _call(request: _Request, obj: dict[str, Any]) -> Any:
    """A `call`, `shape` or `vjp`, with the switched-off names switched off for it."""
    function = request.codec.decode(obj["target"])
    args = request.codec.decode(obj["args"])
    kwargs = request.codec.decode(obj["kwargs"])
    switch_dn = request.codec.decode(obj["switch_dn"])
    switch_ns = request.codec.decode(obj["switch_ns"])
    user_ns = _user_ns()
    saved_dn = {name: getattr(dn, name) for name in switch_dn}
    saved_ns = {name: user_ns[name] for name in switch_ns if name in user_ns}
    try:
        for name, value in switch_dn.items():
            setattr(dn, name, value)
        user_ns.update(switch_ns)
        if obj["op"] == "call":
            return function(*args, **kwargs)
        positions = obj["positions"]

        def partial(*traced):
            merged = list(args)
            for i, value in zip(positions, traced, strict=True):
                merged[i] = value
            return function(*merged, **kwargs)

        if obj["op"] == "shape":
            specs = [jax.ShapeDtypeStruct(tuple(args[i][0]), args[i][1]) for i in positions]
            out = jax.tree_util.tree_leaves(jax.eval_shape(partial, *specs))
            return [[list(leaf.shape), leaf.dtype.name] for leaf in out]
        _, vjp = jax.vjp(partial, *[jnp.asarray(args[i]) for i in positions])
        return list(vjp(jnp.asarray(request.codec.decode(obj["cotangent"]))))
    finally:
        for name, value in saved_dn.items():
            setattr(dn, name, value)
        for name in switch_ns:
            user_ns.pop(name, None)
        user_ns.update(saved_ns)


def _answer(request: _Request, obj: dict[str, Any]) -> dict[str, Any]:
    op = obj["op"]
    if op == "get":
        user_ns = _user_ns()
        if obj["name"] not in user_ns:
            return {"missing": True}
        return {"ok": user_ns[obj["name"]]}
    if op == "names":
        return {"ok": sorted(n for n in _user_ns() if not n.startswith("_"))}
    if op == "release":
        for i in obj["ids"]:
            _HANDLES.pop(i, None)
        return {"ok": None}
    if op in ("call", "shape", "vjp"):
        return {"ok": _call(request, obj)}
    if op == "get" and not isinstance(obj["name"], str):
        raise ValueError("a name must be a str")
    raise ValueError(f"unknown operation {op!r}")


def serve(message: str) -> None:
    """Perform one request and publish its answer (see the module's notes).

    **Arguments:**

    - `message`: the request, JSON (`_wire`).
    """
    from IPython.display import display

    request = _Request()
    try:
        answer = _answer(request, json.loads(message))
    except Exception as error:
        answer = {"error": _error(error)}
    answer["refs"] = {str(k): v for k, v in request.refs.items()}
    try:
        text = request.codec.dumps(answer)
    except Exception as error:
        text = request.codec.dumps({"error": _error(error), "refs": {}})
    display({MIME: text}, raw=True)


def _error(error: BaseException) -> dict[str, Any]:
    message = str(error)
    if len(message) > MAX_ERROR:
        message = message[:MAX_ERROR] + f"... ({len(message) - MAX_ERROR} more characters)"
    return {"type": type(error).__name__, "message": message}
