"""``python -m validation`` is ``mdgs validate``."""

from validation.cli import validate_main

if __name__ == "__main__":
    validate_main()
