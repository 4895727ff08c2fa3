"""PH curves (seed 004 and beyond): the direct and inverse problems against the seed's own
equations written out, closed forms, the kernel's curves and quadrature, scipy, and finite
differences.

Seed errors found (the tests follow the equations, not the printed numbers):
- eq. 7 prints y'(u) with `2u (a0 b1 - a1 b0)`; `2 f v` has `2u (a0 b1 + a1 b0)`, as eq. 8
  (line 5) and eq. 9 (y_k) use.
- Example 1: eq. 9 gives P_k = (-17/3, 3) and P_{k+2} = (79/3, -57); the paper prints
  (-3, 3) and (13, -57) (the y values agree).
- Eq. 11 is not the arc length: it is `x(u) - x_k`, the integral of x'(u) alone. Its
  "L = 4" (Example 1) is eq. 11 on the misprinted points; on the points of eq. 9 it gives
  20/3, and the exact length is 58/3. Example 2's "L = 2" is x_{k+1} - x_k; the length of
  both solutions is 20/3.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
import scipy.optimize
from helpers import central_difference

import diffnurbs as dn
from diffnurbs import ph
from diffnurbs._ph_solve import cardinal_matrix

rng = np.random.default_rng(4)
# One set of parameters (both ends first) for every evaluation: each new shape would compile.
U = np.concatenate([[0.0, 1.0], rng.uniform(size=39)])


# --- the seed's equations, written out as printed (real form) -----------------------------


def eq9(coeffs, p_prev, s):
    """Seed eq. 9: the frame points from (a0, a1, b0, b1) and P_{k-1}."""
    a0, a1, b0, b1 = coeffs
    x0, y0 = p_prev
    x2 = (a0**2 - b0**2) / s + x0
    y2 = 2 * a0 * b0 / s + y0
    x1 = x2 * (1 - s) + s * x0 - a0 * a1 + b0 * b1 - (a1**2 - b1**2) / 3
    y1 = y2 * (1 - s) + s * y0 - a0 * b1 - a1 * b0 - 2 * a1 * b1 / 3
    x3 = (a1**2 - b1**2) / (3 * s) - (1 - 2 / s) * x2 - (2 / s - 1) * x1 + x0
    y3 = 2 * a1 * b1 / (3 * s) - (1 - 2 / s) * y2 - (2 / s - 1) * y1 + y0
    return np.array([[x0, y0], [x1, y1], [x2, y2], [x3, y3]])


def eq8(coeffs, frame, s):
    """Seed eq. 8, left side minus right side (six residuals)."""
    a0, a1, b0, b1 = coeffs
    (xm, ym), (xk, yk), (xp, yp), (xq, yq) = frame
    return np.array(
        [
            a0**2 - b0**2 - s * (xp - xm),
            a0 * a1 - b0 * b1 - (2 * s * xm + (s - 3) * xk + (3 - 2 * s) * xp - s * xq),
            a1**2 - b1**2 - 3 * (s * xq + (s - 2) * xp + (2 - s) * xk - s * xm),
            2 * a0 * b0 - s * (yp - ym),
            a0 * b1 + a1 * b0 - (2 * s * ym + (s - 3) * yk + (3 - 2 * s) * yp - s * yq),
            2 * a1 * b1 - 3 * (s * yq + (s - 2) * yp + (2 - s) * yk - s * ym),
        ]
    )


def eq5(frame, s, u):
    """Seed eq. 5: the cardinal segment on the frame, at parameters `u`."""
    pm, pk, pp, pq = (np.asarray(p, float) for p in frame)
    u = np.asarray(u, float)[:, None]
    return ((pp - pm) * (u**3 - 2 * u**2 + u) + (pq - pk) * (u**3 - u**2)) * s + (
        pk * (2 * u**3 - 3 * u**2 + 1) + pp * (-2 * u**3 + 3 * u**2)
    )


def eq11(frame, s, u=1.0):
    """Seed eq. 11 as printed (claimed to be the length)."""
    (xm, _), (xk, _), (xp, _), (xq, _) = frame
    return (
        s * u * (xp - xm)
        + u**2 * (2 * s * xm + (s - 3) * xk + (3 - 2 * s) * xp - s * xq)
        + u**3 * (s * xq + (s - 2) * xp + (2 - s) * xk - s * xm)
    )


def length_by_quad(coeffs):
    """The length as scipy's integral of |P'(u)| with P' = (f^2 - v^2, 2 f v)."""
    a0, a1, b0, b1 = coeffs

    def norm(u):
        f, v = a0 + a1 * u, b0 + b1 * u
        return np.hypot(f * f - v * v, 2 * f * v)

    return scipy.integrate.quad(norm, 0, 1, epsabs=1e-13, epsrel=1e-13)[0]


def same_curve(c, d):
    """Coefficients equal up to the symmetry (a, b) -> (-a, -b)."""
    c, d = np.asarray(c), np.asarray(d)
    return min(np.max(np.abs(c - d)), np.max(np.abs(c + d)))


EXAMPLE1 = np.array([2.0, 3.0, -2.0, -1.0])  # f = 2 + 3u, v = -2 - u
EXAMPLE2 = (np.array([1.0, 1.0]), np.array([-7.0, 10 / 3]), np.array([-5.0, 9.0]))


def random_cases(count, seed):
    """Random coefficients (magnitudes 1e-2 ... 1e2), P_{k-1} and tensions (s in [-1, 1])."""
    local = np.random.default_rng(seed)
    coeffs = local.normal(size=(count, 4)) * 10.0 ** local.uniform(-1, 1, (count, 1))
    p_prev = local.normal(size=(count, 2)) * 10.0 ** local.uniform(-1, 1, (count, 1))
    tension = local.uniform(-1.0, 3.0, count)
    tension = np.where(np.abs(1 - tension) < 0.05, 0.0, tension)  # keep |s| >= 0.025
    return coeffs, p_prev, tension


# --- the seed's examples ---------------------------------------------------------------------


def test_example1_direct_problem_follows_eq9_not_the_printed_x_values():
    frame = np.asarray(ph.cardinal_points(EXAMPLE1, [1.0, 1.0]))
    np.testing.assert_allclose(frame, eq9(EXAMPLE1, [1.0, 1.0], 0.5), atol=1e-13)
    # Printed: P_k = (-3, 3), P_{k+1} = (1, -15), P_{k+2} = (13, -57). Eq. 9 by hand:
    # x_k = 1/2 + 1/2 - 6 + 2 - 8/3 = -17/3, x_{k+2} = x_k + Re((5 - 3i)^2) / s = -17/3 + 32.
    np.testing.assert_allclose(frame[1:], [[-17 / 3, 3], [1, -15], [79 / 3, -57]], atol=1e-13)
    np.testing.assert_allclose(eq8(EXAMPLE1, frame, 0.5), 0, atol=1e-13)
    assert np.max(np.abs(eq8(EXAMPLE1, [[1, 1], [-3, 3], [1, -15], [13, -57]], 0.5))) > 1


def test_example1_length_exact_and_what_eq11_computes():
    exact = float(ph.arc_length(EXAMPLE1))
    # (a0^2 + b0^2) + (a0 a1 + b0 b1) + (a1^2 + b1^2) / 3 = 8 + 8 + 10/3.
    assert exact == pytest.approx(58 / 3, rel=1e-14)
    assert exact == pytest.approx(length_by_quad(EXAMPLE1), rel=1e-12)
    frame = np.asarray(ph.cardinal_points(EXAMPLE1, [1.0, 1.0]))
    assert eq11([[1, 1], [-3, 3], [1, -15], [13, -57]], 0.5) == pytest.approx(4)  # printed L
    # Eq. 11 is x(1) - x(0): on the frame of eq. 9 it gives the x-displacement 20/3.
    assert eq11(frame, 0.5) == pytest.approx(frame[2, 0] - frame[1, 0], rel=1e-13)
    assert eq11(frame, 0.5) == pytest.approx(20 / 3, rel=1e-13)


def test_example2_inverse_problem_two_solutions_paper_first():
    coeffs, p_next2 = ph.solve_cardinal(*EXAMPLE2)
    assert coeffs.shape == (2, 4) and p_next2.shape == (2, 2)
    # The paper's b0 = 2, a0 = 1, b1 = -1, a1 = 2 and P_{k+2} = (9, 15.3333) come first.
    np.testing.assert_allclose(coeffs[0], [1, 2, 2, -1], atol=1e-12)
    np.testing.assert_allclose(p_next2[0], [9, 46 / 3], atol=1e-12)
    # The other root of the quadratic: alpha1 = -3 alpha0 - (2 - i) = -5 - 5i.
    np.testing.assert_allclose(coeffs[1], [1, -5, 2, -5], atol=1e-12)
    np.testing.assert_allclose(p_next2[1], [7, 154 / 3], atol=1e-12)
    for c, q in zip(np.asarray(coeffs), np.asarray(p_next2), strict=True):
        np.testing.assert_allclose(eq8(c, [*EXAMPLE2, q], 0.5), 0, atol=1e-12)
    # Both have the exact length 20/3; the printed "L = 2" is eq. 11 = x_{k+1} - x_k.
    np.testing.assert_allclose(ph.arc_length(coeffs), [20 / 3, 20 / 3], rtol=1e-13)
    assert length_by_quad(np.asarray(coeffs[1])) == pytest.approx(20 / 3, rel=1e-12)
    assert eq11([*EXAMPLE2, p_next2[0]], 0.5) == pytest.approx(2)


def test_example2_closed_form_and_turning_order():
    newton = ph.solve_cardinal(*EXAMPLE2)
    closed = ph.solve_cardinal_closed_form(*EXAMPLE2)
    for a, b in zip(newton, closed, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    # Tangent angles from the hodograph: it turns by -90 degrees along the paper's solution
    # (w = 1 + 2i -> 3 + i) and by 2 arg(-2 + i) = 306.9 degrees (a loop) along the other.
    turns = [-90.0, 2 * np.degrees(np.angle(-2 + 1j))]
    for coeffs, turn in zip(np.asarray(newton[0]), turns, strict=True):
        angles = np.unwrap(
            [np.arctan2(*dn_hodograph(coeffs, u)[::-1]) for u in np.linspace(0, 1, 1001)]
        )
        assert np.degrees(angles[-1] - angles[0]) == pytest.approx(turn, rel=1e-9)


def dn_hodograph(coeffs, u):
    a0, a1, b0, b1 = coeffs
    f, v = a0 + a1 * u, b0 + b1 * u
    return f * f - v * v, 2 * f * v


# --- the PH cubic ----------------------------------------------------------------------------


def test_cardinal_matrix_is_eq5_and_catmull_rom_at_half():
    frame = rng.normal(size=(4, 2))
    u = rng.uniform(size=9)
    for s in (0.5, 0.2, -0.7):
        matrix = np.asarray(cardinal_matrix(jnp.asarray(s)))
        np.testing.assert_allclose(
            dn.matrix_segment(frame, matrix, u), eq5(frame, s, u), atol=1e-13
        )
    np.testing.assert_allclose(
        cardinal_matrix(jnp.asarray(0.5)), dn.cubic_matrix("catmull-rom"), atol=1e-15
    )


def test_ph_identity_at_random_coefficients_and_tensions():
    coeffs, p_prev, tension = random_cases(20, 1)
    u = U
    for c, p, t in zip(coeffs, p_prev, tension, strict=True):
        s = (1 - t) / 2
        frame = np.asarray(ph.cardinal_points(c, p, t))
        np.testing.assert_allclose(
            frame, eq9(c, p, s), rtol=1e-12, atol=1e-12 * np.abs(frame).max()
        )
        curve = ph.cardinal_curve(c, p, t)
        np.testing.assert_allclose(curve(u), eq5(frame, s, u), atol=1e-11 * np.abs(frame).max())
        derivative = np.asarray(curve.derivatives(u, 1)[:, 1])
        np.testing.assert_allclose(
            derivative, np.stack(dn_hodograph(c, u), -1), atol=1e-11 * np.abs(c).max() ** 2
        )
        np.testing.assert_allclose(np.linalg.norm(derivative, axis=-1), ph.speed(c, u), rtol=1e-11)
        np.testing.assert_allclose(
            ph.ph_cubic(c, frame[1]).control_points,
            curve.control_points,
            atol=1e-11 * np.abs(frame).max(),
        )


def test_exact_length_against_gauss_legendre_and_scipy():
    coeffs, p_prev, tension = random_cases(12, 2)
    for c, p, t in zip(coeffs, p_prev, tension, strict=True):
        exact = float(ph.arc_length(c))
        assert exact == pytest.approx(float(ph.cardinal_curve(c, p, t).arc_length()), rel=1e-10)
        assert exact == pytest.approx(length_by_quad(c), rel=1e-10)
        # Chord-length sanity bounds: chord <= L <= control polygon.
        polygon = np.asarray(ph.ph_cubic(c, p).control_points)
        assert np.linalg.norm(polygon[-1] - polygon[0]) <= exact * (1 + 1e-12)
        assert exact <= np.sum(np.linalg.norm(np.diff(polygon, axis=0), axis=-1)) * (1 + 1e-12)
    np.testing.assert_allclose(ph.arc_length(coeffs), [ph.arc_length(c) for c in coeffs])


# --- the inverse problem ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def round_trips():
    """1,000 random direct problems and the vmapped inverse problems of their frames."""
    coeffs, p_prev, tension = random_cases(1000, 3)
    frames = np.asarray(jax.vmap(ph.cardinal_points)(coeffs, p_prev, tension))
    args = (frames[:, 0], frames[:, 1], frames[:, 2], tension)
    newton = jax.jit(jax.vmap(ph.solve_cardinal))(*args)
    closed = jax.jit(jax.vmap(ph.solve_cardinal_closed_form))(*args)
    return coeffs, frames, tension, [np.asarray(x) for x in newton], [np.asarray(x) for x in closed]


def test_round_trips_recover_the_curve_every_time(round_trips):
    coeffs, frames, _, (found, after), _ = round_trips
    size = np.abs(coeffs).max(-1)
    errors = (
        np.array([min(same_curve(c, f) for f in fs) for c, fs in zip(coeffs, found, strict=True)])
        / size
    )
    matched = errors <= 1e-9
    print(f"round trips recovered: {matched.sum()} / {len(matched)}")
    assert matched.all(), f"worst relative error {errors.max():.2e} at case {errors.argmax()}"
    which = np.argmin(
        [[same_curve(c, f) for f in fs] for c, fs in zip(coeffs, found, strict=True)], axis=1
    )
    extent = np.abs(frames).max((-1, -2))
    chosen = after[np.arange(len(after)), which]
    assert np.max(np.abs(chosen - frames[:, 3]) / extent[:, None]) <= 1e-9


def test_round_trips_both_solutions_satisfy_eq8_and_match_the_closed_form(round_trips):
    coeffs, frames, tension, (found, after), (closed, closed_after) = round_trips
    extent = np.abs(frames).max((-1, -2))
    for k in range(len(coeffs)):
        for c, q in zip(found[k], after[k], strict=True):
            residual = eq8(c, [*frames[k, :3], q], (1 - tension[k]) / 2)
            assert np.max(np.abs(residual)) <= 1e-10 * extent[k] * (1 + abs(tension[k]))
    scale = np.sqrt(extent)[:, None, None]
    assert np.max(np.abs(found - closed) / scale) <= 1e-9
    assert np.max(np.abs(after - closed_after) / extent[:, None, None]) <= 1e-9
    # Two distinct curves, of equal length, in order of increasing |turning|.
    assert np.min(np.abs(after[:, 0] - after[:, 1]).max(-1) / extent) > 1e-6
    lengths = np.asarray(ph.arc_length(found))
    np.testing.assert_allclose(lengths[:, 0], lengths[:, 1], rtol=1e-9)
    w0 = found[..., 0] + 1j * found[..., 2]
    w1 = w0 + found[..., 1] + 1j * found[..., 3]
    turn = np.abs(np.angle(w1 / w0))
    assert np.all(turn[:, 0] <= turn[:, 1] + 1e-12)


def test_double_root_gives_one_solution():
    # 4 (P_{k+1} - P_k) = s (P_{k+1} - P_{k-1}): P_{k-1} = 0, P_{k+1} = (4, 8), s = 1/2.
    coeffs, p_next2 = ph.solve_cardinal([0.0, 0.0], [3.5, 7.0], [4.0, 8.0])
    closed = ph.solve_cardinal_closed_form([0.0, 0.0], [3.5, 7.0], [4.0, 8.0])
    assert coeffs.shape == (1, 4) and closed[0].shape == (1, 4)
    assert same_curve(coeffs[0], closed[0][0]) <= 1e-7
    np.testing.assert_allclose(
        eq8(coeffs[0], [[0, 0], [3.5, 7], [4, 8], p_next2[0]], 0.5), 0, atol=1e-12
    )


def test_collinear_frame_gives_mirror_images_counter_clockwise_first():
    # D = P_{k+1} - P_k parallel to s (P_{k+1} - P_{k-1}) with 4 D < s (P_{k+1} - P_{k-1}):
    # the two curves are reflections of each other in the line, turning by +-253 degrees.
    frame = ([0.0, 0.0], [1.9, 0.0], [2.0, 0.0])
    newton, closed = ph.solve_cardinal(*frame), ph.solve_cardinal_closed_form(*frame)
    for a, b in zip(newton, closed, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    coeffs, p_next2 = (np.asarray(x) for x in newton)
    np.testing.assert_allclose(coeffs[1], coeffs[0] * [1, 1, -1, -1], atol=1e-12)
    np.testing.assert_allclose(p_next2[1], p_next2[0] * [1, -1], atol=1e-12)
    assert p_next2[0, 1] < 0  # w turns counter-clockwise from w(0) = 1 ...
    alpha0, beta = coeffs[0, 0] + 1j * coeffs[0, 2], coeffs[0, :2].sum() + 1j * coeffs[0, 2:].sum()
    assert np.angle(beta / alpha0) > 0  # ... so the tangent w^2 turns counter-clockwise


def test_solve_in_float32():
    points = [np.asarray(p, np.float32) for p in EXAMPLE2]
    coeffs, p_next2 = ph.solve_cardinal(*points)
    assert coeffs.dtype == jnp.float32 and p_next2.dtype == jnp.float32
    np.testing.assert_allclose(coeffs, [[1, 2, 2, -1], [1, -5, 2, -5]], atol=1e-4)
    np.testing.assert_allclose(p_next2, [[9, 46 / 3], [7, 154 / 3]], rtol=1e-5)


# --- gradients -------------------------------------------------------------------------------


def frame_length(points, tension, index=0, solve=ph.solve_cardinal):
    coeffs, _ = solve(points[0], points[1], points[2], tension)
    return ph.arc_length(coeffs[index])


def frame_next_point(points, tension, index=1, solve=ph.solve_cardinal):
    return solve(points[0], points[1], points[2], tension)[1][index].sum()


@pytest.mark.parametrize("quantity", [frame_length, frame_next_point])
def test_gradient_through_the_solver_matches_finite_differences(quantity):
    points = np.stack(EXAMPLE2) + rng.normal(scale=0.1, size=(3, 2))
    tension = 0.3
    grads = jax.grad(quantity, argnums=(0, 1))(jnp.asarray(points), tension)
    grads = [np.asarray(g) for g in grads]
    assert all(np.all(np.isfinite(g)) for g in grads)
    fd = central_difference(lambda p: float(quantity(p, tension)), points)
    np.testing.assert_allclose(grads[0], fd, rtol=1e-6, atol=1e-7)
    fd = central_difference(lambda t: float(quantity(points, t[()])), tension)
    np.testing.assert_allclose(grads[1], fd, rtol=1e-6, atol=1e-7)
    # The same derivatives by autodiff through the closed form.
    closed = jax.grad(
        lambda p, t: quantity(p, t, solve=ph.solve_cardinal_closed_form), argnums=(0, 1)
    )(jnp.asarray(points), tension)
    for a, b in zip(grads, closed, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-10)


# --- chains and fitting ----------------------------------------------------------------------


def test_chain_is_the_cardinal_spline_of_its_points():
    chain = ph.cardinal_chain(
        [0.0, 0.0], [1.0, 0.0], [2.0, 1.0], 5, tension=0.2, choices=[0, 1, 0, 0, 1]
    )
    points = np.asarray(chain.points)
    assert points.shape == (8, 2) and chain.coeffs.shape == (5, 4)
    # Segment j on [j, j + 1] is the segment of the ordinary cardinal spline on points[j + 1].
    u = 5 * U
    spline = dn.cardinal_spline(points, 0.2)
    np.testing.assert_allclose(chain.curve()(u), spline(u + 1), atol=1e-10 * np.abs(points).max())
    for j in range(5):
        np.testing.assert_allclose(
            eq8(chain.coeffs[j], points[j : j + 4], 0.4), 0, atol=1e-9 * np.abs(points).max()
        )
    assert float(chain.length) == pytest.approx(float(chain.curve().arc_length()), rel=1e-10)
    np.testing.assert_allclose(chain.lengths, ph.arc_length(chain.coeffs))
    # Segment 1 took the second solution of its frame.
    second = ph.solve_cardinal(*points[1:4], tension=0.2)[1][1]
    np.testing.assert_allclose(points[4], second, atol=1e-10 * np.abs(points).max())


def test_chain_gradient_of_total_length():
    def total(p2):
        return ph.cardinal_chain(jnp.array([0.0, 0.0]), jnp.array([1.0, 0.0]), p2, 5).length

    p2 = np.array([2.0, 1.0])
    grad = np.asarray(jax.grad(total)(jnp.asarray(p2)))
    assert np.all(np.isfinite(grad))
    np.testing.assert_allclose(grad, central_difference(lambda p: float(total(p)), p2), rtol=1e-6)


def test_fit_recovers_an_exact_frame():
    c, p = np.array([0.8, -1.1, 0.4, 0.9]), np.array([0.3, -0.2])
    frame = np.asarray(ph.cardinal_points(c, p, 0.1))
    coeffs, fitted = ph.fit_cardinal(frame, 0.1)
    assert same_curve(coeffs, c) <= 1e-9
    np.testing.assert_allclose(fitted, frame, atol=1e-10)


def test_fit_to_arbitrary_points_is_a_least_squares_minimum():
    points = np.array([[0.0, 0.0], [1.0, 0.2], [2.0, 1.5], [2.2, 3.0]])
    coeffs, fitted = ph.fit_cardinal(points)
    np.testing.assert_allclose(fitted, ph.cardinal_points(coeffs, fitted[0]), atol=1e-12)
    unknowns = np.concatenate([coeffs, fitted[0]])

    def residual(x):  # the seed's eq. 9, written out
        return (eq9(x[:4], x[4:], 0.5) - points).ravel()

    cost = np.sum(residual(unknowns) ** 2)
    assert cost > 1e-4  # these points are not a PH frame
    # First-order optimality: the gradient of the cost vanishes (finite differences).
    gradient = central_difference(lambda x: np.sum(residual(x) ** 2), unknowns)
    assert np.max(np.abs(gradient)) <= 1e-7
    # scipy's least squares from random starts finds nothing better.
    local = np.random.default_rng(5)
    best = min(
        scipy.optimize.least_squares(residual, local.normal(size=6), xtol=1e-14, ftol=1e-14).cost
        * 2
        for _ in range(8)
    )
    assert cost <= best * (1 + 1e-7) + 1e-14


def test_fit_and_quintic_gradients_match_finite_differences():
    points = np.array([[0.0, 0.0], [1.0, 0.2], [2.0, 1.5], [2.2, 3.0]])

    def fitted_length(q):
        return ph.arc_length(ph.fit_cardinal(q)[0])

    grad = np.asarray(jax.grad(fitted_length)(jnp.asarray(points)))
    fd = central_difference(lambda q: float(fitted_length(q)), points)
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-8)

    def least_energy(d1):
        return jnp.min(ph.quintic_hermite(points[0], points[3], points[1], d1).bending_energy)

    grad = np.asarray(jax.grad(least_energy)(jnp.asarray(points[2])))
    fd = central_difference(lambda d: float(least_energy(d)), points[2])
    np.testing.assert_allclose(grad, fd, rtol=1e-6)


# --- PH quintic Hermite interpolation --------------------------------------------------------


def bending_energy_by_quad(control_points):
    """`int kappa^2 |r'| dt` of a Bezier curve, by scipy from its power form (numpy)."""
    n = len(control_points) - 1
    bernstein = [
        np.polynomial.Polynomial([0] * i + [math.comb(n, i)])
        * np.polynomial.Polynomial([1, -1]) ** (n - i)
        for i in range(n + 1)
    ]
    x, y = (
        sum(p * b for p, b in zip(control_points[:, k], bernstein, strict=True)) for k in (0, 1)
    )
    dx, dy, ddx, ddy = x.deriv(), y.deriv(), x.deriv(2), y.deriv(2)

    def integrand(t):
        speed = np.hypot(dx(t), dy(t))
        return (dx(t) * ddy(t) - dy(t) * ddx(t)) ** 2 / speed**5

    return scipy.integrate.quad(integrand, 0, 1, limit=200, epsabs=0, epsrel=1e-11)[0]


def test_quintic_hermite_interpolants_meet_the_end_conditions():
    p0, p1, d0, d1 = rng.normal(size=(4, 2)) * [[1], [1], [3], [3]]
    result = ph.quintic_hermite(p0, p1, d0, d1)
    assert result.control_points.shape == (4, 6, 2)
    curves = [result.curve(i) for i in range(4)]
    energies = np.asarray(result.bending_energy)
    for curve, energy in zip(curves, energies, strict=True):
        derivatives = np.asarray(curve.derivatives(U, 1))
        np.testing.assert_allclose(derivatives[:2, 0], [p0, p1], atol=1e-12)
        np.testing.assert_allclose(derivatives[:2, 1], [d0, d1], atol=1e-11)
        # PH: the speed is a polynomial of degree 4 (a quintic's |r'|^2 would have degree 8).
        speed = np.linalg.norm(derivatives[:, 1], axis=-1)
        fit = np.polynomial.polynomial.Polynomial.fit(U, speed, 4)
        np.testing.assert_allclose(fit(U), speed, atol=1e-10 * speed.max())
        assert energy == pytest.approx(
            bending_energy_by_quad(np.asarray(curve.control_points)), rel=1e-7
        )
    # Four distinct curves, and the best is the least energy.
    values = np.asarray([curve(U) for curve in curves])
    gaps = np.abs(values[:, None] - values[None]).max((-1, -2)) + np.eye(4)
    assert gaps.min() > 1e-3
    assert int(result.best) == int(np.argmin(result.bending_energy))
    np.testing.assert_array_equal(result.curve().control_points, result.control_points[result.best])


def test_quintic_hermite_of_a_straight_segment_is_the_line():
    result = ph.quintic_hermite([0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 0.0])
    best = result.curve()
    np.testing.assert_allclose(np.asarray(best(U))[:, 1], 0, atol=1e-14)
    assert float(result.bending_energy[result.best]) == pytest.approx(0, abs=1e-20)


# --- offsets ---------------------------------------------------------------------------------


@pytest.mark.parametrize("coeffs", [EXAMPLE1, [1.0, -5.0, 2.0, -5.0], [1.0, 0.5, 0.0, 0.0]])
@pytest.mark.parametrize("distance", [0.7, -1.3])
def test_offset_is_rational_quintic_at_exact_distance(coeffs, distance):
    start = np.array([0.5, -1.0])
    curve = ph.ph_cubic(coeffs, start)
    offset = ph.offset_curve(coeffs, start, distance)
    assert offset.degree == 5 and offset.rational and np.all(np.asarray(offset.weights) > 0)
    # The pointwise offset P(u) + d N(u), N the unit tangent turned by +90 degrees.
    normal = np.asarray(curve.tangent(U)) @ np.array([[0.0, 1.0], [-1.0, 0.0]])
    np.testing.assert_allclose(offset(U), curve(U) + distance * normal, atol=1e-12 * 20)
    gap = np.asarray(offset(U) - curve(U))
    tangent = np.asarray(curve.derivatives(U, 1))[:, 1]
    np.testing.assert_allclose(np.linalg.norm(gap, axis=-1), abs(distance), rtol=1e-12)
    np.testing.assert_allclose(np.sum(gap * tangent, -1), 0, atol=1e-11 * np.abs(tangent).max())
    # Positive distances lie to the left: cross(tangent, gap) = d |tangent|.
    cross = tangent[:, 0] * gap[:, 1] - tangent[:, 1] * gap[:, 0]
    np.testing.assert_allclose(cross, distance * np.linalg.norm(tangent, axis=-1), rtol=1e-11)


def test_offset_gradient_is_finite_and_matches_finite_differences():
    def point(x):  # x = (a0, a1, b0, b1, d)
        return ph.offset_curve(x[:4], jnp.zeros(2), x[4])(0.3) @ jnp.array([1.0, 2.0])

    x = np.concatenate([[1.0, -5.0, 2.0, -5.0], [0.5]])  # w turns > 90 degrees: two pieces
    grad = np.asarray(jax.grad(point)(jnp.asarray(x)))
    assert np.all(np.isfinite(grad))
    # Rounding in the rational construction (~1e-13) over h = 1e-6 limits the differences.
    fd = central_difference(lambda y: float(point(y)), x)
    np.testing.assert_allclose(grad, fd, rtol=1e-6)


# --- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (([1.0, 1.0], [1.0, 1.0], [0.0, 2.0]), "p_prev and p_k coincide"),
        (([1.0, 1.0], [0.0, 2.0], [1.0, 1.0]), "p_prev and p_next coincide"),
        (([1.0, 1.0], [0.0, 2.0], [0.0, 2.0]), "p_k and p_next coincide"),
    ],
)
def test_coincident_points_raise(points, message):
    for solve in (ph.solve_cardinal, ph.solve_cardinal_closed_form):
        with pytest.raises(ValueError, match=message):
            solve(*points)
    with pytest.raises(ValueError, match=message):
        ph.cardinal_chain(*points, 2)


def test_bad_input_raises_clear_errors():
    with pytest.raises(ValueError, match="tension 1 makes s"):
        ph.solve_cardinal(*EXAMPLE2, tension=1.0)
    with pytest.raises(ValueError, match="tension 1 makes s"):
        ph.cardinal_points(EXAMPLE1, [0.0, 0.0], 1.0)
    with pytest.raises(ValueError, match="tension must be a scalar"):
        ph.cardinal_points(EXAMPLE1, [0.0, 0.0], [0.0, 0.1])
    with pytest.raises(ValueError, match=r"coeffs must have shape \(\.\.\., 4\)"):
        ph.arc_length([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"coeffs must have shape \(4,\)"):
        ph.ph_cubic(np.ones((2, 4)), [0.0, 0.0])
    with pytest.raises(ValueError, match="p_k must be a planar point"):
        ph.solve_cardinal([0.0, 0.0], [1.0, 2.0, 3.0], [2.0, 0.0])
    with pytest.raises(ValueError, match="p_prev must have shape"):
        ph.cardinal_points(EXAMPLE1, 1.0)
    with pytest.raises(ValueError, match="coeffs must be finite"):
        ph.arc_length([1.0, np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="u must lie in the domain"):
        ph.speed(EXAMPLE1, 1.5)
    with pytest.raises(ValueError, match=r"points must have shape \(4, 2\)"):
        ph.fit_cardinal(np.ones((3, 2)))
    with pytest.raises(ValueError, match="segments must be a Python int >= 1"):
        ph.cardinal_chain(*EXAMPLE2, 0)
    with pytest.raises(ValueError, match="choices must be 0 or 1"):
        ph.cardinal_chain(*EXAMPLE2, 2, choices=[0, 2])
    with pytest.raises(ValueError, match=r"choices must have shape \(2,\)"):
        ph.cardinal_chain(*EXAMPLE2, 2, choices=[0])
    with pytest.raises(ValueError, match="d1 must be a non-zero end derivative"):
        ph.quintic_hermite([0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="offset_curve needs a regular PH cubic"):
        ph.offset_curve([1.0, -2.0, 0.0, 0.0], [0.0, 0.0], 0.1)  # f = 1 - 2u vanishes at 1/2
    with pytest.raises(ValueError, match="distance must be a scalar"):
        ph.offset_curve(EXAMPLE1, [0.0, 0.0], [0.1, 0.2])
