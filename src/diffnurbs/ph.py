"""Pythagorean-hodograph (PH) curves: planar PH cubics as cardinal spline segments (seed 004),
PH quintic Hermite interpolation and exact rational offsets.

A polynomial curve is PH when its speed `|P'(u)|` is a polynomial (seed eq. 1). In the
plane, `P'(u) = (f^2 - v^2, 2 f v)` gives `|P'| = f^2 + v^2` (eq. 2, 3); with linear
`f = a0 + a1 u`, `v = b0 + b1 u` (eq. 4) the curve is a cubic, described here by
`coeffs = (a0, a1, b0, b1)`. Its arc length is a polynomial in the coefficients and its
offsets are rational curves.

Seed 004 writes the cubic as the segment of a cardinal spline (tension `t`,
`s = (1 - t) / 2`, Catmull-Rom at `t = 0`) on the points `P_{k-1}, P_k, P_{k+1}, P_{k+2}`
(eq. 5):

- the direct problem (eq. 9): `cardinal_points(coeffs, p_prev, tension)`;
- the inverse problem (eq. 8): `solve_cardinal(p_prev, p_k, p_next, tension)`, numerically
  with optimistix, and `solve_cardinal_closed_form`; two distinct curves in general;
- `arc_length(coeffs)` (exact), `parameter_at_length(coeffs, s)` and
  `equal_arc_parameters(coeffs, count)` (its exact inverse, a polynomial root),
  `speed(coeffs, u)`, `ph_cubic(coeffs, start)` and `cardinal_curve(coeffs, p_prev, tension)`
  (the segment as a `NURBSCurve`);
- `cardinal_chain(p0, p1, p2, segments, tension, choices)`: a spline marched segment by
  segment, `fit_cardinal(points, tension)`: the PH segment nearest four points;
- `quintic_hermite(p0, p1, d0, d1)`: the four PH quintic Hermite interpolants;
- `offset_curve(coeffs, start, distance)`: the exact offset as a rational `NURBSCurve`.

Everything is differentiable with `jax.grad` (through the solvers by implicit
differentiation) and works in float32 and float64. Complex notation in the docstrings:
`w(u) = f + i v = alpha0 + alpha1 u`, `alpha0 = a0 + i b0`, `alpha1 = a1 + i b1`, and the
hodograph is `P'(u) = w(u)^2`.
"""

from ._ph_chain import (
    PHChain as PHChain,
    cardinal_chain as cardinal_chain,
    fit_cardinal as fit_cardinal,
)
from ._ph_cubic import (
    arc_length as arc_length,
    cardinal_curve as cardinal_curve,
    cardinal_points as cardinal_points,
    equal_arc_parameters as equal_arc_parameters,
    offset_curve as offset_curve,
    parameter_at_length as parameter_at_length,
    ph_cubic as ph_cubic,
    speed as speed,
)
from ._ph_quintic import QuinticHermite as QuinticHermite, quintic_hermite as quintic_hermite
from ._ph_solve import (
    solve_cardinal as solve_cardinal,
    solve_cardinal_closed_form as solve_cardinal_closed_form,
)
