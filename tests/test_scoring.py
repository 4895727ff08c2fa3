"""Trusted scoring (`_scoring.Scorer`): the master's tests run in this process, the student's
names come from the kernel as data. The demo master scores full marks, the blank demo exercise
0, and every forging attempt on the blank exercise 0; the wire format round-trips every type
it carries exactly and refuses the rest with a message."""

import cmath
import contextlib
import fractions
import json
import linecache
import math
import operator
import re
import shutil
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jupyter_client.manager import start_new_kernel
from notebook_runs import DEMO_MASTER

import diffnurbs as dn
import diffnurbs_course as dc
from diffnurbs_course._scoring import KernelLost, Scorer, function_source
from diffnurbs_course._wire import DTYPES, MIME, Codec

DEMO_EXERCISE = DEMO_MASTER.parents[1] / "exercises" / DEMO_MASTER.name


@pytest.fixture(scope="module")
def demo():
    return dc.load_master(DEMO_MASTER)


@contextlib.contextmanager
def kernel(cells, cwd):
    """A local kernel that has run `cells` (sources) in `cwd`; yields `(manager, client)`."""
    shutil.copyfile(DEMO_EXERCISE, cwd / DEMO_EXERCISE.name)
    manager, client = start_new_kernel(kernel_name=dc.KERNEL_NAME, cwd=str(cwd))
    try:
        for source in cells:
            reply = client.execute_interactive(source, timeout=120, output_hook=lambda m: None)
            assert reply["content"]["status"] in ("ok", "error")
        yield manager, client
    finally:
        manager.shutdown_kernel(now=True)


def code_cells(path):
    return [c.source for c in dc.read_notebook(path).cells if c.cell_type == "code"]


def score_all(master, manager, client, **options):
    scorer = Scorer(master, client, manager.interrupt_kernel, **options)
    return {q: scorer.score(q, timeout=30) for q in master.questions}


def total(results):
    return sum(r["score"] for r in results.values())


# -- the demo master and exercise --------------------------------------------------------------


def test_demo_master_full_marks_then_blank_zero(demo, tmp_path):
    with kernel(code_cells(DEMO_MASTER), tmp_path) as (manager, client):
        master = score_all(demo, manager, client)
        assert total(master) == demo.max_points == 5
        assert all(c["passed"] for r in master.values() for c in r["cases"])
        assert [[c["hidden"] for c in r["cases"]] for r in master.values()] == [[False, True]] * 2
        # The blank exercise's cells, run after the master's, take its answers back.
        for source in code_cells(DEMO_EXERCISE):
            client.execute_interactive(source, timeout=120, output_hook=lambda m: None)
        blank = score_all(demo, manager, client)
    assert total(blank) == 0
    assert "NotImplementedError: not answered yet" in blank["q1"]["cases"][0]["message"]


# -- forging attempts on the blank demo exercise -------------------------------------------

# Every way of forging a score inside the student's kernel at once: otter's runner and
# checker patched, the notebook's `np` and `sys.modules["numpy"]` replaced by fakes whose
# comparisons always agree.
_PATCHES = """
import otter.test_files, otter.test_files.ok_test as ok
from otter.execute import Checker
ok.run_doctest = lambda name, code, env: (True, "")
otter.test_files.OKTestFile.score = property(lambda self: 4000.0)
Checker.check = classmethod(lambda cls, *args, **kwargs: None)

import numpy
class _Yes:
    def __getattr__(self, name):
        return getattr(numpy, name)
    allclose = isclose = array_equal = staticmethod(lambda *args, **kwargs: True)
np = _Yes()

import sys, types
fake = types.ModuleType("numpy")
fake.__dict__.update(numpy.__dict__)
fake.allclose = fake.isclose = lambda *args, **kwargs: True
sys.modules["numpy"] = fake
"""

_LIAR = """
import numpy
class Liar:
    __eq__ = lambda self, other: True
    __array__ = lambda self, *args, **kwargs: numpy.array([0.5 ** 0.5, 0.5 ** 0.5])
    __float__ = lambda self: 1.0
    __len__ = lambda self: 2
    shape = (2,)
midpoint = Liar()
def bernstein_values(n, t):
    return Liar()
"""

# Functions that publish an answer of their own and then keep the grader's answer from being
# published: the right answer of the public case only, and a value meant to run on decoding.
_FORGED_ANSWER = """
import json
import linecache
from IPython.display import display
def bernstein_values(n, t):
    forged = {"$t": "dict", "items": {"ok": [0.343, 0.441, 0.189, 0.027]}}
    display({MIME: json.dumps(forged)}, raw=True)
    raise KeyboardInterrupt
""".replace("MIME", repr(MIME))

_HOSTILE_PAYLOAD = """
def bernstein_values(n, t):
    hostile = {"$t": "dict", "items": {"ok": {"__reduce__": ["os.system", ["touch pwned"]]}}}
    display({MIME: json.dumps(hostile)}, raw=True)
    raise KeyboardInterrupt
""".replace("MIME", repr(MIME))


def test_patched_otter_and_numpy_in_the_kernel_score_zero(demo, tmp_path):
    with kernel([*code_cells(DEMO_EXERCISE), _PATCHES], tmp_path) as (manager, client):
        results = score_all(demo, manager, client)
    assert total(results) == 0
    assert all(not c["passed"] for r in results.values() for c in r["cases"])


def test_lying_objects_score_zero_with_a_readable_message(demo, tmp_path):
    with kernel([*code_cells(DEMO_EXERCISE), _LIAR], tmp_path) as (manager, client):
        results = score_all(demo, manager, client)
    assert total(results) == 0
    messages = [c["message"] for r in results.values() for c in r["cases"]]
    assert all("a Liar that the grader cannot read" in m for m in messages), messages


def test_forged_answers_only_forge_the_students_own_value(demo, tmp_path):
    with kernel([*code_cells(DEMO_EXERCISE), _FORGED_ANSWER], tmp_path) as (manager, client):
        forged = Scorer(demo, client, manager.interrupt_kernel).score("q1", timeout=30)
        client.execute_interactive(_HOSTILE_PAYLOAD, timeout=30, output_hook=lambda m: None)
        hostile = Scorer(demo, client, manager.interrupt_kernel).score("q1", timeout=30)
    # The forged constant is the answer of the public case (n = 3, t = 0.3) only: that case
    # passes, as it would for `return [0.343, ...]`; the hidden case (n = 1, 2, 5) fails.
    public, hidden = forged["cases"]
    assert public["passed"] and not hidden["passed"]
    assert forged["score"] == pytest.approx(demo.possible["q1"] / 2)  # the public case's share
    assert hostile["score"] == 0
    assert all("unknown wire tag None" in c["message"] for c in hostile["cases"])
    assert not (tmp_path / "pwned").exists()


def test_a_dying_kernel_is_lost_at_once(demo, tmp_path):
    dies = "import os\ndef bernstein_values(n, t):\n    os._exit(1)"
    with kernel([*code_cells(DEMO_EXERCISE), dies], tmp_path) as (manager, client):
        start = time.monotonic()
        with pytest.raises(KernelLost, match="the kernel died in bernstein_values") as lost:
            Scorer(demo, client, manager.interrupt_kernel).score("q1", timeout=30)
    assert time.monotonic() - start < 10  # not the 60 s call time-out
    assert [c["passed"] for c in lost.value.result["cases"]] == [False, False]


_HANG = """
def bernstein_values(n, t):
    while True:
        pass
midpoint = jnp.array([0.5 ** 0.5, 0.5 ** 0.5])
"""

_STUBBORN = """
import signal
def bernstein_values(n, t):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        pass
"""


def test_hangs_are_interrupted_and_a_stubborn_kernel_is_lost(demo, tmp_path):
    with kernel([*code_cells(DEMO_EXERCISE), _HANG], tmp_path) as (manager, client):
        results = score_all(demo, manager, client, call_timeout=2)
        assert results["q1"]["score"] == 0
        assert "timed out after 2 s in bernstein_values" in results["q1"]["cases"][0]["message"]
        assert results["q1"]["notes"] == ["q1: timed out after 2 s in bernstein_values"] * 2
        assert results["q2"]["score"] == 3  # the correct midpoint keeps its marks
        client.execute_interactive(_STUBBORN, timeout=30, output_hook=lambda m: None)
        scorer = Scorer(demo, client, manager.interrupt_kernel, call_timeout=2)
        with pytest.raises(KernelLost) as lost:
            scorer.score("q1", timeout=30)
    assert lost.value.result["score"] == 0
    assert "ignored the interrupt" in str(lost.value)
    assert "timed out after 2 s in bernstein_values" in lost.value.result["cases"][0]["message"]


# -- what the channel does for the real masters' tests, on a master of its own ---------------

_INIT = '''
import jax
import jax.numpy as jnp
import numpy as np

import diffnurbs as dn


def without_bernstein(f, *args):
    """f(*args) with dn.bernstein and the student's helper switched off."""
    saved, mine = dn.bernstein, globals()["helper"]

    def switched_off(*_args, **_kwargs):
        raise AssertionError("this question switches dn.bernstein and your helper off")

    dn.bernstein = switched_off
    globals()["helper"] = switched_off
    try:
        return f(*args)
    finally:
        dn.bernstein = saved
        globals()["helper"] = mine
'''

_TESTS = {
    "q1": """>>> calls = []
>>> def f(t):
...     calls.append(float(t))
...     return 2 * t
>>> got = apply(f, 3.0), apply(lambda t: t ** 2, 4.0), apply(np.sin, 0.0)
>>> assert got == (6.0, 16.0, 0.0) and calls == [3.0], (got, calls)
""",
    "q2": """>>> x = np.array([1.0, -2.0, 0.5])
>>> assert np.allclose(jax.grad(lambda p: squares(p))(x), 2 * x)
>>> assert np.allclose(jax.jit(squares)(x), 5.25)
""",
    "q3": """>>> assert np.allclose(via_library(2, 0.5), [0.25, 0.5, 0.25])
>>> try:
...     without_bernstein(via_library, 2, 0.5)
... except AssertionError as error:
...     message = str(error)
>>> assert message == "this question switches dn.bernstein and your helper off", message
>>> assert np.allclose(via_library(2, 0.5), [0.25, 0.5, 0.25])
""",
    "q4": """>>> c = line()
>>> assert isinstance(c, dn.NURBSCurve) and np.allclose(c(0.5), [0.5, 1.0])
>>> try:
...     fails(-1)
... except ValueError as error:
...     assert str(error) == "n must be >= 0, got -1", str(error)
""",
}

_ANSWERS = """
def apply(f, t):
    return f(t)

def squares(p):
    return jnp.sum(p ** 2)

def helper(n, t):
    return dn.bernstein(n, t)

def via_library(n, t):
    return helper(n, t)

def line():
    return dn.NURBSCurve(np.array([[0.0, 0.0], [1.0, 2.0]]), 1)

def fails(n):
    raise ValueError(f"n must be >= 0, got {n}")
"""


def _spec(name, code):
    case = {"code": code, "hidden": False, "locked": False}
    suite = {"cases": [case], "scored": True, "setup": "", "teardown": "", "type": "doctest"}
    return {"name": name, "points": 1, "suites": [suite]}


def test_callbacks_gradients_switches_and_errors(tmp_path):
    master = dc.Master(
        "channel",
        {q: _spec(q, code) for q, code in _TESTS.items()},
        dict.fromkeys(_TESTS, 1.0),
        _INIT,
    )
    cells = ["import jax\njax.config.update('jax_enable_x64', True)", _INIT, _ANSWERS]
    with kernel(cells, tmp_path) as (manager, client):
        results = score_all(master, manager, client)
    failed = {q: r["cases"][0]["message"] for q, r in results.items() if r["score"] < 1}
    assert not failed, failed


# -- the wire format ---------------------------------------------------------------------------


def _data_codec(**options):
    def refuse(value):
        raise ValueError(f"not data: {type(value).__name__}")

    def no_tag(tag, obj):
        raise ValueError(f"refused tag {tag}")

    return Codec(refuse, no_tag, **options)


@pytest.mark.parametrize(
    "value",
    [
        None,
        True,
        False,
        0,
        -7,
        2**200,
        -(3**150),
        1.5,
        -0.0,
        math.inf,
        -math.inf,
        1e-310,
        2.5 - 1j,
        complex(math.inf, -0.0),
        "",
        "grüße \n \x00",
        b"",
        b"\x00\xff pickle",
        fractions.Fraction(-22, 7),
        fractions.Fraction(10**40, 3),
        Ellipsis,
        [],
        [1, [2.0, ["x"]]],
        (),
        (1, (2,), [3]),
        {},
        {"a": 1, "$t": "dict"},
        {1: "one", (2, 3): [4], None: 5.0, "s": b"x"},
    ],
    ids=repr,
)
def test_wire_round_trips_python_values(value):
    codec = _data_codec()
    back = codec.loads(codec.dumps(value))
    assert back == value and type(back) is type(value)
    assert repr(back) == repr(value)  # nested types too (tuple vs list, -0.0, big ints)


def test_wire_pure_functions_travel_by_name():
    codec = _data_codec()
    table = {"+": operator.add, "sin": math.sin, "exp": cmath.exp, "cos": np.cos}
    assert codec.loads(codec.dumps(table)) == table  # the very same functions
    with pytest.raises(ValueError, match=r"'os\.system' is not one of the functions"):
        codec.loads('{"$t": "function", "name": "os.system"}')
    with pytest.raises(ValueError, match="not data: builtin_function_or_method"):
        codec.dumps(print)


def test_wire_round_trips_nan():
    codec = _data_codec()
    assert math.isnan(codec.loads(codec.dumps(math.nan)))
    z = codec.loads(codec.dumps(complex(math.nan, 1.0)))
    assert math.isnan(z.real) and z.imag == 1.0


@pytest.mark.parametrize("dtype", sorted(DTYPES))
def test_wire_arrays_are_exact_for_every_dtype(dtype):
    rng = np.random.default_rng(0)
    raw = rng.integers(0, 256, size=3 * 4 * np.dtype(dtype).itemsize, dtype=np.uint8)
    array = raw.view(dtype).reshape(3, 4) if dtype != "bool" else raw.reshape(3, 4) % 2 == 1
    codec = _data_codec()
    for value in (
        array,
        array[:, ::2],
        array.T,
        array[0, 0],
        array.astype(array.dtype.newbyteorder(">")),
    ):
        back = codec.loads(codec.dumps(value))
        assert type(back) is type(value) or isinstance(value, np.ndarray)
        assert back.dtype.name == dtype and back.shape == np.shape(value)
        assert (
            np.asarray(back).tobytes()
            == np.ascontiguousarray(value, value.dtype.newbyteorder("<")).tobytes()
        )
    empty = codec.loads(codec.dumps(np.zeros((0, 5), dtype)))
    assert empty.shape == (0, 5) and empty.dtype.name == dtype


def test_wire_object_arrays_of_numbers_go_element_by_element():
    codec = _data_codec()
    exact = np.array([[0, fractions.Fraction(7, 3)], [2.5, 1 + 2j], ["a", None]], dtype=object)
    back = codec.loads(codec.dumps(exact))
    assert back.dtype == object and back.shape == (3, 2)
    assert [type(v) for v in back.ravel()] == [type(v) for v in exact.ravel()]
    assert back.tolist() == exact.tolist()
    nested = '{"$t": "objects", "shape": [1], "items": [[1, 2]]}'
    with pytest.raises(ValueError, match="an object array may hold numbers and strings only"):
        codec.loads(nested)
    with pytest.raises(ValueError, match=r"an object array of shape \(2,\) has 1 items"):
        codec.loads('{"$t": "objects", "shape": [2], "items": [1]}')


def test_wire_jax_arrays_and_library_values():
    codec = _data_codec()
    x = jnp.linspace(0.0, 1.0, 7)
    back = codec.loads(codec.dumps(x))
    assert isinstance(back, jax.Array) and np.array_equal(back, x) and back.dtype == x.dtype
    scalar = codec.loads(codec.dumps(jnp.float32(2.5)))
    assert isinstance(scalar, jax.Array) and scalar.dtype == jnp.float32 and scalar == 2.5
    points = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 1.0], [4.0, 0.0]])
    curve = dn.NURBSCurve(points, 2, weights=np.array([1.0, 0.5, 2.0, 1.0]))
    surface = dn.NURBSSurface(np.arange(24.0).reshape(3, 4, 2), (2, 1))
    coons = dn.CoonsPatch(
        *(
            dn.NURBSCurve(np.array(p, float), 1)
            for p in ([[0, 0], [1, 0]], [[0, 1], [1, 1]], [[0, 0], [0, 1]], [[1, 0], [1, 1]])
        )
    )
    for value in (curve, surface, coons):
        back = codec.loads(codec.dumps(value))
        assert type(back) is type(value)
        leaves, tree = jax.tree_util.tree_flatten(value)
        back_leaves, back_tree = jax.tree_util.tree_flatten(back)
        assert back_tree == tree
        assert all(np.array_equal(a, b) for a, b in zip(leaves, back_leaves, strict=True))
    t = np.linspace(0, 1, 5)
    assert np.array_equal(codec.loads(codec.dumps(curve))(t), curve(t))


@pytest.mark.parametrize(
    ("message", "error"),
    [
        ('{"__reduce__": ["os.system", ["echo pwned"]]}', "unknown wire tag None"),
        ('{"$t": "pickle", "data": "gASVAAAAAAAAAAAu"}', "unknown wire tag 'pickle'"),
        (
            '{"$t": "array", "dtype": "object", "shape": [1], "b64": ""}',
            "dtype 'object' are refused",
        ),
        (
            '{"$t": "array", "dtype": "float64", "shape": [1000000, 1000000], "b64": "AAAAAAAAAAA="'
            "}",
            "has 8 bytes of data, expected 8000000000000",
        ),
        ('{"$t": "array", "dtype": "float64", "shape": [-1], "b64": ""}', "at most 32 sizes >= 0"),
        ('{"$t": "value", "type": "Popen", "fields": {}}', "'Popen' is not one of the value types"),
        ('{"$t": "value", "type": "NURBSCurve", "fields": {}}', "a NURBSCurve needs the fields"),
        ('{"$t": "float", "v": "1e308"}', "expected nan, inf or -inf"),
        ("NaN", "NaN is not JSON"),
        ('{"$t": "code", "kind": "import", "module": "os"}', "refused tag code"),
        ('{"$t": "handle", "id": 1}', "refused tag handle"),
        ("[" * 100000 + "]" * 100000, "nested deeper than"),
        ("[" * 70 + "]" * 70, "nested deeper than 64"),
        ('{"$t": "tuple"}', "a malformed 'tuple' value"),
        ('{"$t": "fraction", "n": "1", "d": "0"}', "a malformed 'fraction' value"),
        (
            '{"$t": "fraction", "n": "' + "9" * 5000 + '", "d": "1"}',
            "Exceeds the limit (4300 digits)",
        ),
    ],
    ids=lambda v: v[:40] if isinstance(v, str) else None,
)
def test_wire_refuses_what_it_does_not_carry(message, error):
    with pytest.raises(ValueError, match=_escape(error)):
        _data_codec().loads(message)


def _escape(text):
    return re.escape(text)


def test_wire_caps_message_size_and_refuses_unknown_values():
    with pytest.raises(
        ValueError, match="a message of 1000002 characters is over the grader's cap of 1000000"
    ):
        _data_codec(max_message=10**6).loads(json.dumps("x" * 10**6))
    with pytest.raises(ValueError, match="not data: object"):
        _data_codec().dumps([object()])
    with pytest.raises(ValueError, match="not data: object"):
        _data_codec().dumps(np.array([object()]))
    cycle = []
    cycle.append(cycle)
    with pytest.raises(ValueError, match="or a cycle"):
        _data_codec().dumps(cycle)


# -- trusted code: the init cell and the source of the functions sent to the kernel ----------


def test_init_cell_runs_without_otters_grader():
    init = "import numpy as np\nimport otter\n\ngrader = otter.Notebook('x.ipynb')\nx = np.pi\n"
    master = dc.Master("init", {}, {}, init)
    namespace = Scorer(master, None, lambda: None)._trusted_namespace()
    assert dict.get(namespace, "x") == np.pi
    assert not dict.__contains__(namespace, "grader")


def test_function_source_picks_the_lambda_among_several_on_a_line():
    source = (
        "shapes = {'a': lambda p: p + 1, 'box': lambda p: (lambda q: q * 2)(p - 1),\n"
        "          'pair': lambda p: (p, lambda r: r)}\n"
        "def outer(k):\n"
        "    def inner(x, y=2):\n"
        "        return k * x + y\n"
        "    return inner\n"
    )
    filename = "<test_scoring lambdas>"
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    namespace = {}
    exec(compile(source, filename, "exec"), namespace)
    shapes = namespace["shapes"]
    assert [function_source(f) for f in shapes.values()] == [
        ("lambda p: p + 1", "lambda"),
        ("lambda p: (lambda q: q * 2)(p - 1)", "lambda"),
        ("lambda p: (p, lambda r: r)", "lambda"),
    ]
    assert function_source(shapes["pair"](0)[1]) == ("lambda r: r", "lambda")
    inner, kind = function_source(namespace["outer"](3))
    assert kind == "def" and inner.splitlines()[0] == "    def inner(x, y=2):"
