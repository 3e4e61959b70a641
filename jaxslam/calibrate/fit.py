r"""Fit noise levels by gradient ascent on a particle filter's log marginal likelihood
estimate, and choose the iterate to keep on held-out scans.

**Ascent** (:func:`ascend`, shared by every filter family). Each Adam step (optax)
runs ``filters`` filters on the fitting scans with fresh keys (``vmap`` over keys),
averages their gradients of ``log Z / T`` with respect to the log noise levels, and
records the mean objective and the variance of the per-filter gradients. With
``decay < 1`` the step size follows a cosine from ``learning_rate`` down to
``decay * learning_rate``, so that the last iterates settle instead of wandering
with the gradient noise where the objective is flat.

**Selection on validation scans** (:func:`select_by_validation`, default on). The
objective has cliffs the gradient cannot see: noise levels small enough for a filter
with hard data association to lose track make ``log Z`` collapse (a discrete change
of association), and a finite-particle estimate rewards small noise that a filter
with more particles, or later scans, do not. So the window is split: the first
``1 - validation`` of it is fitted, the rest is held out. Every ``validate_every``-th
iterate (the start and the last included) is scored by the mean held-out
one-step log-likelihood

.. math:: v_j(\theta) = \frac{1}{|V|} \sum_{t \in V} \log \hat p_j(z_t \mid z_{1:t-1}; \theta)

of ``validation_filters`` filters ``j`` with ``validation_particles`` particles run
through the whole window (forward only). The same keys serve every candidate
(common random numbers), so the candidates are compared pairwise. The kept iterate
is the best candidate by mean score, but only if it beats the start by more than
``validation_margin`` standard errors of the paired differences
:math:`v_j(\theta) - v_j(\theta_0)`; otherwise the start is kept. Nothing
generalises, nothing changes: calibration cannot make the noise worse on held-out
data by more than the evaluation noise. Without validation (``validation=0``) the
kept iterate is the one with the largest training objective (noisy: each step's
value comes from fresh keys).

**Guard: the filter you will run must not do worse** (``guard_likelihood``, default
``"gated"``: ``jaxslam run --params`` runs the paper's gated filter). The scores
above come from filters weighing by the objective's likelihood (the mixture, unbiased
in the noise levels); the same held-out scans are also run, with the same keys, by
filters weighing as the filter you will run. A candidate is admissible only if every
one of those does at least as well as under the start,
:math:`g_j(\theta) \ge g_j(\theta_0)` for all :math:`j`; the kept iterate is the best
admissible one. Why both: the mixture filter keeps track at noise levels where the
gated one already loses it (an innovation that leaves the gate stops counting, so a
gated filter that loses track does so abruptly, which the mixture's scores do not
show), while the gated likelihood alone is biased to small noise (the gate shrinks
with the noise, below).

The landmark filters' objective and :func:`~jaxslam.calibrate.landmark.calibrate` are in
:mod:`jaxslam.calibrate.landmark`, SRUPF-GM's in :mod:`jaxslam.calibrate.grid`.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax



@dataclasses.dataclass
class Validation:
    """The held-out scoring of :func:`select_by_validation`.

    Attributes:
        fit_scans: scans ``[0, fit_scans)`` were fitted; ``[fit_scans, scans)`` held out.
        scans: the whole window.
        filters, particles: filters (common keys for every candidate) and particles each.
        margin: standard errors of the paired difference a candidate must beat the start by.
        steps: the candidate iterates (indices into the parameter trajectory; 0 is the start).
        scores: ``(len(steps), filters)`` mean held-out log-likelihood per scan.
        selected: the index into ``steps`` of the kept iterate.
        time_s: time of all validation runs (compilation included) [s].
        likelihood: the validation filters' weights (landmark filters; None elsewhere).
        guard_likelihood, guard_scores: the guard filters' weights and ``(len(steps),
            filters)`` scores (None without a guard).
    """

    fit_scans: int
    scans: int
    filters: int
    particles: int
    margin: float
    steps: list[int]
    scores: list[list[float]]
    selected: int
    time_s: float
    likelihood: str | None = None
    guard_likelihood: str | None = None
    guard_scores: list[list[float]] | None = None

    def to_json(self) -> dict[str, Any]:
        scores = np.asarray(self.scores)
        return {**dataclasses.asdict(self), "mean_scores": scores.mean(1).tolist(),
                "selected_step": self.steps[self.selected]}


@dataclasses.dataclass
class CalibrationResult:
    """Outcome of :func:`jaxslam.calibrate.landmark.calibrate` (and of the grid calibration).

    Attributes:
        names: the calibrated parameters.
        before, after: their values before and after (a list for a vector parameter). ``after`` is the iterate kept
            (``best_step``): with validation the one chosen on the held-out scans
            (:func:`select_by_validation`, the start itself when no iterate is
            significantly better there), without it the one with the largest training
            objective. Not the last one: the objective has cliffs the gradient cannot
            see (a step can move the levels to where the filter loses track, and the
            objective does not recover).
        last: the parameters after the last Adam step.
        best_step: the index (into ``trajectory``) of ``after``.
        train_best_step: the step with the largest training objective.
        log_likelihood: per Adam step, the mean over filters of ``log Z / T`` on the
            fitting scans at the parameters of that step (before its update).
        gradient_variance: per step, the variance over filters of each gradient
            component, ``(steps, len(names))``.
        trajectory: per step, the parameter values, ``(steps + 1, len(names))``.
        validation: the held-out scoring (None without validation).
        compile_s, wall_s: compilation time and the time of all steps [s].
        config: the static configuration; ``params``: the full parameters after.
        window, fit_window: the scans used, and those fitted.
        columns: a name per column of ``trajectory`` (default ``names``; a vector
            parameter has a column per entry).
    """

    names: tuple[str, ...]
    before: dict[str, Any]
    after: dict[str, Any]
    last: dict[str, Any]
    best_step: int
    train_best_step: int
    log_likelihood: list[float]
    gradient_variance: list[list[float]]
    trajectory: list[list[float]]
    validation: Validation | None
    compile_s: float
    wall_s: float
    config: Any
    params: Any
    window: int
    fit_window: int
    filters: int
    columns: tuple[str, ...] | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "names": list(self.names), "columns": list(self.columns or self.names),
            "params_before": self.before, "params_after": self.after,
            "params_last": self.last, "best_step": self.best_step, "train_best_step": self.train_best_step,
            "log_likelihood": self.log_likelihood, "log_likelihood_unit": "log Z / scans (mean over filters)",
            "gradient_variance": self.gradient_variance, "parameter_trajectory": self.trajectory,
            "validation": None if self.validation is None else self.validation.to_json(),
            "compile_s": self.compile_s, "time_s": self.wall_s, "steps": len(self.log_likelihood),
            "window": self.window, "fit_window": self.fit_window, "filters_per_step": self.filters,
            "config": dataclasses.asdict(self.config),
        }


@dataclasses.dataclass
class Ascent:
    """What :func:`ascend` records (see :class:`CalibrationResult`)."""

    log_likelihood: list[float]
    gradient_variance: list[list[float]]
    trajectory: list[list[float]]
    compile_s: float
    wall_s: float


def ascend(
    objective: Any,
    args: tuple,
    theta: Any,
    steps: int,
    learning_rate: float,
    filters: int,
    seed: int,
    decay: float = 1.0,
    callback: Any = None,
) -> Ascent:
    """Adam ascent of the jitted ``objective(keys (filters,), theta, *args) ->
    (values (filters,), grads (filters, K))`` over ``theta`` (log noise levels).

    Step ``i`` uses the keys ``split(fold_in(PRNGKey(seed), i), filters)``. Filters
    whose value or gradient is not finite are left out of that step's mean (an error
    if none is left). ``callback(step, mean_value, values)`` after each step, with
    ``values = exp(theta)`` after the update.
    """
    if not 0.0 < decay <= 1.0:
        raise ValueError(f"decay must be in (0, 1], got {decay}")
    dtype = jnp.asarray(theta).dtype
    theta = jnp.asarray(theta)
    schedule = optax.cosine_decay_schedule(learning_rate, max(steps, 1), alpha=decay)
    optimiser = optax.adam(schedule)
    opt_state = optimiser.init(theta)
    base = jax.random.PRNGKey(seed)
    curve, variances, path = [], [], [np.exp(np.asarray(theta, float)).tolist()]
    start = time.perf_counter()
    keys = jax.random.split(jax.random.fold_in(base, 0), filters)
    compiled = objective.lower(keys, theta, *args).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    for i in range(steps):
        keys = jax.random.split(jax.random.fold_in(base, i), filters)
        values, grads = compiled(keys, theta, *args)
        values, grads = np.asarray(values, float), np.asarray(grads, float)
        ok = np.isfinite(values) & np.all(np.isfinite(grads), axis=1)
        if not ok.any():
            raise FloatingPointError(f"step {i}: no filter gave a finite log-likelihood and gradient at {path[-1]}")
        curve.append(float(values[ok].mean()))
        variances.append(grads[ok].var(0).tolist())
        # Adam minimises: ascend the log-likelihood.
        updates, opt_state = optimiser.update(jnp.asarray(-grads[ok].mean(0), dtype), opt_state, theta)
        theta = optax.apply_updates(theta, updates)
        path.append(np.exp(np.asarray(theta, float)).tolist())
        if callback is not None:
            callback(i, curve[-1], path[-1])
    return Ascent(curve, variances, path, compile_s, time.perf_counter() - start)


def select_by_validation(scores: Any, margin: float = 2.0, guard: Any = None) -> int:
    """The candidate to keep from held-out scores ``(candidates, filters)``, candidate
    0 being the start: the best mean, if its paired difference to the start exceeds
    ``margin`` standard errors (and 0); else 0. Filters with a non-finite score for
    either candidate count as infinitely bad for the candidate that has it. With
    ``guard`` (same shape: the held-out scores of the filter you will run) only the
    candidates whose every guard score is at least the start's are considered."""
    scores = np.asarray(scores, float)
    if scores.ndim != 2 or scores.shape[0] < 1 or scores.shape[1] < 1:
        raise ValueError(f"scores must be (candidates, filters), got shape {scores.shape}")
    scores = np.where(np.isnan(scores), -np.inf, scores)
    means = scores.mean(1)
    if guard is not None:
        guard = np.asarray(guard, float)
        if guard.shape != scores.shape:
            raise ValueError(f"guard must have the scores' shape {scores.shape}, got {guard.shape}")
        guard = np.where(np.isnan(guard), -np.inf, guard)
        admissible = np.all(guard >= guard[0], axis=1)
        means = np.where(admissible, means, -np.inf)
        means[0] = scores[0].mean()
    best = int(np.argmax(means))
    if best == 0 or not np.isfinite(means[best]):
        return 0
    if not np.isfinite(means[0]):
        return best
    diff = scores[best] - scores[0]
    n = diff.shape[0]
    se = float(diff.std(ddof=1) / np.sqrt(n)) if n > 1 else 0.0
    return best if diff.mean() > max(margin * se, 0.0) else 0


def validation_steps(steps: int, every: int) -> list[int]:
    """Candidate iterates: ``0, every, 2 every, ...`` and the last, ``steps``."""
    if every < 1:
        raise ValueError(f"validate_every must be >= 1, got {every}")
    return sorted(set(range(0, steps + 1, every)) | {steps})


def validate(
    score: Callable[[jax.Array, Any], Any],
    trajectory: Sequence[Sequence[float]],
    steps: list[int],
    filters: int,
    seed: int,
    margin: float,
    guard: Callable[[jax.Array, Any], Any] | None = None,
) -> tuple[list[list[float]], list[list[float]] | None, int]:
    """Held-out scores ``score(keys (filters,), theta) -> (filters,)`` of the candidate
    iterates ``trajectory[steps]`` with one set of keys for all (common random
    numbers), the same of ``guard`` (None without), and the index into ``steps`` that
    :func:`select_by_validation` keeps."""
    # Keys apart from the training keys (those are fold_in(PRNGKey(seed), step)).
    keys = jax.random.split(jax.random.split(jax.random.PRNGKey(seed))[1], filters)
    thetas = [jnp.log(jnp.asarray(trajectory[s])) for s in steps]
    scores = [np.asarray(score(keys, th), float).tolist() for th in thetas]
    guards = None if guard is None else [np.asarray(guard(keys, th), float).tolist() for th in thetas]
    return scores, guards, select_by_validation(scores, margin, guards)


def split_window(window: int, validation: float) -> int:
    """The scans fitted, ``window - round(validation * window)`` (both parts >= 1 scan)."""
    if not 0.0 <= validation < 1.0:
        raise ValueError(f"validation must be a fraction in [0, 1), got {validation}")
    held = int(round(validation * window))
    if validation > 0 and (held < 1 or window - held < 1):
        raise ValueError(f"a window of {window} scans cannot be split {1 - validation:.2f} / {validation:.2f}")
    return window - held


def select_iterate(
    ascent: Ascent,
    seed: int,
    score: Callable[[jax.Array, Any], Any] | None = None,
    window: tuple[int, int, int] = (0, 0, 0),
    validate_every: int = 5,
    validation_filters: int = 8,
    validation_margin: float = 2.0,
    guard: Callable[[jax.Array, Any], Any] | None = None,
) -> tuple[int, int, Validation | None]:
    """The iterate of an :func:`ascend` to keep: ``(kept step, step with the best
    training objective, validation record)``. With ``score(keys, theta) -> (filters,)``
    held-out scores, the kept step is chosen by :func:`validate` on ``window =
    (fit_scans, scans, validation particles)``; without, it is the best training step."""
    train_best = int(np.argmax(ascent.log_likelihood))
    if score is None:
        return train_best, train_best, None
    start = time.perf_counter()
    candidates = validation_steps(len(ascent.log_likelihood), validate_every)
    scores, guards, chosen = validate(score, ascent.trajectory, candidates, validation_filters, seed,
                                      validation_margin, guard)
    record = Validation(*window[:2], validation_filters, window[2], validation_margin, candidates, scores, chosen,
                        time.perf_counter() - start, guard_scores=guards)
    return candidates[chosen], train_best, record
