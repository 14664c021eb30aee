"""Dataset sizes: the presets of ``mdgs generate --preset``.

Every preset keeps the paper's 110 frames per trajectory (Appendix B.4) and differs
only in the number of trajectories. The generalization variants (Table 3) are test
sets only and use the preset's test size.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Preset", "PRESETS", "split_counts"]


@dataclass(frozen=True)
class Preset:
    """How many trajectories a split gets, and how they are batched into part files."""

    name: str
    train: int
    valid: int
    test: int
    n_frames: int = 110
    """Frames per trajectory (the paper's 110 time steps)."""
    batch: int = 10
    """Trajectories per part file: the unit of work, of resume and of sharding."""

    def counts(self, splits: tuple[str, ...]) -> dict[str, int]:
        return {s: getattr(self, s) for s in splits}


PRESETS: dict[str, Preset] = {
    # CI-sized: 4 trajectories per scene, seconds per scene.
    "tiny": Preset("tiny", train=2, valid=1, test=1, batch=2),
    # A development set: 60 trajectories per scene.
    "small": Preset("small", train=40, valid=10, test=10, batch=10),
    # The paper's scale: 2200 trajectories per scene (Appendix B.4). The paper gives no
    # split; 2000/100/100 keeps 91 % for training and 100 trajectories (11,000 frames)
    # per evaluation split, enough for the mean +- std of rollout MSE of Tables 1-3.
    "paper": Preset("paper", train=2000, valid=100, test=100, batch=50),
}


def split_counts(n_traj: int, splits: tuple[str, ...]) -> dict[str, int]:
    """Counts for ``--n-traj N``: the paper's proportions (100/2200 each for valid and test)."""
    if len(splits) == 1:  # one split alone (a long test or validation set): all of them
        return {splits[0]: n_traj}
    if n_traj < len(splits):
        raise ValueError(
            f"--n-traj {n_traj} is too small: each of {', '.join(splits)} needs at least one trajectory"
        )
    held = max(1, round(n_traj * 100 / 2200))
    out = {s: held for s in splits if s != "train"}
    out["train"] = n_traj - sum(out.values())
    return {s: out[s] for s in splits}
