"""Result codes of every ROSHAN solver (batch and online), in the style of ``optimistix.RESULTS``.

A solve never raises by default: it returns a :data:`RESULTS` item (a pytree, so it stacks under
``vmap``) and callers read ``info.result`` / ``info.success``. ``throw=True`` turns a non-success
code into a runtime error (``eqx.error_if``) carrying the code's message.

Success is strict: the stopping rule was met on an accepted step *and* the final state and cost
are finite. A solve that stops because no step lowers the cost any more (damping above its
limit) is not reported as converged: that is :attr:`RESULTS.damping_limit`. Nor is a solve with
no usable measurement (:attr:`RESULTS.no_measurements`), nor a batch
solve that converged with objects the data could not fix (``SolveInfo.unfixable``): that is
:attr:`RESULTS.unfixable_objects`, so "successful" always means every real object counts.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

__all__ = ["RESULTS", "result_code", "result_message"]


class RESULTS(optx.RESULTS):  # pyright: ignore[reportGeneralTypeIssues]
    """Outcome of a solve: ``optx.RESULTS`` (so ``successful``, ``max_steps_reached``,
    ``nonfinite``, ... and their messages) extended with the damping search's two failures.

    Compare with ``info.result == RESULTS.successful`` (works under ``vmap``); the message of a
    code is ``RESULTS[item]``; the integer is :func:`result_code`. An ``optx.RESULTS`` item
    becomes one of these with ``RESULTS.promote(item)``. The ROSHAN solvers report
    ``successful``, ``max_steps_reached`` (a batch solve's step budget,
    ``SolverConfig.max_steps``), ``nonfinite`` and the codes below (``unfixable_objects`` from the
    batch Schur solver only: it replaces ``successful`` when any real object is flagged
    unfixable; the estimate of the other objects and the poses is the converged one;
    ``iterations_reached`` from the online smoother only, whose budget is ``iterations``;
    ``no_measurements`` from every solver when the problem has no usable box, whatever the LM
    did: a solve with nothing to fit is never ``successful``).
    """

    damping_limit = (
        "No step lowered the cost although the damping reached its limit (`lambda_max`): the "
        "problem diverged or sits on a plateau (e.g. degenerate geometry)."
    )
    ill_conditioned = (
        "The damped normal equations could not be solved (non-finite step) up to the damping "
        "limit: the problem is ill-conditioned."
    )
    unfixable_objects = (
        "The solve converged, but some objects could not be fixed by the data (no valid "
        "projection in one of their frames, or box edges far off after the rescue; "
        "`SolveInfo.unfixable`): they were left out of the joint solve and their estimates are "
        "not to be trusted."
    )
    no_measurements = (
        "Nothing was solved: the problem holds no usable measurement (every box is masked out, "
        "dropped by the front end, or refers to a masked pose or object), so the estimate is its "
        "initialisation."
    )
    iterations_reached = (
        "The online smoother's step budget ran out before the stopping rule was met "
        "(`iterations` of `online_init` per optimisation, or of `online_optimize`): normal while "
        "frames arrive, the next optimisation continues from this estimate."
    )


def result_code(result) -> jnp.ndarray:
    """The int32 code of a :data:`RESULTS` item (array, batched under ``vmap``)."""
    return jnp.asarray(result._value, jnp.int32)


def result_message(result) -> str | list:
    """The message of a :data:`RESULTS` item, ``"successful"`` for success; for a batched item
    (under ``vmap``, leading axes) a nested list of messages of the same shape."""
    value = np.asarray(jax.device_get(result._value))
    if value.ndim:
        return [result_message(jax.tree_util.tree_map(lambda _: np.asarray(v), result)) for v in value]
    msg = RESULTS[result]
    return msg or "successful"
