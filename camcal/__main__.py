"""``python -m camcal``: the same as the ``camcal`` command."""

from camcal.cli import main

if __name__ == "__main__":
    main()
