"""A late sample predicted from the ones before it: the linear predictor of a real-time
node's stale input.

In real time nobody waits: a force servo controller acts on a reference force that has not
arrived (``seft_ros.core.controller.ReferencePlayout``), and a rig outputs a valve command
that has not arrived (``seft_plant_sim.realtime.WallClockRig`` with ``realtime_late_command:
predict``). Both predict the missing sample from the ones they received, with the same
linear predictor (:class:`SampleHistory`): the nodes share it from here, below both.

Imports numpy only.

References
----------
J. Makhoul (1975), Linear prediction: a tutorial review, Proc. IEEE 63(4), 561-580 (the
covariance method, Sec. III).
"""

import numpy as np

__all__ = ['SampleHistory', 'PREDICTION_ORDER', 'PREDICTION_WINDOW_S', 'PREDICTION_RIDGE',
           'window_steps']

#: Order of the linear predictor of a late sample [samples].
PREDICTION_ORDER = 8
#: Span of samples the predictor is fitted to [s].
PREDICTION_WINDOW_S = 0.5
#: Ridge weight of the predictor's fit, relative to the mean power of its regressors.
PREDICTION_RIDGE = 1e-6


def window_steps(dt: float) -> int:
    """The samples :data:`PREDICTION_WINDOW_S` spans at the sample period `dt` [s]."""
    return int(round(PREDICTION_WINDOW_S / float(dt)))


class SampleHistory:
    """The last `window` samples of a signal, by step, and the linear prediction of a later
    one.

    :meth:`predict` fits a linear predictor of order :data:`PREDICTION_ORDER` to the
    `window` samples up to a step by least squares (the autocorrelation-free *covariance
    method*, Makhoul 1975, with a ridge of :data:`PREDICTION_RIDGE` times the regressors'
    mean power) and runs it ahead. The signals of a test (a reference force, a valve
    command) are dominated by its lightly damped modes, which such a predictor follows
    exactly (an AR(2) predicts a sinusoid without error). It declines (None) where the
    history is not contiguous or its one-step residual over the window is no smaller than
    linear extrapolation's: the caller then extrapolates linearly.

    Parameters
    ----------
    window : int >= 4 * PREDICTION_ORDER
        Samples the predictor is fitted to.
    spare : int >= 0
        Samples newer than the one predicted from that the history may hold without losing
        the window (a rig stores a command as it arrives, before it acts: a stall's
        commands arrive together).

    Raises
    ------
    ValueError
        `window` too short, or `spare` negative.
    """

    def __init__(self, window: int, spare: int = 0):
        window = int(window)
        if window < 4 * PREDICTION_ORDER:
            raise ValueError(f'prediction window {window!r}: expected at least '
                             f'{4 * PREDICTION_ORDER} samples')
        if int(spare) < 0:
            raise ValueError(f'spare samples {spare!r}: expected >= 0')
        self.window = window
        size = window + PREDICTION_ORDER + int(spare)
        self._values = np.zeros(size)                         # x[j] at j % size
        self._steps = np.full(size, -1, dtype=np.int64)

    def store(self, step: int, value: float) -> None:
        """Sample `step` of the signal (any order; an older one than the slot holds is
        dropped, a repeat replaces it)."""
        i = step % self._values.size
        if step >= self._steps[i]:
            self._values[i] = value
            self._steps[i] = step

    def value(self, step: int) -> float | None:
        """Sample `step` if the history holds it, else None."""
        i = step % self._values.size
        return float(self._values[i]) if self._steps[i] == step else None

    def predict(self, newest: int, ahead: int) -> float | None:
        """``x[newest + ahead]`` by the linear predictor fitted to the samples up to
        `newest` (None: too few of them in a row, or linear extrapolation fits better)."""
        size = self._values.size
        steps = np.arange(newest - self.window - PREDICTION_ORDER + 1, newest + 1)
        if steps[0] < 0 or not np.array_equal(self._steps[steps % size], steps):
            return None
        x = self._values[steps % size]
        p = PREDICTION_ORDER
        # rows: x[i-1], ..., x[i-p] -> x[i]
        regressors = np.lib.stride_tricks.sliding_window_view(x[:-1], p)[:, ::-1]
        target = x[p:]
        gram = regressors.T @ regressors
        ridge = PREDICTION_RIDGE * np.trace(gram) / p
        try:
            coef = np.linalg.solve(gram + ridge * np.eye(p), regressors.T @ target)
        except np.linalg.LinAlgError:
            return None
        residual = target - regressors @ coef
        linear = target[1:] - (2.0 * x[p:-1] - x[p - 1:-2])
        if not (np.all(np.isfinite(coef))
                and residual[1:] @ residual[1:] < linear @ linear):
            return None
        recent = list(x[-p:][::-1])                  # x[newest], x[newest - 1], ...
        for _ in range(ahead):
            recent.insert(0, float(np.dot(coef, recent[:p])))
        return recent[0]
