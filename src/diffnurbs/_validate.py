"""Input checks shared by curves and surfaces.

Concrete arrays are checked eagerly and raise `ValueError` naming the problem and the
expected value. Traced arrays (inside `jit` or `grad`) cannot be inspected: the checks of
knots, weights and finiteness go through `eqx.error_if` there, which raises when the
compiled code runs; parameters (`check_parameter`) and the inputs of the basis functions
(`check_basis_arguments`) are not checked at all. Shape and count checks are static and
always raise `ValueError`.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def concrete(x):
    """`x` as a NumPy array, or None when it is traced."""
    try:
        return np.asarray(x)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return None


def float_dtype(*arrays):
    """The common floating dtype of the inputs (float32 unless x64 is enabled)."""
    return jnp.result_type(*[a.dtype for a in arrays if hasattr(a, "dtype")], float)


def check_degree(degree, minimum=1, name="degree"):
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)):
        raise ValueError(f"{name} must be a Python int, got {degree!r}")
    if degree < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {degree}")
    return int(degree)


def check_rank(x, ndim, name, layout):
    if x.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions {layout}, got shape {x.shape}")


def check_grid_axes(us, vs):
    """The two axes of a tensor grid are 1-D arrays of parameters."""
    check_rank(us, 1, "us", "(a 1-D array of u values)")
    check_rank(vs, 1, "vs", "(a 1-D array of v values)")


def check_finite(x, name):
    values = concrete(x)
    if values is None:
        return eqx.error_if(x, ~jnp.all(jnp.isfinite(x)), f"{name} must be finite")
    if not np.all(np.isfinite(values)):
        where = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
        raise ValueError(f"{name} must be finite, got {values[where]} at index {where}")
    return x


def check_weights(weights, shape, name="weights"):
    if weights.shape != shape:
        raise ValueError(
            f"{name} must have shape {shape} (one per control point), got {weights.shape}"
        )
    values = concrete(weights)
    if values is None:
        bad = ~jnp.all(jnp.isfinite(weights) & (weights > 0))
        return eqx.error_if(weights, bad, f"{name} must be finite and positive")
    if not np.all(np.isfinite(values) & (values > 0)):
        where = tuple(int(i) for i in np.argwhere(~(np.isfinite(values) & (values > 0)))[0])
        raise ValueError(
            f"{name} must be finite and positive, got {values[where]} at index {where}"
        )
    return weights


def check_knots(knots, n_control, degree, name="knots"):
    """Length n + p + 1, finite, non-decreasing, multiplicity <= p + 1, non-empty domain.

    The length is checked always; the values when concrete (`ValueError` naming the first
    fault), and when traced through one `eqx.error_if` for all four value conditions.
    """
    check_rank(knots, 1, name, "(a knot vector)")
    expected = n_control + degree + 1
    if knots.shape[0] != expected:
        raise ValueError(
            f"expected {expected} {name} (n + p + 1 = {n_control} control points + degree "
            f"{degree} + 1), got {knots.shape[0]}"
        )
    values = concrete(knots)
    if values is None:
        bad = ~jnp.all(jnp.isfinite(knots)) | jnp.any(jnp.diff(knots) < 0)
        # Non-decreasing knots repeat a value more than p + 1 times iff some
        # knots[i] == knots[i + p + 1].
        bad = bad | jnp.any(knots[degree + 1 :] == knots[: -degree - 1])
        bad = bad | ~(knots[degree] < knots[n_control])
        return eqx.error_if(
            knots,
            bad,
            f"{name} must be finite, non-decreasing, repeat a value at most degree + 1 times, "
            "with a non-empty domain",
        )
    check_finite(knots, name)
    steps = np.diff(values)
    if np.any(steps < 0):
        i = int(np.argmax(steps < 0))
        raise ValueError(
            f"{name} must be non-decreasing, got {name}[{i + 1}] = {values[i + 1]} < "
            f"{name}[{i}] = {values[i]}"
        )
    distinct, counts = np.unique(values, return_counts=True)
    if counts.max() > degree + 1:
        raise ValueError(
            f"a knot may repeat at most degree + 1 = {degree + 1} times, got {name} value "
            f"{distinct[counts.argmax()]} {counts.max()} times"
        )
    if not values[degree] < values[n_control]:
        raise ValueError(
            f"the domain [{name}[p], {name}[n + 1]] = [{values[degree]}, {values[n_control]}] "
            "is empty; expected the two knots to differ"
        )
    return knots


def check_control_count(count, degree, name="control points", at_most=None, source="points"):
    """A degree-`p` B-spline has at least `p + 1` control points, and a fit no more than
    `at_most`, the number of its data `source`; `name` says what is counted."""
    if count < degree + 1:
        raise ValueError(
            f"expected at least p + 1 = {degree + 1} {name} for degree {degree}, got {count}"
        )
    if at_most is not None and count > at_most:
        raise ValueError(f"expected at most {at_most} {name} (the number of {source}), got {count}")


def domain_ends(knots, degree):
    """`(knots[p], knots[-p - 1])`, the ends of a spline's domain, as 0-d arrays.

    Concrete knots are read in NumPy: eager indexing would compile a program for every
    length of knot vector, and the domain is read on every evaluation.
    """
    values = concrete(knots)
    if values is None:
        return knots[degree], knots[-degree - 1]
    return jax.device_put(values[degree]), jax.device_put(values[-degree - 1])


def check_parameter(u, lower, upper, name="u"):
    """Raise for concrete parameters outside `[lower, upper]`, naming the first one and
    the domain; traced ones pass. A few units of rounding beyond an end are not an error
    (a parameter computed as `1.0` may come out `1.0000000000000002`): the evaluators
    clamp to the domain."""
    values, lo, hi = concrete(u), concrete(lower), concrete(upper)
    if values is None or lo is None or hi is None or values.size == 0:
        return
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name} must be finite")
    slack = 16 * np.finfo(np.result_type(values.dtype, float)).eps * max(1.0, abs(lo), abs(hi))
    outside = (values < lo - slack) | (values > hi + slack)
    if np.any(outside):
        where = tuple(int(i) for i in np.argwhere(outside)[0])
        at = f" at index {where}" if where else ""
        raise ValueError(f"{name} must lie in the domain [{lo}, {hi}], got {values[where]}{at}")


def check_basis_arguments(knots, degree, u=None):
    """For the basis functions: concrete knots form a knot vector with at least `2 p + 2`
    knots (`check_knots`), and concrete parameters `u`, where given, lie in its domain
    `[knots[p], knots[-p - 1]]`.

    Traced values are not checked and nothing is added to a compiled program: the
    basis functions sit in the inner loops of evaluation.
    """
    values = concrete(knots)
    if values is None:
        return
    check_rank(values, 1, "knots", "(a knot vector)")
    if values.shape[0] < 2 * degree + 2:
        raise ValueError(
            f"expected at least 2 (p + 1) = {2 * degree + 2} knots for degree {degree}, "
            f"got {values.shape[0]}"
        )
    check_knots(values, values.shape[0] - degree - 1, degree)
    if u is not None:
        check_parameter(u, values[degree], values[-degree - 1])


def check_order(order):
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 0:
        raise ValueError(f"derivative order must be an int >= 0, got {order!r}")
    return int(order)


def check_pair(value, name):
    """A `(u direction, v direction)` pair of anything, as a tuple."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a pair (u direction, v direction), got {value!r}")
    return tuple(value)


def check_degree_pair(degree, name="degree"):
    """The degrees `(p, q)` of a surface, each a Python int >= 1."""
    p, q = check_pair(degree, name)
    return check_degree(p, name=f"{name} p"), check_degree(q, name=f"{name} q")


def check_solver_options(max_steps, tol):
    """`max_steps` a positive Python int; `tol` None or a finite number > 0."""
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)):
        raise ValueError(f"max_steps must be a Python int, got {max_steps!r}")
    if max_steps <= 0:
        raise ValueError(f"max_steps must be positive, got {max_steps}")
    if tol is not None and not (np.ndim(tol) == 0 and np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a finite number > 0, got {tol!r}")
