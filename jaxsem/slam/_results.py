"""Result codes of every ROSHAN solver (batch and online), in the style of ``optimistix.RESULTS``.

A solve never raises by default: it returns a :data:`RESULTS` item (a pytree, so it stacks under
``vmap``) and callers read ``info.result`` / ``info.success``. ``throw=True`` turns a non-success
code into a runtime error (``eqx.error_if``) carrying the code's message.

Success is strict: the stopping rule was met on an accepted step *and* the final state and cost
are finite. A solve that stops because no step lowers the cost any more (damping above its
limit) is not reported as converged: that is :attr:`RESULTS.damping_limit`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

__all__ = ["RESULTS", "result_code", "result_message"]


class RESULTS(eqx.Enumeration):
    """Outcome of a solve (``RESULTS.successful`` or one of the failure codes).

    Compare with ``info.result == RESULTS.successful`` (works under ``vmap``); the message of a
    code is ``RESULTS[item]``; the integer is :func:`result_code`.
    """

    successful = ""
    max_steps_reached = (
        "The solver took its maximum number of steps before meeting the stopping rule; raise "
        "`max_steps` (SolverConfig) or loosen `rtol` / `atol`."
    )
    nonfinite = (
        "Non-finite (NaN or inf) values in the input, the cost, the linearisation or the final "
        "state: check the problem and the initial estimate."
    )
    damping_limit = (
        "No step lowered the cost although the damping reached its limit (`lambda_max`): the "
        "problem diverged or sits on a plateau (e.g. degenerate geometry)."
    )
    ill_conditioned = (
        "The damped normal equations could not be solved (non-finite step) up to the damping "
        "limit: the problem is ill-conditioned."
    )


def result_code(result) -> jnp.ndarray:
    """The int32 code of a :data:`RESULTS` item (array, batched under ``vmap``)."""
    return jnp.asarray(result._value, jnp.int32)


def result_message(result) -> str:
    """The message of a concrete (unbatched) :data:`RESULTS` item; ``"successful"`` for success."""
    msg = RESULTS[result]
    return msg or "successful"
