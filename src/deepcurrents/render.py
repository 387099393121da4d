"""Kept so that ``python -m deepcurrents.render`` still works; the command is ``deepcurrents.cli.render``
(console script ``deepcurrents-render``)."""

from deepcurrents.cli.render import main

if __name__ == "__main__":
    main()
