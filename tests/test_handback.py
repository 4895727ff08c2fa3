"""Feedback files for students (`write_feedback`): scores, failures, no hidden test code.

Two demo submissions are graded for real (`grade_directory`): alice answers q1 wrongly and
q2 correctly, bob hands in the blank exercise. Their pages are checked against the master's
own tests (public messages shown, hidden code never) and, for HTML, with Python's HTML parser
(only the page's own tags, every student string escaped).
"""

from html.parser import HTMLParser

import nbformat
import pytest
from markdown_it import MarkdownIt
from notebook_runs import DEMO_MASTER, answered

import diffnurbs_course as dc
from diffnurbs_course._handback import MESSAGE_LIMIT, write_feedback

DEMO_EXERCISE = DEMO_MASTER.parents[1] / "exercises" / DEMO_MASTER.name

WRONG_Q1 = """from math import comb


def bernstein_values(n, t):
    i = jnp.arange(n + 1)
    b = jnp.array([comb(n, k) for k in range(n + 1)], dtype=float)
    return 2 * b * t**i * (1 - t) ** (n - i)
"""


@pytest.fixture(scope="module")
def graded(tmp_path_factory) -> list[dc.GradeResult]:
    work = tmp_path_factory.mktemp("handback")
    alice = answered(DEMO_MASTER, work)
    next(c for c in alice.cells if "def bernstein_values" in c.source).source = WRONG_Q1
    for name, nb in (("alice", alice), ("bob", dc.read_notebook(DEMO_EXERCISE))):
        (work / "submissions" / name).mkdir(parents=True)
        nbformat.write(nb, work / "submissions" / name / DEMO_MASTER.name)
    return dc.grade_directory(work / "submissions", DEMO_MASTER.parent)


def _hidden_code_lines() -> list[str]:
    """Every line of every hidden test case of the demo master, without doctest prompts."""
    lines = []
    for spec in dc.load_master(DEMO_MASTER).tests.values():
        for suite in spec["suites"]:
            for case in suite["cases"]:
                if case["hidden"]:
                    lines += [line[4:].strip() for line in case["code"].splitlines()]
    return [line for line in lines if line]


def _public_messages() -> list[str]:
    """The assert messages of alice's failing public test, as the master writes them."""
    return ["the values at t = 0.3 sum to 2, expected 1"]


class _Tags(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.text = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)

    def handle_data(self, data):
        self.text.append(data)


def _parse(page: str) -> _Tags:
    parser = _Tags()
    parser.feed(page)
    return parser


PAGE_TAGS = {"html", "head", "meta", "title", "style", "body", "h1", "h2", "p", "code"}
PAGE_TAGS |= {"strong", "ul", "li", "pre"}


@pytest.mark.parametrize("format", ["md", "html"])
def test_pages_show_scores_and_failures_but_no_hidden_code(graded, tmp_path, format):
    alice, bob = graded
    assert (alice.scores, bob.scores) == ({"q1": 0.0, "q2": 3.0}, {"q1": 0.0, "q2": 0.0})
    paths = write_feedback(graded, tmp_path, format=format)
    assert [p.name for p in paths] == [f"alice__99_demo.{format}", f"bob__99_demo.{format}"]
    pages = [p.read_text(encoding="utf-8") for p in paths]
    if format == "html":
        pages = ["".join(_parse(page).text) for page in pages]
    for page, result in zip(pages, graded, strict=True):
        assert "Feedback: 99_demo" in page
        assert f"{result.total:g} / 5" in page
        for line in _hidden_code_lines():
            assert line not in page
    alice_page, bob_page = pages
    assert "q1: 0 / 2" in alice_page and "q2: 3 / 3" in alice_page
    assert "2 of 2 tests failed." in alice_page and "Passed (2 of 2 tests)." in alice_page
    for message in _public_messages():
        assert message in alice_page
    # The public test's failed statement is shown; the hidden one's bare assert says only that.
    assert "assert np.isclose(values.sum(), 1.0)" in alice_page
    assert "A hidden test failed:" in alice_page and "AssertionError" in alice_page
    assert bob_page.count("Not answered yet.") == 2


def test_html_escapes_everything_from_the_submission(graded, tmp_path):
    alice = graded[0]
    hostile = dc.GradeResult.from_json(alice.to_json())
    hostile.file = "eve/<img src=x onerror=alert(1)>.ipynb"
    script = "<script>alert('x')</script>"
    for case in hostile.details["q1"]["cases"]:
        case["message"] = case["message"].replace("sum to 2", f"sum to {script}")
        case["message"] = case["message"].replace("AssertionError\n", f"ValueError: {script}\n")
    (path,) = write_feedback([hostile], tmp_path, format="html")
    page = path.read_text(encoding="utf-8")
    parsed = _parse(page)
    assert set(parsed.tags) <= PAGE_TAGS
    assert "script" not in parsed.tags and "img" not in parsed.tags
    text = "".join(parsed.text)
    assert text.count(script) == 2  # shown as text: once public, once hidden
    assert "<img src=x onerror=alert(1)>.ipynb" in text


def test_markdown_keeps_student_text_inside_code(graded, tmp_path):
    hostile = dc.GradeResult.from_json(graded[0].to_json())
    breakout = "```\n# Full marks\n<img src=x onerror=alert(1)>"
    for case in hostile.details["q1"]["cases"]:
        case["message"] = case["message"].replace("sum to 2", f"sum to {breakout}")
    (path,) = write_feedback([hostile], tmp_path, format="md")
    rendered = MarkdownIt("commonmark").render(path.read_text(encoding="utf-8"))
    parsed = _parse(rendered)
    assert "img" not in parsed.tags
    headings = [tag for tag in parsed.tags if tag in ("h1", "h2")]
    assert headings == ["h1", "h2", "h2"]  # the title and one per question, no "Full marks"
    assert "<img src=x onerror=alert(1)>" in "".join(parsed.text)


def test_long_messages_are_shortened(graded, tmp_path):
    hostile = dc.GradeResult.from_json(graded[0].to_json())
    for case in hostile.details["q1"]["cases"]:
        case["message"] = case["message"].replace("sum to 2", "sum to " + "9" * 100_000)
    (path,) = write_feedback([hostile], tmp_path, format="md")
    page = path.read_text(encoding="utf-8")
    (line,) = [line for line in page.splitlines() if "999" in line]
    assert line.startswith("AssertionError: the values at t = 0.3 sum to 999")
    assert line.endswith("9…") and len(line) == MESSAGE_LIMIT


def test_time_outs_and_crashes_in_plain_words_teacher_notes_left_out(graded, tmp_path):
    result = dc.GradeResult.from_json(graded[0].to_json())
    result.notes = [
        "timed out after 300 s in code cell 4",
        "q2: tests timed out after 60 s",
        "the kernel died",
        "grading failed: RuntimeError: /srv/grader/secret/path",
    ]
    result.flags = ["code cell 4 imports subprocess (other programs)"]
    del result.details["q2"]
    (path,) = write_feedback([result], tmp_path, format="md")
    page = path.read_text(encoding="utf-8")
    assert "Code cell 4 was still running when the time limit (300 s) ran out" in page
    q2 = page[page.index("## q2") :]
    assert "Its tests did not finish within 60 s." in q2
    assert "Python stopped while running this notebook" in page
    for teacher_only in ("/srv/grader", "grading failed", "subprocess", "alice/"):
        assert teacher_only not in page


def test_unmatched_and_unreadable_submissions_get_pages(tmp_path):
    unmatched = dc.GradeResult("x/notes.ipynb", None, notes=["no master matches it"])
    unreadable = dc.GradeResult("x/99_demo.ipynb", "99_demo", {"q1": 0.0}, {"q1": 2.0})
    unreadable.notes = ["unreadable notebook: JSONDecodeError: Expecting value"]
    first, second = (p.read_text() for p in write_feedback([unmatched, unreadable], tmp_path))
    assert "did not match any assignment" in first and "Total" not in first
    assert "could not be read as a notebook" in second
    assert "q1: 0 / 2" in second and "Not graded: its tests did not run." in second
    assert "JSONDecodeError" not in second


def test_file_names_are_safe_and_unique(tmp_path):
    labels = ["a/b.ipynb", "a__b.ipynb", "A__B.ipynb", "../../etc/passwd.ipynb", "ü ?.ipynb"]
    results = [dc.GradeResult(label, None) for label in labels]
    out = tmp_path / "out"
    paths = write_feedback(results, out, format="html")
    assert len({p.name.lower() for p in paths}) == len(labels)
    for path in paths:
        assert path.parent == out and path.is_file()
        assert path.name.replace("_", "").replace("-", "").replace(".", "").isalnum()
    assert sorted(out.iterdir()) == sorted(paths)


def test_unknown_format_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"format must be one of \('md', 'html'\), got 'pdf'"):
        write_feedback([], tmp_path, format="pdf")
