"""The models: one :class:`~mdgs.models.base.Simulator` contract and the registry every command reads.

:data:`MODELS` maps a name (``mdgs train --model NAME``, study files) to its class; each class
carries its ``Config`` dataclass (every default documented) and a one-line ``summary``.
"""

from __future__ import annotations

from mdgs.models.base import (
    Batch,
    ModelError,
    Simulator,
    State,
    batch_of,
    compile_step,
    one_step_error,
)
from mdgs.models.gns import GNS
from mdgs.models.hgns import HGNS
from mdgs.models.lgns import LGNS
from mdgs.models.mdgs import MDGS, MDGSNoConstraint, MDGSSingleSpeed
from mdgs.models.references import ConstantTwist, MuJoCoReference
from mdgs.models.sgnn import SGNN, SGNNSnap

__all__ = ["MODELS", "LEARNED", "REFERENCES", "Simulator", "State", "Batch", "ModelError", "batch_of", "compile_step", "one_step_error",
           "get_model"]

#: name -> Simulator class: the one registry the CLI, the trainer, the evaluator and the study read.
#: Learned models first (the paper's method, its ablations, then the peers), then the references.
MODELS: dict[str, type[Simulator]] = {
    cls.name: cls for cls in (MDGS, MDGSNoConstraint, MDGSSingleSpeed, GNS, SGNN, SGNNSnap, LGNS, HGNS, ConstantTwist, MuJoCoReference)
}
#: Names of the models that are trained.
LEARNED = tuple(n for n, c in MODELS.items() if c.learned)
#: Names of the non-learned references.
REFERENCES = tuple(n for n, c in MODELS.items() if not c.learned)


def get_model(name: str) -> type[Simulator]:
    """The class registered as ``name``; ModelError naming the known models otherwise."""
    if name not in MODELS:
        raise ModelError(f"unknown model {name!r}; choose one of {', '.join(MODELS)}")
    return MODELS[name]
