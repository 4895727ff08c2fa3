"""The diffnurbs course's machinery, beside the library: notebooks, exercises, grading.

Runs the course's notebooks headless, generates the student exercises from the otter-grader
masters and checks them (authoring rules, drift, hidden-test leaks), and grades submissions:
`diffnurbs-grade` (`main`). Needs the `course` extra (`pip install "diffnurbs[course]"`);
`import diffnurbs` never imports it. Every folder is an argument: `CourseLayout(root)` names
the folders of a course repository, `find_solutions` the default masters of the grader.
The conventions are written down for chapter authors in `course/AUTHORING.md`.
"""

from ._batch import find_submissions as find_submissions, grade_directory as grade_directory
from ._cli import main as main
from ._exercises import (
    exercise_drift as exercise_drift,
    generate_exercise as generate_exercise,
    hidden_test_leaks as hidden_test_leaks,
    normalize_exercise as normalize_exercise,
    notebook_sources as notebook_sources,
)
from ._feedback import NOT_ANSWERED as NOT_ANSWERED, Feedback as Feedback, Notebook as Notebook
from ._flags import (
    batch_flags as batch_flags,
    handed_out_code as handed_out_code,
    submission_flags as submission_flags,
)
from ._grading import (
    CELL_TIMEOUT as CELL_TIMEOUT,
    CHECK_TIMEOUT as CHECK_TIMEOUT,
    DEFAULT_TIMEOUT as DEFAULT_TIMEOUT,
    MAX_RESTARTS as MAX_RESTARTS,
    MESSAGE_LIMIT as MESSAGE_LIMIT,
    OUTPUT_LIMIT as OUTPUT_LIMIT,
    RECOVERY_TIMEOUT as RECOVERY_TIMEOUT,
    SANDBOX_LIMITS as SANDBOX_LIMITS,
    GradeResult as GradeResult,
    grade_notebook as grade_notebook,
)
from ._handback import write_feedback as write_feedback
from ._layout import CourseLayout as CourseLayout, find_solutions as find_solutions
from ._masters import (
    Master as Master,
    load_master as load_master,
    load_masters as load_masters,
    match_master as match_master,
)
from ._notebooks import (
    HEADLESS_ENV as HEADLESS_ENV,
    KERNEL_NAME as KERNEL_NAME,
    KERNELSPEC as KERNELSPEC,
    CellError as CellError,
    PollingNotebookClient as PollingNotebookClient,
    cell_errors as cell_errors,
    clean_notebook as clean_notebook,
    count_figures as count_figures,
    execute_notebook as execute_notebook,
    make_client as make_client,
    notebooks as notebooks,
    policy_problems as policy_problems,
    read_notebook as read_notebook,
    use_headless_defaults as use_headless_defaults,
)
from ._otter import (
    ANSWER_TAG as ANSWER_TAG,
    ASSIGNMENT_CONFIG as ASSIGNMENT_CONFIG,
    Assigned as Assigned,
    assign as assign,
    assignment_config_text as assignment_config_text,
    autograder_zip as autograder_zip,
    hidden_cases as hidden_cases,
    otter_tests as otter_tests,
)
from ._policy import (
    master_problems as master_problems,
    problems_in_test_code as problems_in_test_code,
)
from ._report import (
    CHECK_TAG as CHECK_TAG,
    LIMITS as LIMITS,
    ChapterMetrics as ChapterMetrics,
    chapter_metrics as chapter_metrics,
    course_report as course_report,
    heading_anchors as heading_anchors,
    jupyter_anchor as jupyter_anchor,
)
from ._sandbox import (
    SCRATCH as SCRATCH,
    AsyncSandboxKernelManager as AsyncSandboxKernelManager,
    SandboxKernelManager as SandboxKernelManager,
    SandboxLimits as SandboxLimits,
    sandbox_problem as sandbox_problem,
)
from ._scores import question_columns as question_columns, write_csv as write_csv
from ._scoring import KernelLost as KernelLost, Scorer as Scorer, StudentError as StudentError
from ._site import build_site as build_site, stage_site as stage_site
