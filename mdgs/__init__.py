"""mdgs: scenes -> datasets -> graphs -> models -> training -> rollouts (the MDGS simulator)."""

__all__: list[str] = []
