"""Kept so that ``python -m deepcurrents.evaluate`` still works; the command is ``deepcurrents.cli.evaluate``
(console script ``deepcurrents-evaluate``)."""

from deepcurrents.cli.evaluate import main

if __name__ == "__main__":
    main()
