"""validation: runs the checks of :mod:`kane`, decides verdicts, reports them (CLI, JSON, docs)."""

__all__: list[str] = []
