"""Every kind of bad input gets a ValueError that names the problem and what was expected."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

POINTS = np.array([[0.0, 0], [1, 2], [2, 0], [3, 1]])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"knots": [0, 0, 0, 0.5, 1, 1, 1]}, r"expected 8 knots \(n \+ p \+ 1"),
        ({"knots": [0, 0, 0, 0.7, 0.5, 1, 1, 1]}, r"non-decreasing, got knots\[4\] = 0.5"),
        ({"knots": [0, 0, 0, 0.5, np.nan, 1, 1, 1]}, "knots must be finite"),
        ({"knots": [0, 0, 0, 0, 1, 1, 1], "degree": 2}, "at most degree \\+ 1 = 3 times"),
        ({"knots": [1, 1, 1, 1, 1, 1, 1, 1.0]}, "at most degree"),
        ({"knots": np.zeros((2, 4))}, "1 dimensions"),
        ({"weights": [1, 1, 0, 1]}, "weights must be finite and positive, got 0.0 at index"),
        ({"weights": [1, -2, 1, 1]}, "finite and positive"),
        ({"weights": [1, np.inf, 1, 1]}, "finite and positive"),
        ({"weights": [1, 1, 1]}, r"weights must have shape \(4,\)"),
        ({"degree": 0}, "degree must be >= 1, got 0"),
        ({"degree": 4}, "expected at least p \\+ 1 = 5 control points for degree 4, got 4"),
        ({"degree": 2.0}, "degree must be a Python int"),
        (
            {"control_points": np.array([[0.0, np.nan], [1, 1], [2, 2], [3, 3]])},
            "control_points must be finite",
        ),
        ({"control_points": np.arange(4.0)}, r"2 dimensions \(n_control, dim\)"),
    ],
)
def test_bad_curve_input(kwargs, message):
    arguments = {"control_points": POINTS, "degree": 3} | kwargs
    if "knots" in kwargs and "degree" not in kwargs:
        arguments["degree"] = 3
    with pytest.raises(ValueError, match=message):
        dn.NURBSCurve(**arguments)


def test_empty_domain():
    with pytest.raises(ValueError, match="at most degree"):
        dn.NURBSCurve(POINTS, 1, [0, 0.5, 0.5, 0.5, 0.5, 1])


def test_traced_knots_are_checked_when_the_program_runs():
    knots_of = jax.jit(lambda knots: dn.NURBSCurve(POINTS, 1, knots).knots)
    knots_of(jnp.asarray([0, 0, 0.5, 0.7, 1, 1.0]))
    # A value more than p + 1 times: the traced branch checks the multiplicity too.
    with pytest.raises(Exception, match="repeat a value at most degree \\+ 1 times"):
        knots_of(jnp.asarray([0, 0, 0.5, 0.5, 0.5, 1.0])).block_until_ready()
    with pytest.raises(Exception, match="non-decreasing"):
        knots_of(jnp.asarray([0, 0, 0.7, 0.5, 1, 1.0])).block_until_ready()


def test_bad_derivative_orders_and_parameters():
    curve = dn.NURBSCurve(POINTS, 3)
    with pytest.raises(ValueError, match="order must be an int >= 0, got -1"):
        curve.derivatives(0.5, -1)
    with pytest.raises(ValueError, match="order must be an int"):
        curve.derivatives(0.5, 1.5)
    with pytest.raises(ValueError, match=r"u must lie in the domain \[0.0, 1.0\]"):
        curve(1.01)
    with pytest.raises(ValueError, match="u must be finite"):
        curve(np.nan)
    with pytest.raises(ValueError, match="a <= b"):
        curve.arc_length(0.8, 0.2)
    with pytest.raises(ValueError, match="dimension >= 2"):
        dn.NURBSCurve(POINTS[:, :1], 3).curvature(0.5)
    with pytest.raises(ValueError, match="order must be an int"):
        dn.ders_basis_funs([0, 0, 1, 1], 1, 0.5, -2)
    with pytest.raises(ValueError, match="basis index"):
        dn.cox_de_boor([0, 0, 1, 1], 1, 2, 0.5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"control_points": np.zeros((3, 3))}, r"3 dimensions \(nu, nv, dim\)"),
        ({"degree": 2}, "degree must be a pair"),
        ({"degree": (2, 3)}, "along v"),
        ({"knots": ([0, 0, 0, 1, 1, 1], [0, 0, 1, 1])}, "expected 6 knots V"),
        ({"knots": [0, 0, 0, 1, 1, 1]}, "knots must be a pair"),
        ({"weights": np.ones((3, 2))}, r"weights must have shape \(3, 3\)"),
        ({"weights": -np.ones((3, 3))}, "finite and positive"),
    ],
)
def test_bad_surface_input(kwargs, message):
    arguments = {"control_points": np.zeros((3, 3, 3)), "degree": (2, 2)} | kwargs
    with pytest.raises(ValueError, match=message):
        dn.NURBSSurface(**arguments)


def test_bad_surface_calls():
    surface = dn.NURBSSurface(np.zeros((3, 3, 3)), (2, 2))
    with pytest.raises(ValueError, match="v must lie in the domain"):
        surface(0.5, 2.0)
    with pytest.raises(ValueError, match="1-D array"):
        surface.grid(np.zeros((2, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="order must be an int >= 0"):
        surface.derivatives(0.5, 0.5, -1)


def test_de_casteljau_bad_input():
    with pytest.raises(ValueError, match=r"2 dimensions \(n_control, dim\)"):
        dn.de_casteljau(np.zeros(3), 0.5)
    with pytest.raises(ValueError, match="finite and positive"):
        dn.de_casteljau(np.zeros((3, 2)), 0.5, weights=[1, 0, 1])
