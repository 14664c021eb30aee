"""kane: Kane's method, the MDGS paper's claims, and the checks that decide them.

Imports without torch. Public API is listed in ``__all__``.
"""

__all__: list[str] = []
