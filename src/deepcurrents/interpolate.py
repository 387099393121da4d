"""Kept so that ``python -m deepcurrents.interpolate`` still works; the command is ``deepcurrents.cli.interpolate``
(console script ``deepcurrents-interpolate``)."""

from deepcurrents.cli.interpolate import main

if __name__ == "__main__":
    main()
