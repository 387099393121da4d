"""Kept so that ``python -m deepcurrents.generate`` still works; the command is ``deepcurrents.cli.generate``
(console script ``deepcurrents-generate``)."""

from deepcurrents.cli.generate import main

if __name__ == "__main__":
    main()
