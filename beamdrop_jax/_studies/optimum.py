"""What the optimisers return: `optimize_placement` moves the board, `optimize_mounts` the screws; both report
the best found, its objective and the scene's own, the history, and what it cost."""

import abc

import equinox as eqx
from jaxtyping import Array, Float

from .._common.report import summary_text


class AbstractOptimum(eqx.Module):
    """The outcome of an optimiser: `value` (the objective of the best found), `initial_value` (the scene's own),
    `history` (the objective per step of the best start), `n_evaluations` (objective evaluations, each with its
    gradient), `n_drops` (drops per evaluation), `objective` ("mean", "max" or "cvar")."""

    value: eqx.AbstractVar[Float[Array, ""]]
    initial_value: eqx.AbstractVar[Float[Array, ""]]
    history: eqx.AbstractVar[Float[Array, " steps"]]
    n_evaluations: eqx.AbstractVar[int]
    n_drops: eqx.AbstractVar[int]
    objective: eqx.AbstractVar[str]

    @abc.abstractmethod
    def summary(self) -> dict:
        """Before and after, units in the keys."""

    def __repr__(self) -> str:
        return summary_text(self.summary(), type(self).__name__)
