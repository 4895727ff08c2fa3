"""The data encoding between the grader and a submission's kernel: JSON, never pickle.

Every value is a JSON document. Python's JSON types travel as themselves except dicts, which
are always wrapped in a tagged object, so any other JSON object is a tag, `{"$t": name, ...}`:

- `float` nan/inf, `complex`, `bytes`, `tuple`, `fractions.Fraction`, `Ellipsis` (a blank
  answer `x = ...`), `dict` (str keys as an object, other keys as pairs);
- numpy arrays and scalars and JAX arrays of the whitelisted dtypes (`DTYPES`): shape, dtype
  and the base64 of the little-endian buffer; object arrays of numbers and strings (exact
  fractions) element by element, never as objects;
- the library's value types (`VALUE_TYPES`): the type's name and its fields;
- pure arithmetic functions (`PURE_FUNCTIONS`: `math.sin`, `operator.add`, `np.sin`) by name;
- `handle`, `code`, `ref`: what the two ends make of everything else (`Codec.other` and
  `Codec.tag`): a remote object, a trusted function sent as source, a shared mutable value.

Decoding is bounded: a message longer than `MAX_MESSAGE` characters or nested deeper than
`MAX_DEPTH` is refused with a `ValueError`, as is every tag, dtype or type name not listed
here, and an array whose shape does not match its data.
"""

from __future__ import annotations

import base64
import cmath
import fractions
import json
import math
import operator
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import diffnurbs as dn

MIME = "application/vnd.diffnurbs.rpc+json"
"""The MIME type of the kernel's answers (a `display_data` output)."""

MAX_MESSAGE = 64 * 2**20
"""Default cap, in characters, on one message from the kernel."""

MAX_DEPTH = 64
"""Cap on the nesting of containers in one message."""

MAX_DIMS = 32
"""Cap on the number of dimensions of an array."""

DTYPES = frozenset(
    ("bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64")
) | frozenset(("float16", "float32", "float64", "complex64", "complex128"))
"""The array dtypes that travel (object and structured dtypes never do)."""

# The library's value types the answers return, captured at import: the tests may switch
# `dn.NURBSCurve` off (`setattr(dn, ...)`) while values still have to be decoded.
VALUE_TYPES: dict[str, type] = {
    name: value
    for name, value in sorted(vars(dn).items())
    if isinstance(value, type)
    and issubclass(value, eqx.Module)
    and not value.__name__.startswith("Abstract")
}
"""The `diffnurbs` value types that travel, by name (`eqx.Module` subclasses)."""

_TYPE_NAMES = {cls: name for name, cls in VALUE_TYPES.items()}

_OPERATORS = [
    "abs",
    "add",
    "and_",
    "eq",
    "floordiv",
    "ge",
    "gt",
    "index",
    "inv",
    "invert",
    "le",
    "lshift",
    "lt",
    "matmul",
    "mod",
    "mul",
    "ne",
    "neg",
    "not_",
    "or_",
    "pos",
    "pow",
    "rshift",
    "sub",
    "truediv",
    "truth",
    "xor",
]

PURE_FUNCTIONS: dict[str, Callable[..., Any]] = {
    **{f"math.{n}": f for n, f in vars(math).items() if callable(f) and not n.startswith("_")},
    **{f"cmath.{n}": f for n, f in vars(cmath).items() if callable(f) and not n.startswith("_")},
    **{f"operator.{n}": getattr(operator, n) for n in _OPERATORS},
    **{f"numpy.{n}": f for n, f in vars(np).items() if isinstance(f, np.ufunc)},
}
"""Functions that travel by name: pure arithmetic (`math`, `cmath`, the arithmetic and
comparison `operator`s, numpy's ufuncs), so a table of operations such as `{"+": operator.add,
"sin": math.sin}` is data, and each end calls its own copy."""

_PURE_NAMES = {id(f): name for name, f in PURE_FUNCTIONS.items()}


def _rebuild_curve(fields: dict[str, Any]) -> Any:
    return VALUE_TYPES["NURBSCurve"](
        fields["control_points"], fields["degree"], fields["knots"], fields["weights"]
    )


def _rebuild_surface(fields: dict[str, Any]) -> Any:
    knots = (fields["knots_u"], fields["knots_v"])
    return VALUE_TYPES["NURBSSurface"](
        fields["control_points"], fields["degree"], knots, fields["weights"]
    )


# Curves and surfaces go through their constructors, which check shapes, degrees and knots.
# The other types' constructors take other arguments than their fields (`CoonsPatch` builds
# its corners, `HalfEdgeMesh` its tables from faces): their fields are set as they came.
_REBUILD: dict[str, Callable[[dict[str, Any]], Any]] = {
    "NURBSCurve": _rebuild_curve,
    "NURBSSurface": _rebuild_surface,
}


def _rebuild_fields(cls: type, fields: dict[str, Any]) -> Any:
    value = object.__new__(cls)
    for name, field in fields.items():
        object.__setattr__(value, name, field)
    return value


class Codec:
    """One end's encoder and decoder.

    **Arguments:**

    - `other`: encodes a value none of the wire's types covers, as a tagged dict (a handle,
      code), or raises `ValueError`.
    - `tag`: decodes the tags `handle`, `code` and `ref` (`tag(name, obj)`), or raises
      `ValueError` for the ones this end refuses.
    - `max_message`: cap on the characters of a message to decode.
    """

    def __init__(
        self,
        other: Callable[[Any], dict[str, Any]],
        tag: Callable[[str, dict[str, Any]], Any],
        *,
        max_message: int = MAX_MESSAGE,
    ):
        self.other = other
        self.tag = tag
        self.max_message = max_message

    def dumps(self, value: Any) -> str:
        """`value` as a JSON message."""
        return json.dumps(self.encode(value), allow_nan=False, separators=(",", ":"))

    def loads(self, text: str) -> Any:
        """The value of a JSON message (see the module's notes for what is refused)."""
        if not isinstance(text, str):
            raise ValueError(f"a wire message must be a str, got {type(text).__name__}")
        if len(text) > self.max_message:
            raise ValueError(
                f"a message of {len(text)} characters is over the grader's cap of "
                f"{self.max_message}: return smaller values"
            )
        try:
            obj = json.loads(text, parse_constant=_no_constant)
        except RecursionError:
            raise ValueError(f"a message nested deeper than {MAX_DEPTH} levels") from None
        return self.decode(obj)

    def encode(self, value: Any, depth: int = 0) -> Any:
        """`value` as a JSON-able object."""
        if depth > MAX_DEPTH:
            raise ValueError(f"a value nested deeper than {MAX_DEPTH} levels (or a cycle)")
        if value is None or isinstance(value, bool | str):
            return value
        if isinstance(value, int) and type(value) is int:
            return value
        if type(value) is float:
            return value if math.isfinite(value) else {"$t": "float", "v": repr(value)}
        if type(value) is complex:
            return {"$t": "complex", "re": self.encode(value.real), "im": self.encode(value.imag)}
        if value is Ellipsis:
            return {"$t": "ellipsis"}
        if type(value) is bytes:
            return {"$t": "bytes", "b64": base64.b64encode(value).decode("ascii")}
        if type(value) is fractions.Fraction:
            return {"$t": "fraction", "n": str(value.numerator), "d": str(value.denominator)}
        if type(value) is list:
            return [self.encode(v, depth + 1) for v in value]
        if type(value) is tuple:
            return {"$t": "tuple", "items": [self.encode(v, depth + 1) for v in value]}
        if type(value) is dict:
            if all(type(k) is str for k in value):
                items = {k: self.encode(v, depth + 1) for k, v in value.items()}
                return {"$t": "dict", "items": items}
            pairs = [
                [self.encode(k, depth + 1), self.encode(v, depth + 1)] for k, v in value.items()
            ]
            return {"$t": "dict", "pairs": pairs}
        if isinstance(value, np.ndarray | np.generic) and value.dtype.name in DTYPES:
            return _encode_array(np.asarray(value), scalar=isinstance(value, np.generic))
        if type(value) is np.ndarray and value.dtype == object and value.ndim <= MAX_DIMS:
            # element by element, as data: exact fractions in an array (`np.array([Fraction(7,
            # 3), ...])`); an element that is no number or string makes the whole a handle
            items = [self.encode(v, depth + 1) for v in value.ravel().tolist()]
            if all(type(v) in _PLAIN or v.get("$t") in _NUMBER_TAGS for v in items):
                return {"$t": "objects", "shape": list(value.shape), "items": items}
        if (
            isinstance(value, jax.Array)
            and not isinstance(value, jax.core.Tracer)
            and value.dtype.name in DTYPES
        ):
            return _encode_array(np.asarray(value), jax=True)
        name = _PURE_NAMES.get(id(value))
        if name is not None and PURE_FUNCTIONS[name] is value:
            return {"$t": "function", "name": name}
        if type(value) in _TYPE_NAMES:
            fields = {f: self.encode(getattr(value, f), depth + 1) for f in _fields(type(value))}
            return {"$t": "value", "type": _TYPE_NAMES[type(value)], "fields": fields}
        return self.other(value)

    def decode(self, obj: Any, depth: int = 0) -> Any:
        """The value of a JSON-able object made by `encode` (at the other end)."""
        if depth > MAX_DEPTH:
            raise ValueError(f"a message nested deeper than {MAX_DEPTH} levels")
        if obj is None or isinstance(obj, bool | int | float | str):
            return obj
        if isinstance(obj, list):
            return [self.decode(v, depth + 1) for v in obj]
        if not isinstance(obj, dict):
            raise ValueError(f"not a wire value: {type(obj).__name__}")
        tag = obj.get("$t")
        try:
            return self._decode_tag(tag, obj, depth)
        except (KeyError, TypeError, AttributeError, ZeroDivisionError) as error:
            raise ValueError(f"a malformed {tag!r} value on the wire: {error!r}") from None

    def _decode_tag(self, tag: Any, obj: dict[str, Any], depth: int) -> Any:
        if tag == "float":
            if obj["v"] not in ("nan", "inf", "-inf"):
                raise ValueError(f"a float tag holds {obj['v']!r}, expected nan, inf or -inf")
            return float(obj["v"])
        if tag == "complex":
            return complex(_number(self.decode(obj["re"])), _number(self.decode(obj["im"])))
        if tag == "ellipsis":
            return Ellipsis
        if tag == "bytes":
            return base64.b64decode(_str(obj["b64"]), validate=True)
        if tag == "fraction":
            return fractions.Fraction(int(_str(obj["n"])), int(_str(obj["d"])))
        if tag == "tuple":
            return tuple(self.decode(v, depth + 1) for v in _list(obj["items"]))
        if tag == "dict":
            if "items" in obj:
                items = obj["items"]
                if not isinstance(items, dict):
                    raise ValueError("a dict's items must be a JSON object")
                return {k: self.decode(v, depth + 1) for k, v in items.items()}
            pairs = [_list(p) for p in _list(obj["pairs"])]
            return {self.decode(k, depth + 1): self.decode(v, depth + 1) for k, v in pairs}
        if tag == "array":
            return _decode_array(obj)
        if tag == "objects":
            shape, items = _shape(obj["shape"]), _list(obj["items"])
            if math.prod(shape) != len(items):
                raise ValueError(f"an object array of shape {tuple(shape)} has {len(items)} items")
            values = [self.decode(v, depth + 1) for v in items]
            if not all(type(v) in _ELEMENT_TYPES for v in values):
                raise ValueError("an object array may hold numbers and strings only")
            array = np.empty(len(values), dtype=object)
            array[:] = values
            return array.reshape(shape)
        if tag == "value":
            name = obj["type"]
            if name not in VALUE_TYPES:
                raise ValueError(f"{name!r} is not one of the value types {sorted(VALUE_TYPES)}")
            fields = {k: self.decode(v, depth + 1) for k, v in obj["fields"].items()}
            if set(fields) != set(_fields(VALUE_TYPES[name])):
                raise ValueError(f"a {name} needs the fields {_fields(VALUE_TYPES[name])}")
            rebuild = _REBUILD.get(name)
            return rebuild(fields) if rebuild else _rebuild_fields(VALUE_TYPES[name], fields)
        if tag == "function":
            if obj["name"] not in PURE_FUNCTIONS:
                raise ValueError(f"{obj['name']!r} is not one of the functions that travel by name")
            return PURE_FUNCTIONS[obj["name"]]
        if tag in ("handle", "code", "ref"):
            return self.tag(tag, obj)
        raise ValueError(f"unknown wire tag {tag!r} (keys {sorted(obj)[:5]}): refused")


_PLAIN = (type(None), bool, int, float, str)
_NUMBER_TAGS = frozenset(("float", "complex", "fraction"))
_ELEMENT_TYPES = (type(None), bool, int, float, complex, str, fractions.Fraction)


def _shape(shape: Any) -> list[int]:
    shape = _list(shape)
    if len(shape) > MAX_DIMS or not all(type(n) is int and n >= 0 for n in shape):
        raise ValueError(f"an array shape must be at most {MAX_DIMS} sizes >= 0, got {shape!r}")
    return shape


def _fields(cls: type) -> list[str]:
    return list(cls.__dataclass_fields__)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON: the wire tags non-finite floats")


def _number(value: Any) -> float:
    if type(value) not in (int, float):
        raise ValueError(f"expected a number, got {type(value).__name__}")
    return value


def _str(value: Any) -> str:
    if not isinstance(value, str):
        raise ValueError(f"expected a string, got {type(value).__name__}")
    return value


def _list(value: Any) -> list[Any]:
    if not isinstance(value, list):
        raise ValueError(f"expected a list, got {type(value).__name__}")
    return value


def _encode_array(array: np.ndarray, *, scalar: bool = False, jax: bool = False) -> dict:
    data = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<"))
    return {
        "$t": "array",
        "dtype": array.dtype.name,
        "shape": list(array.shape),
        "b64": base64.b64encode(data.tobytes()).decode("ascii"),
        "scalar": scalar,
        "jax": jax,
    }


def _decode_array(obj: dict[str, Any]) -> Any:
    dtype, shape = obj["dtype"], _shape(obj["shape"])
    if dtype not in DTYPES:
        raise ValueError(f"arrays of dtype {dtype!r} are refused: expected one of {sorted(DTYPES)}")
    data = base64.b64decode(_str(obj["b64"]), validate=True)
    little = np.dtype(dtype).newbyteorder("<")
    if math.prod(shape) * little.itemsize != len(data):
        raise ValueError(
            f"an array of shape {tuple(shape)} and dtype {dtype} has {len(data)} bytes of data, "
            f"expected {math.prod(shape) * little.itemsize}"
        )
    array = np.frombuffer(data, little).astype(dtype).reshape(shape)
    if obj.get("jax"):
        return jnp.asarray(array)
    return array[()] if obj.get("scalar") else array
