"""``python -m mdgs.cli`` is the ``mdgs`` command (also under ``torchrun``)."""

from mdgs.cli import app

if __name__ == "__main__":
    app()
