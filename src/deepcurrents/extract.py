"""Kept so that ``python -m deepcurrents.extract`` still works; the command is ``deepcurrents.cli.extract``
(console script ``deepcurrents-extract``)."""

from deepcurrents.cli.extract import main

if __name__ == "__main__":
    main()
