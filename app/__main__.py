"""``python -m app --help``: the command line (:mod:`app.cli`)."""

from app.cli import main

if __name__ == "__main__":
    main()
